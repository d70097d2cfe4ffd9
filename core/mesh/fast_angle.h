#pragma once
/// @file fast_angle.h
/// A batched atan2 for angles: the corner and dihedral angles of a 187k-vertex mesh are about
/// 1.7 million atan2 per evaluation, which a server session pays after every move.

#include <cstddef>

namespace meshdeform::core {

/// out[i] = atan2(y[i], x[i]) for y[i] >= 0 (an angle in [0, pi]), within 2 ulp of std::atan2
/// (Cephes' atan rational approximation after reducing the ratio to [0, 0.66]); atan2(0, x) is
/// 0 for x >= 0 (also -0) and pi for x < 0. Branch-free, so the compiler vectorises it: about
/// 4x std::atan2's throughput on x86-64 with SSE2. Non-finite input gives an unspecified value.
/// `out` may alias `y` or `x`.
void atan2_nonnegative(const double* y, const double* x, double* out, std::ptrdiff_t n);

}  // namespace meshdeform::core
