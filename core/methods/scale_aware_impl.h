#pragma once
/// @file scale_aware_impl.h
/// Internal to the scale-aware solver (scale_aware.cpp: the iteration, the cold start and the
/// public interface; scale_aware_system.cpp: step two's system, its assembly, factorizations and
/// energies; scale_aware_pcg.cpp: the operators, preconditioners and the three PCG forms). Not
/// part of the library's interface: include core/methods/scale_aware.h instead.

#include "core/methods/scale_aware.h"

#include <omp.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <future>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "core/linalg/anderson.h"
#include "core/linalg/sparse_cholesky.h"
#include "core/mesh/measures.h"
#include "core/mesh/topology.h"
#include "core/mesh/validate.h"
#include "core/methods/arap.h"
#include "core/methods/constraints.h"
#include "core/methods/convergence.h"
#include "core/methods/laplacian.h"
#include "core/methods/normals_step.h"
#include "core/methods/ora.h"
#include "core/methods/rotation_start.h"
#include "core/methods/scale_control.h"

namespace meshdeform::core {

/// Helpers shared by the solver's translation units.
namespace scale_aware_detail {

using Clock = std::chrono::steady_clock;

inline double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Rotation by angle (cos c, sin s) about the unit axis n, right-hand rule (Rodrigues).
inline Eigen::Matrix3d rodrigues(const Eigen::Vector3d& n, double c, double s) {
  Eigen::Matrix3d K;
  K << 0, -n.z(), n.y(), n.z(), 0, -n.x(), -n.y(), n.x(), 0;
  return c * Eigen::Matrix3d::Identity() + s * K + (1.0 - c) * n * n.transpose();
}

// Step two's conjugate-gradient iteration preconditioned by a (possibly lagged) factor.
struct PcgOutcome {
  int iterations = 0;
  bool converged = false;
  bool cancelled = false;
};

// Preconditioned conjugate gradients on a symmetric positive definite operator, the one loop of
// step two's three forms (plain, joint, Schur complement): from the caller's iterate x and its
// residual r = b - A x, until |r| <= threshold (converged), max_iterations steps, a breakdown
// (p'Ap <= 0: the caller refactors and retries; neither converged nor cancelled) or a stop
// request (cancelled). apply(p, Ap) is the operator (it may size Ap), precondition(r) returns
// M^-1 r, and on_step(alpha) updates what the caller keeps beside x along the step's direction
// (the Schur form's H^-1 C x).
template <typename Apply, typename Precondition, typename OnStep>
PcgOutcome conjugate_gradients(Eigen::VectorXd& x, Eigen::VectorXd r, double threshold,
                               int max_iterations, const std::stop_token& stop, Apply&& apply,
                               Precondition&& precondition, OnStep&& on_step) {
  PcgOutcome out;
  if (r.norm() <= threshold) {
    out.converged = true;
    return out;
  }
  Eigen::VectorXd z = precondition(r);
  Eigen::VectorXd p = z;
  Eigen::VectorXd Ap(x.size());
  double rz = r.dot(z);
  for (int it = 0; it < max_iterations; ++it) {
    if (stop.stop_requested()) {
      out.cancelled = true;
      return out;
    }
    apply(p, Ap);
    const double pAp = p.dot(Ap);
    if (!(pAp > 0)) break;
    const double alpha = rz / pAp;
    x.noalias() += alpha * p;
    on_step(alpha);
    r.noalias() -= alpha * Ap;
    ++out.iterations;
    if (r.norm() <= threshold) {
      out.converged = true;
      return out;
    }
    z = precondition(r);
    const double rz_next = r.dot(z);
    p = z + (rz_next / rz) * p;
    rz = rz_next;
  }
  return out;
}

}  // namespace scale_aware_detail

using scale_aware_detail::Clock;
using scale_aware_detail::PcgOutcome;

struct ScaleAwareSolver::Impl {
  // Mesh and measures.
  int nv = 0;
  int nf = 0;
  RowPositions V0;
  Triangles F;
  MeshTopology topology;
  RowPositions N0;
  Eigen::VectorXd corner_cos, corner_sin, corner_ratio;  // 3#F, corner 3f+k at F(f,k)
  double bbox_diagonal = 1;
  Eigen::VectorXd rest_phi;  // #IE rest dihedral angles (folds_of)
  // All rest measures, for E_theta / E_phi (track_metrics) and the ORA report: measured on first
  // use, then kept (every candidate and every later solve compares against the same rest).
  std::optional<Measures> rest_measures;
  const Measures& rest() {
    if (!rest_measures) rest_measures = compute_measures(V0, F, topology, threads);
    return *rest_measures;
  }

  // Constraints.
  Eigen::VectorXi constrained;
  std::vector<int> slot;  // #V: row in targets, or -1
  ScaleAwareSettings settings;
  int threads = 1;
  std::optional<LaplacianEditor> laplacian;
  std::optional<RigidityStitcher> stitcher;  // built on the first ORA / magnification request
  // Built at create, or on the first rigid start if lazy; freed by a cold Auto solve.
  std::optional<ArapSolver> rigid_start;
  std::optional<RotationPropagationStart> propagated_start;  // built on the first Propagated start

  // Step two: A(N) = G^T G + lambda C^T C in a fixed 3x3-block pattern (full symmetric storage,
  // columns 3b..3b+2 hold the blocks of b's sorted closed neighbourhood).
  SparseMatrix A;
  std::vector<int> col_base;               // #V: offset of column 3b in the value array
  std::vector<int> col_stride;             // #V: entries per column of b = 3 (deg(b) + 1)
  std::vector<std::array<int, 9>> face_rank;  // rank of F(f,p) within F(f,q)'s neighbourhood
  std::vector<Eigen::Matrix3d> corner_map;    // 3#F: l R(N_f, theta) per corner (lagged path)
  // With the block-trace preconditioner (the default) A is never formed: multiply() applies
  // G^T G + rho (L (x) I3) + lambda C^T C face by face (matrix-free), applying each corner's
  // l R(N_f, theta) from the normal and the rest cosine, sine and ratio (corner_apply) rather
  // than a stored 3x3 matrix: 96 bytes read per face instead of 216, and no per-iteration
  // assembly or storage for A. The lagged-Cholesky preconditioner needs A's values to factor,
  // so only that path forms the corner matrices and fills A.
  RowPositions map_normals;    // #F: the normals of the last assemble()
  bool assembled = false;      // A's pattern exists and assemble() fills it
  double step_two_rho = 0;     // the rigidity of the last assemble(): part of step two's matrix
  mutable std::vector<double> face_products;  // 9#F scratch of the matrix-free multiply
  // The matrix-free multiply's per-face constants (kEdgeForm per face, from the rest measures
  // alone): a face's Eq. 12 energy sum_c ||r_c||^2 is e^T K_f e in its edges e1 = v1 - v0,
  // e2 = v2 - v0, and with M_c = l_c R(n, theta_c) (M^T M = l^2 I, M + M^T and M - M^T in n) the
  // blocks of K_f are alpha I + beta n n^T (diagonal) and gamma I + delta [n]x + epsilon n n^T
  // (off-diagonal): seven numbers and the normal give the face's product (build_edge_form()).
  static constexpr int kEdgeForm = 7;
  std::vector<double> edge_form;
  SparseCholesky cholesky;
  // The block-trace preconditioner T (x) I3, factored: with settings.split_preconditioner (the
  // default) over the factored vertices K only (the free ones and the constrained ones with a
  // free neighbour), the decoupled ones D (constrained, every neighbour constrained: the inside
  // of handle and fixed regions) by their diagonal: [T_KK 0; 0 diag(T_DD)]. Every row of D
  // carries the handle weight lambda (1 + rho), which dominates it, and the coupling the split
  // drops, T_KD, joins two such rows: the free vertices keep all their coupling. Measured
  // (docs/benchmarks.md, issue 13): the PCG steps (within one in 15 iterations) and energies of the whole
  // factor on the Spot edits and the irregular Table 1 models, a factor over 57% of the
  // vertices on Spot 47k's edits (43% constrained): create + prepare about 18% shorter, 14 MiB
  // less peak. (Dropping every constrained vertex instead, coupling to free vertices included,
  // cost 30-50% more PCG steps.)
  struct TraceBlocks {
    SparseCholesky factor;              // T, or T_KK when split
    bool split = false;
    Eigen::VectorXd decoupled_inverse;  // 1 / T(v, v) per decoupled vertex, when split
    bool ready = false;
  };
  std::vector<int> factored_vertices;  // ascending: free, or constrained with a free neighbour
  std::vector<int> factored_index;     // #V: row in T_KK, or -1
  std::vector<int> decoupled_vertices;  // ascending: constrained, every neighbour constrained
  Status factor_trace_blocks(const SparseMatrix& T, TraceBlocks& blocks) const;
  Eigen::VectorXd solve_trace_blocks(const TraceBlocks& blocks, const Eigen::VectorXd& r) const;
  TraceBlocks trace_blocks;  // BlockTrace preconditioner at rho = 0, constant
  // Scale control (issue 12), built on the first solve with rigidity > 0. The block-trace
  // preconditioner then factors T + rho L_cot (still constant per rho): cached for one rho.
  std::optional<ScaleControl> scale_control;
  TraceBlocks trace_rigid_blocks;
  double trace_rigid_rho = -1;
  double preconditioner_rho = 0;  // which factor precondition() uses
  // The handle weight of step two: lambda, times (1 + rigidity) with scale control, since the
  // scale term adds about rigidity times Eq. 12's magnitude and the handles must keep their
  // relative pull (measured: handles drift past 1e-3 of the diagonal otherwise).
  double handle_weight = 0;
  bool refactor_pending = true;
  double pcg_iteration_flops = 0;

  // State carried between solves (warm start).
  Eigen::VectorXd x;  // 3#V current positions, interleaved xyz (row-major #V x 3)
  Positions current;  // the same positions as #V x 3, for positions()
  RowPositions N;     // current normals
  std::vector<Eigen::Quaterniond> rotations;
  bool has_previous = false;
  bool rotations_warm = false;
  // The stopping rule's state after the last committed solve, its targets and rigidity: a solve
  // that continues it (Previous, the same targets and test) carries it over
  // (core/methods/convergence.h), so that short solves in a row are judged as one. Cleared by reset()
  // and set_positions().
  std::optional<ConvergenceMonitor> carried_monitor;
  Positions carried_targets;
  double carried_rho = -1;
  double carried_energy = 0;  // the committed iterate's energy (its last iteration's)
  // Anderson's window, carried the same way: without it every short solve restarts the
  // acceleration, and the server's refinement in 2-iteration slices ran close to the plain
  // iteration (Spot 187k from a drag's end: energy 0.570 after 200 sliced iterations, where one
  // solve converges in 83 at 0.543). Held only while a solve ended on its budget (2 x 6 columns
  // of 3#V doubles: 54 MB at 187k vertices).
  std::optional<AndersonAccelerator> carried_accelerator;
  double carried_merit = 0;

  /// @param[in] checked  the topology of a mesh the caller has validated, or null to validate
  ///                     and build it here.
  Status build(const Positions& V0_in, const Triangles& F_in, const MeshTopology* checked,
               const Eigen::VectorXi& constrained_in, const ScaleAwareSettings& settings_in,
               const std::stop_token& stop, const BuildProgress& progress);
  /// The ARAP solver of the rigid start (factors ARAP's reduced cotangent Laplacian).
  Status build_rigid_start() {
    ArapSettings arap_settings;
    arap_settings.threads = settings.threads;
    MD_ASSIGN_OR_RETURN(ArapSolver built,
                        ArapSolver::create(V0, F, topology, constrained, arap_settings));
    rigid_start.emplace(std::move(built));
    return Status::success();
  }
  /// The scale term's constant system (built once, used at every rigidity > 0).
  Status build_scale_control() {
    ScaleControl control;
    MD_RETURN_IF_ERROR(control.build(V0, F, topology, N0, constrained, settings.scale_pull,
                                     settings.scale_smooth_length));
    control.set_normal_tie(settings.scale_normal_tie);
    control.set_threads(threads);
    scale_control.emplace(std::move(control));
    return Status::success();
  }
  void build_pattern();
  void assemble(const RowPositions& normals, double rigidity = 0.0);
  SparseMatrix block_trace_matrix(double rigidity) const;
  Status prepare_rigidity(double rigidity);
  double joint_energy(const Eigen::VectorXd& pos, const Eigen::VectorXd& target_vec,
                      double rigidity) const;
  Eigen::VectorXd precondition(const Eigen::VectorXd& r) const;
  double energy(const Eigen::VectorXd& pos, const Eigen::VectorXd& target_vec) const;
  Eigen::VectorXd rhs(const Positions& targets) const;
  void multiply(const Eigen::VectorXd& in, Eigen::VectorXd& out) const;
  void multiply_free(const double* in, double* out, const double* scale,
                     double* coupling) const;
  void multiply_joint(const Eigen::VectorXd& in, Eigen::VectorXd& out, double rigidity) const;
  Eigen::VectorXd precondition_joint(const Eigen::VectorXd& r, double rigidity) const;
  PcgOutcome pcg_schur(const Eigen::VectorXd& b, Eigen::VectorXd& x, double rigidity,
                       double reduction, double tolerance, int max_iterations,
                       const std::stop_token& stop);
  PcgOutcome pcg_joint(const Eigen::VectorXd& b, Eigen::VectorXd& sol, double rigidity,
                       double reduction, double tolerance, int max_iterations,
                       const std::stop_token& stop) const;
  PcgOutcome pcg(const Eigen::VectorXd& b, Eigen::VectorXd& sol, double reduction,
                 double tolerance, int max_iterations, const std::stop_token& stop) const;
  RowPositions normals_of(const Eigen::VectorXd& pos, const RowPositions& fallback) const;
  /// One candidate solve: its report and the state a commit would keep.
  struct Candidate {
    SolveReport report;
    Eigen::VectorXd x;
    RowPositions N;
    std::vector<Eigen::Quaterniond> rotations;
    bool rotations_warm = false;
    std::optional<ConvergenceMonitor> monitor;  // the stopping rule's state at its end
    // Anderson's state when the iteration ended on its budget (neither converged nor
    // stopped for folds): the accelerator holds the window up to the returned plain iterate,
    // whose mix a continuing solve forms first; `merit` is the last accepted merit.
    std::optional<AndersonAccelerator> accelerator;
    double merit = 0;
  };
  /// The outer iterations of solve() from one start (Rigid, Laplacian, Propagated, Paper or
  /// Previous),
  /// without the ORA stitch and without committing: the solver's warm-start state is unchanged.
  /// `state`, when given, replaces the solver's own warm-start state for a Previous start;
  /// `until_fold_free` also stops the iteration once the iterate has no folds.
  Result<Candidate> run_from(StartFrom from, const Positions& targets, const SolveOptions& options,
                             const ProgressCallback& progress, const std::stop_token& stop,
                             Clock::time_point start, const Candidate* state = nullptr,
                             bool until_fold_free = false);
  /// Interior edges of `pos` whose dihedral angle moved by more than 90 degrees from the rest
  /// (a crease the rest shape does not have; core::count_folds).
  int folds_of(const Eigen::VectorXd& pos) const;
  void build_edge_form();
  // Whether the joint system's two preconditioner solves run side by side (precondition_joint).
  bool side_by_side_solves() const { return threads > 1 && nv > 2000; }
  /// M u for corner k (3f + c) of a face with normal n, M = l R(n, theta) (rodrigues()), or
  /// M^T u with sign -1: l (cos u + sign sin n x u + (1 - cos)(n . u) n).
  Eigen::Vector3d corner_apply(int k, const Eigen::Vector3d& n, const Eigen::Vector3d& u,
                               double sign) const {
    const double c = corner_cos(k);
    return corner_ratio(k) * (c * u + (sign * corner_sin(k)) * n.cross(u) + ((1.0 - c) * n.dot(u)) * n);
  }
};

}  // namespace meshdeform::core
