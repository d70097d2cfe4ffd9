#include "core/linalg/rotation_fit.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>
#include <Eigen/LU>

#include "core/methods/normals_step.h"

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

namespace {

constexpr int kLanes = 4;

inline double det3(double a00, double a01, double a02, double a10, double a11, double a12,
                   double a20, double a21, double a22) {
  return a00 * (a11 * a22 - a12 * a21) - a01 * (a10 * a22 - a12 * a20) +
         a02 * (a10 * a21 - a11 * a20);
}

/// closest_rotation() for kLanes matrices at once: the same steps (Horn's matrix, Newton on the
/// quartic from the same bound with the same stopping rule per lane, the largest adjugate
/// column), in lanes that the compiler can keep side by side; lanes that need the SVD fallback
/// (a zero matrix, a near-double top eigenvalue) are marked and done by the scalar function.
void closest_rotations_batch(const Eigen::Matrix3d* S, Eigen::Matrix3d* R) {
  double a[10][kLanes];  // Horn's N, upper triangle: 00 01 02 03 11 12 13 22 23 33
  double lambda[kLanes], c0[kLanes], c1[kLanes], c2[kLanes];
  bool fallback[kLanes];
  for (int l = 0; l < kLanes; ++l) {
    const Eigen::Matrix3d& m = S[l];
    const double sxx = m(0, 0), sxy = m(1, 0), sxz = m(2, 0);
    const double syx = m(0, 1), syy = m(1, 1), syz = m(2, 1);
    const double szx = m(0, 2), szy = m(1, 2), szz = m(2, 2);
    const double fro2 = sxx * sxx + sxy * sxy + sxz * sxz + syx * syx + syy * syy + syz * syz +
                        szx * szx + szy * szy + szz * szz;
    fallback[l] = !(fro2 > 0);
    a[0][l] = sxx + syy + szz;
    a[1][l] = syz - szy;
    a[2][l] = szx - sxz;
    a[3][l] = sxy - syx;
    a[4][l] = sxx - syy - szz;
    a[5][l] = sxy + syx;
    a[6][l] = szx + sxz;
    a[7][l] = -sxx + syy - szz;
    a[8][l] = syz + szy;
    a[9][l] = -sxx - syy + szz;
    // det(N) by Laplace along the first two rows (N symmetric).
    const double n00 = a[0][l], n01 = a[1][l], n02 = a[2][l], n03 = a[3][l];
    const double n11 = a[4][l], n12 = a[5][l], n13 = a[6][l];
    const double n22 = a[7][l], n23 = a[8][l], n33 = a[9][l];
    const double s0 = n00 * n11 - n01 * n01, s1 = n00 * n12 - n02 * n01;
    const double s2 = n00 * n13 - n03 * n01, s3 = n01 * n12 - n02 * n11;
    const double s4 = n01 * n13 - n03 * n11, s5 = n02 * n13 - n03 * n12;
    const double k5 = n22 * n33 - n23 * n23, k4 = n12 * n33 - n23 * n13;
    const double k3 = n12 * n23 - n22 * n13, k2 = n02 * n33 - n23 * n03;
    const double k1 = n02 * n23 - n22 * n03, k0 = n02 * n13 - n12 * n03;
    c0[l] = s0 * k5 - s1 * k4 + s2 * k3 + s3 * k2 - s4 * k1 + s5 * k0;
    c1[l] = -8.0 * det3(sxx, syx, szx, sxy, syy, szy, sxz, syz, szz);
    c2[l] = -2.0 * fro2;
    lambda[l] = std::sqrt(3.0 * fro2);
  }
  bool active[kLanes];
  for (int l = 0; l < kLanes; ++l) active[l] = !fallback[l];
  for (int k = 0; k < 60; ++k) {
    int running = 0;
    for (int l = 0; l < kLanes; ++l) {
      const double x = lambda[l], l2 = x * x;
      const double p = (l2 + c2[l]) * l2 + c1[l] * x + c0[l];
      const double dp = (4.0 * l2 + 2.0 * c2[l]) * x + c1[l];
      const bool go = active[l] && dp > 0;
      const double step = go ? p / dp : 0.0;
      const double next = x - step;
      lambda[l] = next;
      active[l] = go && !(std::abs(step) <= 1e-14 * next);
      running += active[l] ? 1 : 0;
    }
    if (running == 0) break;
  }
  for (int l = 0; l < kLanes; ++l) {
    const double x = lambda[l];
    const double m00 = a[0][l] - x, m01 = a[1][l], m02 = a[2][l], m03 = a[3][l];
    const double m11 = a[4][l] - x, m12 = a[5][l], m13 = a[6][l];
    const double m22 = a[7][l] - x, m23 = a[8][l], m33 = a[9][l] - x;
    // Minors M(r, c) of the symmetric A = N - lambda I (M(r, c) = M(c, r)).
    const double d00 = det3(m11, m12, m13, m12, m22, m23, m13, m23, m33);
    const double d11 = det3(m00, m02, m03, m02, m22, m23, m03, m23, m33);
    const double d22 = det3(m00, m01, m03, m01, m11, m13, m03, m13, m33);
    const double d33 = det3(m00, m01, m02, m01, m11, m12, m02, m12, m22);
    const double d01 = det3(m01, m12, m13, m02, m22, m23, m03, m23, m33);
    const double d02 = det3(m01, m11, m13, m02, m12, m23, m03, m13, m33);
    const double d03 = det3(m01, m11, m12, m02, m12, m22, m03, m13, m23);
    const double d12 = det3(m00, m01, m03, m02, m12, m23, m03, m13, m33);
    const double d13 = det3(m00, m01, m02, m02, m12, m22, m03, m13, m23);
    const double d23 = det3(m00, m01, m02, m01, m11, m12, m03, m13, m23);
    // The largest diagonal minor picks the adjugate column (first one on ties).
    int best = 0;
    double best_value = std::abs(d00);
    if (std::abs(d11) > best_value) best = 1, best_value = std::abs(d11);
    if (std::abs(d22) > best_value) best = 2, best_value = std::abs(d22);
    if (std::abs(d33) > best_value) best = 3, best_value = std::abs(d33);
    fallback[l] = fallback[l] || !(best_value > 1e-10 * x * x * x);
    // q(j) = (-1)^(best + j) M(best, j).
    double w, qx, qy, qz;
    if (best == 0) {
      w = d00, qx = -d01, qy = d02, qz = -d03;
    } else if (best == 1) {
      w = -d01, qx = d11, qy = -d12, qz = d13;
    } else if (best == 2) {
      w = d02, qx = -d12, qy = d22, qz = -d23;
    } else {
      w = -d03, qx = d13, qy = -d23, qz = d33;
    }
    const Eigen::Quaterniond q = Eigen::Quaterniond(w, qx, qy, qz).normalized();
    R[l] = q.toRotationMatrix();
  }
  for (int l = 0; l < kLanes; ++l) {
    if (fallback[l]) R[l] = closest_rotation(S[l]);
  }
}

}  // namespace

void closest_rotations(const Eigen::Matrix3d* S, Eigen::Matrix3d* R, int count) {
  int i = 0;
  for (; i + kLanes <= count; i += kLanes) closest_rotations_batch(S + i, R + i);
  for (; i < count; ++i) R[i] = closest_rotation(S[i]);
}

}  // namespace meshdeform::core
