#include "core/mesh/fast_angle.h"

#include <cmath>

// Built with -fno-trapping-math (core/CMakeLists.txt): the selects below may then evaluate both
// sides, which is what lets GCC vectorise the loop; no floating-point exception is relied on.

namespace meshdeform::core {
namespace {

// Cephes atan (atan.c, S. L. Moshier): atan(t) = t + t z P(z) / Q(z), z = t^2, for
// |t| <= 0.66; relative error 1.8e-16 there.
constexpr double kP0 = -8.750608600031904122785e-1;
constexpr double kP1 = -1.615753718733365076637e1;
constexpr double kP2 = -7.500855792314704667340e1;
constexpr double kP3 = -1.228866684490136173410e2;
constexpr double kP4 = -6.485021904942025371773e1;
constexpr double kQ0 = 2.485846490142306297962e1;
constexpr double kQ1 = 1.650270098316988542046e2;
constexpr double kQ2 = 4.328810604912902668951e2;
constexpr double kQ3 = 4.853903996359136964868e2;
constexpr double kQ4 = 1.945506571482613964425e2;
// pi/2 = kPiOver2 + kPiOver2Low to twice double precision.
constexpr double kPiOver2 = 1.57079632679489655800e+00;
constexpr double kPiOver2Low = 6.123233995736765886130e-17;
constexpr double kPiOver4 = 0.5 * kPiOver2;
constexpr double kPi = 2.0 * kPiOver2;

inline double angle(double y, double x) {
  const double ax = std::fabs(x);
  // Ratio lo / hi in [0, 1]; above 0.66, atan(t) = pi/4 + atan((t - 1) / (t + 1)).
  const bool swap = y > ax;
  const double lo = swap ? ax : y;
  const double hi = swap ? y : ax;
  const bool reduce = lo > 0.66 * hi;
  const double num = reduce ? lo - hi : lo;
  const double den = reduce ? lo + hi : (hi == 0 ? 1.0 : hi);  // atan2(0, 0) = 0
  const double t = num / den;
  const double z = t * t;
  const double p = (((kP0 * z + kP1) * z + kP2) * z + kP3) * z + kP4;
  const double q = ((((z + kQ0) * z + kQ1) * z + kQ2) * z + kQ3) * z + kQ4;
  double r = (reduce ? kPiOver4 + 0.5 * kPiOver2Low : 0.0) + (t * (z * p / q) + t);
  r = swap ? (kPiOver2 - r) + kPiOver2Low : r;  // atan(1 / u) = pi/2 - atan(u)
  return x < 0 ? (kPi - r) + 2.0 * kPiOver2Low : r;  // the second quadrant
}

}  // namespace

void atan2_nonnegative(const double* y, const double* x, double* out, std::ptrdiff_t n) {
  for (std::ptrdiff_t i = 0; i < n; ++i) out[i] = angle(y[i], x[i]);
}

}  // namespace meshdeform::core
