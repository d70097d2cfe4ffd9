#include "core/methods/scale_control.h"

#include <Eigen/SparseCore>
#include <algorithm>
#include <cmath>
#include <string>

#include "core/linalg/rotation_fit.h"

namespace meshdeform::core {
namespace {

constexpr double kExactTieAbove = 1e6;

// An orthonormal frame [t b] of the plane with unit normal n, t along `along` when it is usable.
Eigen::Matrix<double, 3, 2> plane_frame(const Eigen::Vector3d& n, const Eigen::Vector3d& along) {
  Eigen::Vector3d t = along - along.dot(n) * n;
  double len = t.norm();
  if (!(len > 1e-300)) {
    t = std::abs(n.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    t -= t.dot(n) * n;
    len = t.norm();
  }
  t /= len;
  Eigen::Matrix<double, 3, 2> frame;
  frame.col(0) = t;
  frame.col(1) = n.cross(t);
  return frame;
}

}  // namespace

Status ScaleControl::build(const RowPositions& V0, const Triangles& F, const MeshTopology& topology,
                           const RowPositions& N0, const Eigen::VectorXi& constrained, double pull,
                           double smooth_length) {
  nv_ = static_cast<int>(V0.rows());
  nf_ = static_cast<int>(F.rows());
  F_ = F;
  N0_ = N0;
  pull_ = pull;
  weight_.assign(3 * static_cast<size_t>(nf_), 0.0);
  rest_edge_.assign(3 * static_cast<size_t>(nf_), Eigen::Vector3d::Zero());
  rest_frame_.resize(nf_);
  fit_a_.resize(nf_);
  area_.resize(nf_);
  double total_area = 0;
  for (int f = 0; f < nf_; ++f) {
    Eigen::Vector3d p[3];
    for (int k = 0; k < 3; ++k) p[k] = V0.row(F(f, k)).transpose();
    const double area = 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).norm();
    area_(f) = area;
    total_area += area;
    double a = 0;
    for (int k = 0; k < 3; ++k) {
      // Edge opposite corner k, from corner k+1 to corner k+2; cot of the angle at corner k.
      const Eigen::Vector3d u = p[(k + 1) % 3] - p[k], v = p[(k + 2) % 3] - p[k];
      const double cot = u.dot(v) / u.cross(v).norm();
      const double w = 0.5 * cot;
      const size_t c = 3 * static_cast<size_t>(f) + k;
      weight_[c] = w;
      rest_edge_[c] = p[(k + 2) % 3] - p[(k + 1) % 3];
      a += w * rest_edge_[c].squaredNorm();
    }
    fit_a_(f) = a;
    rest_frame_[f] = plane_frame(N0.row(f).transpose(), p[1] - p[0]);
  }

  // Mesh edges with both ends constrained: their length change is the scale the handles imply.
  std::vector<int> slot(nv_, -1);
  for (Eigen::Index j = 0; j < constrained.size(); ++j) slot[constrained(j)] = static_cast<int>(j);
  handle_edges_.clear();
  handle_rest_length2_ = 0;
  for (int i = 0; i < nv_; ++i) {
    if (slot[i] < 0) continue;
    for (int t = topology.vv_offsets[i]; t < topology.vv_offsets[i + 1]; ++t) {
      const int j = topology.vv_neighbors[t];
      if (j > i && slot[j] >= 0) {
        handle_edges_.emplace_back(slot[i], slot[j]);
        handle_rest_length2_ += (V0.row(i) - V0.row(j)).squaredNorm();
      }
    }
  }
  free_reference_ = handle_edges_.empty() || !(handle_rest_length2_ > 0);

  // Scale system H = diag(a) + L_faces(mu w_fg) + nu diag(A), unknowns s; with a free reference
  // scale (no constrained edge) one more unknown s_bar: + nu [0, -A; -A^T, sum A].
  const double xi2 = smooth_length * smooth_length * total_area;
  const int n = free_reference_ ? nf_ + 1 : nf_;
  edge_faces_ = topology.edge_faces;
  edge_weight_.resize(edge_faces_.rows());
  std::vector<Eigen::Triplet<double>> entries;
  entries.reserve(3 * static_cast<size_t>(nf_) + 4 * edge_faces_.rows() + 1);
  for (int f = 0; f < nf_; ++f) {
    entries.emplace_back(f, f, fit_a_(f) + pull * area_(f));
    if (free_reference_) {
      entries.emplace_back(nf_, f, -pull * area_(f));
      entries.emplace_back(f, nf_, -pull * area_(f));
    }
  }
  if (free_reference_) entries.emplace_back(nf_, nf_, pull * total_area);
  for (Eigen::Index e = 0; e < edge_faces_.rows(); ++e) {
    const int f = edge_faces_(e, 0), g = edge_faces_(e, 1);
    const int a = topology.interior_edges(e, 0), b = topology.interior_edges(e, 1);
    const double len2 = (V0.row(a) - V0.row(b)).squaredNorm();
    const double w = xi2 * len2 / (area_(f) + area_(g));
    edge_weight_[e] = w;
    entries.emplace_back(f, f, w);
    entries.emplace_back(g, g, w);
    entries.emplace_back(f, g, -w);
    entries.emplace_back(g, f, -w);
  }
  SparseMatrix H(n, n);
  H.setFromTriplets(entries.begin(), entries.end());
  scale_matrix_ = H;
  // Constant, and solved with one right-hand side in every PCG step of the joint system: the
  // simplicial form solves faster than the supernodal one (sparse_cholesky.h).
  scale_system_.set_simplicial_solves(true);
  MD_RETURN_IF_ERROR(scale_system_.analyze(H));
  MD_RETURN_IF_ERROR(scale_system_.factorize(H));
  // The scales start at 1; the frames' rotated edges (72 B per face) are allocated by reset(),
  // which every solve calls before its first step: a solver's first solve runs its rigid start
  // (converged ARAP) without them.
  frame_edge_.clear();
  frame_edge_.shrink_to_fit();
  reset_scales();
  return Status::success();
}

void ScaleControl::set_reference(const Positions& targets) {
  if (free_reference_) return;
  double moved = 0;
  for (const auto& [a, b] : handle_edges_) moved += (targets.row(a) - targets.row(b)).squaredNorm();
  s_bar_ = std::sqrt(moved / handle_rest_length2_);
}

void ScaleControl::reset() {
  frame_edge_ = rest_edge_;  // identity frames
  reset_scales();
}

void ScaleControl::reset_scales() {
  s_ = Eigen::VectorXd::Ones(nf_);
  if (free_reference_) s_bar_ = 1.0;
  fit_b_ = Eigen::VectorXd::Zero(nf_);
}

void ScaleControl::set_frame(int f, const Eigen::Matrix3d& R) {
  for (int k = 0; k < 3; ++k) {
    const size_t c = 3 * static_cast<size_t>(f) + k;
    frame_edge_[c] = R * rest_edge_[c];
  }
}

void ScaleControl::update_rotations(const Eigen::VectorXd& x, const RowPositions& N) {
  MD_ASSERT(!frame_edge_.empty());  // reset() comes first
  tie_energy_ = 0;
  const bool parallel = nf_ > 4000 && threads_ > 1;
  // Past ~1e6 the tie term swamps the fit in M and the in-plane angle is lost to round-off
  // (Horn's top eigenvalue becomes nearly double): such values are the exact tie in all but name.
  if (normal_tie_ < kExactTieAbove) {
    // A soft tie: R_f = argmax tr(R^T (s_f M3 + beta A_f N_f N0_f^T)) over SO(3), M3 = sum_k w_k
    // e_k e0_k^T (the fit is -2 s_f tr(R^T M3) + const, the tie -2 beta A_f tr(R^T N N0^T) +
    // const): the rotation of the polar decomposition.
    per_face_.resize(nf_);
    constexpr int kBatch = 4;  // four faces' fits side by side (closest_rotations)
    const int blocks = (nf_ + kBatch - 1) / kBatch;
#pragma omp parallel for schedule(static) num_threads(threads_) if (parallel)
    for (int block = 0; block < blocks; ++block) {
      const int first = block * kBatch;
      const int count = std::min(kBatch, nf_ - first);
      Eigen::Matrix3d M[kBatch], R[kBatch];
      for (int l = 0; l < count; ++l) {
        const int f = first + l;
        M[l].setZero();
        for (int k = 0; k < 3; ++k) {
          const size_t c = 3 * static_cast<size_t>(f) + k;
          const Eigen::Vector3d e = edge(x, f, k);
          M[l].noalias() += weight_[c] * e * rest_edge_[c].transpose();
        }
        const Eigen::Vector3d n = N.row(f).transpose();
        const Eigen::Vector3d n0 = N0_.row(f).transpose();
        M[l] = s_(f) * M[l] + (normal_tie_ * area_(f)) * n * n0.transpose();
      }
      closest_rotations(M, R, count);
      for (int l = 0; l < count; ++l) {
        const int f = first + l;
        set_frame(f, R[l]);
        const Eigen::Vector3d n = N.row(f).transpose();
        const Eigen::Vector3d n0 = N0_.row(f).transpose();
        per_face_[f] = normal_tie_ * area_(f) * (R[l] * n0 - n).squaredNorm();
      }
    }
    for (int f = 0; f < nf_; ++f) tie_energy_ += per_face_[f];
    return;
  }
#pragma omp parallel for schedule(static) num_threads(threads_) if (parallel)
  for (int f = 0; f < nf_; ++f) {
    Eigen::Vector3d p[3];
    for (int k = 0; k < 3; ++k) p[k] = x.segment<3>(3 * F_(f, k));
    // R_f maps the rest plane onto the plane of the step-one normal N_f (R_f N0_f = N_f), so the
    // fit, like Eq. 12, bends the surface the way the normals on the Gauss map say; only the
    // in-plane angle is left, and the best one for sum_k w_k || e_k - s R e0_k ||^2 is the
    // rotation part of the 2 x 2 matrix M2 = sum_k w_k (U^T e_k)(V^T e0_k)^T (exact, closed form).
    const Eigen::Vector3d n = N.row(f).transpose();
    const Eigen::Matrix<double, 3, 2> U = plane_frame(n, p[1] - p[0]);
    const Eigen::Matrix<double, 3, 2>& V = rest_frame_[f];
    Eigen::Matrix2d M2 = Eigen::Matrix2d::Zero();
    for (int k = 0; k < 3; ++k) {
      const size_t c = 3 * static_cast<size_t>(f) + k;
      const Eigen::Vector3d e = p[(k + 2) % 3] - p[(k + 1) % 3];
      M2.noalias() +=
          weight_[c] * (U.transpose() * e) * (V.transpose() * rest_edge_[c]).transpose();
    }
    // The fit is -2 s_f tr(R^T M) + ...: for a negative scale the best angle maximises -tr.
    if (s_(f) < 0) M2 = -M2;
    const double rc = M2(0, 0) + M2(1, 1), rs = M2(1, 0) - M2(0, 1);
    const double r = std::hypot(rc, rs);
    const double co = r > 0 ? rc / r : 1.0, si = r > 0 ? rs / r : 0.0;
    Eigen::Matrix2d C;
    C << co, -si, si, co;
    set_frame(f, U * C * V.transpose() + n * N0_.row(f));
  }
}

void ScaleControl::couple_with_frames(const Eigen::VectorXd& x, double* out) const {
  const bool parallel = nf_ > 4000 && threads_ > 1;
#pragma omp parallel for schedule(static) num_threads(threads_) if (parallel)
  for (int f = 0; f < nf_; ++f) {
    double b = 0;
    for (int k = 0; k < 3; ++k) {
      const size_t c = 3 * static_cast<size_t>(f) + k;
      const Eigen::Vector3d e = edge(x, f, k);
      b += weight_[c] * e.dot(frame_edge_[c]);
    }
    out[f] = b;
  }
}

void ScaleControl::update_scales(const Eigen::VectorXd& x) {
  couple_with_frames(x, fit_b_.data());
  if (free_reference_) {
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(nf_ + 1);
    rhs.head(nf_) = fit_b_;
    const Eigen::VectorXd sol = scale_system_.solve(rhs);
    s_ = sol.head(nf_);
    s_bar_ = sol(nf_);
  } else {
    const Eigen::VectorXd rhs = fit_b_ + (pull_ * s_bar_) * area_;
    s_ = scale_system_.solve(rhs);
  }
}

Eigen::VectorXd ScaleControl::scale_unknowns_vector() const {
  Eigen::VectorXd out(scale_unknowns());
  out.head(nf_) = s_;
  if (free_reference_) out(nf_) = s_bar_;
  return out;
}

void ScaleControl::set_scale_unknowns(const Eigen::VectorXd& unknowns) {
  s_ = unknowns.head(nf_);
  if (free_reference_) s_bar_ = unknowns(nf_);
}

Eigen::VectorXd ScaleControl::scale_rhs() const {
  if (free_reference_) return Eigen::VectorXd::Zero(nf_ + 1);
  return (pull_ * s_bar_) * area_;
}

void ScaleControl::multiply_coupling(const Eigen::VectorXd& x, Eigen::VectorXd& out) const {
  MD_ASSERT(!frame_edge_.empty());  // reset() comes first
  out.setZero(scale_unknowns());
  couple_with_frames(x, out.data());
}

void ScaleControl::add_coupling_transpose(const Eigen::VectorXd& s, double alpha,
                                          Eigen::VectorXd& out_x) const {
  for (int f = 0; f < nf_; ++f) {
    for (int k = 0; k < 3; ++k) {
      const size_t c = 3 * static_cast<size_t>(f) + k;
      const Eigen::Vector3d g = (alpha * weight_[c] * s(f)) * frame_edge_[c];
      out_x.segment<3>(3 * F_(f, (k + 2) % 3)) += g;
      out_x.segment<3>(3 * F_(f, (k + 1) % 3)) -= g;
    }
  }
}

void ScaleControl::multiply_scale_matrix(const Eigen::VectorXd& s, Eigen::VectorXd& out) const {
  out = scale_matrix_ * s;
}

Eigen::VectorXd ScaleControl::solve_scale_matrix(const Eigen::VectorXd& r) const {
  return scale_system_.solve(r);
}

void ScaleControl::add_rhs(double rho, Eigen::VectorXd& b) const {
  MD_ASSERT(!frame_edge_.empty());  // reset() comes first
  for (int f = 0; f < nf_; ++f) {
    for (int k = 0; k < 3; ++k) {
      const size_t c = 3 * static_cast<size_t>(f) + k;
      const Eigen::Vector3d g = (rho * weight_[c] * s_(f)) * frame_edge_[c];
      b.segment<3>(3 * F_(f, (k + 2) % 3)) += g;
      b.segment<3>(3 * F_(f, (k + 1) % 3)) -= g;
    }
  }
}

double ScaleControl::energy(const Eigen::VectorXd& x) const {
  MD_ASSERT(!frame_edge_.empty());  // reset() comes first
  const bool parallel = nf_ > 4000 && threads_ > 1;
  per_face_.resize(nf_);
#pragma omp parallel for schedule(static) num_threads(threads_) if (parallel)
  for (int f = 0; f < nf_; ++f) {
    double sum = 0;
    for (int k = 0; k < 3; ++k) {
      const size_t c = 3 * static_cast<size_t>(f) + k;
      const Eigen::Vector3d e = edge(x, f, k);
      sum += weight_[c] * (e - s_(f) * frame_edge_[c]).squaredNorm();
    }
    per_face_[f] = sum;
  }
  double fit = 0;
  for (int f = 0; f < nf_; ++f) fit += per_face_[f];
  double smooth = 0;
  for (Eigen::Index e = 0; e < edge_faces_.rows(); ++e) {
    const double d = s_(edge_faces_(e, 0)) - s_(edge_faces_(e, 1));
    smooth += edge_weight_[e] * d * d;
  }
  double pull = 0;
  for (int f = 0; f < nf_; ++f) pull += area_(f) * (s_(f) - s_bar_) * (s_(f) - s_bar_);
  return fit + smooth + pull_ * pull + tie_energy_;
}

}  // namespace meshdeform::core
