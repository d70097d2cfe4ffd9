#pragma once
/// @file multilevel.h
/// The multilevel solve (issue 41): a cold scale-aware solve through a hierarchy of coarser
/// meshes, so that the error the full-resolution iteration removes slowly (smooth, low
/// frequency) is removed where it is cheap. docs/multilevel.md has the measurements behind every
/// choice below and what was tried instead.
///
/// Levels. MeshHierarchy (core/multires/multires.h) decimates the mesh to about 1/`level_ratio` of its
/// vertices per level, down to `coarsest_vertices` (constrained region borders kept, the inside
/// of handle and fixed regions decimated). Every level's vertices are vertices of the level
/// above, at their rest positions, and each level prolongs to the one above with a Prolongation
/// (harmonic base plus details in local frames).
///
/// The cascade, coarsest level L to full resolution 0:
///  1. start: ARAP (the rigid start of StartFrom::Auto) on level L from its Laplacian guess, then
///     on every finer level from the level below prolonged, each to the rigid start's tolerance:
///     A_L, ..., A_0. Converged ARAP on a level starts close to converged ARAP on the next, so
///     each finer level needs few of its (cheap) iterations where a single-level rigid start
///     spends hundreds at full resolution.
///  2. levels: the scale-aware solve on level L from StartFrom::Auto (its rigid start, and the
///     other start candidates where that folds: the basin is chosen where it is cheap), giving
///     S_L; then on each level k = L-1 ... 1 from the transferred start
///         x_k = A_k + P_k(S_(k+1)) - P_k(A_(k+1))
///     to the level tolerance, giving S_k. The transfer carries the coarse level's scale-aware
///     correction of ARAP (smooth: local scale, the normals' slow mode) onto this level's
///     converged ARAP, whose details are this level's own: a plain prolongation P_k(S_(k+1))
///     leaves detail errors (the harmonic base's kinks at coarse vertices) that the
///     scale-aware iteration removes slowly, and A_k - P_k(A_(k+1)) also carries this level's
///     correction of the coarse discretization, measured on ARAP, which transfers to the
///     scale-aware solution too.
///  3. fine: the full-resolution solve from x_0 with the caller's options (budget, tolerance,
///     ORA / magnification), whose iterations are the result's history.
/// Every solve on every level stops by the same rule (core/methods/convergence.h). A rigid motion or a
/// uniform scaling of the handles is an exact zero of the scale-aware energy on every level,
/// and every transfer maps it exactly (Prolongation does), so it is exact at full resolution.

#include <cstdint>
#include <memory>
#include <stop_token>
#include <vector>

#include <Eigen/Core>

#include "core/base/status.h"
#include "core/mesh/mesh_data.h"
#include "core/mesh/topology.h"
#include "core/methods/deform_types.h"
#include "core/methods/scale_aware.h"

namespace meshdeform::core {

/// How a coarse level's scale-aware result starts the level above.
enum class LevelTransfer {
  /// x_k = A_k + P_k(S_(k+1)) - P_k(A_(k+1)) (above): the default.
  Correction,
  /// x_k = P_k(S_(k+1)): the plain prolongation (measured slower; kept for the study).
  Prolong,
  /// x_k = A_k + P_k(S_(k+1)) - P_k(R_k A_k), R_k A_k the rows of A_k at level k+1's vertices:
  /// only A_k's details relative to its own coarse vertices are carried, so an A_k whose start
  /// stopped early (its smooth part not converged) adds no smooth error (a study variant).
  Detail,
};

/// How a MultilevelSolver is built and how its cascade runs.
struct MultilevelSettings {
  /// Every level's scale-aware solver (threads, lambda, preconditioner, scale constants).
  ScaleAwareSettings solver;
  /// The coarsest level's target vertex count: levels are added while the next one would have
  /// at least this many vertices (it stays above its target when the locked region borders
  /// need more). >= 100.
  int coarsest_vertices = 2000;
  /// Each level has about 1/level_ratio of the vertices of the level above. >= 2.
  int level_ratio = 4;
  /// A level is kept only when it has at most this fraction of the vertices of the level above
  /// (decimation stops early where region borders are locked). In (0, 1).
  double min_reduction = 0.75;
  /// Stopping tolerance of the coarse levels' scale-aware solves (the rule of
  /// SolveOptions::stopping_rule); <= 0: the solve's own tolerance. Loose by measurement: the
  /// coarse levels carry the smooth part of the correction, which their first iterations
  /// find; converging them further costs more than the full-resolution iterations it saves.
  double level_tolerance = 1e-2;
  /// Budget of outer iterations on each coarse level. >= 1.
  int level_max_iterations = 100;
  /// Budget of ARAP iterations of the start on every level but the coarsest (which has
  /// SolveOptions::rigid_start_iterations, its start being the Laplacian guess): from the
  /// converged level below, ARAP meets the rigid start's tolerance in tens of iterations, or
  /// creeps along a flat valley where more iterations change nothing the transfer uses. >= 1.
  int start_max_iterations = 200;
  /// Budget of the start's ARAP iterations at full resolution (level 0), at most
  /// start_max_iterations. The transfer to level 0 needs this level's own details, which the
  /// first iterations from the prolonged level 1 fix; the smooth remainder is the prolonged
  /// level's already. >= 1.
  int fine_start_max_iterations = 200;
  /// > 0: the start's ARAP on every level but the coarsest (each from the level below,
  /// prolonged) stops under the Remaining rule (core/methods/convergence.h) at this tolerance,
  /// within the budgets above, instead of the rigid start's own test (a last relative change
  /// below SolveOptions::rigid_start_tolerance, 1e-6), which the default (0) keeps. A study
  /// setting, measured and not made the default (docs/multilevel.md): at 3e-4 the 187k Spot
  /// bend's start takes 3.6 s instead of 9.2 s and its result's energy is 0.5% higher, but at
  /// 750k the full-resolution start then runs into its budget (200 iterations against 137)
  /// and the result's energy is 1.6% higher. The coarsest level, started from its Laplacian
  /// guess, always runs to the rigid start's tolerance.
  double start_level_tolerance = 0;
  LevelTransfer transfer = LevelTransfer::Correction;
  /// Coarse-grid corrections during the full-resolution iteration (a study variant, off by
  /// default: measured slower, docs/multilevel.md): after every fine_correction_interval fine
  /// iterations, level 1 is solved from the iterate's restriction and the change prolonged
  /// back, this many times. >= 0.
  int fine_corrections = 0;
  int fine_correction_interval = 3;  ///< >= 1
  /// Keep the start's full-resolution ARAP solver (its factorization) from create() on instead
  /// of building it in every cascade: a cascade then does nothing at full resolution that does
  /// not look at its stop token for longer than an iteration (the factorization does not: 1.5-3
  /// s at 187k vertices, 160 MiB kept). For callers that cascade more than once and must stop
  /// promptly: the multiresolution deformer's refinement, preempted by the next move.
  bool keep_fine_start = false;
  /// Threads of the hierarchy's decimation and of the prolongations (>= 1); the solvers use
  /// solver.threads.
  int threads = 1;
  std::uint64_t seed = 1;  ///< the decimation's draws
};

/// A scale-aware solver for one mesh and one handle set that solves cold by the multilevel
/// cascade and warm at full resolution. Not thread-safe: one caller at a time.
class MultilevelSolver {
 public:
  /// Builds the hierarchy, the prolongations between consecutive levels and the
  /// full-resolution solver (ScaleAwareSolver, its default start's factorization left to the
  /// first solve that needs it). The coarse levels' solvers are built by each cascade and freed
  /// after it.
  /// @param[in] V, F, constrained  as for ScaleAwareSolver::create.
  /// @param[in] progress  phases "decimate", "validate", "prolongation", "step_two".
  /// @return InvalidArgument for a bad mesh, constrained set or settings; the errors of
  ///         MeshHierarchy::build, Prolongation::create and ScaleAwareSolver::create;
  ///         Cancelled when `stop` is requested.
  [[nodiscard]] static Result<MultilevelSolver> create(const Positions& V, const Triangles& F,
                                                       const Eigen::VectorXi& constrained,
                                                       const MultilevelSettings& settings = {},
                                                       const BuildProgress& progress = {},
                                                       std::stop_token stop = {});
  /// The same for a mesh the caller has validated and whose topology it has built.
  [[nodiscard]] static Result<MultilevelSolver> create(const Positions& V, const Triangles& F,
                                                       const MeshTopology& topology,
                                                       const Eigen::VectorXi& constrained,
                                                       const MultilevelSettings& settings = {},
                                                       const BuildProgress& progress = {},
                                                       std::stop_token stop = {});

  /// The cascade toward #C x 3 targets (row j for constrained(j)); the result becomes the
  /// full-resolution solver's previous result, so later Auto / Previous solves continue from it.
  /// options.start is not used (the cascade is the cold Auto solve); every other option applies
  /// to the full-resolution solve (max_iterations and tolerance its budget and stop, ORA and
  /// magnification after it), the start phase uses rigid_start_iterations on every level and
  /// rigid_start_tolerance (the levels above the coarsest: the settings' start_level_tolerance
  /// when it is set), the coarse levels the settings' level budget and tolerance. With one
  /// level (a mesh too small to decimate) it is the single-level Auto solve.
  /// @param[in] progress  after every iteration of every phase and level (IterationInfo's phase,
  ///                      level and level_vertices say which; elapsed_seconds from the start of
  ///                      the cascade).
  /// @return the full-resolution solve's report with SolveReport::levels and phases filled in,
  ///         start and start_candidates those of the coarsest level, folded_edges of the
  ///         result; the errors of ScaleAwareSolver::solve and ArapSolver::solve (InvalidArgument
  ///         for bad targets or options, naming them); Cancelled when `stop` is requested
  ///         between or during the levels' solves (the solver keeps its previous result).
  [[nodiscard]] Result<SolveReport> solve(const Positions& targets,
                                          const SolveOptions& options = {},
                                          const ProgressCallback& progress = {},
                                          std::stop_token stop = {});

  /// The full-resolution solver (warm solves, explicit starts).
  ScaleAwareSolver& fine();
  const ScaleAwareSolver& fine() const;
  /// Levels used, full resolution included (1 when the mesh is too small to decimate).
  int level_count() const;
  /// Vertex count of level k (0 = full resolution).
  int level_vertices(int k) const;
  /// Constrained vertex count of level k.
  int level_constrained(int k) const;
  /// Seconds create() spent on the hierarchy, the prolongations and the fine solver.
  double hierarchy_seconds() const;
  double prolongation_seconds() const;
  double fine_setup_seconds() const;

  MultilevelSolver(MultilevelSolver&&) noexcept;
  MultilevelSolver& operator=(MultilevelSolver&&) noexcept;
  ~MultilevelSolver();

 private:
  struct Impl;
  explicit MultilevelSolver(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace meshdeform::core
