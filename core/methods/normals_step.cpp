#include "core/methods/normals_step.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include <Eigen/SVD>

#include "core/linalg/rotation_fit.h"

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
/// (instruction-level parallelism; GCC does not vectorise these loops, -fopt-info-vec, so the
/// lanes go through vector registers in pairs by hand, below).
constexpr int kLanes = 4;
struct RotationBatch {
  double b[9][kLanes];  // B(i, j) at b[3 i + j]
  double q[4][kLanes];  // w, x, y, z
  double r[9][kLanes];  // result R(i, j) at r[3 i + j]
};

// Two lanes per 16-byte vector (GCC / Clang vector extensions: SSE2 on x86-64, its baseline, so
// no dispatch): every operation is the scalar one in the same order (x86-64 has no FMA to
// contract into), so each lane's result is the one-lane-at-a-time loop's bit for bit, at half the
// instructions for the divisions and square roots that bound this loop.
static_assert(kLanes % 2 == 0, "lanes are processed in pairs");
typedef double Pair __attribute__((vector_size(16)));
using Mask = decltype(Pair{} < Pair{});  // all bits set in a lane where a comparison holds

inline Pair load(const double* p) {
  Pair v;
  std::memcpy(&v, p, sizeof v);
  return v;
}
inline void store(double* p, Pair v) { std::memcpy(p, &v, sizeof v); }
inline Pair select(Mask mask, Pair if_set, Pair if_clear) {
  return (Pair)((mask & (Mask)if_set) | (~mask & (Mask)if_clear));
}
inline Pair sqrt_of(Pair v) {
#if defined(__SSE2__)
  return _mm_sqrt_pd(v);
#else
  return Pair{std::sqrt(v[0]), std::sqrt(v[1])};
#endif
}

inline void batch_matrices(const double (&q)[4][kLanes], double (&r)[9][kLanes]) {
  for (int l = 0; l < kLanes; l += 2) {
    // Eigen's Quaternion::toRotationMatrix, term for term.
    const Pair w = load(&q[0][l]), x = load(&q[1][l]), y = load(&q[2][l]), z = load(&q[3][l]);
    const Pair tx = 2.0 * x, ty = 2.0 * y, tz = 2.0 * z;
    const Pair twx = tx * w, twy = ty * w, twz = tz * w;
    const Pair txx = tx * x, txy = ty * x, txz = tz * x;
    const Pair tyy = ty * y, tyz = tz * y, tzz = tz * z;
    store(&r[0][l], 1.0 - (tyy + tzz));
    store(&r[1][l], txy - twz);
    store(&r[2][l], txz + twy);
    store(&r[3][l], txy + twz);
    store(&r[4][l], 1.0 - (txx + tzz));
    store(&r[5][l], tyz - twx);
    store(&r[6][l], txz - twy);
    store(&r[7][l], tyz + twx);
    store(&r[8][l], 1.0 - (txx + tyy));
  }
}

void refine_rotations(RotationBatch& batch, int max_iterations) {
  const Mask sign = (Mask)Pair{-0.0, -0.0};
  Mask done[kLanes / 2] = {};  // all bits clear: not converged
  for (int it = 0; it < max_iterations; ++it) {
    double r[9][kLanes];
    batch_matrices(batch.q, r);
    int active = 0;
    for (int l = 0; l < kLanes; l += 2) {
      // omega = sum_c R.col(c) x B.col(c), denom = |sum_c R.col(c) . B.col(c)| + 1e-9.
      Pair ox = {}, oy = {}, oz = {}, dot = {};
      for (int c = 0; c < 3; ++c) {
        const Pair rx = load(&r[c][l]), ry = load(&r[3 + c][l]), rz = load(&r[6 + c][l]);
        const Pair bx = load(&batch.b[c][l]), by = load(&batch.b[3 + c][l]);
        const Pair bz = load(&batch.b[6 + c][l]);
        ox += ry * bz - rz * by;
        oy += rz * bx - rx * bz;
        oz += rx * by - ry * bx;
        dot += rx * bx + ry * by + rz * bz;
      }
      const Pair denom = (Pair)((Mask)dot & ~sign) + 1e-9;  // |dot| + 1e-9
      ox /= denom;
      oy /= denom;
      oz /= denom;
      const Mask converged = done[l / 2] | (ox * ox + oy * oy + oz * oz < 1e-26);
      done[l / 2] = converged;
      active += (converged[0] == 0) + (converged[1] == 0);
      // q <- normalise((1, omega / 2) q) where not converged.
      const Pair hx = 0.5 * ox, hy = 0.5 * oy, hz = 0.5 * oz;
      const Pair w = load(&batch.q[0][l]), x = load(&batch.q[1][l]);
      const Pair y = load(&batch.q[2][l]), z = load(&batch.q[3][l]);
      const Pair nw = w - (hx * x + hy * y + hz * z);
      const Pair nx = x + w * hx + (hy * z - hz * y);
      const Pair ny = y + w * hy + (hz * x - hx * z);
      const Pair nz = z + w * hz + (hx * y - hy * x);
      const Pair inv = 1.0 / sqrt_of(nw * nw + nx * nx + ny * ny + nz * nz);
      store(&batch.q[0][l], select(converged, w, nw * inv));
      store(&batch.q[1][l], select(converged, x, nx * inv));
      store(&batch.q[2][l], select(converged, y, ny * inv));
      store(&batch.q[3][l], select(converged, z, nz * inv));
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
    double max_change2 = 0;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel) \
    reduction(max : max_change2)
    for (int f = 0; f < nf; ++f) {
      const Eigen::Vector3d n0 = N0.row(f).transpose();
      const Eigen::Vector3d sum =
          (matrices[F(f, 0)] + matrices[F(f, 1)] + matrices[F(f, 2)]) * n0;
      const double len = sum.norm();
      if (len < 1e-12) continue;  // opposite rotations cancel: keep the previous normal
      const Eigen::Vector3d next = sum / len;
      // The largest squared change, one square root per sweep: sqrt is monotone, so this is
      // the largest change bit for bit.
      max_change2 = std::max(max_change2, (next - N.row(f).transpose()).squaredNorm());
      N.row(f) = next.transpose();
    }
    ++sweeps;
    warm = true;
    if (std::sqrt(max_change2) < tolerance) break;
  }
  return sweeps;
}

}  // namespace meshdeform::core
