#pragma once
/// @file arap.h
/// As-rigid-as-possible surface modeling (Sorkine & Alexa 2007), a baseline for the scale-aware
/// solver: minimise
///   E(V, R) = sum_i sum_{j in N(i)} w_ij ||(v_i - v_j) - R_i (v0_i - v0_j)||^2
/// over the positions V and one rotation R_i per vertex, by alternating
///   local:  R_i = argmax trace(R^T S_i), S_i = sum_j w_ij (v_i - v_j)(v0_i - v0_j)^T (Kabsch, 3x3
///           SVD with the reflection removed);
///   global: L V = b, b_i = sum_j w_ij / 2 (R_i + R_j)(v0_i - v0_j), with the constrained vertices
///           eliminated (hard constraints: handles land exactly on their targets, as in the
///           original paper, libigl and CGAL).
/// Each step minimises E exactly in its own block of unknowns, so E never increases.
///
/// Weights: w_ij = (cot alpha_ij + cot beta_ij) / 2 from the rest mesh (one cotangent on a boundary
/// edge), clamped per edge to at least 1e-3 times the mean |w| (the same rule as the Laplacian
/// editor): negative weights (an edge facing two obtuse angles) would make the energy indefinite,
/// and the clamp keeps the reduced Laplacian positive definite. Any positive weights keep the rest
/// pose and every rigid motion of it exact zeros of E, so the clamp changes only how non-rigid
/// edits are spread.
///
/// Split like libigl's arap_precomputation/arap_solve: `ArapSolver::create` builds the weights and
/// factors the reduced cotangent Laplacian L_UU once per handle set (it does not depend on the
/// targets or the rotations); every iteration is then one rotation fit per vertex and one
/// back-substitution with three right-hand sides.

#include <memory>
#include <stop_token>

#include <Eigen/Core>

#include "core/base/status.h"
#include "core/mesh/mesh_data.h"
#include "core/mesh/topology.h"
#include "core/methods/deform_types.h"

namespace meshdeform::core {

/// Settings fixed for the lifetime of an ARAP solver.
struct ArapSettings {
  /// OpenMP threads for the per-vertex loops; 0 means all hardware threads. Default 1 for the
  /// reasons given in ScaleAwareSettings::threads. Results do not depend on it (bit for bit).
  int threads = 1;
};

/// The ARAP deformation solver for one mesh and one handle set.
class ArapSolver {
 public:
  /// Precomputes the cotangent weights and factors the reduced Laplacian L_UU (free vertices).
  /// @param[in] V0           #V x 3 rest positions.
  /// @param[in] F            #F x 3 triangles, validate_triangle_mesh(V0, F) ok.
  /// @param[in] constrained  #C distinct vertex indices whose positions are prescribed exactly
  ///                         at solve time (fixed and handle vertices alike).
  /// @param[in] settings     threads.
  /// @return the solver; InvalidArgument for a mesh that fails validation, an index out of range
  ///         or repeated, or a connected component without a constrained vertex (the energy is
  ///         invariant to translation, so such a component is not pinned; the message names the
  ///         component and one of its vertices); NumericalFailure if the factorization fails.
  ///         One constrained vertex per component is enough: the result is then a rigid motion
  ///         of that component (a translation when started from the rest pose).
  [[nodiscard]] static Result<ArapSolver> create(const Positions& V0, const Triangles& F,
                                                 const Eigen::VectorXi& constrained,
                                                 const ArapSettings& settings = {});
  /// The same for a mesh the caller has validated (validate_triangle_mesh) and whose topology
  /// it has built (build_topology(F, #V)): neither is done again (the scale-aware solver's rigid
  /// start). The constrained indices are still checked.
  [[nodiscard]] static Result<ArapSolver> create(const Positions& V0, const Triangles& F,
                                                 const MeshTopology& topology,
                                                 const Eigen::VectorXi& constrained,
                                                 const ArapSettings& settings = {});

  /// Deforms toward #C x 3 targets (row j for constrained(j)); the constrained vertices land
  /// exactly on their targets.
  /// Start (options.start): Auto = the previous result if there is one, else the Laplacian guess;
  /// the Laplacian guess is one global step with every R_i = I (L_UU V_U = (L V0)_U - L_UC T, i.e.
  /// Laplacian editing with hard constraints and the same weights, costing one back-substitution);
  /// Previous = the previous result (the rest mesh before the first solve). Either start gets its
  /// constrained rows set to the targets, so every iterate, the start included, is feasible.
  /// History: iteration 0 is the start; each entry's energy is the ARAP energy
  /// min_R E(V, R) of that iterate (non-increasing), e_theta / e_phi against the rest mesh when
  /// options.track_metrics, normal_sweeps = pcg_iterations = 0, normals_seconds the local step
  /// (rotation fits and energy), linear_seconds the global step (right-hand side and
  /// back-substitution), assemble_seconds 0. Anderson acceleration over the positions
  /// (options.anderson_window; 0 turns it off) is safeguarded by the energy: a mix that does not
  /// lower it is replaced by the plain update, counted in anderson_rejections. Stops when
  /// options.stopping_rule holds at options.tolerance (core/methods/convergence.h), or the
  /// energy falls below 1e-20 (bbox diagonal)^2 sum w_ij
  /// (a weighted RMS edge residual of 1e-10 of the bounding box: an exact fit), or after
  /// options.max_iterations iterations. options.inner_iterations, lambda, pcg_tolerance and
  /// adaptive_pcg do not apply to ARAP and are ignored; ora and face_scale (scale-aware only)
  /// are rejected. Deterministic.
  /// @param[in] targets   #C x 3 target positions.
  /// @param[in] options   max_iterations >= 0, tolerance >= 0, start, track_metrics.
  /// @param[in] progress  called after the start and after every iteration, on this thread.
  /// @param[in] stop      checked on entry and before every iteration.
  /// @return the report (factorizations = 0: the factor is built by create); InvalidArgument for
  ///         options out of range, options.ora or a non-empty options.face_scale, a wrong number of
  ///         target rows or a non-finite target (naming it); Cancelled when `stop` is requested
  ///         mid-solve (the solver keeps its previous state); NumericalFailure if an iterate is not
  ///         finite.
  [[nodiscard]] Result<SolveReport> solve(const Positions& targets,
                                          const SolveOptions& options = {},
                                          const ProgressCallback& progress = {},
                                          std::stop_token stop = {});

  /// The current positions (the rest mesh before the first solve).
  const Positions& positions() const;
  /// The constrained vertex indices given to create().
  const Eigen::VectorXi& constrained() const;
  /// Forgets the previous result: positions() is the rest mesh again and the next Auto solve
  /// starts from the Laplacian guess.
  void reset();
  /// Makes `V` the previous result, so that the next Auto or Previous solve starts from it (its
  /// constrained rows are set to the targets then), e.g. a coarse level's result prolonged to
  /// this mesh (core/multires/multilevel.h).
  /// @param[in] V  #V x 3 finite positions.
  /// @return InvalidArgument for a wrong shape or a non-finite coordinate (the solver unchanged).
  [[nodiscard]] Status set_positions(const Positions& V);

  ArapSolver(ArapSolver&&) noexcept;
  ArapSolver& operator=(ArapSolver&&) noexcept;
  ~ArapSolver();

 private:
  struct Impl;
  explicit ArapSolver(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// One-off convenience: create + solve.
/// @return the errors of ArapSolver::create and ArapSolver::solve.
[[nodiscard]] Result<SolveReport> deform_arap(const Positions& V0, const Triangles& F,
                                              const Eigen::VectorXi& constrained,
                                              const Positions& targets,
                                              const SolveOptions& options = {},
                                              const ProgressCallback& progress = {});

}  // namespace meshdeform::core
