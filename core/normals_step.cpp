#include "core/normals_step.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/SVD>

#include "core/rotation_fit.h"

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

namespace {

/// refine_rotation() for kLanes fans at once, each lane's arithmetic that of the scalar
/// iteration (a lane that has converged keeps its q): the scalar iteration is one long chain of
/// dependent operations (quaternion, matrix, cross products, a division, a square root), so a
/// fan at a time leaves the core waiting; independent lanes side by side fill its pipeline
/// (instruction-level parallelism: GCC does not vectorise these loops, -fopt-info-vec).
constexpr int kLanes = 4;
struct RotationBatch {
  double b[9][kLanes];  // B(i, j) at b[3 i + j]
  double q[4][kLanes];  // w, x, y, z
  double r[9][kLanes];  // result R(i, j) at r[3 i + j]
};

inline void batch_matrices(const double (&q)[4][kLanes], double (&r)[9][kLanes]) {
  for (int l = 0; l < kLanes; ++l) {
    // Eigen's Quaternion::toRotationMatrix, term for term.
    const double w = q[0][l], x = q[1][l], y = q[2][l], z = q[3][l];
    const double tx = 2 * x, ty = 2 * y, tz = 2 * z;
    const double twx = tx * w, twy = ty * w, twz = tz * w;
    const double txx = tx * x, txy = ty * x, txz = tz * x;
    const double tyy = ty * y, tyz = tz * y, tzz = tz * z;
    r[0][l] = 1 - (tyy + tzz);
    r[1][l] = txy - twz;
    r[2][l] = txz + twy;
    r[3][l] = txy + twz;
    r[4][l] = 1 - (txx + tzz);
    r[5][l] = tyz - twx;
    r[6][l] = txz - twy;
    r[7][l] = tyz + twx;
    r[8][l] = 1 - (txx + tyy);
  }
}

void refine_rotations(RotationBatch& batch, int max_iterations) {
  bool done[kLanes] = {};
  for (int it = 0; it < max_iterations; ++it) {
    double r[9][kLanes];
    batch_matrices(batch.q, r);
    int active = 0;
    for (int l = 0; l < kLanes; ++l) {
      // omega = sum_c R.col(c) x B.col(c), denom = |sum_c R.col(c) . B.col(c)| + 1e-9.
      double ox = 0, oy = 0, oz = 0, dot = 0;
      for (int c = 0; c < 3; ++c) {
        const double rx = r[c][l], ry = r[3 + c][l], rz = r[6 + c][l];
        const double bx = batch.b[c][l], by = batch.b[3 + c][l], bz = batch.b[6 + c][l];
        ox += ry * bz - rz * by;
        oy += rz * bx - rx * bz;
        oz += rx * by - ry * bx;
        dot += rx * bx + ry * by + rz * bz;
      }
      const double denom = std::abs(dot) + 1e-9;
      ox /= denom;
      oy /= denom;
      oz /= denom;
      const bool converged = done[l] || ox * ox + oy * oy + oz * oz < 1e-26;
      done[l] = converged;
      active += converged ? 0 : 1;
      // q <- normalise((1, omega / 2) q) where not converged.
      const double hx = 0.5 * ox, hy = 0.5 * oy, hz = 0.5 * oz;
      const double w = batch.q[0][l], x = batch.q[1][l], y = batch.q[2][l], z = batch.q[3][l];
      const double nw = w - (hx * x + hy * y + hz * z);
      const double nx = x + w * hx + (hy * z - hz * y);
      const double ny = y + w * hy + (hz * x - hx * z);
      const double nz = z + w * hz + (hx * y - hy * x);
      const double inv = 1.0 / std::sqrt(nw * nw + nx * nx + ny * ny + nz * nz);
      batch.q[0][l] = converged ? w : nw * inv;
      batch.q[1][l] = converged ? x : nx * inv;
      batch.q[2][l] = converged ? y : ny * inv;
      batch.q[3][l] = converged ? z : nz * inv;
    }
    if (active == 0) break;
  }
  batch_matrices(batch.q, batch.r);
}

}  // namespace

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
    const bool cold = !warm && sweeps == 0;
    // Local: one rotation per vertex fan. B = sum_f N_f N0_f^T; R maximises trace(R^T B).
    auto fan_matrix = [&](int v) {
      Eigen::Matrix3d B = Eigen::Matrix3d::Zero();
      for (int k = topology.vf_offsets[v]; k < topology.vf_offsets[v + 1]; ++k) {
        const int f = topology.vf_faces[k];
        B.noalias() += N.row(f).transpose() * N0.row(f);
      }
      return B;
    };
    if (cold) {
      // No previous rotations: start from the closed-form fit (Horn's quaternion,
      // closest_rotations(), about 4x cheaper than an SVD), kLanes fans at a time; the
      // refinement below then makes it exact where the fit loses digits (a nearly flat fan, whose
      // rotation about its normal is barely determined).
      const int blocks = (nv + kLanes - 1) / kLanes;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
      for (int block = 0; block < blocks; ++block) {
        const int first = block * kLanes;
        const int count = std::min(kLanes, nv - first);
        Eigen::Matrix3d B[kLanes], R[kLanes];
        for (int l = 0; l < count; ++l) B[l] = fan_matrix(first + l);
        closest_rotations(B, R, count);
        for (int l = 0; l < count; ++l) {
          rotations[first + l] = Eigen::Quaterniond(R[l]).normalized();
        }
      }
    }
    // Refinement from the previous sweep's rotations (or the fit above): kLanes fans at a time,
    // then the rest one by one.
    const int blocks = nv / kLanes;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
    for (int block = 0; block < blocks; ++block) {
      RotationBatch batch;
      for (int l = 0; l < kLanes; ++l) {
        const int v = block * kLanes + l;
        const Eigen::Matrix3d B = fan_matrix(v);
        for (int e = 0; e < 9; ++e) batch.b[e][l] = B(e / 3, e % 3);
        batch.q[0][l] = rotations[v].w();
        batch.q[1][l] = rotations[v].x();
        batch.q[2][l] = rotations[v].y();
        batch.q[3][l] = rotations[v].z();
      }
      refine_rotations(batch, 3);
      for (int l = 0; l < kLanes; ++l) {
        const int v = block * kLanes + l;
        rotations[v] = Eigen::Quaterniond(batch.q[0][l], batch.q[1][l], batch.q[2][l],
                                          batch.q[3][l]);
        for (int e = 0; e < 9; ++e) matrices[v](e / 3, e % 3) = batch.r[e][l];
      }
    }
    for (int v = blocks * kLanes; v < nv; ++v) {
      refine_rotation(fan_matrix(v), rotations[v], 3);
      matrices[v] = rotations[v].toRotationMatrix();
    }
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
