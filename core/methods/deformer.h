#pragma once
/// @file deformer.h
/// One interface over every deformation method, so that callers (CLI, bench, service) switch
/// methods without changing code: the scale-aware solver (Liu et al.), as-rigid-as-possible
/// (Sorkine & Alexa 2007) and Laplacian editing (Sorkine et al. 2004). Each is prefactored per
/// handle set by make_deformer() and solved per target set, with the same options, progress and
/// cancellation.

#include <functional>
#include <memory>
#include <stop_token>
#include <string_view>

#include <Eigen/Core>

#include "core/base/status.h"
#include "core/mesh/mesh_data.h"
#include "core/mesh/topology.h"
#include "core/methods/deform_types.h"
#include "core/methods/laplacian.h"
#include "core/methods/scale_aware.h"

namespace meshdeform::core {

enum class Method {
  ScaleAware,  ///< Liu et al., the default
  Arap,        ///< as-rigid-as-possible, cotangent weights, cached factorization
  Laplacian,   ///< Laplacian editing, one linear solve
};

/// "scale_aware", "arap", "laplacian".
const char* method_name(Method method);
/// Inverse of method_name (also accepts "scale-aware"); InvalidArgument names the bad value.
[[nodiscard]] Result<Method> parse_method(std::string_view name);

/// "auto", "laplacian", "previous", "rigid", "propagated".
const char* start_name(StartFrom start);
/// Inverse of start_name; InvalidArgument names the bad value and the accepted ones.
[[nodiscard]] Result<StartFrom> parse_start(std::string_view name);

/// DeformerSettings::multilevel_above and multilevel_coarsest_vertices by default (chosen from
/// the measurements in docs/multilevel.md).
inline constexpr int kDefaultMultilevelAbove = 20000;
inline constexpr int kDefaultMultilevelCoarsest = 1000;

/// Settings fixed per handle set (they define the cached matrices).
struct DeformerSettings {
  double lambda = 100.0;  ///< soft handle weight (scale-aware, Laplacian); ARAP pins handles exactly
  int threads = 1;        ///< OpenMP threads for per-element loops
  LaplacianWeights laplacian_weights = LaplacianWeights::Cotangent;  ///< Laplacian method/guess
  double refactor_cost_ratio = 0.5;  ///< scale-aware lagged-factor rule
  /// Scale-aware step two's PCG preconditioner (see core/methods/scale_aware.h).
  StepTwoPreconditioner preconditioner = StepTwoPreconditioner::BlockTrace;
  /// Scale-aware on meshes of more vertices than this (0: never) and than twice
  /// multires_coarse_vertices: a multiresolution deformer
  /// (core/multires/multires.h, issue 15). Its solves run on a coarse level of an OpenMesh decimation
  /// hierarchy (region borders of the constrained set kept) and are prolonged to full
  /// resolution with their details: a move costs a coarse solve plus a prolongation. Solves with
  /// SolveOptions::full_resolution, ORA or magnification run the full-resolution solver instead
  /// (built on first use): ORA and magnification moves warm-started from the prolonged result;
  /// a full_resolution solve (background refinement) that does not continue an earlier one,
  /// on a mesh above multilevel_above, by the multilevel cascade (as a cold solve; start Auto,
  /// rigidity > 0, SolveOptions::multilevel), otherwise warm-started from the prolonged
  /// result too. A coarse solve reports converged = false.
  int multires_above = 0;
  /// The coarse level's target vertex count (it stays above when the constrained region
  /// borders need more).
  int multires_coarse_vertices = 10000;
  /// Scale-aware on meshes of more vertices than this (0: never), unless multires_above
  /// applies: a multilevel solver (core/multires/multilevel.h, issue 41). Its cold Auto solves
  /// (SolveOptions::multilevel) with rigidity > 0 run the coarse-to-fine cascade; warm solves,
  /// explicit starts, rigidity 0 (the paper's Laplacian start) and SolveOptions::multilevel =
  /// false solve at full resolution as the single-level solver does.
  int multilevel_above = kDefaultMultilevelAbove;
  /// The multilevel hierarchy's coarsest level target (MultilevelSettings::coarsest_vertices).
  int multilevel_coarsest_vertices = kDefaultMultilevelCoarsest;
};

/// A prefactored deformation method for one mesh and one handle set.
class Deformer {
 public:
  virtual ~Deformer() = default;
  virtual Method method() const = 0;
  /// Deforms toward #C x 3 targets (row j for constrained()(j)); warm-starts from the previous
  /// result when options.start allows. Per method:
  ///  - ScaleAware: ScaleAwareSolver::solve with the options unchanged, so options.lambda must
  ///    equal DeformerSettings::lambda (InvalidArgument otherwise).
  ///  - Arap: ArapSolver::solve; handles land exactly on their targets; options.lambda,
  ///    inner_iterations, pcg_tolerance, adaptive_pcg, rigidity and rigid_start_iterations are
  ///    ignored, start Rigid means Laplacian, ora and face_scale rejected.
  ///  - Laplacian: one direct solve. options.lambda must equal DeformerSettings::lambda; start,
  ///    max_iterations, tolerance, rigidity and rigid_start_iterations are ignored (nothing iterates), ora and face_scale
  ///    rejected. The history holds a single entry, iteration 0 = the result (energy 0: the
  ///    editor's objective is not evaluated; e_theta / e_phi when options.track_metrics),
  ///    iterations = 0, converged = true, and progress is called once.
  /// @param[in] targets   #C x 3 target positions.
  /// @param[in] options   see SolveOptions and the per-method notes above.
  /// @param[in] progress  called after every iteration (iteration 0 included), on this thread.
  /// @param[in] stop      cancellation.
  /// @return the report; InvalidArgument for out-of-range options, a lambda that differs from
  ///         the settings (ScaleAware, Laplacian), ora or face_scale given to Arap or Laplacian,
  ///         a wrong number of target rows or a non-finite target (naming it), or (ScaleAware
  ///         only) coinciding targets of a component; Cancelled when `stop` is requested
  ///         (positions() keeps the previous result); NumericalFailure if the solve breaks down.
  [[nodiscard]] virtual Result<SolveReport> solve(const Positions& targets,
                                                  const SolveOptions& options = {},
                                                  const ProgressCallback& progress = {},
                                                  std::stop_token stop = {}) = 0;
  /// The current positions (rest before the first solve).
  virtual const Positions& positions() const = 0;
  /// The constrained vertex indices given to make_deformer().
  virtual const Eigen::VectorXi& constrained() const = 0;
  /// Forgets the previous result: positions() is the rest mesh again.
  virtual void reset() = 0;

  /// Hands a part of the precompute that a later kind of solve needs to another thread, while
  /// this deformer keeps solving: the multiresolution deformer's full-resolution solver (seconds
  /// at 10^5 vertices; moves run on the coarse level meanwhile, and full-resolution solves build
  /// it in place if it is not there yet). The task copies what it needs, may run on any thread
  /// concurrently with solve(), and returns an installer to call on the thread that owns this
  /// deformer (a no-op if the part got built meanwhile, or on any other deformer). Empty when
  /// nothing is pending.
  /// `next`: the options of the solves it is for (their rigidity's setup is built too).
  using Installer = std::function<void(Deformer&)>;
  using BackgroundBuild = std::function<Result<Installer>(std::stop_token)>;
  [[nodiscard]] virtual BackgroundBuild background_build(const SolveOptions& next) {
    (void)next;
    return {};
  }
  /// Whether background_build() would return a task (cheap: copies nothing).
  [[nodiscard]] virtual bool needs_background_build() const { return false; }
};

/// Builds a deformer: validates the mesh and the constrained set and factors the method's
/// matrices (ScaleAware: ScaleAwareSettings from lambda, threads and refactor_cost_ratio; Arap:
/// threads only; Laplacian: laplacian_weights and lambda).
/// @param[in] method       which method.
/// @param[in] V0           #V x 3 rest positions.
/// @param[in] F            #F x 3 triangles.
/// @param[in] constrained  #C distinct vertex indices (fixed and handle vertices alike).
/// @param[in] settings     see DeformerSettings.
/// @return InvalidArgument for a bad mesh, bad or repeated indices, or a component the method
///         cannot pin (scale-aware: fewer than two constrained vertices; ARAP and Laplacian:
///         none), or settings out of range (lambda not positive and finite, or
///         refactor_cost_ratio not positive, for the methods that use them); NumericalFailure if
///         a factorization fails; Cancelled when `stop` is requested before or between the
///         precompute's phases (a running factorization itself finishes).
/// @param[in] progress     the precompute's phases (BuildProgress: scale-aware "validate",
///                         "rigid_start", "step_two", or the multiresolution phases; ARAP and
///                         Laplacian "factorize"), on this thread; may be empty.
[[nodiscard]] Result<std::unique_ptr<Deformer>> make_deformer(Method method, const Positions& V0,
                                                              const Triangles& F,
                                                              const Eigen::VectorXi& constrained,
                                                              const DeformerSettings& settings = {},
                                                              std::stop_token stop = {},
                                                              const BuildProgress& progress = {});
/// The same for a mesh the caller has validated (validate_triangle_mesh) and whose topology it
/// has built (build_topology(F, #V)), e.g. a server session when the mesh was uploaded: no
/// method does either again (0.17 s at 187k vertices). The constrained indices are still
/// checked.
[[nodiscard]] Result<std::unique_ptr<Deformer>> make_deformer(
    Method method, const Positions& V0, const Triangles& F, const MeshTopology& topology,
    const Eigen::VectorXi& constrained, const DeformerSettings& settings = {},
    std::stop_token stop = {}, const BuildProgress& progress = {});

}  // namespace meshdeform::core
