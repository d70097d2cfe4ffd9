// Step two's iterative solve of the scale-aware solver: the matrix-free operators, the
// preconditioners and the three PCG forms (plain, joint, Schur complement).
#include "core/methods/scale_aware_impl.h"

namespace meshdeform::core {

using scale_aware_detail::conjugate_gradients;

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

}  // namespace meshdeform::core
