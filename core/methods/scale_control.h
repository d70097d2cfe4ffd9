#pragma once
/// @file scale_control.h
/// Internal to core: the in-loop scale term of the scale-aware solver (issue 12, "rigidity").
/// The paper's energy (Eq. 12) is invariant to scale, so nothing in the solve bounds how much
/// local scale may drift. This term adds, weighted by the user's `rigidity` rho,
///
///   E_s(x, R, s, s_bar) = sum_f sum_{k in f} w_k || e_k(x) - s_f R_f e0_k ||^2     (fit)
///                       + mu  sum_{f~g} w_fg (s_f - s_g)^2                           (smoothness)
///                       + nu  sum_f A_f (s_f - s_bar)^2                              (pull)
///
/// with per-face rotations R_f, per-face linear scales s_f and a reference scale s_bar;
/// w_k = cot(opposite angle) / 2 in the rest triangle (so the fit is A_f ||J_f - s_f R_f||_F^2, the
/// ARAP/ASAP energy of Liu et al. 2008 with the scale of each face a variable), w_fg = xi^2 |e|^2 /
/// (A_f + A_g) over interior edges (a Dirichlet energy of s with length scale xi), and the pull
/// toward s_bar, not toward 1: s_bar is the scale the handles imply (the length change of the
/// mesh edges between constrained vertices), or a free variable when no edge joins two
/// constrained vertices. Either way a similarity edit costs nothing. The whole term is
/// homogeneous of degree 2 in (x, s, s_bar), like Eq. 12.
/// Block steps, each an exact minimiser of E_s in its block:
///   rotations: R_f maps the rest plane onto the plane of the step-one normal N_f (so the fit bends
///              the surface as the normals say, like Eq. 12) with the in-plane angle that
///              minimises the fit given x and s: closed form per face (a 2 x 2 polar angle);
///   scales:    one constant sparse SPD system in (s, s_bar), factored once;
///   vertices:  adds rho (L_cot (x) I3) to step two's matrix and rho * fit targets to its rhs.

#include <Eigen/Core>
#include <limits>
#include <utility>
#include <vector>

#include "core/mesh/mesh_data.h"
#include "core/methods/normals_step.h"
#include "core/linalg/sparse_cholesky.h"
#include "core/base/status.h"
#include "core/mesh/topology.h"

namespace meshdeform::core {

/// The constant parts of the scale term for one mesh, and its rotation / scale block steps.
class ScaleControl {
 public:
  /// Precomputes weights and factors the scale system.
  /// @param[in] V0       #V x 3 rest positions (validated).
  /// @param[in] F        #F x 3 triangles.
  /// @param[in] N0       #F x 3 rest unit normals.
  /// @param[in] pull     nu >= 0, pull of s_f toward s_bar (relative to the fit's 2 A_f per face).
  /// @param[in] smooth_length  xi / sqrt(total rest area) >= 0, the smoothness length.
  /// @return NumericalFailure if the scale system cannot be factored.
  [[nodiscard]] Status build(const RowPositions& V0, const Triangles& F,
                             const MeshTopology& topology, const RowPositions& N0,
                             const Eigen::VectorXi& constrained, double pull, double smooth_length);

  /// Sets the reference scale s_bar from the handle targets (#C x 3, rows as `constrained`):
  /// sqrt(sum |t_i - t_j|^2 / sum |p_i - p_j|^2) over mesh edges with both ends constrained, the
  /// scale the handles themselves imply. Without such edges s_bar is a free variable instead.
  void set_reference(const Positions& targets);

  /// Cotangent Laplacian of the fit term (w summed over the faces of edge ij; L(i, i) =
  /// -sum_j L(i, j)), face by face: block[3 p + q] is the contribution of face f to
  /// L(F(f,p), F(f,q)). Formed from the face's three corner weights when asked (the weight of
  /// corner k sits on the edge opposite it), not stored: 9 doubles per face less.
  void face_laplacian_block(int f, double (&block)[9]) const {
    const double* w = weight_.data() + 3 * static_cast<size_t>(f);
    block[0] = w[1] + w[2];
    block[4] = w[0] + w[2];
    block[8] = w[0] + w[1];
    block[5] = block[7] = -w[0];
    block[2] = block[6] = -w[1];
    block[1] = block[3] = -w[2];
  }

  /// Rotation step: for every face, the exact minimiser of the fit over the rotations R_f with
  /// R_f N0_f = N_f, given x and s.
  /// @param[in] x  3#V interleaved positions.  @param[in] N  #F x 3 unit normals of step one.
  void update_rotations(const Eigen::VectorXd& x, const RowPositions& N);
  /// Scale step: the exact minimiser over (s, s_bar) given x and the rotations.
  void update_scales(const Eigen::VectorXd& x);
  /// beta >= 0 (or infinity, the default: R_f N0_f = N_f exactly): the frames' pull toward the
  /// step-one normals, beta A_f ||R_f N0_f - N_f||^2, added to the energy.
  void set_normal_tie(double beta) { normal_tie_ = beta; }
  /// OpenMP threads of the per-face loops (rotation step, scale right-hand side, energy); the
  /// results do not depend on it (per-face values are summed in face order). Default 1.
  void set_threads(int threads) { threads_ = threads > 0 ? threads : 1; }
  /// Resets s = s_bar = 1, R = identity. Call before the first rotation or scale step, product
  /// or energy of a solve (build() leaves the frames unallocated).
  void reset();

  /// Adds the fit term's right-hand side (the gradient's constant part), scaled by rho, to b.
  void add_rhs(double rho, Eigen::VectorXd& b) const;
  /// E_s(x, R, s, s_bar) (without rho).
  double energy(const Eigen::VectorXd& x) const;

  const Eigen::VectorXd& scales() const { return s_; }
  double global_scale() const { return s_bar_; }

  // The joint (x, s) form of the term for step two, with the rotations fixed:
  //   E_s = x^T L x - 2 s^T C x + s^T H s - 2 r^T s + const,
  // C the #S x 3#V map x -> (sum_k w_k (R_f e0_k) . e_k(x))_f, H the constant scale matrix and
  // r = nu s_bar A (fixed reference) or 0 (free). #S = #F, or #F + 1 with a free reference.

  /// #S, the number of scale unknowns.
  int scale_unknowns() const { return free_reference_ ? nf_ + 1 : nf_; }
  /// (s) or (s, s_bar): the current scale unknowns; set_scale_unknowns writes them back.
  Eigen::VectorXd scale_unknowns_vector() const;
  void set_scale_unknowns(const Eigen::VectorXd& unknowns);
  /// r.
  Eigen::VectorXd scale_rhs() const;
  /// out = C x (#S; 0 for s_bar).
  void multiply_coupling(const Eigen::VectorXd& x, Eigen::VectorXd& out) const;
  /// out_x += alpha C^T s.
  void add_coupling_transpose(const Eigen::VectorXd& s, double alpha, Eigen::VectorXd& out_x) const;
  /// Face f's part of the coupling, for a product that visits faces anyway (the solver's
  /// matrix-free one): adds alpha_s times face f's column of C^T to the sums of its corners
  /// (sum[k] for F(f, k)) and returns (C x)_f, with v[k] the position of F(f, k).
  double face_coupling(int f, const Eigen::Vector3d v[3], double alpha_s,
                       Eigen::Vector3d sum[3]) const {
    double b = 0;
    for (int k = 0; k < 3; ++k) {
      const size_t c = 3 * static_cast<size_t>(f) + k;
      const Eigen::Vector3d& target = frame_edge_[c];
      const int head = (k + 2) % 3, tail = (k + 1) % 3;
      b += weight_[c] * (v[head] - v[tail]).dot(target);
      const Eigen::Vector3d g = (alpha_s * weight_[c]) * target;
      sum[head] += g;
      sum[tail] -= g;
    }
    return b;
  }
  /// out = H s.
  void multiply_scale_matrix(const Eigen::VectorXd& s, Eigen::VectorXd& out) const;
  /// H^-1 r with the constant factor.
  Eigen::VectorXd solve_scale_matrix(const Eigen::VectorXd& r) const;

 private:
  /// s = s_bar = 1 and no rotation-step term: reset() without the frames.
  void reset_scales();
  /// Stores face f's frame R as its rotated rest edges.
  void set_frame(int f, const Eigen::Matrix3d& R);
  /// out[f] = sum_k w_k e_k(x) . (R_f e0_k) for every face: the coupling of x with the frames
  /// (update_scales' fit and multiply_coupling). `out` holds at least #F values.
  void couple_with_frames(const Eigen::VectorXd& x, double* out) const;
  /// e_k(x): the edge of face f opposite corner k, from corner k+1 to corner k+2.
  Eigen::Vector3d edge(const Eigen::VectorXd& x, int f, int k) const {
    return x.segment<3>(3 * F_(f, (k + 2) % 3)) - x.segment<3>(3 * F_(f, (k + 1) % 3));
  }

  int nv_ = 0, nf_ = 0;
  Triangles F_;
  std::vector<double> weight_;                           // 3#F: w_k of the edge opposite corner k
  std::vector<Eigen::Vector3d> rest_edge_;               // 3#F: e0_k = V0(F(f,k+2)) - V0(F(f,k+1))
  std::vector<Eigen::Matrix<double, 3, 2>> rest_frame_;  // #F: [t0 b0] of the rest plane
  RowPositions N0_;
  Eigen::VectorXd fit_a_;  // #F: sum_k w_k |e0_k|^2 (= 2 A_f)
  Eigen::VectorXd area_;   // #F rest areas
  Eigen::Matrix<int, Eigen::Dynamic, 2> edge_faces_;
  std::vector<std::pair<int, int>> handle_edges_;  // rows of targets of constrained mesh edges
  double handle_rest_length2_ = 0;
  bool free_reference_ = true;
  std::vector<double> edge_weight_;  // mu w_fg per interior edge
  double pull_ = 0;
  SparseCholesky scale_system_;  // H, #S x #S
  SparseMatrix scale_matrix_;    // H
  // State.
  // R_f e0_k per corner, the only use of the face frames: kept instead of R_f so that the
  // products of every PCG step and energy read one vector per corner.
  std::vector<Eigen::Vector3d> frame_edge_;  // 3#F
  Eigen::VectorXd s_;
  double s_bar_ = 1;
  double normal_tie_ = std::numeric_limits<double>::infinity();
  double tie_energy_ = 0;  // beta sum_f A_f ||R_f N0_f - N_f||^2 at the last R-step
  Eigen::VectorXd fit_b_;  // #F: tr(R_f^T sum_k w_k e_k e0_k^T) at the last R-step
  int threads_ = 1;
  mutable std::vector<double> per_face_;  // #F scratch: per-face terms summed in face order
};

}  // namespace meshdeform::core
