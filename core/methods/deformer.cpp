#include "core/methods/deformer.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>

#include "core/mesh/measures.h"
#include "core/mesh/topology.h"
#include "core/mesh/validate.h"
#include "core/methods/arap.h"
#include "core/methods/constraints.h"
#include "core/methods/scale_aware.h"
#include "core/multires/multilevel.h"
#include "core/multires/multires.h"

namespace meshdeform::core {

std::uint64_t coarse_level_key(const Triangles& F, const Eigen::VectorXi& to_fine) {
  std::uint64_t hash = 14695981039346656037ull;  // FNV-1a offset basis
  const auto mix = [&hash](std::int64_t value) {
    for (int byte = 0; byte < 8; ++byte) {
      hash ^= static_cast<std::uint64_t>(value >> (8 * byte)) & 0xffu;
      hash *= 1099511628211ull;  // FNV prime
    }
  };
  mix(to_fine.size());
  for (Eigen::Index i = 0; i < to_fine.size(); ++i) mix(to_fine(i));
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int c = 0; c < 3; ++c) mix(F(f, c));
  }
  return hash;
}

namespace {

using Clock = std::chrono::steady_clock;

// The iterative solvers already have the Deformer shape: the adapter only forwards.
// For scale-aware, options go through unchanged: options.lambda must equal DeformerSettings::lambda.
template <typename Solver, Method kMethod>
class SolverDeformer final : public Deformer {
 public:
  explicit SolverDeformer(Solver solver) : solver_(std::move(solver)) {}
  Method method() const override { return kMethod; }
  Result<SolveReport> solve(const Positions& targets, const SolveOptions& options,
                            const ProgressCallback& progress, std::stop_token stop) override {
    if constexpr (kMethod == Method::Arap) {
      // ARAP's rotation-aware starts are the scale-aware solver's: here they are its Laplacian
      // guess.
      if (options.start == StartFrom::Rigid || options.start == StartFrom::Propagated ||
          options.start == StartFrom::Paper) {
        SolveOptions laplacian_start = options;
        laplacian_start.start = StartFrom::Laplacian;
        return solver_.solve(targets, laplacian_start, progress, std::move(stop));
      }
    }
    return solver_.solve(targets, options, progress, std::move(stop));
  }
  const Positions& positions() const override { return solver_.positions(); }
  const Eigen::VectorXi& constrained() const override { return solver_.constrained(); }
  void reset() override { solver_.reset(); }

 private:
  Solver solver_;
};
using ScaleAwareDeformer = SolverDeformer<ScaleAwareSolver, Method::ScaleAware>;
using ArapDeformer = SolverDeformer<ArapSolver, Method::Arap>;

// Scale-aware through a coarse level (DeformerSettings::multires_above): moves solve on the
// coarse level and are prolonged; full_resolution, ORA and magnification (per fine face) solve at
// full resolution, warm-started from the prolonged result.
class MultiresScaleAwareDeformer final : public Deformer {
 public:
  MultiresScaleAwareDeformer(MultiresDeformer multires, const Eigen::VectorXi& constrained)
      : multires_(std::move(multires)), constrained_(constrained) {}
  Method method() const override { return Method::ScaleAware; }
  Result<SolveReport> solve(const Positions& targets, const SolveOptions& options,
                            const ProgressCallback& progress, std::stop_token stop) override {
    if (options.full_resolution) return multires_.refine(targets, options, progress, std::move(stop));
    if (options.ora || options.face_scale.size() > 0) {
      // A move that needs the full resolution continues from the drag's prolonged result: the
      // refinement's cascade (seconds at 10^5 vertices) is not a move's to run.
      SolveOptions warm = options;
      warm.multilevel = false;
      return multires_.refine(targets, warm, progress, std::move(stop));
    }
    MD_ASSIGN_OR_RETURN(MultiresMove move, multires_.move(targets, options, progress, std::move(stop)));
    SolveReport report = std::move(move.coarse);
    if (!coarse_mesh_) {
      const MeshLevel& level = multires_.hierarchy().level(multires_.coarse_level());
      auto mesh = std::make_shared<CoarseLevelMesh>();
      mesh->F = level.F;
      mesh->to_fine = level.to_fine;
      mesh->key = coarse_level_key(mesh->F, mesh->to_fine);
      coarse_mesh_ = std::move(mesh);
    }
    report.coarse = std::make_shared<const CoarseLevelPositions>(
        CoarseLevelPositions{coarse_mesh_, std::move(report.V)});
    report.V = std::move(move.V);
    report.seconds += move.prolong_seconds;
    report.converged = false;  // the full resolution has not been solved
    return report;
  }
  const Positions& positions() const override { return multires_.positions(); }
  const Eigen::VectorXi& constrained() const override { return constrained_; }
  void reset() override { multires_.reset(); }

  bool needs_background_build() const override { return multires_.needs_fine_solver(); }
  BackgroundBuild background_build(const SolveOptions& next) override {
    std::optional<MultiresDeformer::FineSolverInputs> inputs =
        multires_.fine_solver_inputs(next.rigidity);
    if (!inputs) return {};
    auto shared = std::make_shared<const MultiresDeformer::FineSolverInputs>(std::move(*inputs));
    return [shared, id = id_](std::stop_token stop) -> Result<Installer> {
      MD_ASSIGN_OR_RETURN(MultilevelSolver built,
                          MultiresDeformer::build_fine_solver(*shared, std::move(stop)));
      // std::function needs a copyable callable: the solver travels in a shared_ptr.
      auto solver = std::make_shared<MultilevelSolver>(std::move(built));
      return Installer([solver, id](Deformer& deformer) {
        auto* target = dynamic_cast<MultiresScaleAwareDeformer*>(&deformer);
        if (target == nullptr || target->id_ != id) return;  // not the deformer it was built for
        target->multires_.install_fine_solver(std::move(*solver));
      });
    };
  }

 private:
  MultiresDeformer multires_;
  Eigen::VectorXi constrained_;
  std::shared_ptr<const CoarseLevelMesh> coarse_mesh_;  // made with the first move
  // Tells a background build's installer which deformer it was built for (addresses get reused).
  const std::uint64_t id_ = next_id();
  static std::uint64_t next_id() {
    static std::atomic<std::uint64_t> counter{0};
    return ++counter;
  }
};

// Scale-aware through a multilevel solver (DeformerSettings::multilevel_above): a cold Auto solve
// runs the cascade, everything else the full-resolution solver.
class MultilevelScaleAwareDeformer final : public Deformer {
 public:
  MultilevelScaleAwareDeformer(MultilevelSolver solver, const Eigen::VectorXi& constrained)
      : solver_(std::move(solver)), constrained_(constrained) {}
  Method method() const override { return Method::ScaleAware; }
  Result<SolveReport> solve(const Positions& targets, const SolveOptions& options,
                            const ProgressCallback& progress, std::stop_token stop) override {
    // The cascade replaces the rigid start of Auto; at rigidity 0 Auto is the paper's Laplacian
    // start, which stays the single-level solve (the paper mode, unchanged).
    const bool cascade = options.multilevel && options.start == StartFrom::Auto &&
                         options.rigidity > 0 && !warm_;
    Result<SolveReport> report = cascade
                                     ? solver_.solve(targets, options, progress, std::move(stop))
                                     : solver_.fine().solve(targets, options, progress,
                                                            std::move(stop));
    if (report.ok()) warm_ = true;
    return report;
  }
  const Positions& positions() const override { return solver_.fine().positions(); }
  const Eigen::VectorXi& constrained() const override { return constrained_; }
  void reset() override {
    solver_.fine().reset();
    warm_ = false;
  }

 private:
  MultilevelSolver solver_;
  Eigen::VectorXi constrained_;
  bool warm_ = false;  // the full-resolution solver holds a result to continue from
};

// Laplacian editing is one direct solve: no iterations, no start, nothing to warm.
class LaplacianDeformer final : public Deformer {
 public:
  LaplacianDeformer(LaplacianEditor editor, const Positions& V0, const Triangles& F,
                    MeshTopology topology, const Eigen::VectorXi& constrained, double lambda)
      : editor_(std::move(editor)),
        V0_(V0),
        F_(F),
        topology_(std::move(topology)),
        constrained_(constrained),
        lambda_(lambda),
        bbox_diagonal_((V0.colwise().maxCoeff() - V0.colwise().minCoeff()).norm()),
        current_(V0) {}

  Method method() const override { return Method::Laplacian; }

  Result<SolveReport> solve(const Positions& targets, const SolveOptions& options,
                            const ProgressCallback& progress, std::stop_token stop) override {
    const auto start = Clock::now();
    if (options.ora || options.face_scale.size() != 0) {
      return Error(ErrorCode::InvalidArgument,
                   std::string("ORA and magnification belong to the scale-aware method, not "
                               "Laplacian editing (") +
                       (options.ora ? "ora is set" : "face_scale is not empty") + ")");
    }
    MD_RETURN_IF_ERROR(check_targets(targets, constrained_, topology_, bbox_diagonal_, false));
    if (options.lambda != lambda_) {
      return Error(ErrorCode::InvalidArgument, "lambda is fixed when the deformer is created (" +
                                                   std::to_string(lambda_) + "); got " +
                                                   std::to_string(options.lambda));
    }
    if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "solve cancelled");
    MD_ASSIGN_OR_RETURN(Positions V, editor_.solve(targets));

    IterationInfo info;
    info.linear_seconds = std::chrono::duration<double>(Clock::now() - start).count();
    if (options.track_metrics) {
      if (!rest_) rest_ = compute_measures(V0_, F_, topology_);
      const AngleErrors errors = angle_errors(*rest_, V, F_, topology_);
      info.e_theta = errors.e_theta;
      info.e_phi = errors.e_phi;
    }
    info.elapsed_seconds = std::chrono::duration<double>(Clock::now() - start).count();
    SolveReport report;
    report.start = StartFrom::Laplacian;  // a direct solve: no start of its own
    report.history.push_back(info);
    report.converged = true;  // a direct solve is exact
    if (progress) progress(info);

    current_ = V;
    report.V = std::move(V);
    report.seconds = std::chrono::duration<double>(Clock::now() - start).count();
    return report;
  }

  const Positions& positions() const override { return current_; }
  const Eigen::VectorXi& constrained() const override { return constrained_; }
  void reset() override { current_ = V0_; }

 private:
  LaplacianEditor editor_;
  Positions V0_;
  Triangles F_;
  MeshTopology topology_;
  Eigen::VectorXi constrained_;
  double lambda_ = 0;
  double bbox_diagonal_ = 1;
  std::optional<Measures> rest_;  // computed on the first solve that tracks metrics
  Positions current_;
};

}  // namespace

const char* method_name(Method method) {
  switch (method) {
    case Method::ScaleAware:
      return "scale_aware";
    case Method::Arap:
      return "arap";
    case Method::Laplacian:
      return "laplacian";
  }
  return "unknown";
}

Result<Method> parse_method(std::string_view name) {
  if (name == "scale_aware" || name == "scale-aware") return Method::ScaleAware;
  if (name == "arap") return Method::Arap;
  if (name == "laplacian") return Method::Laplacian;
  return Error(ErrorCode::InvalidArgument,
               "unknown method \"" + std::string(name) +
                   "\" (expected \"scale_aware\", \"arap\" or \"laplacian\")");
}

const char* start_name(StartFrom start) {
  switch (start) {
    case StartFrom::Auto:
      return "auto";
    case StartFrom::Laplacian:
      return "laplacian";
    case StartFrom::Previous:
      return "previous";
    case StartFrom::Rigid:
      return "rigid";
    case StartFrom::Propagated:
      return "propagated";
    case StartFrom::Paper:
      return "paper";
  }
  return "auto";
}

Result<StartFrom> parse_start(std::string_view name) {
  for (StartFrom start : {StartFrom::Auto, StartFrom::Laplacian, StartFrom::Previous,
                          StartFrom::Rigid, StartFrom::Propagated, StartFrom::Paper}) {
    if (name == start_name(start)) return start;
  }
  return Error(ErrorCode::InvalidArgument,
               "unknown start \"" + std::string(name) +
                   "\" (expected auto, laplacian, previous, rigid, propagated or paper)");
}

namespace {

/// The multilevel solver's settings of a deformer (a cold solve's cascade, and the
/// multiresolution deformer's refinement).
MultilevelSettings multilevel_settings(const ScaleAwareSettings& solver,
                                       const DeformerSettings& settings) {
  MultilevelSettings multilevel;
  multilevel.solver = solver;
  multilevel.coarsest_vertices = std::max(settings.multilevel_coarsest_vertices, 100);
  multilevel.threads = std::max(1, settings.threads);
  return multilevel;
}

/// make_deformer; `checked` (may be null) is the topology of a mesh the caller validated.
Result<std::unique_ptr<Deformer>> make_deformer_impl(Method method, const Positions& V0,
                                                     const Triangles& F,
                                                     const MeshTopology* checked,
                                                     const Eigen::VectorXi& constrained,
                                                     const DeformerSettings& settings,
                                                     std::stop_token stop,
                                                     const BuildProgress& progress) {
  if (stop.stop_requested()) {
    return Error(ErrorCode::Cancelled, "precompute cancelled (deadline or client)");
  }
  switch (method) {
    case Method::ScaleAware: {
      ScaleAwareSettings s;
      s.lambda = settings.lambda;
      s.threads = settings.threads;
      s.refactor_cost_ratio = settings.refactor_cost_ratio;
      s.preconditioner = settings.preconditioner;
      if (settings.multires_above > 0 && V0.rows() > settings.multires_above &&
          V0.rows() > 2 * static_cast<Eigen::Index>(settings.multires_coarse_vertices)) {
        MultiresDeformerSettings multires;
        multires.solver = s;
        multires.hierarchy.level_vertices = {std::max(settings.multires_coarse_vertices, 3)};
        // Big handle regions would keep the coarse level large: only their borders are kept.
        multires.hierarchy.constraint_levels = ConstraintLevels::KeepBorders;
        multires.hierarchy.threads = std::max(1, settings.threads);
        // Refinement after a drag runs the multilevel cascade where a cold solve would.
        if (settings.multilevel_above > 0 && V0.rows() > settings.multilevel_above) {
          multires.refine_cascade = true;
          multires.cascade = multilevel_settings(s, settings);
          // A move preempts refinement: no full-resolution factorization inside a cascade.
          multires.cascade.keep_fine_start = true;
        }
        MD_ASSIGN_OR_RETURN(
            MultiresDeformer built,
            checked != nullptr
                ? MultiresDeformer::create(V0, F, *checked, constrained, multires, progress, stop)
                : MultiresDeformer::create(V0, F, constrained, multires, progress, stop));
        return std::unique_ptr<Deformer>(
            std::make_unique<MultiresScaleAwareDeformer>(std::move(built), constrained));
      }
      if (settings.multilevel_above > 0 && V0.rows() > settings.multilevel_above) {
        const MultilevelSettings multilevel = multilevel_settings(s, settings);
        MD_ASSIGN_OR_RETURN(
            MultilevelSolver built,
            checked != nullptr
                ? MultilevelSolver::create(V0, F, *checked, constrained, multilevel, progress, stop)
                : MultilevelSolver::create(V0, F, constrained, multilevel, progress, stop));
        return std::unique_ptr<Deformer>(
            std::make_unique<MultilevelScaleAwareDeformer>(std::move(built), constrained));
      }
      MD_ASSIGN_OR_RETURN(ScaleAwareSolver solver,
                          checked != nullptr
                              ? ScaleAwareSolver::create(V0, F, *checked, constrained, s, stop,
                                                         progress)
                              : ScaleAwareSolver::create(V0, F, constrained, s, stop, progress));
      return std::unique_ptr<Deformer>(std::make_unique<ScaleAwareDeformer>(std::move(solver)));
    }
    case Method::Arap: {
      ArapSettings s;
      s.threads = settings.threads;
      report_progress(progress, "factorize", 0.0);
      MD_ASSIGN_OR_RETURN(ArapSolver solver,
                          checked != nullptr ? ArapSolver::create(V0, F, *checked, constrained, s)
                                             : ArapSolver::create(V0, F, constrained, s));
      report_progress(progress, "factorize", 1.0);
      return std::unique_ptr<Deformer>(std::make_unique<ArapDeformer>(std::move(solver)));
    }
    case Method::Laplacian: {
      report_progress(progress, "factorize", 0.0);
      MeshTopology topology;
      if (checked != nullptr) {
        topology = *checked;
      } else {
        MD_RETURN_IF_ERROR(validate_triangle_mesh(V0, F));
        MD_ASSIGN_OR_RETURN(topology, build_topology(F, static_cast<int>(V0.rows())));
      }
      MD_ASSIGN_OR_RETURN(LaplacianEditor editor,
                          LaplacianEditor::create(V0, F, topology, constrained,
                                                  settings.laplacian_weights, settings.lambda));
      report_progress(progress, "factorize", 1.0);
      return std::unique_ptr<Deformer>(std::make_unique<LaplacianDeformer>(
          std::move(editor), V0, F, std::move(topology), constrained, settings.lambda));
    }
  }
  return Error(ErrorCode::InvalidArgument,
               "unknown method " + std::to_string(static_cast<int>(method)));
}

}  // namespace

Result<std::unique_ptr<Deformer>> make_deformer(Method method, const Positions& V0,
                                                const Triangles& F,
                                                const Eigen::VectorXi& constrained,
                                                const DeformerSettings& settings,
                                                std::stop_token stop,
                                                const BuildProgress& progress) {
  return make_deformer_impl(method, V0, F, nullptr, constrained, settings, std::move(stop),
                            progress);
}

Result<std::unique_ptr<Deformer>> make_deformer(Method method, const Positions& V0,
                                                const Triangles& F, const MeshTopology& topology,
                                                const Eigen::VectorXi& constrained,
                                                const DeformerSettings& settings,
                                                std::stop_token stop,
                                                const BuildProgress& progress) {
  MD_ASSERT(topology.vertex_count == V0.rows() && topology.face_count == F.rows());
  return make_deformer_impl(method, V0, F, &topology, constrained, settings, std::move(stop),
                            progress);
}

}  // namespace meshdeform::core
