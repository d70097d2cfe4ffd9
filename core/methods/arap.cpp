#include "core/methods/arap.h"

#include <omp.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <Eigen/LU>

#include "core/linalg/anderson.h"
#include "core/linalg/rotation_fit.h"
#include "core/linalg/sparse_cholesky.h"
#include "core/mesh/measures.h"
#include "core/mesh/topology.h"
#include "core/mesh/validate.h"
#include "core/methods/constraints.h"
#include "core/methods/convergence.h"
#include "core/methods/normals_step.h"

namespace meshdeform::core {
namespace {

using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// Position of `b` in the sorted neighbour list of `a` (b must be a neighbour).
int neighbor_slot(const MeshTopology& topology, int a, int b) {
  const auto first = topology.vv_neighbors.begin() + topology.vv_offsets[a];
  const auto last = topology.vv_neighbors.begin() + topology.vv_offsets[a + 1];
  const auto it = std::lower_bound(first, last, b);
  MD_ASSERT(it != last && *it == b);
  return static_cast<int>(it - topology.vv_neighbors.begin());
}

}  // namespace

struct ArapSolver::Impl {
  int nv = 0;
  RowPositions V0;
  Triangles F;
  MeshTopology topology;
  std::optional<Measures> rest;  // for e_theta / e_phi, measured on the first solve with metrics
  double bbox_diagonal = 1;
  int threads = 1;

  // w_ij per directed neighbour entry, aligned with topology.vv_neighbors (w_ij = w_ji).
  std::vector<double> weight;
  double weight_total = 0;  // sum over directed entries
  // Rest edge v0_i - v0_j per directed entry (aligned with weight), and per vertex the weighted
  // sum c_i = sum_j w_ij (v0_i - v0_j): the global step's right-hand side is
  // b_i = R_i c_i / 2 + sum_j w_ij R_j (v0_i - v0_j) / 2, one matrix product per entry, not two.
  std::vector<Eigen::Vector3d> rest_edge;
  std::vector<Eigen::Vector3d> weighted_edge_sum;

  Eigen::VectorXi constrained;
  std::vector<int> slot;        // #V: row in targets, or -1
  std::vector<int> free_index;  // #V: row in the reduced system, or -1
  std::vector<int> free_vertices;
  SparseCholesky cholesky;  // of L_UU, factored once

  // State carried between solves.
  RowPositions x;     // current positions
  Positions current;  // the same, for positions()
  bool has_previous = false;

  Status build(const Positions& V0_in, const Triangles& F_in, const Eigen::VectorXi& constrained_in,
               const ArapSettings& settings);
  void build_weights();
  Status factor();
  // Local step: the best rotation per vertex for positions P; returns the ARAP energy
  // E(P, R) = min_R E(P, .) of P.
  double fit_rotations(const RowPositions& P, std::vector<Eigen::Matrix3d>& R) const;
  // Global step: the constrained minimiser of E(., R), written into P.
  void solve_positions(const std::vector<Eigen::Matrix3d>& R, const Positions& targets,
                       RowPositions& P) const;
};

Status ArapSolver::Impl::build(const Positions& V0_in, const Triangles& F_in,
                               const Eigen::VectorXi& constrained_in,
                               const ArapSettings& settings) {
  MD_RETURN_IF_ERROR(check_constrained(constrained_in, topology, 1));

  threads = settings.threads > 0 ? settings.threads : omp_get_max_threads();
  nv = static_cast<int>(V0_in.rows());
  V0 = V0_in;
  F = F_in;
  constrained = constrained_in;
  slot.assign(nv, -1);
  for (Eigen::Index j = 0; j < constrained.size(); ++j) slot[constrained(j)] = static_cast<int>(j);
  free_index.assign(nv, -1);
  free_vertices.clear();
  for (int v = 0; v < nv; ++v) {
    if (slot[v] < 0) {
      free_index[v] = static_cast<int>(free_vertices.size());
      free_vertices.push_back(v);
    }
  }
  bbox_diagonal = (V0.colwise().maxCoeff() - V0.colwise().minCoeff()).norm();
  build_weights();
  MD_RETURN_IF_ERROR(factor());

  x = V0;
  current = V0_in;
  has_previous = false;
  return Status::success();
}

void ArapSolver::Impl::build_weights() {
  // Half a cotangent per face corner, added to the opposite edge in both directions; faces in
  // index order, so the sums (and everything after them) are deterministic.
  weight.assign(topology.vv_neighbors.size(), 0.0);
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int o = F(f, k), i = F(f, (k + 1) % 3), j = F(f, (k + 2) % 3);
      const Eigen::Vector3d a = (V0.row(i) - V0.row(o)).transpose();
      const Eigen::Vector3d b = (V0.row(j) - V0.row(o)).transpose();
      const double cot = a.dot(b) / std::max(a.cross(b).norm(), 1e-300);
      weight[neighbor_slot(topology, i, j)] += 0.5 * cot;
      weight[neighbor_slot(topology, j, i)] += 0.5 * cot;
    }
  }
  // Clamp like the Laplacian editor (laplacian.cpp): an edge whose two opposite angles sum to more
  // than pi has a negative weight, which makes the energy indefinite and can break the
  // factorization. Each edge appears twice here, so the mean over entries is the mean over edges.
  double mean = 0;
  for (double w : weight) mean += std::abs(w);
  mean /= std::max<size_t>(weight.size(), 1);
  const double floor = mean > 0 ? 1e-3 * mean : 1.0;
  weight_total = 0;
  for (double& w : weight) {
    w = std::max(w, floor);
    weight_total += w;
  }
  rest_edge.resize(weight.size());
  weighted_edge_sum.assign(static_cast<size_t>(nv), Eigen::Vector3d::Zero());
  for (int i = 0; i < nv; ++i) {
    for (int k = topology.vv_offsets[i]; k < topology.vv_offsets[i + 1]; ++k) {
      rest_edge[k] = (V0.row(i) - V0.row(topology.vv_neighbors[k])).transpose();
      weighted_edge_sum[i] += weight[k] * rest_edge[k];
    }
  }
}

Status ArapSolver::Impl::factor() {
  const int n = static_cast<int>(free_vertices.size());
  if (n == 0) return Status::success();  // every vertex is prescribed: nothing to solve
  std::vector<Eigen::Triplet<double>> entries;
  entries.reserve(topology.vv_neighbors.size() + free_vertices.size());
  for (int r = 0; r < n; ++r) {
    const int i = free_vertices[r];
    double diagonal = 0;
    for (int k = topology.vv_offsets[i]; k < topology.vv_offsets[i + 1]; ++k) {
      diagonal += weight[k];
      const int c = free_index[topology.vv_neighbors[k]];
      if (c >= 0) entries.emplace_back(r, c, -weight[k]);
    }
    entries.emplace_back(r, r, diagonal);
  }
  SparseMatrix L(n, n);
  L.setFromTriplets(entries.begin(), entries.end());
  L.makeCompressed();
  // Factored once, solved every iteration with 3 right-hand sides: simplicial solves pay.
  cholesky.set_simplicial_solves(true);
  MD_RETURN_IF_ERROR(cholesky.analyze(L));
  return cholesky.factorize(L);
}

double ArapSolver::Impl::fit_rotations(const RowPositions& P,
                                       std::vector<Eigen::Matrix3d>& R) const {
  std::vector<double> per_vertex(nv);
  const bool parallel = nv > 2000 && threads > 1;
  // Four fans at a time: their fits side by side (closest_rotations), each exactly the fan's own.
  constexpr int kBatch = 4;
  const int blocks = (nv + kBatch - 1) / kBatch;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (int block = 0; block < blocks; ++block) {
    const int first = block * kBatch;
    const int count = std::min(kBatch, nv - first);
    Eigen::Matrix3d S[kBatch];
    for (int l = 0; l < count; ++l) {
      const int i = first + l;
      const Eigen::Vector3d p = P.row(i).transpose();
      // S = sum_j w_ij e'_ij e_ij^T; R_i maximises trace(R^T S), i.e. minimises the fan's energy.
      S[l].setZero();
      for (int k = topology.vv_offsets[i]; k < topology.vv_offsets[i + 1]; ++k) {
        const int j = topology.vv_neighbors[k];
        S[l].noalias() += (weight[k] * (p - P.row(j).transpose())) * rest_edge[k].transpose();
      }
    }
    // An exact fit, whatever the previous rotation was, keeps the alternation a proper
    // block-coordinate descent. (Mueller's iteration warm-started from the previous rotation was
    // tried: it is not exact within a few steps, and was no faster than Eigen's Jacobi SVD. The
    // closed form is exact to round-off and about 4x cheaper than the SVD.)
    closest_rotations(S, R.data() + first, count);
    for (int l = 0; l < count; ++l) {
      const int i = first + l;
      const Eigen::Vector3d p = P.row(i).transpose();
      double e = 0;
      for (int k = topology.vv_offsets[i]; k < topology.vv_offsets[i + 1]; ++k) {
        const int j = topology.vv_neighbors[k];
        e += weight[k] * ((p - P.row(j).transpose()) - R[i] * rest_edge[k]).squaredNorm();
      }
      per_vertex[i] = e;
    }
  }
  double energy = 0;
  for (double e : per_vertex) energy += e;  // serial: the same sum for any thread count
  return energy;
}

void ArapSolver::Impl::solve_positions(const std::vector<Eigen::Matrix3d>& R,
                                       const Positions& targets, RowPositions& P) const {
  for (Eigen::Index j = 0; j < constrained.size(); ++j) P.row(constrained(j)) = targets.row(j);
  const int n = static_cast<int>(free_vertices.size());
  if (n == 0) return;
  // Normal equations of E for fixed R: sum_j w_ij (v_i - v_j) = sum_j w_ij / 2 (R_i + R_j) e_ij
  // for every free i, with the prescribed neighbours moved to the right-hand side.
  Eigen::MatrixXd b(n, 3);
  const bool parallel = nv > 2000 && threads > 1;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (int r = 0; r < n; ++r) {
    const int i = free_vertices[r];
    Eigen::Vector3d sum = 0.5 * (R[i] * weighted_edge_sum[i]);
    for (int k = topology.vv_offsets[i]; k < topology.vv_offsets[i + 1]; ++k) {
      const int j = topology.vv_neighbors[k];
      sum.noalias() += (0.5 * weight[k]) * (R[j] * rest_edge[k]);
      if (slot[j] >= 0) sum += weight[k] * targets.row(slot[j]).transpose();
    }
    b.row(r) = sum.transpose();
  }
  const Eigen::MatrixXd solution = cholesky.solve(b);
  for (int r = 0; r < n; ++r) P.row(free_vertices[r]) = solution.row(r);
}

ArapSolver::ArapSolver(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ArapSolver::ArapSolver(ArapSolver&&) noexcept = default;
ArapSolver& ArapSolver::operator=(ArapSolver&&) noexcept = default;
ArapSolver::~ArapSolver() = default;

Result<ArapSolver> ArapSolver::create(const Positions& V0, const Triangles& F,
                                      const Eigen::VectorXi& constrained,
                                      const ArapSettings& settings) {
  MD_RETURN_IF_ERROR(validate_triangle_mesh(V0, F));
  MD_ASSIGN_OR_RETURN(MeshTopology topology, build_topology(F, static_cast<int>(V0.rows())));
  return create(V0, F, topology, constrained, settings);
}

Result<ArapSolver> ArapSolver::create(const Positions& V0, const Triangles& F,
                                      const MeshTopology& topology,
                                      const Eigen::VectorXi& constrained,
                                      const ArapSettings& settings) {
  auto impl = std::make_unique<Impl>();
  impl->topology = topology;
  MD_RETURN_IF_ERROR(impl->build(V0, F, constrained, settings));
  return ArapSolver(std::move(impl));
}

const Positions& ArapSolver::positions() const { return impl_->current; }

const Eigen::VectorXi& ArapSolver::constrained() const { return impl_->constrained; }

void ArapSolver::reset() {
  Impl& s = *impl_;
  s.x = s.V0;
  s.current = s.V0;
  s.has_previous = false;
}

Status ArapSolver::set_positions(const Positions& V) {
  Impl& s = *impl_;
  if (V.rows() != s.nv || !V.allFinite()) {
    return Error(ErrorCode::InvalidArgument,
                 "set_positions needs " + std::to_string(s.nv) + " finite rows, got " +
                     std::to_string(V.rows()) + (V.allFinite() ? "" : " with a non-finite value"));
  }
  s.x = V;
  s.current = V;
  s.has_previous = true;
  return Status::success();
}

Result<SolveReport> ArapSolver::solve(const Positions& targets, const SolveOptions& options,
                                      const ProgressCallback& progress, std::stop_token stop) {
  Impl& s = *impl_;
  const auto start = Clock::now();
  if (options.max_iterations < 0 || !(options.tolerance >= 0)) {
    const std::string got =
        std::to_string(options.max_iterations) + " and " + std::to_string(options.tolerance);
    return Error(
        ErrorCode::InvalidArgument,
        "solve options out of range: need max_iterations >= 0 and tolerance >= 0, got " + got);
  }
  if (options.ora || options.face_scale.size() != 0) {
    return Error(ErrorCode::InvalidArgument,
                 std::string("ORA and magnification belong to the scale-aware method, not ARAP (") +
                     (options.ora ? "ora is set" : "face_scale is not empty") + ")");
  }
  MD_RETURN_IF_ERROR(check_targets(targets, s.constrained, s.topology, s.bbox_diagonal, false));
  if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "solve cancelled");

  // Work on a copy: a cancelled or failed solve leaves the solver as it was.
  RowPositions P = s.x;
  std::vector<Eigen::Matrix3d> R(s.nv, Eigen::Matrix3d::Identity());
  const bool from_laplacian = options.start == StartFrom::Laplacian ||
                              (options.start == StartFrom::Auto && !s.has_previous);
  if (from_laplacian) {
    // One global step with R = I: Laplacian editing with hard constraints, from the same factor.
    s.solve_positions(R, targets, P);
  } else {
    for (Eigen::Index j = 0; j < s.constrained.size(); ++j) {
      P.row(s.constrained(j)) = targets.row(j);
    }
  }

  auto record = [&](IterationInfo& info) {
    if (options.track_metrics) {
      const Positions V = P;
      if (!s.rest) s.rest = compute_measures(s.V0, s.F, s.topology);
      const AngleErrors errors = angle_errors(*s.rest, V, s.F, s.topology);
      info.e_theta = errors.e_theta;
      info.e_phi = errors.e_phi;
    }
    info.elapsed_seconds = seconds_since(start);
  };

  SolveReport report;
  report.start = from_laplacian ? StartFrom::Laplacian : StartFrom::Previous;
  // As in the scale-aware solver, an exact fit (rest pose, rigid motion) ends on an absolute
  // floor, where relative changes stop meaning anything: a weighted RMS edge residual of 1e-10 of
  // the bounding box. Both steps are direct (no PCG tolerance), so round-off sits far below it;
  // the scale-aware solver's 1e-8 would stop the slow rigid modes of a floppy handle set at
  // position errors near 1e-6 of the bounding box.
  const double energy_floor = 1e-20 * s.bbox_diagonal * s.bbox_diagonal * s.weight_total;
  {
    IterationInfo info;
    if (!P.allFinite()) {
      return Error(ErrorCode::NumericalFailure, "the starting positions are not finite");
    }
    info.energy = s.fit_rotations(P, R);
    record(info);
    report.history.push_back(info);
    if (progress) progress(info);
  }

  // The stopping rule (core/methods/convergence.h).
  ConvergenceMonitor monitor(options.stopping_rule, options.tolerance, energy_floor);
  if (monitor.start(report.history.back().energy)) report.converged = true;
  report.estimated_remaining = monitor.estimated_remaining();
  double previous_energy = report.history.back().energy;
  // Anderson acceleration (core/linalg/anderson.h) over the positions: x -> G(x) is one local
  // step (the rotations of x) and one global step. The constrained rows of every G(x) are the
  // targets, so every mix of them is feasible too. Safeguard: an accelerated iterate whose energy exceeds the
  // last accepted one is replaced by the plain update and the window restarts, so the energy
  // still never increases.
  const bool accelerate = options.anderson_window > 0;
  AndersonAccelerator accelerator(options.anderson_window);
  RowPositions G;
  const auto flat = [](RowPositions& M) { return Eigen::Map<Eigen::VectorXd>(M.data(), M.size()); };
  if (accelerate) accelerator.reset(flat(P));
  for (int it = 1; it <= options.max_iterations && !report.converged; ++it) {
    if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "solve cancelled");
    IterationInfo info;
    info.iteration = it;

    auto phase = Clock::now();
    if (accelerate) {
      G = P;
      s.solve_positions(R, targets, G);
    } else {
      s.solve_positions(R, targets, P);
    }
    info.linear_seconds = seconds_since(phase);
    if (!(accelerate ? G : P).allFinite()) {
      return Error(
          ErrorCode::NumericalFailure,
          "the global step produced non-finite positions at iteration " + std::to_string(it));
    }
    // The local step for the next iteration also gives this iterate's energy min_R E(P, R).
    phase = Clock::now();
    if (accelerate) {
      flat(P) = accelerator.compute(flat(G));
      info.energy = s.fit_rotations(P, R);
      if (!(info.energy <= previous_energy)) {  // also rejects a non-finite mix
        P = G;
        info.energy = s.fit_rotations(P, R);
        accelerator.reset(flat(P));
        ++report.anderson_rejections;
      }
    } else {
      info.energy = s.fit_rotations(P, R);
    }
    info.normals_seconds = seconds_since(phase);  // the local step, step one's counterpart
    record(info);
    report.history.push_back(info);
    report.iterations = it;
    if (progress) progress(info);

    previous_energy = info.energy;
    if (monitor.add(info.energy)) report.converged = true;
    report.estimated_remaining = monitor.estimated_remaining();
  }

  // Commit.
  s.x = P;
  s.current = P;
  s.has_previous = true;
  report.V = s.current;
  report.seconds = seconds_since(start);
  report.phases.fine = report.seconds;
  return report;
}

Result<SolveReport> deform_arap(const Positions& V0, const Triangles& F,
                                const Eigen::VectorXi& constrained, const Positions& targets,
                                const SolveOptions& options, const ProgressCallback& progress) {
  MD_ASSIGN_OR_RETURN(ArapSolver solver, ArapSolver::create(V0, F, constrained));
  return solver.solve(targets, options, progress);
}

}  // namespace meshdeform::core
