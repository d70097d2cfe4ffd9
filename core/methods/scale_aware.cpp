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
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Rotation by angle (cos c, sin s) about the unit axis n, right-hand rule (Rodrigues).
Eigen::Matrix3d rodrigues(const Eigen::Vector3d& n, double c, double s) {
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

}  // namespace

// Auto's cold start (solve()): another start's result replaces the best so far when it has
// fewer folds and at most this multiple of the rigid start's energy.
constexpr double kFoldFreeEnergyRatio = 1.5;

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

  Status build(const Positions& V0_in, const Triangles& F_in, const Eigen::VectorXi& constrained_in,
               const ScaleAwareSettings& settings_in, const std::stop_token& stop,
               const BuildProgress& progress);
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

void ScaleAwareSolver::Impl::build_edge_form() {
  // Corner residuals in the edges: r0 = -M0 e1 + e2, r1 = (M1 - I) e1 - M1 e2,
  // r2 = e1 + (M2 - I) e2 (corner c's residual M_c (v_c - v_{c+1}) + v_{c+2} - v_c), so
  //   K11 = (l0^2 + l1^2 + 2) I - (M1 + M1^T),  K22 = (l1^2 + l2^2 + 2) I - (M2 + M2^T),
  //   K12 = -M0^T + M1 + M2 - (l1^2 + 1) I,
  // and M = l (cos I + sin [n]x + (1 - cos) n n^T).
  edge_form.resize(kEdgeForm * static_cast<size_t>(nf));
  for (int f = 0; f < nf; ++f) {
    double l[3], c[3], s[3];
    for (int k = 0; k < 3; ++k) {
      l[k] = corner_ratio(3 * f + k);
      c[k] = corner_cos(3 * f + k);
      s[k] = corner_sin(3 * f + k);
    }
    double* out = edge_form.data() + kEdgeForm * static_cast<size_t>(f);
    // K11 = alpha1 I + beta1 n n^T, K22 = alpha2 I + beta2 n n^T,
    // K12 = gamma I + delta [n]x + epsilon n n^T.
    out[0] = l[0] * l[0] + l[1] * l[1] + 2.0 - 2.0 * l[1] * c[1];
    out[1] = -2.0 * l[1] * (1.0 - c[1]);
    out[2] = l[1] * l[1] + l[2] * l[2] + 2.0 - 2.0 * l[2] * c[2];
    out[3] = -2.0 * l[2] * (1.0 - c[2]);
    out[4] = -l[0] * c[0] + l[1] * c[1] + l[2] * c[2] - l[1] * l[1] - 1.0;
    out[5] = l[0] * s[0] + l[1] * s[1] + l[2] * s[2];
    out[6] = -l[0] * (1.0 - c[0]) + l[1] * (1.0 - c[1]) + l[2] * (1.0 - c[2]);
  }
}

Status ScaleAwareSolver::Impl::build(const Positions& V0_in, const Triangles& F_in,
                                     const Eigen::VectorXi& constrained_in,
                                     const ScaleAwareSettings& settings_in,
                                     const std::stop_token& stop,
                                     const BuildProgress& progress) {
  const auto check_stop = [&stop]() -> Status {
    if (!stop.stop_requested()) return Status::success();
    return Error(ErrorCode::Cancelled, "precompute cancelled (deadline or client)");
  };
  if (!(settings_in.lambda > 0) || !std::isfinite(settings_in.lambda)) {
    return Error(ErrorCode::InvalidArgument, "lambda must be positive and finite");
  }
  if (!(settings_in.refactor_cost_ratio > 0)) {
    return Error(ErrorCode::InvalidArgument, "refactor_cost_ratio must be positive");
  }
  if (!(settings_in.scale_pull >= 0) || !std::isfinite(settings_in.scale_pull) ||
      !(settings_in.scale_smooth_length >= 0) || !std::isfinite(settings_in.scale_smooth_length) ||
      !(settings_in.scale_normal_tie >= 0)) {
    return Error(ErrorCode::InvalidArgument,
                 "scale_pull and scale_smooth_length must be finite and >= 0, scale_normal_tie "
                 ">= 0 (infinity allowed)");
  }
  report_progress(progress, "validate", 0.0);
  MD_RETURN_IF_ERROR(validate_triangle_mesh(V0_in, F_in));
  MD_ASSIGN_OR_RETURN(topology, build_topology(F_in, static_cast<int>(V0_in.rows())));
  MD_RETURN_IF_ERROR(check_constrained(constrained_in, topology, 2));

  settings = settings_in;
  handle_weight = settings.lambda;
  threads = settings.threads > 0 ? settings.threads : omp_get_max_threads();
  nv = static_cast<int>(V0_in.rows());
  nf = static_cast<int>(F_in.rows());
  V0 = V0_in;
  F = F_in;
  constrained = constrained_in;
  slot.assign(nv, -1);
  for (Eigen::Index j = 0; j < constrained.size(); ++j) slot[constrained(j)] = static_cast<int>(j);
  factored_vertices.clear();
  decoupled_vertices.clear();
  factored_index.assign(nv, -1);
  for (int v = 0; v < nv; ++v) {
    bool factored = slot[v] < 0;
    for (int t = topology.vv_offsets[v]; !factored && t < topology.vv_offsets[v + 1]; ++t) {
      factored = slot[topology.vv_neighbors[t]] < 0;
    }
    if (!factored) {
      decoupled_vertices.push_back(v);
      continue;
    }
    factored_index[v] = static_cast<int>(factored_vertices.size());
    factored_vertices.push_back(v);
  }
  bbox_diagonal = (V0.colwise().maxCoeff() - V0.colwise().minCoeff()).norm();

  const Measures rest = compute_measures(V0_in, F_in, topology);
  corner_cos = rest.theta.array().cos();
  corner_sin = rest.theta.array().sin();
  corner_ratio = rest.ratio;
  build_edge_form();
  rest_phi = rest.phi;
  N0 = face_normals(V0_in, F_in);
  report_progress(progress, "validate", 1.0);

  MD_RETURN_IF_ERROR(check_stop());
  if (!settings.lazy_laplacian_guess) {
    // The default start's factor (Auto at rigidity > 0: the rigid start). The Laplacian guess
    // (a denser bi-Laplacian factor) is built by the first solve that starts from it.
    report_progress(progress, "rigid_start", 0.0);
    if (threads > 1) {
      // Two independent factorizations on two cores: ARAP's Laplacian here and the scale
      // term's face system (which every solve at rigidity > 0, the default, needs) beside it.
      // 46,850-vertex Spot: 0.5-0.7 s and 0.7 s one after the other.
      std::future<Status> scale = std::async(std::launch::async, [this] {
        return build_scale_control();
      });
      const Status rigid = build_rigid_start();
      const Status built = scale.get();
      MD_RETURN_IF_ERROR(rigid);
      MD_RETURN_IF_ERROR(built);
    } else {
      MD_RETURN_IF_ERROR(build_rigid_start());
    }
    report_progress(progress, "rigid_start", 1.0);
    MD_RETURN_IF_ERROR(check_stop());
  }

  report_progress(progress, "step_two", 0.0);
  build_pattern();
  // The rest normals give the first numeric factor; later systems reuse it as a preconditioner.
  assemble(N0);
  MD_RETURN_IF_ERROR(check_stop());
  if (settings.preconditioner == StepTwoPreconditioner::BlockTrace) {
    // The block-trace factor is built by the first solve that needs it (prepare_rigidity): at
    // rigidity 0 that is T's, with scale control T + rho L's, so creating a solver that only
    // ever runs at the default rigidity never factors T (one n x n factorization less).
    refactor_pending = false;
  } else {
    MD_RETURN_IF_ERROR(cholesky.analyze(A));
    MD_RETURN_IF_ERROR(cholesky.factorize(A));
    refactor_pending = false;
  }
  // Triangular solves are memory-bound and a supernodal factorization runs BLAS-3: measured on
  // this project's 2-core machine, a solve flop costs 2-6x a factorization flop (a factorization
  // took the time of 13 solves on 40k vertices, 19 on 5k, against flop ratios of 77 and 34).
  // Weighting solve flops by 5 keeps the rule deterministic while near the real break-even
  // (measured on the Table 1 suite: 2x faster than weight 1 on the ~5k models, same errors).
  constexpr double kSolveFlopWeight = 5.0;
  pcg_iteration_flops =
      settings.preconditioner == StepTwoPreconditioner::BlockTrace
          ? 0.0
          : kSolveFlopWeight * (cholesky.solve_flops() + 2.0 * static_cast<double>(A.nonZeros()));

  x = Eigen::Map<const Eigen::VectorXd>(V0.data(), 3 * nv);
  current = V0_in;
  N = N0;
  rotations.assign(nv, Eigen::Quaterniond::Identity());
  has_previous = false;
  rotations_warm = true;  // identity is exact at rest
  report_progress(progress, "step_two", 1.0);
  return Status::success();
}

void ScaleAwareSolver::Impl::build_pattern() {
  assembled = settings.preconditioner == StepTwoPreconditioner::LaggedCholesky;
  if (!assembled) {
    // face_products is allocated by the first multiply: a solver's first, cold solve runs its
    // start (converged ARAP and its Anderson history at the default) before any product, so
    // the 72 B per face are not held beside the start's arrays at the solve's peak.
    face_products.clear();
    return;
  }
  corner_map.resize(3 * static_cast<size_t>(nf));
  col_base.resize(nv);
  col_stride.resize(nv);
  long long nnz = 0;
  for (int b = 0; b < nv; ++b) {
    const int degree = topology.vv_offsets[b + 1] - topology.vv_offsets[b];
    col_base[b] = static_cast<int>(nnz);
    col_stride[b] = 3 * (degree + 1);
    nnz += 3LL * col_stride[b];
  }
  A.resize(3 * nv, 3 * nv);
  A.resizeNonZeros(static_cast<Eigen::Index>(nnz));
  int* outer = A.outerIndexPtr();
  int* inner = A.innerIndexPtr();
  for (int b = 0; b < nv; ++b) {
    // Closed neighbourhood of b in ascending order.
    std::vector<int> hood(topology.vv_neighbors.begin() + topology.vv_offsets[b],
                          topology.vv_neighbors.begin() + topology.vv_offsets[b + 1]);
    hood.insert(std::lower_bound(hood.begin(), hood.end(), b), b);
    for (int d = 0; d < 3; ++d) {
      int* rows = inner + col_base[b] + d * col_stride[b];
      outer[3 * b + d] = col_base[b] + d * col_stride[b];
      for (size_t r = 0; r < hood.size(); ++r) {
        for (int c = 0; c < 3; ++c) rows[3 * r + c] = 3 * hood[r] + c;
      }
    }
  }
  outer[3 * nv] = static_cast<int>(nnz);
  std::fill(A.valuePtr(), A.valuePtr() + nnz, 0.0);

  auto rank_in = [&](int a, int b) {
    const auto first = topology.vv_neighbors.begin() + topology.vv_offsets[b];
    const auto last = topology.vv_neighbors.begin() + topology.vv_offsets[b + 1];
    const int below = static_cast<int>(std::lower_bound(first, last, a) - first);
    return a == b ? below : below + (b < a ? 1 : 0);
  };
  face_rank.resize(nf);
  for (int f = 0; f < nf; ++f) {
    for (int p = 0; p < 3; ++p) {
      for (int q = 0; q < 3; ++q) face_rank[f][3 * p + q] = rank_in(F(f, p), F(f, q));
    }
  }
}

void ScaleAwareSolver::Impl::assemble(const RowPositions& normals, double rigidity) {
  map_normals = normals;
  step_two_rho = rigidity;
  if (!assembled) return;  // multiply() works from the normals
  const bool parallel = nv > 2000 && threads > 1;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (int f = 0; f < nf; ++f) {
    const Eigen::Vector3d n = normals.row(f).transpose();
    for (int k = 0; k < 3; ++k) {
      const int c = 3 * f + k;
      corner_map[c] = corner_ratio(c) * rodrigues(n, corner_cos(c), corner_sin(c));
    }
  }
  // Each thread owns whole block columns, so no two threads write the same value. Within a
  // column, faces are visited in ascending order, which keeps A exactly symmetric.
  double* values = A.valuePtr();
  const double lambda = handle_weight;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (int b = 0; b < nv; ++b) {
    double* column = values + col_base[b];
    const int stride = col_stride[b];
    std::fill(column, column + 3 * stride, 0.0);
    for (int t = topology.vf_offsets[b]; t < topology.vf_offsets[b + 1]; ++t) {
      const int f = topology.vf_faces[t];
      const int q = F(f, 0) == b ? 0 : (F(f, 1) == b ? 1 : 2);
      // Corner c: r = (M - I) v_c - M v_{c+1} + v_{c+2} with M = l R, so M^T M = l^2 I and
      // every block K_p^T K_q is a combination of M, M^T and I: no 3x3 products needed.
      // The mirror block (q, p) in another column comes out as the exact transpose, so A stays
      // exactly symmetric.
      Eigen::Matrix3d blocks[3];
      for (auto& m : blocks) m.setZero();
      for (int c = 0; c < 3; ++c) {
        const Eigen::Matrix3d& M = corner_map[3 * f + c];
        const double l2 = corner_ratio(3 * f + c) * corner_ratio(3 * f + c);
        // Role of a local vertex in this corner: 0 = v (K = M - I), 1 = v_{c+1} (K = -M),
        // 2 = v_{c+2} (K = I).
        const int role_q = (q - c + 3) % 3;
        for (int p = 0; p < 3; ++p) {
          const int role_p = (p - c + 3) % 3;
          Eigen::Matrix3d& out = blocks[p];
          switch (3 * role_p + role_q) {
            case 0:  // (M-I)^T (M-I) = (l^2 + 1) I - M - M^T
              out -= M + M.transpose();
              out.diagonal().array() += l2 + 1.0;
              break;
            case 1:  // (M-I)^T (-M) = M - l^2 I
              out += M;
              out.diagonal().array() -= l2;
              break;
            case 3:  // (-M)^T (M-I) = M^T - l^2 I
              out += M.transpose();
              out.diagonal().array() -= l2;
              break;
            case 2:  // (M-I)^T I = M^T - I
              out += M.transpose();
              out.diagonal().array() -= 1.0;
              break;
            case 6:  // I (M-I) = M - I
              out += M;
              out.diagonal().array() -= 1.0;
              break;
            case 4:  // (-M)^T (-M) = l^2 I
              out.diagonal().array() += l2;
              break;
            case 5:  // (-M)^T I = -M^T
              out -= M.transpose();
              break;
            case 7:  // I (-M) = -M
              out -= M;
              break;
            default:  // case 8: I I
              out.diagonal().array() += 1.0;
              break;
          }
        }
      }
      for (int p = 0; p < 3; ++p) {
        const int rank = face_rank[f][3 * p + q];
        for (int d = 0; d < 3; ++d) {
          for (int r = 0; r < 3; ++r) column[d * stride + 3 * rank + r] += blocks[p](r, d);
        }
      }
      if (rigidity > 0) {
        // The scale term's fit adds rho (L_cot (x) I3): the same vertex-adjacency pattern.
        double cot[9];
        scale_control->face_laplacian_block(f, cot);
        for (int p = 0; p < 3; ++p) {
          const int rank = face_rank[f][3 * p + q];
          const double value = rigidity * cot[3 * p + q];
          for (int d = 0; d < 3; ++d) column[d * stride + 3 * rank + d] += value;
        }
      }
    }
    if (slot[b] >= 0) {
      // Position of b in its own closed neighbourhood: number of neighbours below b.
      const auto first = topology.vv_neighbors.begin() + topology.vv_offsets[b];
      const auto last = topology.vv_neighbors.begin() + topology.vv_offsets[b + 1];
      const int own = static_cast<int>(std::lower_bound(first, last, b) - first);
      for (int d = 0; d < 3; ++d) column[d * stride + 3 * own + d] += lambda;
    }
  }
}

SparseMatrix ScaleAwareSolver::Impl::block_trace_matrix(double rigidity) const {
  // tr/3 of each block of G^T G with the case table of assemble(): tr M = l (1 + 2 cos theta),
  // whatever the normal, so this matrix is fixed by the rest measures alone. tr/3 of
  // rho (L (x) I3) is rho L. Written straight into the vertex-adjacency pattern (column b: b's
  // sorted closed neighbourhood), faces in index order and the handles last, the order in which
  // a triplet list would have summed them (a list of 9 entries per face was the solver's peak
  // memory, and sorting it 4% of create + prepare on the irregular models).
  SparseMatrix T(nv, nv);
  T.resizeNonZeros(static_cast<Eigen::Index>(topology.vv_neighbors.size()) + nv);
  int* outer = T.outerIndexPtr();
  int* inner = T.innerIndexPtr();
  double* values = T.valuePtr();
  int k = 0;
  for (int b = 0; b < nv; ++b) {
    outer[b] = k;
    bool own = false;
    for (int t = topology.vv_offsets[b]; t < topology.vv_offsets[b + 1]; ++t) {
      const int j = topology.vv_neighbors[t];
      if (!own && j > b) inner[k++] = b, own = true;
      inner[k++] = j;
    }
    if (!own) inner[k++] = b;
  }
  outer[nv] = k;
  std::fill(values, values + k, 0.0);
  const auto entry = [&](int row, int col) -> double& {
    return values[std::lower_bound(inner + outer[col], inner + outer[col + 1], row) - inner];
  };
  for (int f = 0; f < nf; ++f) {
    double block[9] = {0, 0, 0, 0, 0, 0, 0, 0, 0};
    for (int c = 0; c < 3; ++c) {
      const int corner = 3 * f + c;
      const double l = corner_ratio(corner), l2 = l * l;
      const double tr = l * (1.0 + 2.0 * corner_cos(corner));
      for (int p = 0; p < 3; ++p) {
        for (int q = 0; q < 3; ++q) {
          const int role_p = (p - c + 3) % 3, role_q = (q - c + 3) % 3;
          double value = 0;
          switch (3 * role_p + role_q) {
            case 0: value = l2 + 1.0 - 2.0 * tr / 3.0; break;
            case 1: case 3: value = tr / 3.0 - l2; break;
            case 2: case 6: value = tr / 3.0 - 1.0; break;
            case 4: value = l2; break;
            case 5: case 7: value = -tr / 3.0; break;
            default: value = 1.0; break;
          }
          block[3 * p + q] += value;
        }
      }
    }
    double cot[9];
    if (rigidity > 0) scale_control->face_laplacian_block(f, cot);
    for (int p = 0; p < 3; ++p) {
      for (int q = 0; q < 3; ++q) {
        double value = block[3 * p + q];
        if (rigidity > 0) value += rigidity * cot[3 * p + q];
        entry(F(f, p), F(f, q)) += value;
      }
    }
  }
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    entry(constrained(j), constrained(j)) += handle_weight;
  }
  return T;
}

Status ScaleAwareSolver::Impl::prepare_rigidity(double rigidity) {
  if (settings.preconditioner == StepTwoPreconditioner::LaggedCholesky &&
      rigidity != preconditioner_rho) {
    refactor_pending = true;  // A(N) + rho L changed by more than the lag rule can know
  }
  preconditioner_rho = rigidity;
  handle_weight = rigidity == 0 ? settings.lambda : settings.lambda * (1.0 + rigidity);
  if (rigidity == 0) {
    if (settings.preconditioner == StepTwoPreconditioner::BlockTrace && !trace_blocks.ready) {
      MD_RETURN_IF_ERROR(factor_trace_blocks(block_trace_matrix(0.0), trace_blocks));
    }
    return Status::success();
  }
  // Scale control first: T + rho L's L is the scale term's face Laplacian.
  if (!scale_control) MD_RETURN_IF_ERROR(build_scale_control());
  if (settings.preconditioner == StepTwoPreconditioner::BlockTrace && trace_rigid_rho != rigidity) {
    // The preconditioner stays constant for a given rho, so only a change of rho (a slider
    // move) refactors this n x n matrix.
    trace_rigid_rho = -1;
    MD_RETURN_IF_ERROR(factor_trace_blocks(block_trace_matrix(rigidity), trace_rigid_blocks));
    trace_rigid_rho = rigidity;
  }
  return Status::success();
}

double ScaleAwareSolver::Impl::joint_energy(const Eigen::VectorXd& pos,
                                            const Eigen::VectorXd& target_vec,
                                            double rigidity) const {
  const double e = energy(pos, target_vec);
  return rigidity > 0 ? e + rigidity * scale_control->energy(pos) : e;
}

Status ScaleAwareSolver::Impl::factor_trace_blocks(const SparseMatrix& T,
                                                  TraceBlocks& blocks) const {
  blocks.ready = false;
  blocks.split = settings.split_preconditioner && !decoupled_vertices.empty();
  // Constant for the solver's life (per rho) and solved once per PCG step: the simplicial form
  // solves faster than the supernodal one (sparse_cholesky.h).
  blocks.factor.set_simplicial_solves(true);
  if (!blocks.split) {
    MD_RETURN_IF_ERROR(blocks.factor.analyze(T));
    MD_RETURN_IF_ERROR(blocks.factor.factorize(T));
    blocks.ready = true;
    return Status::success();
  }
  blocks.decoupled_inverse.resize(static_cast<Eigen::Index>(decoupled_vertices.size()));
  for (size_t j = 0; j < decoupled_vertices.size(); ++j) {
    const int v = decoupled_vertices[j];
    const double diagonal = T.coeff(v, v);
    if (!(diagonal > 0)) {
      return Error(ErrorCode::NumericalFailure,
                   "block-trace preconditioner: non-positive diagonal at constrained vertex " +
                       std::to_string(v));
    }
    blocks.decoupled_inverse(static_cast<Eigen::Index>(j)) = 1.0 / diagonal;
  }
  // T_KK in T's full symmetric storage: the factored columns and their factored rows (still
  // sorted: factored_index increases with the vertex index). Empty when every vertex is
  // constrained.
  const int nk = static_cast<int>(factored_vertices.size());
  if (nk == 0) {
    blocks.ready = true;
    return Status::success();
  }
  SparseMatrix TKK(nk, nk);
  TKK.resizeNonZeros(T.nonZeros());
  int* outer = TKK.outerIndexPtr();
  int* inner = TKK.innerIndexPtr();
  double* values = TKK.valuePtr();
  int k = 0;
  for (int c = 0; c < nk; ++c) {
    outer[c] = k;
    const int b = factored_vertices[c];
    for (Eigen::Index t = T.outerIndexPtr()[b]; t < T.outerIndexPtr()[b + 1]; ++t) {
      const int row = factored_index[T.innerIndexPtr()[t]];
      if (row < 0) continue;
      inner[k] = row;
      values[k++] = T.valuePtr()[t];
    }
  }
  outer[nk] = k;
  TKK.resizeNonZeros(k);
  MD_RETURN_IF_ERROR(blocks.factor.analyze(TKK));
  MD_RETURN_IF_ERROR(blocks.factor.factorize(TKK));
  blocks.ready = true;
  return Status::success();
}

Eigen::VectorXd ScaleAwareSolver::Impl::solve_trace_blocks(const TraceBlocks& blocks,
                                                           const Eigen::VectorXd& r) const {
  // The interleaved xyz vector is an #V x 3 row-major matrix: (T (x) I3)^-1 solves its columns.
  if (!blocks.split) {
    const Eigen::MatrixXd R = Eigen::Map<const RowPositions>(r.data(), nv, 3);
    const RowPositions Z = blocks.factor.solve(R);
    return Eigen::Map<const Eigen::VectorXd>(Z.data(), 3 * static_cast<Eigen::Index>(nv));
  }
  Eigen::VectorXd out(r.size());
  const int nk = static_cast<int>(factored_vertices.size());
  if (nk > 0) {
    Eigen::MatrixXd R(nk, 3);
    for (int k = 0; k < nk; ++k) R.row(k) = r.segment<3>(3 * factored_vertices[k]).transpose();
    const Eigen::MatrixXd Z = blocks.factor.solve(R);
    for (int k = 0; k < nk; ++k) out.segment<3>(3 * factored_vertices[k]) = Z.row(k).transpose();
  }
  for (size_t j = 0; j < decoupled_vertices.size(); ++j) {
    const int v = decoupled_vertices[j];
    out.segment<3>(3 * v) =
        blocks.decoupled_inverse(static_cast<Eigen::Index>(j)) * r.segment<3>(3 * v);
  }
  return out;
}

Eigen::VectorXd ScaleAwareSolver::Impl::precondition(const Eigen::VectorXd& r) const {
  if (settings.preconditioner == StepTwoPreconditioner::LaggedCholesky) return cholesky.solve(r);
  return solve_trace_blocks(preconditioner_rho > 0 ? trace_rigid_blocks : trace_blocks, r);
}

Eigen::VectorXd ScaleAwareSolver::Impl::rhs(const Positions& targets) const {
  Eigen::VectorXd b = Eigen::VectorXd::Zero(3 * nv);
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    b.segment<3>(3 * constrained(j)) = handle_weight * targets.row(j).transpose();
  }
  return b;
}

double ScaleAwareSolver::Impl::energy(const Eigen::VectorXd& pos,
                                      const Eigen::VectorXd& target_vec) const {
  // Sum of squared corner residuals with the current corner maps, plus the handle term.
  std::vector<double> per_face(nf);
  const bool parallel = nv > 2000 && threads > 1;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (int f = 0; f < nf; ++f) {
    const Eigen::Vector3d n = map_normals.row(f).transpose();
    double s = 0;
    for (int c = 0; c < 3; ++c) {
      const Eigen::Vector3d v = pos.segment<3>(3 * F(f, c));
      const Eigen::Vector3d e1 = pos.segment<3>(3 * F(f, (c + 1) % 3)) - v;
      const Eigen::Vector3d e2 = pos.segment<3>(3 * F(f, (c + 2) % 3)) - v;
      s += (e2 - corner_apply(3 * f + c, n, e1, 1.0)).squaredNorm();
    }
    per_face[f] = s;
  }
  double e = 0;
  for (double s : per_face) e += s;
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    e += handle_weight *
         (pos.segment<3>(3 * constrained(j)) - target_vec.segment<3>(3 * j)).squaredNorm();
  }
  return e;
}

void ScaleAwareSolver::Impl::multiply_free(const double* in, double* out, const double* scale,
                                           double* coupling) const {
  // Per face, G^T G of Eq. 12's corner residuals r = M (v_a - v_b) + v_d - v_a (a, b, d the
  // corner's vertex and the next two) as the face's edge form (build_edge_form(): 2.5x fewer
  // flops than forming r and M^T r corner by corner); plus rho times the face's cotangent
  // block; with `scale`, the joint system's coupling in the same pass (the face's
  // -rho s_f C^T column, and (C x)_f). Each face
  // writes its three vertex sums to its own slot, and each vertex then gathers its faces' slots
  // in a fixed order: no races, and the same sums at any thread count.
  const bool parallel = nv > 2000 && threads > 1;
  const double rho = step_two_rho;
  if (face_products.empty()) face_products.resize(9 * static_cast<size_t>(nf));
  double* products = face_products.data();
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (int f = 0; f < nf; ++f) {
    Eigen::Vector3d v[3], sum[3];
    for (int p = 0; p < 3; ++p) {
      v[p] = Eigen::Map<const Eigen::Vector3d>(in + 3 * static_cast<size_t>(F(f, p)));
      sum[p].setZero();
    }
    // K_f applied to the edges (build_edge_form()): y1 = K11 e1 + K12 e2, y2 = K12^T e1 + K22 e2,
    // and the vertex sums D^T y: -(y1 + y2), y1, y2.
    const Eigen::Vector3d n = map_normals.row(f).transpose();
    const double* k = edge_form.data() + kEdgeForm * static_cast<size_t>(f);
    const Eigen::Vector3d e1 = v[1] - v[0], e2 = v[2] - v[0];
    const double n1 = n.dot(e1), n2 = n.dot(e2);
    const Eigen::Vector3d y1 =
        k[0] * e1 + k[4] * e2 + k[5] * n.cross(e2) + (k[1] * n1 + k[6] * n2) * n;
    const Eigen::Vector3d y2 =
        k[4] * e1 + k[2] * e2 - k[5] * n.cross(e1) + (k[6] * n1 + k[3] * n2) * n;
    sum[0] -= y1 + y2;
    sum[1] += y1;
    sum[2] += y2;
    if (rho > 0) {
      double block[9];
      scale_control->face_laplacian_block(f, block);
      for (int p = 0; p < 3; ++p) {
        sum[p] += rho * (block[3 * p] * v[0] + block[3 * p + 1] * v[1] + block[3 * p + 2] * v[2]);
      }
    }
    if (scale != nullptr) {
      coupling[f] = scale_control->face_coupling(f, v, -rho * scale[f], sum);
    }
    double* slot_of_f = products + 9 * static_cast<size_t>(f);
    for (int p = 0; p < 3; ++p) {
      for (int d = 0; d < 3; ++d) slot_of_f[3 * p + d] = sum[p](d);
    }
  }
  const double lambda = handle_weight;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (int b = 0; b < nv; ++b) {
    double y[3] = {0, 0, 0};
    for (int t = topology.vf_offsets[b]; t < topology.vf_offsets[b + 1]; ++t) {
      const int f = topology.vf_faces[t];
      const int q = F(f, 0) == b ? 0 : (F(f, 1) == b ? 1 : 2);
      const double* from = products + 9 * static_cast<size_t>(f) + 3 * q;
      for (int d = 0; d < 3; ++d) y[d] += from[d];
    }
    if (slot[b] >= 0) {
      for (int d = 0; d < 3; ++d) y[d] += lambda * in[3 * b + d];
    }
    for (int d = 0; d < 3; ++d) out[3 * b + d] = y[d];
  }
}

void ScaleAwareSolver::Impl::multiply(const Eigen::VectorXd& in, Eigen::VectorXd& out) const {
  if (!assembled) {
    out.resize(in.size());
    multiply_free(in.data(), out.data(), nullptr, nullptr);
    return;
  }
  // A is stored in full, so A x = A^T x: each output entry gathers one column.
  const int* outer = A.outerIndexPtr();
  const int* inner = A.innerIndexPtr();
  const double* values = A.valuePtr();
  const int n = static_cast<int>(A.cols());
  out.resize(n);
  const bool parallel = nv > 2000 && threads > 1;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (int c = 0; c < n; ++c) {
    double s = 0;
    for (int k = outer[c]; k < outer[c + 1]; ++k) s += values[k] * in[inner[k]];
    out[c] = s;
  }
}

// Stops when the residual is below `reduction` times the starting residual (the inexact part:
// the warm start is already close) or below `tolerance` times |b| (the absolute floor).
PcgOutcome ScaleAwareSolver::Impl::pcg(const Eigen::VectorXd& b, Eigen::VectorXd& sol,
                                       double reduction, double tolerance, int max_iterations,
                                       const std::stop_token& stop) const {
  const double b_norm = b.norm();
  if (b_norm == 0) {
    sol.setZero();
    PcgOutcome out;
    out.converged = true;
    return out;
  }
  Eigen::VectorXd Ap;
  multiply(sol, Ap);
  Eigen::VectorXd r = b - Ap;
  const double threshold = std::max(tolerance * b_norm, reduction * r.norm());
  return conjugate_gradients(
      sol, std::move(r), threshold, max_iterations, stop,
      [this](const Eigen::VectorXd& p, Eigen::VectorXd& Ap) { multiply(p, Ap); },
      [this](const Eigen::VectorXd& r) { return precondition(r); }, [](double) {});
}

// Step two with scale control solves for the vertices and the face scales together: the joint
// energy is one quadratic in (x, s) once the normals and face frames are fixed,
//   [A + rho L, -rho C^T; -rho C, rho H] [x; s] = [b; rho r],
// and alternating x- and s-steps converge slowly along the scale mode (measured: the area kept
// shrinking for 100+ iterations). The preconditioner is block diagonal: the x block's (the
// block-trace T + rho L, or the lagged factor) and H's constant factor.
void ScaleAwareSolver::Impl::multiply_joint(const Eigen::VectorXd& in, Eigen::VectorXd& out,
                                            double rigidity) const {
  const Eigen::Index n3 = 3 * static_cast<Eigen::Index>(nv);
  const Eigen::Index m = in.size() - n3;
  if (!assembled) {
    // One pass over the faces for the x block and both coupling products.
    out.resize(in.size());
    Eigen::VectorXd cx = Eigen::VectorXd::Zero(m);  // (C x); 0 for a free reference scale
    multiply_free(in.data(), out.data(), in.data() + n3, cx.data());
    Eigen::VectorXd hs;
    scale_control->multiply_scale_matrix(in.tail(m), hs);
    out.tail(m) = rigidity * (hs - cx);
    return;
  }
  Eigen::VectorXd out_x;
  multiply(in.head(n3), out_x);
  scale_control->add_coupling_transpose(in.tail(m), -rigidity, out_x);
  Eigen::VectorXd cx, hs;
  scale_control->multiply_coupling(in.head(n3), cx);
  scale_control->multiply_scale_matrix(in.tail(m), hs);
  out.resize(in.size());
  out.head(n3) = out_x;
  out.tail(m) = rigidity * (hs - cx);
}

Eigen::VectorXd ScaleAwareSolver::Impl::precondition_joint(const Eigen::VectorXd& r,
                                                           double rigidity) const {
  const Eigen::Index n3 = 3 * static_cast<Eigen::Index>(nv);
  const Eigen::Index m = r.size() - n3;
  Eigen::VectorXd out(r.size());
  // Two independent triangular solves (the x block's n x n factor with three right-hand sides,
  // H's #F x #F factor): sequential by nature, but they can run side by side.
#pragma omp parallel sections num_threads(2) if (side_by_side_solves())
  {
#pragma omp section
    out.head(n3) = precondition(r.head(n3));
#pragma omp section
    out.tail(m) = scale_control->solve_scale_matrix(r.tail(m)) / rigidity;
  }
  return out;
}

PcgOutcome ScaleAwareSolver::Impl::pcg_joint(const Eigen::VectorXd& b, Eigen::VectorXd& sol,
                                             double rigidity, double reduction, double tolerance,
                                             int max_iterations, const std::stop_token& stop) const {
  Eigen::VectorXd Ap;
  multiply_joint(sol, Ap, rigidity);
  Eigen::VectorXd r = b - Ap;
  const double threshold = std::max(tolerance * b.norm(), reduction * r.norm());
  return conjugate_gradients(
      sol, std::move(r), threshold, max_iterations, stop,
      [&](const Eigen::VectorXd& p, Eigen::VectorXd& Ap) { multiply_joint(p, Ap, rigidity); },
      [&](const Eigen::VectorXd& r) { return precondition_joint(r, rigidity); }, [](double) {});
}

// Step two with scale control, the scales eliminated: the joint system's second row gives
// s = H^-1 (r + C x), and substituting it leaves the Schur complement
//   S x = (A + rho L - rho C^T H^-1 C) x = b + rho C^T H^-1 r,
// the same solution. CG on S minimises min_s of the joint energy over x, so every step lowers the
// joint energy (as the joint CG does). Preconditioned with the x block's factor alone: the joint
// system's block-diagonal preconditioner leaves the x-s coupling in the spectrum, S does not
// (measured: 15-25% fewer steps on the irregular models and the Spot edits, results equal to the
// joint solve's to the PCG tolerance). A step costs what a joint step costs: C p, one solve with
// H's factor and the face pass for S p (the joint step: the face pass, H p and the same two
// solves), but its two solves depend on each other, where the joint step's can run side by
// side: on two threads the joint system is faster (side_by_side_solves()). Precondition: the
// scales are the exact minimiser for x (step one ends with update_scales()), so H^-1 C x is
// known without a solve. Leaves the scales of the result in the scale control.
PcgOutcome ScaleAwareSolver::Impl::pcg_schur(const Eigen::VectorXd& b, Eigen::VectorXd& x,
                                             double rigidity, double reduction, double tolerance,
                                             int max_iterations, const std::stop_token& stop) {
  ScaleControl& sc = *scale_control;
  const Eigen::VectorXd scale_rhs = sc.scale_rhs();
  // H^-1 r: zero with a free reference scale (r = 0).
  const Eigen::VectorXd hr = scale_rhs.cwiseAbs().maxCoeff() > 0
                                 ? sc.solve_scale_matrix(scale_rhs)
                                 : Eigen::VectorXd::Zero(scale_rhs.size());
  Eigen::VectorXd b_reduced = b;
  sc.add_coupling_transpose(hr, rigidity, b_reduced);
  std::vector<double> coupling(nf);  // multiply_free's (C x) output, unused here
  Eigen::VectorXd hcx = sc.scale_unknowns_vector() - hr;  // H^-1 C x for the current x
  Eigen::VectorXd Ap(x.size());
  multiply_free(x.data(), Ap.data(), hcx.data(), coupling.data());
  Eigen::VectorXd r = b_reduced - Ap;
  const double threshold = std::max(tolerance * b_reduced.norm(), reduction * r.norm());
  // S p = A p + rho L p - rho C^T (H^-1 C p): the face pass takes H^-1 C p as its scales.
  Eigen::VectorXd cp, hcp;
  const PcgOutcome out = conjugate_gradients(
      x, std::move(r), threshold, max_iterations, stop,
      [&](const Eigen::VectorXd& p, Eigen::VectorXd& Sp) {
        sc.multiply_coupling(p, cp);
        hcp = sc.solve_scale_matrix(cp);
        multiply_free(p.data(), Sp.data(), hcp.data(), coupling.data());
      },
      [this](const Eigen::VectorXd& r) { return precondition(r); },
      [&](double alpha) { hcx.noalias() += alpha * hcp; });
  // The scales that minimise the joint energy for the new x (a cancelled step two leaves them:
  // the caller discards its iterate).
  if (!out.cancelled) sc.set_scale_unknowns(hr + hcx);
  return out;
}

RowPositions ScaleAwareSolver::Impl::normals_of(const Eigen::VectorXd& pos,
                                                const RowPositions& fallback) const {
  RowPositions out(nf, 3);
  const bool parallel = nv > 2000 && threads > 1;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (int f = 0; f < nf; ++f) {
    const Eigen::Vector3d a = pos.segment<3>(3 * F(f, 0));
    const Eigen::Vector3d n =
        (pos.segment<3>(3 * F(f, 1)) - a).cross(pos.segment<3>(3 * F(f, 2)) - a);
    const double len = n.norm();
    // A collapsed face has no normal: keep its previous one.
    if (len > 1e-300) {
      out.row(f) = (n / len).transpose();
    } else {
      out.row(f) = fallback.row(f);
    }
  }
  return out;
}

ScaleAwareSolver::ScaleAwareSolver(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ScaleAwareSolver::ScaleAwareSolver(ScaleAwareSolver&&) noexcept = default;
ScaleAwareSolver& ScaleAwareSolver::operator=(ScaleAwareSolver&&) noexcept = default;
ScaleAwareSolver::~ScaleAwareSolver() = default;

Result<ScaleAwareSolver> ScaleAwareSolver::create(const Positions& V0, const Triangles& F,
                                                  const Eigen::VectorXi& constrained,
                                                  const ScaleAwareSettings& settings,
                                                  std::stop_token stop,
                                                  const BuildProgress& progress) {
  auto impl = std::make_unique<Impl>();
  MD_RETURN_IF_ERROR(impl->build(V0, F, constrained, settings, stop, progress));
  return ScaleAwareSolver(std::move(impl));
}

const Positions& ScaleAwareSolver::positions() const { return impl_->current; }

const Eigen::VectorXi& ScaleAwareSolver::constrained() const { return impl_->constrained; }

void ScaleAwareSolver::reset() {
  Impl& s = *impl_;
  s.x = Eigen::Map<const Eigen::VectorXd>(s.V0.data(), 3 * s.nv);
  s.current = s.V0;
  s.N = s.N0;
  s.rotations.assign(s.nv, Eigen::Quaterniond::Identity());
  s.rotations_warm = true;
  s.has_previous = false;
  s.carried_monitor.reset();
}

Status ScaleAwareSolver::set_positions(const Positions& V) {
  Impl& s = *impl_;
  if (V.rows() != s.nv || !V.allFinite()) {
    return Error(ErrorCode::InvalidArgument,
                 "set_positions needs " + std::to_string(s.nv) + " finite rows, got " +
                     std::to_string(V.rows()) + (V.allFinite() ? "" : " with a non-finite value"));
  }
  const RowPositions rows = V;
  s.x = Eigen::Map<const Eigen::VectorXd>(rows.data(), 3 * s.nv);
  s.current = V;
  s.N = s.normals_of(s.x, s.N0);
  s.rotations.assign(s.nv, Eigen::Quaterniond::Identity());
  s.rotations_warm = false;
  s.has_previous = true;
  s.carried_monitor.reset();
  return Status::success();
}

Status ScaleAwareSolver::prepare(double rigidity) {
  MD_RETURN_IF_ERROR(check_rigidity(rigidity));
  return impl_->prepare_rigidity(rigidity);
}

Result<ScaleAwareSolver::Impl::Candidate> ScaleAwareSolver::Impl::run_from(
    StartFrom from, const Positions& targets, const SolveOptions& options,
    const ProgressCallback& progress, const std::stop_token& stop, Clock::time_point start,
    const Candidate* state, bool until_fold_free) {
  Impl& s = *this;
  const double rho = options.rigidity;

  if (from == StartFrom::Paper) {
    // The paper's iteration first, until the Laplacian guess's folds are gone; then the
    // requested rigidity from that fold-free iterate.
    if (rho == 0) return run_from(StartFrom::Laplacian, targets, options, progress, stop, start);
    // The paper's own system: handle weight lambda and T's preconditioner (solve() prepares
    // every solve's rigidity anew, so an early return here leaves nothing wrong behind).
    SolveOptions paper = options;
    paper.rigidity = 0;
    MD_RETURN_IF_ERROR(prepare_rigidity(0));
    MD_ASSIGN_OR_RETURN(const Candidate first, run_from(StartFrom::Laplacian, targets, paper,
                                                        progress, stop, start, nullptr, true));
    MD_RETURN_IF_ERROR(prepare_rigidity(rho));
    MD_ASSIGN_OR_RETURN(Candidate second, run_from(StartFrom::Previous, targets, options,
                                                   progress, stop, start, &first));
    second.report.start = StartFrom::Paper;
    second.report.paper_iterations = first.report.iterations;
    return second;
  }

  // Work on copies: a cancelled or failed solve leaves the solver as it was.
  Eigen::VectorXd x = state != nullptr ? state->x : s.x;
  RowPositions N = state != nullptr ? state->N : s.N;
  std::vector<Eigen::Quaterniond> rotations = state != nullptr ? state->rotations : s.rotations;
  bool rotations_warm = state != nullptr ? state->rotations_warm : s.rotations_warm;

  if (from == StartFrom::Rigid) {
    if (!s.rigid_start) MD_RETURN_IF_ERROR(s.build_rigid_start());
    SolveOptions arap_options;
    arap_options.max_iterations = options.rigid_start_iterations;
    arap_options.tolerance = options.rigid_start_tolerance;
    arap_options.start = StartFrom::Laplacian;
    arap_options.track_metrics = false;
    // rigid_start_tolerance is a relative change (its documented meaning, measured so).
    arap_options.stopping_rule = StoppingRule::Change;
    MD_ASSIGN_OR_RETURN(const SolveReport guess, s.rigid_start->solve(targets, arap_options, {}, stop));
    // Auto's cold start: the cold solve releases the ARAP solver at its end anyway (solve());
    // free it now, so that its factor and arrays (Spot 47k: 32 MB) are not held beside the
    // scale-aware iterations and the other start candidates.
    if (options.start == StartFrom::Auto && !s.has_previous) s.rigid_start.reset();
    const RowPositions guess_rows = guess.V;
    x = Eigen::Map<const Eigen::VectorXd>(guess_rows.data(), 3 * s.nv);
    rotations_warm = false;
  }
  if (from == StartFrom::Propagated) {
    if (!s.propagated_start) {
      MD_ASSIGN_OR_RETURN(RotationPropagationStart built,
                          RotationPropagationStart::create(s.V0, s.F, s.topology, s.constrained,
                                                           s.settings.lambda));
      s.propagated_start.emplace(std::move(built));
    }
    MD_ASSIGN_OR_RETURN(Positions guess, s.propagated_start->guess(targets));
    const RowPositions guess_rows = guess;
    x = Eigen::Map<const Eigen::VectorXd>(guess_rows.data(), 3 * s.nv);
    rotations_warm = false;
  }
  if (from == StartFrom::Laplacian) {
    if (!s.laplacian) {  // ScaleAwareSettings::lazy_laplacian_guess
      MD_ASSIGN_OR_RETURN(LaplacianEditor editor,
                          LaplacianEditor::create(s.V0, s.F, s.topology, s.constrained,
                                                  LaplacianWeights::Cotangent, s.settings.lambda));
      s.laplacian.emplace(std::move(editor));
    }
    MD_ASSIGN_OR_RETURN(Positions guess, s.laplacian->solve(targets));
    const RowPositions guess_rows = guess;
    x = Eigen::Map<const Eigen::VectorXd>(guess_rows.data(), 3 * s.nv);
    rotations_warm = false;  // the guess may be far from the previous rotations
  }

  const Eigen::VectorXd b = s.rhs(targets);
  Eigen::VectorXd target_vec(3 * targets.rows());
  for (Eigen::Index j = 0; j < targets.rows(); ++j) {
    target_vec.segment<3>(3 * j) = targets.row(j).transpose();
  }
  auto record = [&](IterationInfo& info, const Eigen::VectorXd& pos) {
    if (options.track_metrics) {
      const Positions P = Eigen::Map<const RowPositions>(pos.data(), s.nv, 3);
      const AngleErrors errors = angle_errors(s.rest(), P, s.F, s.topology);
      info.e_theta = errors.e_theta;
      info.e_phi = errors.e_phi;
    }
    info.elapsed_seconds = seconds_since(start);
  };

  SolveReport report;
  // Energies are compared relative to the squared size of the mesh: a mesh that fits exactly
  // (identity or a similarity) reaches round-off, where relative changes mean nothing.
  const double scale2 = s.bbox_diagonal * s.bbox_diagonal;
  // The floor: an RMS corner residual of 1e-8 of the bounding box, where the solve's own
  // round-off (pcg_tolerance) leaves the energy fluctuating.
  // With scale control the term and the handle weight carry a factor (1 + rho), and so does the
  // round-off they leave.
  const double energy_floor = 1e-16 * scale2 * 3.0 * s.nf * (1.0 + rho);
  {
    IterationInfo info;
    N = s.normals_of(x, N);
    s.assemble(N, rho);
    if (rho > 0) {
      // The scale variables are block minimisers of the current vertices: no state to carry.
      s.scale_control->reset();
      s.scale_control->set_reference(targets);
      s.scale_control->update_rotations(x, N);
      s.scale_control->update_scales(x);
    }
    info.energy = s.joint_energy(x, target_vec, rho);
    info.energy_before = info.energy;
    record(info, x);
    report.history.push_back(info);
    if (progress) progress(info);
  }

  // The stopping rule (core/methods/convergence.h); its last relative change also sets step two's
  // inexact PCG tolerance below.
  ConvergenceMonitor monitor(options.stopping_rule, options.tolerance, energy_floor);
  const bool continues = from == StartFrom::Previous && state == nullptr && !until_fold_free &&
                         s.carried_monitor && s.carried_monitor->same_test(monitor) &&
                         s.carried_rho == rho && s.carried_targets.rows() == targets.rows() &&
                         s.carried_targets == targets;
  if (continues) {
    monitor = *s.carried_monitor;  // the iterations before this solve count too
  } else {
    monitor.start(report.history.back().energy);
  }
  report.estimated_remaining = monitor.estimated_remaining();
  double previous_change = 1.0;
  // Anderson acceleration of the outer iteration over the positions (core/linalg/anderson.h; Peng et
  // al. 2018): x -> G(x) is step one at x (normals, face frames, exact scale step) and step two.
  // Every G(x) has the same handle rows up to the soft constraint, and a mix of iterates is a
  // valid iterate. Merit, for the safeguard: the joint energy at x after its own step one and
  // scale step, a function of x alone (up to step one's warm start). An accelerated iterate whose
  // merit is not below the last accepted one is replaced by the plain update it was mixed from,
  // and the window restarts there (Peng et al., Algorithm 1). The first iteration is always the
  // plain one (a one-iteration interactive move is unchanged), and so is the returned iterate:
  // no mix is formed after the last iteration or once the tolerance is met.
  const bool accelerate = options.anderson_window > 0;
  AndersonAccelerator accelerator(std::max(options.anderson_window, 1));
  if (accelerate) accelerator.reset(x);
  Eigen::VectorXd plain;          // G of the previous iterate, while x is an unchecked mix of it
  bool unchecked = false;         // x is an accelerated iterate whose merit is not yet known
  double accepted_merit = std::numeric_limits<double>::infinity();
  for (int it = 1; it <= options.max_iterations; ++it) {
    if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "solve cancelled");
    IterationInfo info;
    info.iteration = it;

    // Step one: normals from the current vertices, then local/global sweeps on the Gauss map;
    // then step two's matrix and, with scale control, the face frames that follow the normals
    // (R_f N0_f = N_f). Returns the iterate's energy with them: the block steps below (scales,
    // then PCG from x) can only lower it. Step one itself is not a minimiser of this energy (it
    // fits normals on the Gauss map), so energies of consecutive iterations are compared through
    // this value, not directly.
    // Also returns, in `merit`, the energy after the scale step (Anderson's safeguard): the
    // scale step leaves Eq. 12's part unchanged, so only the scale term is evaluated again.
    auto step_one = [&](double& merit) {
      auto phase = Clock::now();
      N = s.normals_of(x, N);
      info.normal_sweeps += update_normals(s.N0, s.F, s.topology, N, rotations, rotations_warm,
                                           options.inner_iterations, 1e-9, s.threads);
      rotations_warm = true;
      info.normals_seconds += seconds_since(phase);
      phase = Clock::now();
      s.assemble(N, rho);
      const double e12 = s.energy(x, target_vec);
      double energy_before = e12;
      merit = e12;
      if (rho > 0) {
        s.scale_control->update_rotations(x, N);
        energy_before += rho * s.scale_control->energy(x);
        // An exact scale step (a good warm start for the joint solve, never an increase).
        s.scale_control->update_scales(x);
        if (accelerate) merit += rho * s.scale_control->energy(x);
      }
      info.assemble_seconds += seconds_since(phase);
      return energy_before;
    };
    double merit = 0;
    info.energy_before = step_one(merit);
    if (accelerate) {
      if (unchecked && !(merit < accepted_merit)) {  // also rejects a non-finite mix
        x = plain;
        info.energy_before = step_one(merit);
        accelerator.reset(x);
        ++report.anderson_rejections;
      }
      accepted_merit = merit;
      unchecked = false;
    }

    // Step two: A(N) x = b by PCG with the cached factor, refactoring when that is cheaper.
    auto phase = Clock::now();
    const bool lagged = s.settings.preconditioner == StepTwoPreconditioner::LaggedCholesky;
    // With scale control, one thread solves the Schur complement (fewer steps, its two solves
    // one after the other); with the joint system's two solves side by side on two threads, the
    // joint system is faster (pcg_schur()).
    const bool schur = rho > 0 && !lagged && !s.side_by_side_solves();
    Eigen::VectorXd b_joint;  // the joint system's right-hand side (pcg_schur() forms its own)
    if (rho > 0 && !schur) {
      b_joint.resize(b.size() + s.scale_control->scale_unknowns());
      b_joint << b, rho * s.scale_control->scale_rhs();
    }
    info.assemble_seconds += seconds_since(phase);
    phase = Clock::now();
    if (lagged && s.refactor_pending) {
      MD_RETURN_IF_ERROR(s.cholesky.factorize(s.A));
      s.refactor_pending = false;
      info.refactored = true;
      ++report.factorizations;
    }
    // Inexact alternating minimisation: while the energy still moves a lot, reducing the
    // residual by a modest factor is enough; near convergence the reduction tightens.
    const double reduction =
        options.adaptive_pcg ? std::clamp(previous_change, 1e-8, 0.1) : 0.0;
    const double tolerance = options.pcg_tolerance;
    // Past this many steps a fresh factorization is cheaper than more lagged PCG: stop there,
    // refactor and finish (bounded waste instead of a fixed cap).
    // With scale control the lagged factor preconditions only the x block of the joint system,
    // so a refactorization cannot shorten the coupled part: no early stop there.
    const int max_pcg =
        lagged && rho == 0 ? std::clamp(static_cast<int>(s.settings.refactor_cost_ratio *
                                             s.cholesky.factor_flops() / s.pcg_iteration_flops),
                            4, 200)
               : 500;
    auto run_pcg = [&]() -> PcgOutcome {
      if (rho == 0) return s.pcg(b, x, reduction, tolerance, max_pcg, stop);
      if (schur) return s.pcg_schur(b, x, rho, reduction, tolerance, max_pcg, stop);
      Eigen::VectorXd joint(b_joint.size());
      joint << x, s.scale_control->scale_unknowns_vector();
      const PcgOutcome o = s.pcg_joint(b_joint, joint, rho, reduction, tolerance, max_pcg, stop);
      x = joint.head(x.size());
      s.scale_control->set_scale_unknowns(joint.tail(joint.size() - x.size()));
      return o;
    };
    PcgOutcome outcome = run_pcg();
    if (outcome.cancelled) return Error(ErrorCode::Cancelled, "solve cancelled");
    info.pcg_iterations = outcome.iterations;
    if (!outcome.converged && !lagged) {
      return Error(ErrorCode::NumericalFailure,
                   "step two did not converge at iteration " + std::to_string(it));
    }
    if (!outcome.converged) {
      // The lagged factor no longer preconditions well: refactor now and finish the solve.
      MD_RETURN_IF_ERROR(s.cholesky.factorize(s.A));
      info.refactored = true;
      ++report.factorizations;
      outcome = run_pcg();
      if (outcome.cancelled) return Error(ErrorCode::Cancelled, "solve cancelled");
      info.pcg_iterations += outcome.iterations;
      if (!outcome.converged) {
        return Error(ErrorCode::NumericalFailure,
                     "step two did not converge at iteration " + std::to_string(it));
      }
    }
    report.pcg_iterations += info.pcg_iterations;
    info.linear_seconds = seconds_since(phase);
    // Deterministic refactor rule, in flops: PCG that costs more than a fraction of a
    // factorization means the lagged factor has drifted too far from A(N).
    if (lagged && outcome.iterations * s.pcg_iteration_flops >
                      s.settings.refactor_cost_ratio * s.cholesky.factor_flops()) {
      s.refactor_pending = true;
    }
    if (!x.allFinite()) {
      return Error(ErrorCode::NumericalFailure,
                   "step two produced non-finite positions at iteration " + std::to_string(it));
    }

    info.energy = s.joint_energy(x, target_vec, rho);
    record(info, x);
    report.history.push_back(info);
    report.iterations = it;
    if (progress) progress(info);

    const bool converged = monitor.add(info.energy);
    previous_change = monitor.last_change();
    report.estimated_remaining = monitor.estimated_remaining();
    if (converged) {
      report.converged = true;
      break;
    }
    if (until_fold_free && s.folds_of(x) == 0) break;
    if (accelerate && it < options.max_iterations) {
      plain = x;
      x = accelerator.compute(plain);
      unchecked = true;
    }
  }

  report.start = from;
  Candidate candidate;
  candidate.report = std::move(report);
  candidate.x = std::move(x);
  candidate.N = std::move(N);
  candidate.rotations = std::move(rotations);
  candidate.rotations_warm = rotations_warm;
  candidate.monitor = monitor;
  return candidate;
}

int ScaleAwareSolver::Impl::folds_of(const Eigen::VectorXd& pos) const {
  const Positions P = Eigen::Map<const RowPositions>(pos.data(), nv, 3);
  return count_folds(rest_phi, dihedral_angles(P, F, topology, threads));
}

Result<SolveReport> ScaleAwareSolver::solve(const Positions& targets, const SolveOptions& options,
                                            const ProgressCallback& progress,
                                            std::stop_token stop) {
  Impl& s = *impl_;
  const auto start = Clock::now();
  if (options.max_iterations < 0 || options.inner_iterations < 1 || !(options.tolerance >= 0) ||
      !(options.pcg_tolerance > 0) || options.rigid_start_iterations < 0 ||
      !(options.rigid_start_tolerance >= 0)) {
    return Error(ErrorCode::InvalidArgument,
                 "solve options out of range: max_iterations >= 0, inner_iterations >= 1, "
                 "tolerance >= 0, pcg_tolerance > 0, rigid_start_iterations >= 0 and "
                 "rigid_start_tolerance >= 0 are required");
  }
  MD_RETURN_IF_ERROR(check_targets(targets, s.constrained, s.topology, s.bbox_diagonal, true));
  if (options.face_scale.size() != 0) {
    if (options.face_scale.size() != s.nf) {
      return Error(ErrorCode::InvalidArgument,
                   "face_scale has " + std::to_string(options.face_scale.size()) +
                       " entries for " + std::to_string(s.nf) + " faces");
    }
    for (Eigen::Index f = 0; f < s.nf; ++f) {
      if (!(options.face_scale(f) > 0) || !std::isfinite(options.face_scale(f))) {
        return Error(ErrorCode::InvalidArgument, "face_scale of face " + std::to_string(f) +
                                                     " must be positive and finite");
      }
    }
  }
  MD_RETURN_IF_ERROR(check_rigidity(options.rigidity));
  if (options.lambda != s.settings.lambda) {
    return Error(ErrorCode::InvalidArgument,
                 "lambda is fixed when the solver is created (" + std::to_string(s.settings.lambda) +
                     "); got " + std::to_string(options.lambda));
  }

  const double rho = options.rigidity;
  MD_RETURN_IF_ERROR(s.prepare_rigidity(rho));

  // Auto's cold start: with scale control (rigidity > 0) ARAP run to convergence, whose basin the
  // scale-aware energy then refines (bench/results/rigidity_sweep.md: all three targets of issue
  // 12 on 12 of 12 edits at the default rigidity, against 9 of 12 from the Laplacian guess, which
  // leaves the 135-degree twists in a worse basin); at rigidity 0 the paper's own start, the
  // Laplacian guess (Section 5.2), so that rigidity 0 stays the paper's method.
  const bool cold = options.start == StartFrom::Auto && !s.has_previous;
  StartFrom from = options.start;
  if (from == StartFrom::Auto) {
    from = s.has_previous ? StartFrom::Previous : rho > 0 ? StartFrom::Rigid : StartFrom::Laplacian;
  }
  MD_ASSIGN_OR_RETURN(Impl::Candidate chosen,
                      s.run_from(from, targets, options, progress, stop, start));
  if (cold && rho > 0) {
    // Where converged ARAP creases (bent tubes: interior edges folded by more than 90 degrees
    // near the handles), the scale-aware iteration keeps its creases: they lower its energy, so
    // more iterations do not remove them. Then the result from the Laplacian guess is computed
    // too and, if the best result so far still has folds, the Paper start's (the paper's own
    // iteration until the Laplacian guess's folds are gone, then the rigidity: on the irregular
    // bent cylinder the Laplacian guess's result keeps 2 creases that the scale term set while
    // the guess's 64 folds were being removed). A candidate replaces the best one if it has fewer
    // folds at not much more energy than the rigid start's (or as many folds at less energy).
    // Measured on bench/results/rigidity_sweep.md's edits at rigidity 1-300: on the bent
    // cylinders the fold-free basin costs 0.77-1.31x the creased one's energy, on the Spot twist
    // the Laplacian guess's basin costs 2.1-2.6x (the worse basin of issue 12, E_theta above
    // converged ARAP's), hence kFoldFreeEnergyRatio. Where the rigid start folds nothing, nothing
    // else runs.
    chosen.report.folded_edges = s.folds_of(chosen.x);
    const double rigid_energy = chosen.report.history.back().energy;
    int candidates = 1;
    for (const StartFrom next : {StartFrom::Laplacian, StartFrom::Paper}) {
      if (chosen.report.folded_edges == 0) break;
      MD_ASSIGN_OR_RETURN(Impl::Candidate other,
                          s.run_from(next, targets, options, progress, stop, start));
      ++candidates;
      other.report.folded_edges = s.folds_of(other.x);
      const double energy = chosen.report.history.back().energy;
      const double other_energy = other.report.history.back().energy;
      const bool fewer = other.report.folded_edges < chosen.report.folded_edges &&
                         other_energy <= kFoldFreeEnergyRatio * rigid_energy;
      const bool tie_lower =
          other.report.folded_edges == chosen.report.folded_edges && other_energy < energy;
      if (fewer || tie_lower) chosen = std::move(other);
    }
    chosen.report.start_candidates = candidates;
  }
  SolveReport report = std::move(chosen.report);
  Eigen::VectorXd x = std::move(chosen.x);
  RowPositions N = std::move(chosen.N);
  std::vector<Eigen::Quaterniond> rotations = std::move(chosen.rotations);
  const bool rotations_warm = chosen.rotations_warm;

  report.V = Eigen::Map<const RowPositions>(x.data(), s.nv, 3);
  if (options.ora || options.face_scale.size() != 0) {
    // ORA / magnification (Section 5.3): the stitched mesh is what the caller gets; the solver
    // keeps its own iterate for warm starts, since the stitch is not a fixed point of it.
    const auto stitch_start = Clock::now();
    if (!s.stitcher) {
      MD_ASSIGN_OR_RETURN(RigidityStitcher built,
                          RigidityStitcher::create(s.V0, s.F, s.constrained, s.settings.lambda));
      s.stitcher.emplace(std::move(built));
    }
    MD_ASSIGN_OR_RETURN(Positions stitched,
                        s.stitcher->stitch(report.V, targets, options.face_scale));
    const AngleErrors before = angle_errors(s.rest(), report.V, s.F, s.topology);
    const AngleErrors after = angle_errors(s.rest(), stitched, s.F, s.topology);
    report.stitch = {true,           before.e_theta, before.e_phi, before.area_log_rms,
                     after.e_theta,  after.e_phi,    after.area_log_rms,
                     seconds_since(stitch_start)};
    report.V = std::move(stitched);
  }

  // Commit.
  s.x = x;
  s.N = N;
  s.rotations = std::move(rotations);
  s.rotations_warm = rotations_warm;
  s.has_previous = true;
  s.carried_monitor = std::move(chosen.monitor);
  s.carried_targets = targets;
  s.carried_rho = rho;
  s.current = report.V;
  if (cold) {
    // Later Auto solves start from this result (Previous), so the cold start's solvers are
    // dead weight: the rigid start's ARAP solver (already freed after its guess where the
    // rigid start ran) and, where the start candidates built it, the Laplacian guess's editor
    // (Spot 47k: 32 and 66 MB). reset() makes the next Auto solve cold again, which builds
    // them anew (the rigid start's factorization is 0.1 s at 47k vertices; a cold solve runs up
    // to rigid_start_iterations ARAP iterations after it). Explicit starts keep what they
    // built.
    s.rigid_start.reset();
    s.laplacian.reset();
  }
  report.seconds = seconds_since(start);
  report.phases.start = report.history.empty() ? 0.0 : report.history.front().elapsed_seconds;
  report.phases.fine = report.seconds - report.phases.start;
  return report;
}

Result<SolveReport> deform_scale_aware(const Positions& V0, const Triangles& F,
                                       const Eigen::VectorXi& constrained, const Positions& targets,
                                       const SolveOptions& options,
                                       const ProgressCallback& progress) {
  ScaleAwareSettings settings;
  settings.lambda = options.lambda;
  MD_ASSIGN_OR_RETURN(ScaleAwareSolver solver,
                      ScaleAwareSolver::create(V0, F, constrained, settings));
  return solver.solve(targets, options, progress);
}

}  // namespace meshdeform::core
