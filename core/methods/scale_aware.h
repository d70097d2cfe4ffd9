#pragma once
/// @file scale_aware.h
/// Scale-aware shape manipulation (Liu, Wang, Liu, Liu): keep corner angles and dihedral angles of
/// a mesh under handle constraints by alternating
///   step one (Section 4.1.1): a local/global update of face normals on the Gauss map, and
///   step two (Sections 3.2, 4.1.2): the sparse linear solve of Eq. 12 for the vertices,
/// starting from Laplacian editing (Section 5.2). See docs/algorithm.md in the project notes.
///
/// Split like libigl's precompute/solve: `ScaleAwareSolver::create` is per handle set (topology,
/// measures, the fixed sparsity pattern, symbolic analysis, Laplacian factor); `solve` is per
/// target set and warm-starts from the previous result with the cached (lagged) factorization.

#include <limits>
#include <memory>
#include <stop_token>

#include <Eigen/Core>

#include "core/methods/deform_types.h"
#include "core/mesh/mesh_data.h"
#include "core/mesh/topology.h"
#include "core/base/status.h"

namespace meshdeform::core {

/// How step two's conjugate gradients are preconditioned.
enum class StepTwoPreconditioner {
  /// The exact 3n x 3n Cholesky factor of A(N), kept while it pays (lagged) and refreshed by the
  /// flop-count rule: few PCG steps, but each back-solve streams a large factor.
  LaggedCholesky,
  /// The n x n block-trace matrix (tr of every 3x3 block / 3, a partial trace, so PSD): it only
  /// depends on the rest angles and length ratios (tr(l R(N, theta)) = l (1 + 2 cos theta)), so it
  /// is factored once per handle set and never refreshed; 9x smaller factor, 3 right-hand sides.
  BlockTrace,
};

/// Settings fixed for the lifetime of a solver (they define its matrices).
struct ScaleAwareSettings {
  double lambda = 100.0;   ///< handle weight of Eq. 12 and of the Laplacian initialisation
  /// Refactor step two's matrix when a PCG solve costs more (in flops) than this fraction of a
  /// numeric factorization. Deterministic: counted in flops, not measured in seconds.
  double refactor_cost_ratio = 0.5;
  StepTwoPreconditioner preconditioner = StepTwoPreconditioner::BlockTrace;
  /// BlockTrace only: factor the block-trace matrix over the free vertices and the constrained
  /// vertices next to a free one, and take the other constrained vertices (the inside of handle
  /// and fixed regions, each row dominated by the handle weight) by their diagonal. The same
  /// PCG steps (within one in 15 iterations) on every bench model, a smaller factor where
  /// handle regions are large (Spot 47k: create + prepare about 18% shorter, 14 MiB less).
  /// Off: T whole, as before.
  bool split_preconditioner = true;
  /// OpenMP threads for the per-vertex and per-face loops; 0 means all hardware threads.
  /// Default 1: a service solves many sessions side by side, and on a loaded 2-core machine
  /// extra threads per solve only contend (measured 4x slower). Results do not depend on it,
  /// with one exception: with scale control (rigidity > 0) one thread solves step two's Schur
  /// complement in the scales (fewer PCG steps), two or more threads on a mesh of more than
  /// 2,000 vertices the joint system (its two preconditioner solves side by side, faster
  /// there); the two agree to the PCG tolerance, and any two thread counts of 2 or more give
  /// the same bits.
  /// With 2 or more, create() also builds the scale term's system (every solve at rigidity > 0
  /// needs it) on a second thread beside the rigid start's ARAP factorization.
  int threads = 1;
  /// Scale control (SolveOptions::rigidity > 0; see core/methods/scale_control.h), study constants
  /// rather than user options: they fix the constant scale system, so they are per solver.
  /// nu: pull of each face's scale toward the free global scale, relative to the fit's 2 A_f.
  double scale_pull = 4.0;
  /// xi / sqrt(total rest area): the length over which face scales are smoothed.
  double scale_smooth_length = 0.05;
  /// beta: how firmly each face frame R_f follows the step-one normal, as a penalty
  /// beta A_f ||R_f N0_f - N_f||^2 beside the fit (relative to the fit's 2 A_f s_f^2 per face).
  /// Infinity ties it exactly (R_f N0_f = N_f, only the in-plane angle free: the first design,
  /// which keeps E_phi low but leaves area at 1.5-5x ARAP's at every rigidity); 0 frees it
  /// (ARAP's rotation: area and E_theta fall, E_phi rises above ARAP's). 0.3 by measurement
  /// (bench/results/rigidity_sweep.md, docs/method.md "Scale control").
  double scale_normal_tie = 0.3;
  /// Build the default cold start's factorization (the rigid start's ARAP solver, see
  /// StartFrom::Auto) on the first solve that starts from it instead of at create. For solvers
  /// always seeded with set_positions (the full-resolution solver of a multiresolution deformer)
  /// it is then never built: less precompute and memory. (The name is older than the rigid
  /// start; the Laplacian-editing guess, a denser bi-Laplacian factorization, is always built by
  /// the first solve that starts from it: StartFrom::Laplacian, or Auto at rigidity 0.)
  bool lazy_laplacian_guess = false;
};

/// The scale-aware deformation solver for one mesh and one handle set.
class ScaleAwareSolver {
 public:
  /// Precomputes everything that depends on the mesh and the handle set.
  /// @param[in] V0           #V x 3 rest positions.
  /// @param[in] F            #F x 3 triangles, validate_triangle_mesh(V0, F) ok.
  /// @param[in] constrained  #C distinct vertex indices (fixed and handle vertices alike).
  /// @return the solver; InvalidArgument for an index out of range or repeated, a mesh that fails
  ///         validation, or a connected component with fewer than two constrained vertices
  ///         (the energy is invariant to translation and scale, so such a component is not pinned:
  ///         the message names the component and one of its vertices); NumericalFailure if a
  ///         factorization fails; Cancelled when `stop` is requested (checked between the
  ///         precompute's phases: a CHOLMOD factorization itself runs to its end).
  /// @param[in] progress     phases "validate", "rigid_start" (unless lazy) and "step_two"
  ///                         (see BuildProgress); may be empty.
  [[nodiscard]] static Result<ScaleAwareSolver> create(const Positions& V0, const Triangles& F,
                                                       const Eigen::VectorXi& constrained,
                                                       const ScaleAwareSettings& settings = {},
                                                       std::stop_token stop = {},
                                                       const BuildProgress& progress = {});
  /// The same for a mesh the caller has validated (validate_triangle_mesh) and whose topology
  /// it has built (build_topology(F, #V)), e.g. a level of a multilevel solver or a server
  /// session's mesh: neither is done again, and the rigid start's ARAP solver and ORA's stitcher
  /// use that topology too. The constrained indices are still checked.
  [[nodiscard]] static Result<ScaleAwareSolver> create(const Positions& V0, const Triangles& F,
                                                       const MeshTopology& topology,
                                                       const Eigen::VectorXi& constrained,
                                                       const ScaleAwareSettings& settings = {},
                                                       std::stop_token stop = {},
                                                       const BuildProgress& progress = {});

  /// Deforms toward #C x 3 targets (row j for constrained(j)).
  /// With options.rigidity > 0 the scale term of core/methods/scale_control.h joins the energy (built on
  /// first use); options.start = Rigid starts from a few ARAP iterations (ARAP factored on first
  /// use).
  /// @return the report (positions and per-iteration history); InvalidArgument for a wrong shape or
  ///         non-finite target, targets of a component that coincide (no two distinct positions),
  ///         rigidity negative or not finite, or rigid_start_iterations < 0;
  ///         Cancelled when `stop` is requested mid-solve (the solver keeps its previous state);
  ///         NumericalFailure if the solve breaks down.
  /// A Previous (or warm Auto) solve toward the same targets, rigidity and stopping test as the
  /// last one continues it: the stopping rule's state, the inexact PCG's reduction and, when
  /// the last solve ended on its max_iterations, Anderson's window carry over, so that short
  /// solves in a row (the server's background refinement slices) take the one long solve's
  /// steps. Its history's iteration 0 is the last solve's final iterate and energy.
  [[nodiscard]] Result<SolveReport> solve(const Positions& targets, const SolveOptions& options = {},
                                          const ProgressCallback& progress = {},
                                          std::stop_token stop = {});

  /// The current positions (the rest mesh before the first solve).
  const Positions& positions() const;
  /// The constrained vertex indices given to create().
  const Eigen::VectorXi& constrained() const;
  /// Forgets the previous result: the next Auto solve starts from the Laplacian guess.
  void reset();
  /// Makes `V` the previous result, so that the next Auto or Previous solve starts from it (for
  /// example a coarse solution prolonged to this mesh, core/multires/multires.h). Step one's rotations
  /// restart cold, as after the Laplacian guess.
  /// @param[in] V  #V x 3 finite positions.
  /// @return InvalidArgument for a wrong shape or a non-finite coordinate (the solver unchanged).
  [[nodiscard]] Status set_positions(const Positions& V);
  /// Builds now what the first solve at `rigidity` would build (the scale term and the
  /// preconditioner factor of that rigidity), e.g. on another thread before the solver is
  /// handed over (core/multires/multires.h); results are the same either way.
  /// @return InvalidArgument for a rigidity that is negative or not finite; NumericalFailure if
  ///         a factorization fails.
  [[nodiscard]] Status prepare(double rigidity);

  ScaleAwareSolver(ScaleAwareSolver&&) noexcept;
  ScaleAwareSolver& operator=(ScaleAwareSolver&&) noexcept;
  ~ScaleAwareSolver();

 private:
  struct Impl;
  explicit ScaleAwareSolver(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// One-off convenience: create + solve.
[[nodiscard]] Result<SolveReport> deform_scale_aware(const Positions& V0, const Triangles& F,
                                                     const Eigen::VectorXi& constrained,
                                                     const Positions& targets,
                                                     const SolveOptions& options = {},
                                                     const ProgressCallback& progress = {});

}  // namespace meshdeform::core
