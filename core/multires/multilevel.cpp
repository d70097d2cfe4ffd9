#include "core/multires/multilevel.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/mesh/measures.h"
#include "core/mesh/validate.h"
#include "core/methods/arap.h"
#include "core/methods/constraints.h"
#include "core/multires/multires.h"

namespace meshdeform::core {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

Status check_settings(const MultilevelSettings& s) {
  if (s.coarsest_vertices < 100) {
    return Error(ErrorCode::InvalidArgument, "multilevel coarsest_vertices must be >= 100, got " +
                                                 std::to_string(s.coarsest_vertices));
  }
  if (s.level_ratio < 2) {
    return Error(ErrorCode::InvalidArgument,
                 "multilevel level_ratio must be >= 2, got " + std::to_string(s.level_ratio));
  }
  if (!(s.min_reduction > 0 && s.min_reduction < 1)) {
    return Error(ErrorCode::InvalidArgument, "multilevel min_reduction must be in (0, 1), got " +
                                                 std::to_string(s.min_reduction));
  }
  if (!std::isfinite(s.level_tolerance)) {
    return Error(ErrorCode::InvalidArgument, "multilevel level_tolerance must be finite");
  }
  if (!std::isfinite(s.start_level_tolerance)) {
    return Error(ErrorCode::InvalidArgument, "multilevel start_level_tolerance must be finite");
  }
  if (s.fine_start_max_iterations < 1) {
    return Error(ErrorCode::InvalidArgument,
                 "multilevel fine_start_max_iterations must be >= 1, got " +
                     std::to_string(s.fine_start_max_iterations));
  }
  if (s.start_max_iterations < 1) {
    return Error(ErrorCode::InvalidArgument, "multilevel start_max_iterations must be >= 1, got " +
                                                 std::to_string(s.start_max_iterations));
  }
  if (s.level_max_iterations < 1) {
    return Error(ErrorCode::InvalidArgument, "multilevel level_max_iterations must be >= 1, got " +
                                                 std::to_string(s.level_max_iterations));
  }
  if (s.fine_corrections < 0 || s.fine_correction_interval < 1) {
    return Error(ErrorCode::InvalidArgument,
                 "multilevel fine_corrections must be >= 0 and fine_correction_interval >= 1");
  }
  if (s.threads < 1) {
    return Error(ErrorCode::InvalidArgument,
                 "multilevel threads must be >= 1, got " + std::to_string(s.threads));
  }
  return Status::success();
}

}  // namespace

struct MultilevelSolver::Impl {
  MultilevelSettings settings;
  Positions V;
  Triangles F;
  MeshTopology topology;
  Eigen::VectorXi constrained;  // the caller's order (the fine targets' rows)
  double bbox_diagonal = 1;
  Eigen::VectorXd rest_phi;     // folds of the result
  std::optional<MeshHierarchy> hierarchy;
  /// Hierarchy levels used, full resolution first: used[i + 1] is coarser than used[i].
  std::vector<int> used;
  /// level_topology[i]: the connectivity of level i >= 1, built once at build (MeshHierarchy
  /// validated the level; level 0's is `topology`), for its prolongation and its solvers.
  std::vector<MeshTopology> level_topology;
  /// prolongation[i]: level used[i + 1] -> level used[i].
  std::vector<Prolongation> prolongation;
  /// restriction_rows[i]: the rows of level i + 1's vertices among level i's (what
  /// prolongation[i] was built with).
  std::vector<Eigen::VectorXi> restriction_rows;
  std::optional<ScaleAwareSolver> fine;
  std::optional<ArapSolver> fine_start;  // settings.keep_fine_start: level 0's ARAP, kept
  double hierarchy_seconds = 0, prolongation_seconds = 0, fine_setup_seconds = 0;

  // Without a coarse level (a mesh too small to decimate) there is no hierarchy: level 0 is the
  // mesh itself.
  const MeshLevel& level(int i) const { return hierarchy->level(used[static_cast<size_t>(i)]); }
  int vertices(int i) const {
    return i == 0 ? static_cast<int>(V.rows()) : static_cast<int>(level(i).V.rows());
  }
  int top() const { return static_cast<int>(used.size()) - 1; }
  /// The rows of level i's positions X at level i + 1's vertices (restriction by injection).
  Positions restrict_to_coarse(int i, const Positions& X) const {
    return X(restriction_rows[static_cast<size_t>(i)], Eigen::all);
  }
  const MeshTopology& topology_of(int i) const {
    return i == 0 ? topology : level_topology[static_cast<size_t>(i)];
  }
  /// Targets of level i's constrained vertices (level 0: the caller's order).
  Result<Positions> targets_of(int i, const Positions& targets) const {
    if (i == 0) return targets;
    return hierarchy->level_targets(used[static_cast<size_t>(i)], targets);
  }
  /// The constrained vertices of level i in the order of targets_of(i).
  Eigen::VectorXi constrained_of(int i) const { return i == 0 ? constrained : level(i).constrained; }
  /// A new ARAP solver for the start on level i (its factorization is built here).
  Result<ArapSolver> make_start_solver(int i) const {
    ArapSettings arap_settings;
    arap_settings.threads = settings.solver.threads;
    if (i == 0) return ArapSolver::create(V, F, topology, constrained, arap_settings);
    return ArapSolver::create(level(i).V, level(i).F, topology_of(i), constrained_of(i),
                              arap_settings);
  }
  /// LevelReport::handle_error of level i's positions `X`.
  double handle_error(int i, const Positions& X, const Positions& level_targets) const {
    const Eigen::VectorXi c = constrained_of(i);
    double worst = 0;
    for (Eigen::Index j = 0; j < c.size(); ++j) {
      worst = std::max(worst, (X.row(c(j)) - level_targets.row(j)).norm());
    }
    return worst / std::max(bbox_diagonal, 1e-300);
  }

  Status build(const Positions& V_in, const Triangles& F_in, const Eigen::VectorXi& constrained_in,
               const MultilevelSettings& settings_in, const BuildProgress& progress,
               const std::stop_token& stop);
  Result<Positions> transfer(int i, const Positions& coarse_result, const Positions& arap_here,
                             const Positions& arap_coarse) const;
  /// The full-resolution solve with settings.fine_corrections coarse-grid corrections (the
  /// study's variant, docs/multilevel.md): fine_correction_interval fine iterations, then
  /// level 1 solved from the restriction R x of the iterate (its vertices' rows) to the level
  /// tolerance, giving S, and x <- x + P_0(S) - P_0(R x); the last part runs the rest of the
  /// budget. The reports are merged into one (iterations renumbered).
  Result<SolveReport> solve_with_corrections(const Positions& targets, const SolveOptions& options,
                                             ScaleAwareSolver& level_one,
                                             const ProgressCallback& progress,
                                             const std::stop_token& stop);
};

Result<SolveReport> MultilevelSolver::Impl::solve_with_corrections(
    const Positions& targets, const SolveOptions& options, ScaleAwareSolver& level_one,
    const ProgressCallback& progress, const std::stop_token& stop) {
  MD_ASSIGN_OR_RETURN(const Positions level_targets, targets_of(1, targets));
  SolveReport merged;
  int budget = options.max_iterations;
  for (int cycle = 0; cycle <= settings.fine_corrections; ++cycle) {
    SolveOptions run = options;
    run.max_iterations = cycle < settings.fine_corrections
                             ? std::min(budget, settings.fine_correction_interval)
                             : budget;
    MD_ASSIGN_OR_RETURN(SolveReport part, fine->solve(targets, run, progress, stop));
    const int offset = merged.iterations;
    for (size_t k = merged.history.empty() ? 0 : 1; k < part.history.size(); ++k) {
      IterationInfo info = part.history[k];
      info.iteration += offset;
      merged.history.push_back(info);
    }
    merged.iterations += part.iterations;
    merged.pcg_iterations += part.pcg_iterations;
    merged.factorizations += part.factorizations;
    merged.anderson_rejections += part.anderson_rejections;
    merged.converged = part.converged;
    merged.estimated_remaining = part.estimated_remaining;
    merged.stitch = part.stitch;
    merged.V = part.V;
    budget -= part.iterations;
    if (part.converged || budget <= 0 || cycle == settings.fine_corrections) break;
    // The coarse-grid correction.
    const Positions& x = fine->positions();
    const Positions restricted = restrict_to_coarse(0, x);
    MD_RETURN_IF_ERROR(level_one.set_positions(restricted));
    SolveOptions coarse = options;
    coarse.start = StartFrom::Previous;
    coarse.ora = false;
    coarse.face_scale.resize(0);
    coarse.track_metrics = false;
    coarse.max_iterations = settings.level_max_iterations;
    if (settings.level_tolerance > 0) coarse.tolerance = settings.level_tolerance;
    MD_ASSIGN_OR_RETURN(const SolveReport corrected,
                        level_one.solve(level_targets, coarse, {}, stop));
    const Prolongation& p = prolongation[0];
    MD_ASSIGN_OR_RETURN(const Positions up, p.apply(corrected.V));
    MD_ASSIGN_OR_RETURN(const Positions down, p.apply(restricted));
    MD_RETURN_IF_ERROR(fine->set_positions(x + up - down));
  }
  return merged;
}

Status MultilevelSolver::Impl::build(const Positions& V_in, const Triangles& F_in,
                                     const Eigen::VectorXi& constrained_in,
                                     const MultilevelSettings& settings_in,
                                     const BuildProgress& progress, const std::stop_token& stop) {
  MD_RETURN_IF_ERROR(check_settings(settings_in));
  // The scale-aware energy needs two constrained vertices per component (its fine solver checks
  // it again; checking first keeps the hierarchy from being built for nothing).
  MD_RETURN_IF_ERROR(check_constrained(constrained_in, topology, 2));
  settings = settings_in;
  V = V_in;
  F = F_in;
  constrained = constrained_in;
  bbox_diagonal = (V.colwise().maxCoeff() - V.colwise().minCoeff()).norm();
  const int n = static_cast<int>(V.rows());

  auto start = Clock::now();
  MultiresSettings hs;
  hs.level_vertices.clear();
  for (long target = n / settings.level_ratio; target >= settings.coarsest_vertices;
       target /= settings.level_ratio) {
    hs.level_vertices.push_back(static_cast<int>(target));
  }
  used = {0};
  if (!hs.level_vertices.empty()) {
    hs.constraint_levels = ConstraintLevels::KeepBorders;
    hs.threads = settings.threads;
    hs.seed = settings.seed;
    MD_ASSIGN_OR_RETURN(MeshHierarchy built, MeshHierarchy::build_checked(
                                                 V, F, topology, constrained, hs, progress, stop));
    hierarchy.emplace(std::move(built));
    for (int k = 1; k < hierarchy->level_count(); ++k) {
      const auto count = static_cast<double>(hierarchy->level(k).V.rows());
      const auto above = static_cast<double>(hierarchy->level(used.back()).V.rows());
      if (count <= settings.min_reduction * above) used.push_back(k);
    }
  }
  hierarchy_seconds = seconds_since(start);
  if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "precompute cancelled");

  start = Clock::now();
  report_progress(progress, "prolongation", 0.0);
  // Each coarse level's connectivity is built once, for its prolongation and for the solvers
  // every cold solve creates on it (MeshHierarchy has validated every level).
  level_topology.resize(used.size());
  for (int i = 1; i <= top(); ++i) {
    const MeshLevel& here = level(i);
    MD_ASSIGN_OR_RETURN(level_topology[static_cast<size_t>(i)],
                        build_topology(here.F, static_cast<int>(here.V.rows())));
  }
  for (int i = 0; i < top(); ++i) {
    const MeshLevel& here = level(i);
    const MeshLevel& coarse = level(i + 1);
    // Row of each fine vertex in this level (both lists ascend by fine index).
    std::vector<int> row(static_cast<size_t>(n), -1);
    for (Eigen::Index r = 0; r < here.to_fine.size(); ++r) row[here.to_fine(r)] = static_cast<int>(r);
    Eigen::VectorXi coarse_rows(coarse.to_fine.size());
    for (Eigen::Index r = 0; r < coarse.to_fine.size(); ++r) {
      coarse_rows(r) = row[static_cast<size_t>(coarse.to_fine(r))];
    }
    MD_ASSIGN_OR_RETURN(Prolongation p,
                        Prolongation::create_checked(here.V, here.F, topology_of(i), coarse_rows,
                                                     stop, settings.threads, nullptr));
    prolongation.push_back(std::move(p));
    restriction_rows.push_back(std::move(coarse_rows));
    report_progress(progress, "prolongation",
                    static_cast<double>(i + 1) / static_cast<double>(top()));
  }
  report_progress(progress, "prolongation", 1.0);
  prolongation_seconds = seconds_since(start);

  start = Clock::now();
  // Every solve of the full-resolution solver starts from a transferred start or a previous
  // result, unless a caller asks for another start explicitly: those factorizations wait for it.
  ScaleAwareSettings fine_settings = settings.solver;
  fine_settings.lazy_laplacian_guess = true;
  MD_ASSIGN_OR_RETURN(ScaleAwareSolver solver,
                      ScaleAwareSolver::create(V, F, topology, constrained, fine_settings, stop,
                                               progress));
  fine.emplace(std::move(solver));
  if (settings.keep_fine_start && top() > 0) {
    if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "precompute cancelled");
    MD_ASSIGN_OR_RETURN(ArapSolver arap, make_start_solver(0));
    fine_start.emplace(std::move(arap));
  }
  fine_setup_seconds = seconds_since(start);
  const Measures rest = compute_measures(V, F, topology);
  rest_phi = rest.phi;
  return Status::success();
}

Result<Positions> MultilevelSolver::Impl::transfer(int i, const Positions& coarse_result,
                                                   const Positions& arap_here,
                                                   const Positions& arap_coarse) const {
  const Prolongation& p = prolongation[static_cast<size_t>(i)];
  MD_ASSIGN_OR_RETURN(Positions prolonged, p.apply(coarse_result));
  if (settings.transfer == LevelTransfer::Prolong) return prolonged;
  MD_ASSIGN_OR_RETURN(const Positions arap_prolonged,
                      settings.transfer == LevelTransfer::Detail
                          ? p.apply(restrict_to_coarse(i, arap_here))
                          : p.apply(arap_coarse));
  Positions out = arap_here + prolonged - arap_prolonged;
  if (!out.allFinite()) {
    return Error(ErrorCode::NumericalFailure,
                 "the transfer to level " + std::to_string(i) + " is not finite");
  }
  return out;
}

MultilevelSolver::MultilevelSolver(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
MultilevelSolver::MultilevelSolver(MultilevelSolver&&) noexcept = default;
MultilevelSolver& MultilevelSolver::operator=(MultilevelSolver&&) noexcept = default;
MultilevelSolver::~MultilevelSolver() = default;

Result<MultilevelSolver> MultilevelSolver::create(const Positions& V, const Triangles& F,
                                                  const Eigen::VectorXi& constrained,
                                                  const MultilevelSettings& settings,
                                                  const BuildProgress& progress,
                                                  std::stop_token stop) {
  report_progress(progress, "validate", 0.0);
  MD_RETURN_IF_ERROR(validate_triangle_mesh(V, F));
  MD_ASSIGN_OR_RETURN(const MeshTopology topology, build_topology(F, static_cast<int>(V.rows())));
  report_progress(progress, "validate", 1.0);
  return create(V, F, topology, constrained, settings, progress, std::move(stop));
}

Result<MultilevelSolver> MultilevelSolver::create(const Positions& V, const Triangles& F,
                                                  const MeshTopology& topology,
                                                  const Eigen::VectorXi& constrained,
                                                  const MultilevelSettings& settings,
                                                  const BuildProgress& progress,
                                                  std::stop_token stop) {
  MD_ASSERT(topology.vertex_count == V.rows() && topology.face_count == F.rows());
  if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "precompute cancelled");
  auto impl = std::make_unique<Impl>();
  impl->topology = topology;
  MD_RETURN_IF_ERROR(impl->build(V, F, constrained, settings, progress, stop));
  return MultilevelSolver(std::move(impl));
}

ScaleAwareSolver& MultilevelSolver::fine() { return *impl_->fine; }
const ScaleAwareSolver& MultilevelSolver::fine() const { return *impl_->fine; }
int MultilevelSolver::level_count() const { return static_cast<int>(impl_->used.size()); }
int MultilevelSolver::level_vertices(int k) const { return impl_->vertices(k); }
int MultilevelSolver::level_constrained(int k) const {
  return static_cast<int>(impl_->constrained_of(k).size());
}
double MultilevelSolver::hierarchy_seconds() const { return impl_->hierarchy_seconds; }
double MultilevelSolver::prolongation_seconds() const { return impl_->prolongation_seconds; }
double MultilevelSolver::fine_setup_seconds() const { return impl_->fine_setup_seconds; }

Result<SolveReport> MultilevelSolver::solve(const Positions& targets, const SolveOptions& options,
                                            const ProgressCallback& progress,
                                            std::stop_token stop) {
  Impl& s = *impl_;
  const auto start = Clock::now();
  const auto cancelled = [] { return Error(ErrorCode::Cancelled, "solve cancelled"); };
  MD_RETURN_IF_ERROR(check_targets(targets, s.constrained, s.topology, s.bbox_diagonal, true));
  if (!(options.tolerance >= 0) || options.max_iterations < 0 ||
      options.rigid_start_iterations < 0 || !(options.rigid_start_tolerance >= 0)) {
    return Error(ErrorCode::InvalidArgument,
                 "solve options out of range: max_iterations >= 0, tolerance >= 0, "
                 "rigid_start_iterations >= 0 and rigid_start_tolerance >= 0 are required");
  }
  const int top = s.top();
  if (top == 0) {
    // One level: the single-level cold solve.
    SolveOptions cold = options;
    cold.start = StartFrom::Auto;
    s.fine->reset();
    return s.fine->solve(targets, cold, progress, std::move(stop));
  }

  // Progress of every phase and level, elapsed from the start of the cascade.
  const auto forward = [&](SolvePhase phase, int i) -> ProgressCallback {
    if (!progress) return {};
    const int vertices = s.vertices(i);
    return [&progress, phase, i, vertices, start](const IterationInfo& info) {
      // A coarse level's Auto solve reports its own rigid start as Start: this cascade's start
      // phase has reported that level's ARAP already, so it is not shown twice.
      if (info.phase == SolvePhase::Start && phase != SolvePhase::Start) return;
      IterationInfo out = info;
      out.phase = phase;
      out.level = i;
      out.level_vertices = vertices;
      out.elapsed_seconds = seconds_since(start);
      progress(out);
    };
  };

  std::vector<LevelReport> levels(static_cast<size_t>(top + 1));
  for (int i = 0; i <= top; ++i) {
    levels[static_cast<size_t>(top - i)].level = i;
    levels[static_cast<size_t>(top - i)].vertices = s.vertices(i);
  }
  const auto level_report = [&](int i) -> LevelReport& { return levels[static_cast<size_t>(top - i)]; };

  // 1. The rigid start on every level, coarsest first: A[i].
  std::vector<Positions> arap(static_cast<size_t>(top + 1));
  SolveOptions arap_options;
  arap_options.max_iterations = options.rigid_start_iterations;
  arap_options.tolerance = options.rigid_start_tolerance;
  arap_options.stopping_rule = StoppingRule::Change;  // the rigid start's documented tolerance
  arap_options.track_metrics = false;
  arap_options.anderson_window = SolveOptions{}.anderson_window;
  for (int i = top; i >= 0; --i) {
    if (stop.stop_requested()) return cancelled();
    const auto level_start = Clock::now();
    MD_ASSIGN_OR_RETURN(const Positions level_targets, s.targets_of(i, targets));
    // Level 0's solver is the kept one when there is one (settings.keep_fine_start).
    std::optional<ArapSolver> created;
    if (i != 0 || !s.fine_start) {
      MD_ASSIGN_OR_RETURN(ArapSolver made, s.make_start_solver(i));
      created.emplace(std::move(made));
    }
    ArapSolver& solver = created ? *created : *s.fine_start;
    if (i == top) {
      arap_options.start = StartFrom::Laplacian;
      arap_options.max_iterations = options.rigid_start_iterations;
    } else {
      arap_options.max_iterations =
          std::min(options.rigid_start_iterations, s.settings.start_max_iterations);
      if (i == 0) {
        arap_options.max_iterations =
            std::min(arap_options.max_iterations, s.settings.fine_start_max_iterations);
      }
      if (s.settings.start_level_tolerance > 0) {
        arap_options.stopping_rule = StoppingRule::Remaining;
        arap_options.tolerance = s.settings.start_level_tolerance;
      }
      MD_ASSIGN_OR_RETURN(const Positions prolonged,
                          s.prolongation[static_cast<size_t>(i)].apply(
                              arap[static_cast<size_t>(i + 1)]));
      MD_RETURN_IF_ERROR(solver.set_positions(prolonged));
      arap_options.start = StartFrom::Previous;
    }
    MD_ASSIGN_OR_RETURN(SolveReport arap_report,
                        solver.solve(level_targets, arap_options, forward(SolvePhase::Start, i),
                                     stop));
    arap[static_cast<size_t>(i)] = std::move(arap_report.V);
    level_report(i).start_iterations = arap_report.iterations;
    level_report(i).start_seconds = seconds_since(level_start);
  }
  const double start_seconds = seconds_since(start);

  // 2. The scale-aware iteration on the coarse levels, coarsest first: S.
  const auto levels_start = Clock::now();
  SolveOptions level_options = options;
  level_options.ora = false;
  level_options.face_scale.resize(0);
  level_options.track_metrics = false;
  level_options.max_iterations = s.settings.level_max_iterations;
  if (s.settings.level_tolerance > 0) level_options.tolerance = s.settings.level_tolerance;
  ScaleAwareSettings level_settings = s.settings.solver;
  Positions coarse_result;
  std::optional<ScaleAwareSolver> level_one;  // kept for the fine level's coarse corrections
  StartFrom coarsest_start = StartFrom::Rigid;
  int coarsest_candidates = 1;
  for (int i = top; i >= 1; --i) {
    if (stop.stop_requested()) return cancelled();
    const auto level_start = Clock::now();
    const MeshLevel& here = s.level(i);
    MD_ASSIGN_OR_RETURN(const Positions level_targets, s.targets_of(i, targets));
    // The coarsest level chooses the basin (Auto: its rigid start, and the other candidates
    // where that folds); the levels above start from the transfer and never need those
    // factorizations.
    level_settings.lazy_laplacian_guess = i != top;
    MD_ASSIGN_OR_RETURN(ScaleAwareSolver solver,
                        ScaleAwareSolver::create(here.V, here.F, s.topology_of(i),
                                                 s.constrained_of(i), level_settings, stop));
    SolveOptions run = level_options;
    if (i == top) {
      run.start = StartFrom::Auto;
    } else {
      MD_ASSIGN_OR_RETURN(const Positions x0, s.transfer(i, coarse_result,
                                                         arap[static_cast<size_t>(i)],
                                                         arap[static_cast<size_t>(i + 1)]));
      MD_RETURN_IF_ERROR(solver.set_positions(x0));
      run.start = StartFrom::Previous;
    }
    MD_ASSIGN_OR_RETURN(SolveReport level_solve,
                        solver.solve(level_targets, run, forward(SolvePhase::Levels, i), stop));
    if (i == top) {
      coarsest_start = level_solve.start;
      coarsest_candidates = level_solve.start_candidates;
    }
    LevelReport& lr = level_report(i);
    lr.iterations = level_solve.iterations;
    lr.converged = level_solve.converged;
    lr.energy = level_solve.history.empty() ? 0.0 : level_solve.history.back().energy;
    lr.handle_error = s.handle_error(i, level_solve.V, level_targets);
    lr.seconds = seconds_since(level_start);
    coarse_result = std::move(level_solve.V);
    if (i == 1 && s.settings.fine_corrections > 0) level_one.emplace(std::move(solver));
  }
  const double levels_seconds = seconds_since(levels_start);

  // 3. Full resolution from the transferred start.
  if (stop.stop_requested()) return cancelled();
  const auto fine_start = Clock::now();
  MD_ASSIGN_OR_RETURN(const Positions x0, s.transfer(0, coarse_result, arap[0], arap[1]));
  arap.clear();
  // set_positions only replaces the previous result: a failed or cancelled solve below leaves
  // the solver as it was (its previous result) apart from that warm start.
  ScaleAwareSolver& fine = *s.fine;
  MD_RETURN_IF_ERROR(fine.set_positions(x0));
  SolveOptions fine_options = options;
  fine_options.start = StartFrom::Previous;
  const double fine_offset = seconds_since(start);
  Result<SolveReport> solved = Error(ErrorCode::Internal, "no full-resolution solve ran");
  if (s.settings.fine_corrections <= 0 || !level_one) {
    solved = fine.solve(targets, fine_options, forward(SolvePhase::Fine, 0), stop);
  } else {
    solved = s.solve_with_corrections(targets, fine_options, *level_one,
                                      forward(SolvePhase::Fine, 0), stop);
  }
  if (!solved.ok()) {
    fine.reset();  // cold again, as before the cascade
    return solved.status();
  }
  SolveReport report = std::move(solved).value();
  // The history's times count from the start of the cascade, like the progress reports.
  for (IterationInfo& info : report.history) info.elapsed_seconds += fine_offset;
  LevelReport& lr = level_report(0);
  lr.iterations = report.iterations;
  lr.converged = report.converged;
  lr.energy = report.history.empty() ? 0.0 : report.history.back().energy;
  lr.handle_error = s.handle_error(0, report.V, targets);
  lr.seconds = seconds_since(fine_start);
  report.folded_edges =
      count_folds(s.rest_phi, dihedral_angles(report.V, s.F, s.topology, s.settings.solver.threads));
  report.start = coarsest_start;
  report.start_candidates = coarsest_candidates;
  report.levels = std::move(levels);
  report.phases.start = start_seconds;
  report.phases.levels = levels_seconds;
  report.phases.fine = seconds_since(fine_start);
  report.seconds = seconds_since(start);
  return report;
}

}  // namespace meshdeform::core
