#include "core/normals_step.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/SVD>

namespace meshdeform::core {

void refine_rotation(const Eigen::Matrix3d& B, Eigen::Quaterniond& q, int max_iterations) {
  for (int it = 0; it < max_iterations; ++it) {
    const Eigen::Matrix3d R = q.toRotationMatrix();
    Eigen::Vector3d omega =
        R.col(0).cross(B.col(0)) + R.col(1).cross(B.col(1)) + R.col(2).cross(B.col(2));
    const double denom =
        std::abs(R.col(0).dot(B.col(0)) + R.col(1).dot(B.col(1)) + R.col(2).dot(B.col(2))) + 1e-9;
    omega /= denom;
    if (omega.squaredNorm() < 1e-26) break;
    // Rotate by omega: the quaternion (1, omega / 2) normalised is that rotation to first order
    // and never overshoots, so the iteration keeps Mueller's fixed point without trigonometry.
    const Eigen::Quaterniond step(1.0, 0.5 * omega.x(), 0.5 * omega.y(), 0.5 * omega.z());
    q = (step * q).normalized();
  }
}

Eigen::Quaterniond kabsch_rotation(const Eigen::Matrix3d& B) {
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(B, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d U = svd.matrixU();
  Eigen::Matrix3d R = U * svd.matrixV().transpose();
  if (R.determinant() < 0) {
    U.col(2) *= -1.0;
    R = U * svd.matrixV().transpose();
  }
  return Eigen::Quaterniond(R).normalized();
}

int update_normals(const RowPositions& N0, const Triangles& F, const MeshTopology& topology,
                   RowPositions& N, std::vector<Eigen::Quaterniond>& rotations, bool warm,
                   int max_sweeps, double tolerance, int threads) {
  const int nv = topology.vertex_count;
  const int nf = topology.face_count;
  const bool parallel = nv > 2000 && threads > 1;
  int sweeps = 0;
  std::vector<Eigen::Matrix3d> matrices(nv);
  for (; sweeps < max_sweeps;) {
    const bool use_svd = !warm && sweeps == 0;
    // Local: one rotation per vertex fan. B = sum_f N_f N0_f^T; R maximises trace(R^T B).
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
    for (int v = 0; v < nv; ++v) {
      Eigen::Matrix3d B = Eigen::Matrix3d::Zero();
      for (int k = topology.vf_offsets[v]; k < topology.vf_offsets[v + 1]; ++k) {
        const int f = topology.vf_faces[k];
        B.noalias() += N.row(f).transpose() * N0.row(f);
      }
      if (use_svd) {
        rotations[v] = kabsch_rotation(B);
      } else {
        refine_rotation(B, rotations[v], 3);  // the sweeps themselves warm-start it
      }
    }
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
    for (int v = 0; v < nv; ++v) matrices[v] = rotations[v].toRotationMatrix();
    // Global: each face normal is the normalised mean of its corners' rotated rest normal.
    double max_change = 0;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel) \
    reduction(max : max_change)
    for (int f = 0; f < nf; ++f) {
      const Eigen::Vector3d n0 = N0.row(f).transpose();
      const Eigen::Vector3d sum =
          (matrices[F(f, 0)] + matrices[F(f, 1)] + matrices[F(f, 2)]) * n0;
      const double len = sum.norm();
      if (len < 1e-12) continue;  // opposite rotations cancel: keep the previous normal
      const Eigen::Vector3d next = sum / len;
      max_change = std::max(max_change, (next - N.row(f).transpose()).norm());
      N.row(f) = next.transpose();
    }
    ++sweeps;
    warm = true;
    if (max_change < tolerance) break;
  }
  return sweeps;
}

}  // namespace meshdeform::core
