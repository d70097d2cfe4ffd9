#include "core/linalg/rotation_fit.h"

#include <random>
#include <vector>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "core/methods/normals_step.h"

namespace meshdeform::core {
namespace {

Eigen::Matrix3d random_rotation(std::mt19937& rng) {
  std::normal_distribution<double> normal;
  return Eigen::Quaterniond(normal(rng), normal(rng), normal(rng), normal(rng))
      .normalized()
      .toRotationMatrix();
}

/// Matrices of every kind the fits meet: general, near-rotations (ARAP's fans at convergence),
/// scaled rotations, reflections, rank one and two (a one-face fan), and zero.
std::vector<Eigen::Matrix3d> matrices(int count) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> uniform(-1.0, 1.0);
  std::vector<Eigen::Matrix3d> out;
  for (int i = 0; static_cast<int>(out.size()) < count; ++i) {
    Eigen::Matrix3d S;
    for (int e = 0; e < 9; ++e) S(e / 3, e % 3) = uniform(rng);
    switch (i % 7) {
      case 0: break;
      case 1: S = random_rotation(rng) + 1e-3 * S; break;
      case 2: S = (0.01 + std::abs(uniform(rng))) * random_rotation(rng); break;
      case 3: S = random_rotation(rng) * Eigen::Vector3d(1, 1, -1).asDiagonal(); break;
      case 4: S = S.col(0) * S.row(1); break;
      case 5: S = S.col(0) * S.row(1) + S.col(1) * S.row(2); break;
      case 6: S = i % 14 == 6 ? Eigen::Matrix3d::Zero() : Eigen::Matrix3d(1e-8 * S); break;
    }
    out.push_back(S);
  }
  return out;
}

TEST(RotationFit, ClosestRotationIsAProperRotationMaximisingTheTrace) {
  for (const Eigen::Matrix3d& S : matrices(700)) {
    const Eigen::Matrix3d R = closest_rotation(S);
    EXPECT_LT((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(), 1e-12);
    EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
    // Kabsch (SVD, reflection removed) maximises trace(R^T S) too; where the maximiser is not
    // unique (rank one, a reflection) the objectives still agree, to what the near-double
    // eigenvalue leaves (about 1e-11 measured).
    const Eigen::Matrix3d K = kabsch_rotation(S).toRotationMatrix();
    EXPECT_NEAR((R.transpose() * S).trace(), (K.transpose() * S).trace(),
                1e-10 * (1.0 + S.norm()));
  }
}

TEST(RotationFit, TheBatchedFitIsTheScalarFitForEachMatrix) {
  // Counts that leave 0 to 3 matrices after the last batch of four.
  for (const int count : {0, 1, 3, 4, 5, 8, 11, 701}) {
    SCOPED_TRACE(count);
    const std::vector<Eigen::Matrix3d> S = matrices(count);
    std::vector<Eigen::Matrix3d> R(static_cast<size_t>(count));
    closest_rotations(S.data(), R.data(), count);
    for (int i = 0; i < count; ++i) {
      SCOPED_TRACE(i);
      const Eigen::Matrix3d scalar = closest_rotation(S[i]);
      EXPECT_LT((R[i].transpose() * R[i] - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff(),
                1e-12);
      EXPECT_NEAR(R[i].determinant(), 1.0, 1e-12);
      EXPECT_NEAR((R[i].transpose() * S[i]).trace(), (scalar.transpose() * S[i]).trace(),
                  1e-10 * (1.0 + S[i].norm()));
      // Where the maximiser is unique and well separated (general matrices, near-rotations,
      // scaled rotations: kinds 0-2), the rotations themselves agree to round-off.
      if (i % 7 <= 2) {
        EXPECT_LT((R[i] - scalar).cwiseAbs().maxCoeff(), 1e-12);
      }
    }
  }
}

}  // namespace
}  // namespace meshdeform::core
