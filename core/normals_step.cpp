#include "core/normals_step.h"

#include <algorithm>
#include <cmath>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

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
/// (instruction-level parallelism; GCC does not vectorise these loops, -fopt-info-vec, so the
/// lanes go through SSE2 in pairs by hand, below).
constexpr int kLanes = 4;
struct RotationBatch {
  double b[9][kLanes];  // B(i, j) at b[3 i + j]
  double q[4][kLanes];  // w, x, y, z
  double r[9][kLanes];  // result R(i, j) at r[3 i + j]
};

#if defined(__SSE2__)
// Two lanes per SSE2 register (x86-64's baseline, so no dispatch): every operation is the scalar
// one in the same order (the baseline has no FMA to contract into), so each lane's result is the
// scalar loop's bit for bit, at half the instructions for the divisions and square roots that
// bound this loop.
static_assert(kLanes % 2 == 0, "lanes are processed in SSE2 pairs");

inline __m128d select(__m128d mask, __m128d if_set, __m128d if_clear) {
  return _mm_or_pd(_mm_and_pd(mask, if_set), _mm_andnot_pd(mask, if_clear));
}

inline void batch_matrices(const double (&q)[4][kLanes], double (&r)[9][kLanes]) {
  const __m128d one = _mm_set1_pd(1.0), two = _mm_set1_pd(2.0);
  for (int l = 0; l < kLanes; l += 2) {
    // Eigen's Quaternion::toRotationMatrix, term for term.
    const __m128d w = _mm_loadu_pd(&q[0][l]), x = _mm_loadu_pd(&q[1][l]);
    const __m128d y = _mm_loadu_pd(&q[2][l]), z = _mm_loadu_pd(&q[3][l]);
    const __m128d tx = _mm_mul_pd(two, x), ty = _mm_mul_pd(two, y), tz = _mm_mul_pd(two, z);
    const __m128d twx = _mm_mul_pd(tx, w), twy = _mm_mul_pd(ty, w), twz = _mm_mul_pd(tz, w);
    const __m128d txx = _mm_mul_pd(tx, x), txy = _mm_mul_pd(ty, x), txz = _mm_mul_pd(tz, x);
    const __m128d tyy = _mm_mul_pd(ty, y), tyz = _mm_mul_pd(tz, y), tzz = _mm_mul_pd(tz, z);
    _mm_storeu_pd(&r[0][l], _mm_sub_pd(one, _mm_add_pd(tyy, tzz)));
    _mm_storeu_pd(&r[1][l], _mm_sub_pd(txy, twz));
    _mm_storeu_pd(&r[2][l], _mm_add_pd(txz, twy));
    _mm_storeu_pd(&r[3][l], _mm_add_pd(txy, twz));
    _mm_storeu_pd(&r[4][l], _mm_sub_pd(one, _mm_add_pd(txx, tzz)));
    _mm_storeu_pd(&r[5][l], _mm_sub_pd(tyz, twx));
    _mm_storeu_pd(&r[6][l], _mm_sub_pd(txz, twy));
    _mm_storeu_pd(&r[7][l], _mm_add_pd(tyz, twx));
    _mm_storeu_pd(&r[8][l], _mm_sub_pd(one, _mm_add_pd(txx, tyy)));
  }
}

void refine_rotations(RotationBatch& batch, int max_iterations) {
  const __m128d zero = _mm_setzero_pd(), half = _mm_set1_pd(0.5), one = _mm_set1_pd(1.0);
  const __m128d sign = _mm_set1_pd(-0.0), eps = _mm_set1_pd(1e-9), tiny = _mm_set1_pd(1e-26);
  __m128d done[kLanes / 2];
  for (auto& d : done) d = zero;  // all bits clear: not converged
  for (int it = 0; it < max_iterations; ++it) {
    double r[9][kLanes];
    batch_matrices(batch.q, r);
    int active = 0;
    for (int l = 0; l < kLanes; l += 2) {
      // omega = sum_c R.col(c) x B.col(c), denom = |sum_c R.col(c) . B.col(c)| + 1e-9.
      __m128d ox = zero, oy = zero, oz = zero, dot = zero;
      for (int c = 0; c < 3; ++c) {
        const __m128d rx = _mm_loadu_pd(&r[c][l]), ry = _mm_loadu_pd(&r[3 + c][l]);
        const __m128d rz = _mm_loadu_pd(&r[6 + c][l]);
        const __m128d bx = _mm_loadu_pd(&batch.b[c][l]), by = _mm_loadu_pd(&batch.b[3 + c][l]);
        const __m128d bz = _mm_loadu_pd(&batch.b[6 + c][l]);
        ox = _mm_add_pd(ox, _mm_sub_pd(_mm_mul_pd(ry, bz), _mm_mul_pd(rz, by)));
        oy = _mm_add_pd(oy, _mm_sub_pd(_mm_mul_pd(rz, bx), _mm_mul_pd(rx, bz)));
        oz = _mm_add_pd(oz, _mm_sub_pd(_mm_mul_pd(rx, by), _mm_mul_pd(ry, bx)));
        dot = _mm_add_pd(dot, _mm_add_pd(_mm_add_pd(_mm_mul_pd(rx, bx), _mm_mul_pd(ry, by)),
                                         _mm_mul_pd(rz, bz)));
      }
      const __m128d denom = _mm_add_pd(_mm_andnot_pd(sign, dot), eps);
      ox = _mm_div_pd(ox, denom);
      oy = _mm_div_pd(oy, denom);
      oz = _mm_div_pd(oz, denom);
      const __m128d norm2 =
          _mm_add_pd(_mm_add_pd(_mm_mul_pd(ox, ox), _mm_mul_pd(oy, oy)), _mm_mul_pd(oz, oz));
      const __m128d converged = _mm_or_pd(done[l / 2], _mm_cmplt_pd(norm2, tiny));
      done[l / 2] = converged;
      const int mask = _mm_movemask_pd(converged);  // bit k: lane l + k has converged
      active += 2 - (mask & 1) - (mask >> 1);
      // q <- normalise((1, omega / 2) q) where not converged.
      const __m128d hx = _mm_mul_pd(half, ox), hy = _mm_mul_pd(half, oy);
      const __m128d hz = _mm_mul_pd(half, oz);
      const __m128d w = _mm_loadu_pd(&batch.q[0][l]), x = _mm_loadu_pd(&batch.q[1][l]);
      const __m128d y = _mm_loadu_pd(&batch.q[2][l]), z = _mm_loadu_pd(&batch.q[3][l]);
      const __m128d nw = _mm_sub_pd(
          w, _mm_add_pd(_mm_add_pd(_mm_mul_pd(hx, x), _mm_mul_pd(hy, y)), _mm_mul_pd(hz, z)));
      const __m128d nx = _mm_add_pd(_mm_add_pd(x, _mm_mul_pd(w, hx)),
                                    _mm_sub_pd(_mm_mul_pd(hy, z), _mm_mul_pd(hz, y)));
      const __m128d ny = _mm_add_pd(_mm_add_pd(y, _mm_mul_pd(w, hy)),
                                    _mm_sub_pd(_mm_mul_pd(hz, x), _mm_mul_pd(hx, z)));
      const __m128d nz = _mm_add_pd(_mm_add_pd(z, _mm_mul_pd(w, hz)),
                                    _mm_sub_pd(_mm_mul_pd(hx, y), _mm_mul_pd(hy, x)));
      const __m128d length2 = _mm_add_pd(
          _mm_add_pd(_mm_add_pd(_mm_mul_pd(nw, nw), _mm_mul_pd(nx, nx)), _mm_mul_pd(ny, ny)),
          _mm_mul_pd(nz, nz));
      const __m128d inv = _mm_div_pd(one, _mm_sqrt_pd(length2));
      _mm_storeu_pd(&batch.q[0][l], select(converged, w, _mm_mul_pd(nw, inv)));
      _mm_storeu_pd(&batch.q[1][l], select(converged, x, _mm_mul_pd(nx, inv)));
      _mm_storeu_pd(&batch.q[2][l], select(converged, y, _mm_mul_pd(ny, inv)));
      _mm_storeu_pd(&batch.q[3][l], select(converged, z, _mm_mul_pd(nz, inv)));
    }
    if (active == 0) break;
  }
  batch_matrices(batch.q, batch.r);
}

#else  // no SSE2 (not x86-64): the same lanes one by one, the same results

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

#endif  // __SSE2__

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
