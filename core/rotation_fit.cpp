#include "core/rotation_fit.h"

#include <cmath>

#include <Eigen/Geometry>
#include <Eigen/LU>

#include "core/normals_step.h"

namespace meshdeform::core {
namespace {

/// Determinant of the 3x3 minor of A without row r and column c.
double minor3(const Eigen::Matrix4d& A, int r, int c) {
  int rs[3], cs[3];
  for (int i = 0, k = 0; i < 4; ++i) {
    if (i != r) rs[k++] = i;
  }
  for (int j = 0, k = 0; j < 4; ++j) {
    if (j != c) cs[k++] = j;
  }
  const auto a = [&](int i, int j) { return A(rs[i], cs[j]); };
  return a(0, 0) * (a(1, 1) * a(2, 2) - a(1, 2) * a(2, 1)) -
         a(0, 1) * (a(1, 0) * a(2, 2) - a(1, 2) * a(2, 0)) +
         a(0, 2) * (a(1, 0) * a(2, 1) - a(1, 1) * a(2, 0));
}

}  // namespace

/// The rotation R maximising trace(R^T S), i.e. the Kabsch fit with the reflection removed, in
/// closed form: by Horn's quaternion method it is the quaternion of the largest eigenvalue of a
/// traceless symmetric 4x4 matrix N(S). That eigenvalue is the largest root of N's quartic
/// characteristic polynomial (Theobald's QCP, 2005), found by Newton from the upper bound
/// sqrt(3) ||S||_F (monotone convergence from the right), and the eigenvector is the largest
/// column of adj(N - lambda I), which is rank one. About 4x cheaper than Eigen's 3x3 JacobiSVD
/// (which was two thirds of an ARAP iteration under callgrind) and equal to it to round-off; a
/// (near) double top eigenvalue, where the best rotation is not unique (a rank-one S), falls back
/// to the SVD.
Eigen::Matrix3d closest_rotation(const Eigen::Matrix3d& S) {
  const double fro2 = S.squaredNorm();
  if (!(fro2 > 0)) return Eigen::Matrix3d::Identity();
  const double sxx = S(0, 0), sxy = S(1, 0), sxz = S(2, 0);
  const double syx = S(0, 1), syy = S(1, 1), syz = S(2, 1);
  const double szx = S(0, 2), szy = S(1, 2), szz = S(2, 2);
  Eigen::Matrix4d N;
  N << sxx + syy + szz, syz - szy, szx - sxz, sxy - syx,  //
      syz - szy, sxx - syy - szz, sxy + syx, szx + sxz,   //
      szx - sxz, sxy + syx, -sxx + syy - szz, syz + szy,  //
      sxy - syx, szx + sxz, syz + szy, -sxx - syy + szz;
  // det(lambda I - N) = lambda^4 + c2 lambda^2 + c1 lambda + c0 (N is traceless).
  const double c2 = -2.0 * fro2, c1 = -8.0 * S.determinant(), c0 = N.determinant();
  double lambda = std::sqrt(3.0 * fro2);
  for (int k = 0; k < 60; ++k) {
    const double l2 = lambda * lambda;
    const double p = (l2 + c2) * l2 + c1 * lambda + c0;
    const double dp = (4.0 * l2 + 2.0 * c2) * lambda + c1;
    if (!(dp > 0)) break;
    const double step = p / dp;
    lambda -= step;
    if (std::abs(step) <= 1e-14 * lambda) break;
  }
  Eigen::Matrix4d A = N;
  A.diagonal().array() -= lambda;
  int best = 0;
  double best_value = -1;
  for (int i = 0; i < 4; ++i) {
    const double d = std::abs(minor3(A, i, i));
    if (d > best_value) {
      best_value = d;
      best = i;
    }
  }
  if (!(best_value > 1e-10 * lambda * lambda * lambda)) {
    return kabsch_rotation(S).toRotationMatrix();
  }
  Eigen::Vector4d q;
  for (int j = 0; j < 4; ++j) q(j) = ((best + j) % 2 == 0 ? 1.0 : -1.0) * minor3(A, best, j);
  q.normalize();
  return Eigen::Quaterniond(q(0), q(1), q(2), q(3)).toRotationMatrix();
}


}  // namespace meshdeform::core
