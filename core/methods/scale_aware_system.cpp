// Step two's linear system of the scale-aware solver: the edge form, the sparsity pattern, the
// assembly per iteration, the trace blocks and their factorizations, right-hand side and energies.
#include "core/methods/scale_aware_impl.h"

namespace meshdeform::core {

using scale_aware_detail::rodrigues;

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
                                     const MeshTopology* checked,
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
  if (checked != nullptr) {
    topology = *checked;
  } else {
    MD_RETURN_IF_ERROR(validate_triangle_mesh(V0_in, F_in));
    MD_ASSIGN_OR_RETURN(topology, build_topology(F_in, static_cast<int>(V0_in.rows())));
  }
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

}  // namespace meshdeform::core
