#include "core/curve2d.h"

#include <Eigen/OrderingMethods>
#include <Eigen/SparseCholesky>
#include <Eigen/SparseCore>
#include <Eigen/SparseQR>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <complex>
#include <cstdio>
#include <numbers>
#include <string>
#include <utility>
#include <vector>

namespace meshdeform::core {
namespace {

using SpMat = Eigen::SparseMatrix<double>;
using Triplet = Eigen::Triplet<double>;
using Ldlt = Eigen::SimplicialLDLT<SpMat>;
// Natural ordering keeps a polyline's banded structure (points are numbered along the curve), so
// the QR factor has no fill beyond the band (and one border for a closed curve).
using SparseQr = Eigen::SparseQR<SpMat, Eigen::NaturalOrdering<int>>;
using Clock = std::chrono::steady_clock;

/// Segments shorter than this fraction of the bounding-box diagonal count as zero-length.
constexpr double kZeroLengthRelative = 1e-12;
constexpr int kMaxKochLevel = 10;

std::string fmt_point(double x, double y) {
  char buffer[96];
  std::snprintf(buffer, sizeof(buffer), "(%.17g, %.17g)", x, y);
  return buffer;
}

std::string fmt_num(double value, const char* format) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

double bbox_diagonal(const Points2& P) {
  if (P.rows() == 0) return 0;
  return (P.colwise().maxCoeff() - P.colwise().minCoeff()).norm();
}

Eigen::Index segment_count(const Polyline& curve) {
  const Eigen::Index n = curve.P.rows();
  return curve.closed ? n : n - 1;
}

Eigen::Index joint_count(const Polyline& curve) {
  const Eigen::Index n = curve.P.rows();
  return curve.closed ? n : n - 2;
}

/// The centre point of joint k and its two neighbours (cyclic for a closed curve).
struct Joint {
  Eigen::Index prev, mid, next;
};

Joint joint(const Polyline& curve, Eigen::Index k) {
  const Eigen::Index n = curve.P.rows();
  if (!curve.closed) return {k, k + 1, k + 2};
  return {(k + n - 1) % n, k, (k + 1) % n};
}

/// Signed angle from a to b, in (-pi, pi].
double signed_angle(const Eigen::Vector2d& a, const Eigen::Vector2d& b) {
  const double angle = std::atan2(a.x() * b.y() - a.y() * b.x(), a.dot(b));
  return angle <= -std::numbers::pi ? std::numbers::pi : angle;
}

double wrap_angle(double angle) {
  angle = std::remainder(angle, 2 * std::numbers::pi);  // [-pi, pi]
  return angle <= -std::numbers::pi ? angle + 2 * std::numbers::pi : angle;
}

Status validate_options(const CurveOptions& options) {
  if (!std::isfinite(options.lambda) || options.lambda <= 0) {
    return Error(ErrorCode::InvalidArgument,
                 "lambda must be positive and finite, got " + fmt_num(options.lambda, "%g"));
  }
  if (options.max_iterations < 0) {
    return Error(ErrorCode::InvalidArgument,
                 "max_iterations must be >= 0, got " + std::to_string(options.max_iterations));
  }
  if (!(options.tolerance >= 0)) {
    return Error(ErrorCode::InvalidArgument,
                 "tolerance must be >= 0, got " + fmt_num(options.tolerance, "%g"));
  }
  return Status::success();
}

/// Indices in range, distinct, at least two, not all at one rest position (otherwise a
/// translation/scale/rotation about that position costs nothing: the system is singular).
Status validate_constrained(const Polyline& rest, const Eigen::VectorXi& constrained) {
  const Eigen::Index n = rest.P.rows();
  std::vector<Eigen::Index> first_entry(static_cast<size_t>(n), -1);
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    const int index = constrained(j);
    if (index < 0 || index >= n) {
      return Error(ErrorCode::InvalidArgument,
                   "constrained index " + std::to_string(index) + " (entry " + std::to_string(j) +
                       ") is out of range (#P=" + std::to_string(n) + ")");
    }
    Eigen::Index& seen = first_entry[static_cast<size_t>(index)];
    if (seen >= 0) {
      return Error(ErrorCode::InvalidArgument, "constrained index " + std::to_string(index) +
                                                   " is repeated (entries " + std::to_string(seen) +
                                                   " and " + std::to_string(j) + ")");
    }
    seen = j;
  }
  if (constrained.size() < 2) {
    return Error(ErrorCode::InvalidArgument,
                 "curve editing needs at least 2 constrained points (the scale-aware energy is "
                 "invariant to translation, rotation and scale), got " +
                     std::to_string(constrained.size()));
  }
  const double eps = kZeroLengthRelative * bbox_diagonal(rest.P);
  const Eigen::RowVector2d first = rest.P.row(constrained(0));
  bool has_distinct = false;
  for (Eigen::Index j = 1; j < constrained.size() && !has_distinct; ++j) {
    has_distinct = (rest.P.row(constrained(j)) - first).norm() > eps;
  }
  if (!has_distinct) {
    return Error(ErrorCode::InvalidArgument,
                 "the " + std::to_string(constrained.size()) +
                     " constrained points all lie at the rest position " +
                     fmt_point(first.x(), first.y()) + "; two distinct positions are needed");
  }
  return Status::success();
}

Status validate_targets(const Points2& targets, Eigen::Index constrained_count) {
  if (targets.rows() != constrained_count) {
    return Error(ErrorCode::InvalidArgument,
                 "targets has " + std::to_string(targets.rows()) + " rows, expected " +
                     std::to_string(constrained_count) + " (one per constrained point)");
  }
  for (Eigen::Index j = 0; j < targets.rows(); ++j) {
    if (!targets.row(j).allFinite()) {
      return Error(ErrorCode::InvalidArgument, "target " + std::to_string(j) + " is not finite " +
                                                   fmt_point(targets(j, 0), targets(j, 1)));
    }
  }
  return Status::success();
}

/// lambda S^T S (one coordinate per point), the constraint term of a normal matrix.
void add_constraint_triplets(const Eigen::VectorXi& constrained, double lambda,
                             std::vector<Triplet>& triplets) {
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    triplets.emplace_back(constrained(j), constrained(j), lambda);
  }
}

/// Rows sqrt(lambda) S below `first_row`, for `dims` interleaved coordinates per point.
void add_constraint_rows(const Eigen::VectorXi& constrained, double lambda, int dims,
                         Eigen::Index first_row, std::vector<Triplet>& triplets) {
  const double w = std::sqrt(lambda);
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    for (int d = 0; d < dims; ++d) {
      triplets.emplace_back(static_cast<int>(first_row + dims * j + d), dims * constrained(j) + d,
                            w);
    }
  }
}

/// QR of the stacked least-squares matrix K = [energy rows; sqrt(lambda) S]. The curve systems
/// are bi-Laplacian-like: the normal matrix K^T K has a condition number growing like #P^4 (about
/// 1e15 for a 4,097-point Koch curve), and merely forming it loses the digits that the
/// similarity-exactness guarantee needs (measured: 1e-6 error at 4,097 points with LDLT of
/// K^T K, 1e-12 with QR of K). QR works with cond(K) = sqrt(cond(K^T K)).
Result<std::unique_ptr<SparseQr>> factor_least_squares(SpMat K, const char* what) {
  K.makeCompressed();
  auto qr = std::make_unique<SparseQr>();
  qr->compute(K);
  if (qr->info() != Eigen::Success || qr->rank() < K.cols()) {
    return Error(ErrorCode::NumericalFailure,
                 std::string("QR of the ") + what + " failed (" + std::to_string(K.cols()) +
                     " unknowns, numerical rank " + std::to_string(qr->rank()) + ")");
  }
  return qr;
}

Result<std::unique_ptr<Ldlt>> factor(const SpMat& A, const char* what) {
  auto ldlt = std::make_unique<Ldlt>(A);
  if (ldlt->info() != Eigen::Success) {
    return Error(ErrorCode::NumericalFailure, std::string("LDLT of the ") + what + " failed (" +
                                                  std::to_string(A.rows()) + " unknowns)");
  }
  return ldlt;
}

/// Solves A x = b with one step of iterative refinement (cheap; tightens the ARAP global step).
Eigen::MatrixXd solve_refined(const Ldlt& ldlt, const SpMat& A, const Eigen::MatrixXd& b) {
  Eigen::MatrixXd x = ldlt.solve(b);
  const Eigen::MatrixXd r = b - A * x;
  x += ldlt.solve(r);
  return x;
}

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

// ---------------------------------------------------------------------------------------------
// Laplacian editing.

/// Uniform polyline Laplacian: rows at interior points (open) or every point (closed).
SpMat polyline_laplacian(const Polyline& curve) {
  const Eigen::Index rows = joint_count(curve);
  std::vector<Triplet> triplets;
  triplets.reserve(static_cast<size_t>(3 * rows));
  for (Eigen::Index k = 0; k < rows; ++k) {
    const Joint jt = joint(curve, k);
    triplets.emplace_back(k, jt.mid, 1.0);
    triplets.emplace_back(k, jt.prev, -0.5);
    triplets.emplace_back(k, jt.next, -0.5);
  }
  SpMat L(rows, curve.P.rows());
  L.setFromTriplets(triplets.begin(), triplets.end());
  return L;
}

Points2 stack_targets(const Eigen::VectorXi& constrained, const Points2& targets, Eigen::Index n,
                      double lambda) {
  Points2 b = Points2::Zero(n, 2);
  for (Eigen::Index j = 0; j < constrained.size(); ++j)
    b.row(constrained(j)) = lambda * targets.row(j);
  return b;
}

double constraint_energy(const Points2& P, const Eigen::VectorXi& constrained,
                         const Points2& targets, double lambda) {
  double e = 0;
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    e += (P.row(constrained(j)) - targets.row(j)).squaredNorm();
  }
  return lambda * e;
}

Result<CurveResult> deform_laplacian(const Polyline& rest, const Eigen::VectorXi& constrained,
                                     const Points2& targets, const CurveOptions& options) {
  const auto start = Clock::now();
  const Eigen::Index n = rest.P.rows();
  const SpMat L = polyline_laplacian(rest);
  // K = [L; sqrt(lambda) S], rhs = [L P0; sqrt(lambda) T]; x and y share the factor.
  std::vector<Triplet> triplets;
  triplets.reserve(static_cast<size_t>(L.nonZeros() + constrained.size()));
  for (int c = 0; c < L.outerSize(); ++c) {
    for (SpMat::InnerIterator it(L, c); it; ++it) triplets.emplace_back(it.row(), c, it.value());
  }
  add_constraint_rows(constrained, options.lambda, 1, L.rows(), triplets);
  SpMat K(L.rows() + constrained.size(), n);
  K.setFromTriplets(triplets.begin(), triplets.end());
  MD_ASSIGN_OR_RETURN(auto qr, factor_least_squares(std::move(K), "Laplacian curve system"));
  Eigen::MatrixXd rhs(L.rows() + constrained.size(), 2);
  rhs.topRows(L.rows()) = L * rest.P;
  rhs.bottomRows(constrained.size()) = std::sqrt(options.lambda) * targets;
  CurveResult result;
  result.P = qr->solve(rhs);
  const double energy = (L * (result.P - rest.P)).squaredNorm() +
                        constraint_energy(result.P, constrained, targets, options.lambda);
  result.energy_history.push_back(energy);
  result.seconds = seconds_since(start);
  return result;
}

// ---------------------------------------------------------------------------------------------
// ARAP.

/// The undirected segments (i, i+1) of a polyline, cyclic when closed.
std::vector<std::pair<Eigen::Index, Eigen::Index>> segments(const Polyline& curve) {
  const Eigen::Index n = curve.P.rows();
  std::vector<std::pair<Eigen::Index, Eigen::Index>> list;
  list.reserve(static_cast<size_t>(segment_count(curve)));
  for (Eigen::Index i = 0; i < segment_count(curve); ++i) list.emplace_back(i, (i + 1) % n);
  return list;
}

/// Local step: the rotation angle of each point that best maps its rest segments onto the
/// current ones (2D polar decomposition: atan2 of the summed cross and dot products).
Eigen::VectorXd fit_rotations(const Polyline& rest, const Points2& P,
                              const std::vector<std::pair<Eigen::Index, Eigen::Index>>& segs) {
  const Eigen::Index n = rest.P.rows();
  Eigen::VectorXd cross = Eigen::VectorXd::Zero(n), dot = Eigen::VectorXd::Zero(n);
  for (const auto& [a, b] : segs) {
    const Eigen::Vector2d e0 = (rest.P.row(b) - rest.P.row(a)).transpose();
    const Eigen::Vector2d e = (P.row(b) - P.row(a)).transpose();
    const double c = e0.x() * e.y() - e0.y() * e.x(), d = e0.dot(e);
    // The segment enters both end points' cells (as p_a - p_b and p_b - p_a: same products).
    cross(a) += c;
    dot(a) += d;
    cross(b) += c;
    dot(b) += d;
  }
  Eigen::VectorXd angle(n);
  for (Eigen::Index i = 0; i < n; ++i) angle(i) = std::atan2(cross(i), dot(i));
  return angle;
}

Eigen::Vector2d rotate(double angle, const Eigen::Vector2d& v) {
  const double c = std::cos(angle), s = std::sin(angle);
  return {c * v.x() - s * v.y(), s * v.x() + c * v.y()};
}

double arap_energy(const Polyline& rest, const Points2& P, const Eigen::VectorXd& angle,
                   const std::vector<std::pair<Eigen::Index, Eigen::Index>>& segs,
                   const Eigen::VectorXi& constrained, const Points2& targets, double lambda) {
  double e = 0;
  for (const auto& [a, b] : segs) {
    const Eigen::Vector2d e0 = (rest.P.row(b) - rest.P.row(a)).transpose();
    const Eigen::Vector2d d = (P.row(b) - P.row(a)).transpose();
    e += (d - rotate(angle(a), e0)).squaredNorm() + (d - rotate(angle(b), e0)).squaredNorm();
  }
  return e + constraint_energy(P, constrained, targets, lambda);
}

Result<CurveResult> deform_arap(const Polyline& rest, const Eigen::VectorXi& constrained,
                                const Points2& targets, const CurveOptions& options) {
  const auto start = Clock::now();
  const Eigen::Index n = rest.P.rows();
  const auto segs = segments(rest);
  // E = sum_segments ||d - R_a e0||^2 + ||d - R_b e0||^2 + lambda sum_C ||p - p*||^2
  //   = 2 sum_segments ||d - (R_a + R_b)/2 e0||^2 + lambda ... + const(R), so the global step
  // solves (2 D^T D + lambda S^T S) P = 2 D^T B + lambda S^T T with a constant matrix. That is a
  // path-graph Laplacian (condition number ~ #P^2, not ^4), so LDLT of it loses nothing material.
  std::vector<Triplet> triplets;
  for (const auto& [a, b] : segs) {
    triplets.emplace_back(a, a, 2.0);
    triplets.emplace_back(b, b, 2.0);
    triplets.emplace_back(a, b, -2.0);
    triplets.emplace_back(b, a, -2.0);
  }
  add_constraint_triplets(constrained, options.lambda, triplets);
  SpMat A(n, n);
  A.setFromTriplets(triplets.begin(), triplets.end());
  MD_ASSIGN_OR_RETURN(auto ldlt, factor(A, "ARAP curve system"));
  const Points2 b_targets = stack_targets(constrained, targets, n, options.lambda);

  // Energies this far below the curve's own scale (sum of squared rest segment lengths) are
  // rounding noise, whose relative change means nothing: treat them as converged.
  double rest_scale = 0;
  for (const auto& [a, c] : segs) rest_scale += (rest.P.row(c) - rest.P.row(a)).squaredNorm();
  const double energy_floor = 1e-24 * rest_scale;

  CurveResult result;
  result.P = rest.P;
  Eigen::VectorXd angle = fit_rotations(rest, result.P, segs);
  double energy = arap_energy(rest, result.P, angle, segs, constrained, targets, options.lambda);
  result.energy_history.push_back(energy);
  result.converged = false;
  for (int it = 1; it <= options.max_iterations; ++it) {
    Points2 b = b_targets;
    for (const auto& [a, c] : segs) {
      const Eigen::Vector2d e0 = (rest.P.row(c) - rest.P.row(a)).transpose();
      // Gradient term 2 D^T B with B = (R_a + R_c)/2 e0 for the segment d = p_c - p_a.
      const Eigen::Vector2d rhs = rotate(angle(a), e0) + rotate(angle(c), e0);
      b.row(c) += rhs.transpose();
      b.row(a) -= rhs.transpose();
    }
    result.P = solve_refined(*ldlt, A, b);
    angle = fit_rotations(rest, result.P, segs);
    const double previous = energy;
    energy = arap_energy(rest, result.P, angle, segs, constrained, targets, options.lambda);
    result.energy_history.push_back(energy);
    result.iterations = it;
    if (energy <= energy_floor || std::abs(previous - energy) <= options.tolerance * previous) {
      result.converged = true;
      break;
    }
  }
  result.seconds = seconds_since(start);
  return result;
}

}  // namespace

const char* curve_method_name(CurveMethod method) {
  switch (method) {
    case CurveMethod::Laplacian:
      return "laplacian";
    case CurveMethod::Arap:
      return "arap";
    case CurveMethod::ScaleAware:
      return "scale_aware";
  }
  return "unknown";
}

Status validate_polyline(const Polyline& curve) {
  const Eigen::Index n = curve.P.rows();
  if (n < 3) {
    return Error(ErrorCode::InvalidArgument,
                 "a polyline needs at least 3 points, got " + std::to_string(n));
  }
  for (Eigen::Index i = 0; i < n; ++i) {
    if (!curve.P.row(i).allFinite()) {
      return Error(ErrorCode::InvalidArgument, "point " + std::to_string(i) + " is not finite " +
                                                   fmt_point(curve.P(i, 0), curve.P(i, 1)));
    }
  }
  const double eps = kZeroLengthRelative * bbox_diagonal(curve.P);
  for (Eigen::Index i = 0; i < segment_count(curve); ++i) {
    const Eigen::Index j = (i + 1) % n;
    if ((curve.P.row(j) - curve.P.row(i)).norm() <= eps) {
      return Error(ErrorCode::InvalidArgument, "segment " + std::to_string(i) + " (points " +
                                                   std::to_string(i) + " -> " + std::to_string(j) +
                                                   ") has zero length: both at " +
                                                   fmt_point(curve.P(i, 0), curve.P(i, 1)));
    }
  }
  return Status::success();
}

Result<CurveMeasures> curve_measures(const Polyline& curve) {
  MD_RETURN_IF_ERROR(validate_polyline(curve));
  const Eigen::Index joints = joint_count(curve);
  CurveMeasures m;
  m.theta.resize(joints);
  m.length_ratio.resize(joints);
  for (Eigen::Index k = 0; k < joints; ++k) {
    const Joint jt = joint(curve, k);
    const Eigen::Vector2d e_prev = (curve.P.row(jt.mid) - curve.P.row(jt.prev)).transpose();
    const Eigen::Vector2d e_next = (curve.P.row(jt.next) - curve.P.row(jt.mid)).transpose();
    m.theta(k) = signed_angle(e_prev, e_next);
    m.length_ratio(k) = e_next.norm() / e_prev.norm();
  }
  return m;
}

Result<CurveErrors> curve_errors(const Polyline& rest, const Points2& deformed) {
  if (deformed.rows() != rest.P.rows()) {
    return Error(ErrorCode::InvalidArgument,
                 "deformed curve has " + std::to_string(deformed.rows()) +
                     " points, the rest curve " + std::to_string(rest.P.rows()));
  }
  MD_ASSIGN_OR_RETURN(const CurveMeasures m0, curve_measures(rest));
  MD_ASSIGN_OR_RETURN(const CurveMeasures m1, curve_measures(Polyline{deformed, rest.closed}));
  CurveErrors errors;
  const Eigen::Index joints = m0.theta.size();
  if (joints == 0) return errors;
  double theta_sum = 0, scale_sum = 0;
  for (Eigen::Index k = 0; k < joints; ++k) {
    const double dtheta = wrap_angle(m1.theta(k) - m0.theta(k));
    const double dlog = std::log(m1.length_ratio(k) / m0.length_ratio(k));
    theta_sum += dtheta * dtheta;
    scale_sum += dlog * dlog;
  }
  errors.e_theta = std::sqrt(theta_sum / static_cast<double>(joints));
  errors.scale_log_rms = std::sqrt(scale_sum / static_cast<double>(joints));
  return errors;
}

// ---------------------------------------------------------------------------------------------
// Scale-aware.

struct ScaleAwareCurveSolver::Impl {
  Eigen::VectorXi constrained;
  Eigen::Index point_count = 0;
  double lambda = 0;
  Eigen::Index equation_rows = 0;  // 2 per joint, before the constraint rows
  std::unique_ptr<SparseQr> qr;    // of [G; sqrt(lambda) S], interleaved (x0, y0, x1, y1, ...)
};

ScaleAwareCurveSolver::ScaleAwareCurveSolver(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ScaleAwareCurveSolver::ScaleAwareCurveSolver(ScaleAwareCurveSolver&&) noexcept = default;
ScaleAwareCurveSolver& ScaleAwareCurveSolver::operator=(ScaleAwareCurveSolver&&) noexcept = default;
ScaleAwareCurveSolver::~ScaleAwareCurveSolver() = default;

Result<ScaleAwareCurveSolver> ScaleAwareCurveSolver::create(const Polyline& rest,
                                                            const Eigen::VectorXi& constrained,
                                                            const CurveOptions& options) {
  MD_RETURN_IF_ERROR(validate_polyline(rest));
  MD_RETURN_IF_ERROR(validate_constrained(rest, constrained));
  MD_RETURN_IF_ERROR(validate_options(options));
  const Eigen::Index n = rest.P.rows();
  const Eigen::Index joints = joint_count(rest);
  // Row pair k: (p_next - p_mid) - M (p_mid - p_prev) with M = l R(theta) = [a -b; b a], where
  // a + ib = e_next / e_prev as complex numbers (the rest turning angle and length ratio at once).
  std::vector<Triplet> triplets;
  triplets.reserve(static_cast<size_t>(12 * joints));
  for (Eigen::Index k = 0; k < joints; ++k) {
    const Joint jt = joint(rest, k);
    const std::complex<double> e_prev(rest.P(jt.mid, 0) - rest.P(jt.prev, 0),
                                      rest.P(jt.mid, 1) - rest.P(jt.prev, 1));
    const std::complex<double> e_next(rest.P(jt.next, 0) - rest.P(jt.mid, 0),
                                      rest.P(jt.next, 1) - rest.P(jt.mid, 1));
    const std::complex<double> m = e_next / e_prev;
    const double a = m.real(), b = m.imag();
    const auto rx = static_cast<int>(2 * k), ry = rx + 1;
    const auto nx = static_cast<int>(2 * jt.next), cx = static_cast<int>(2 * jt.mid),
               px = static_cast<int>(2 * jt.prev);
    // + p_next
    triplets.emplace_back(rx, nx, 1.0);
    triplets.emplace_back(ry, nx + 1, 1.0);
    // - (I + M) p_mid
    triplets.emplace_back(rx, cx, -(1.0 + a));
    triplets.emplace_back(rx, cx + 1, b);
    triplets.emplace_back(ry, cx, -b);
    triplets.emplace_back(ry, cx + 1, -(1.0 + a));
    // + M p_prev
    triplets.emplace_back(rx, px, a);
    triplets.emplace_back(rx, px + 1, -b);
    triplets.emplace_back(ry, px, b);
    triplets.emplace_back(ry, px + 1, a);
  }
  add_constraint_rows(constrained, options.lambda, 2, 2 * joints, triplets);
  SpMat K(2 * joints + 2 * constrained.size(), 2 * n);
  K.setFromTriplets(triplets.begin(), triplets.end());

  auto impl = std::make_unique<Impl>();
  impl->constrained = constrained;
  impl->point_count = n;
  impl->lambda = options.lambda;
  impl->equation_rows = 2 * joints;
  MD_ASSIGN_OR_RETURN(impl->qr, factor_least_squares(std::move(K), "scale-aware curve system"));
  return ScaleAwareCurveSolver(std::move(impl));
}

Result<Points2> ScaleAwareCurveSolver::solve(const Points2& targets) const {
  MD_RETURN_IF_ERROR(validate_targets(targets, impl_->constrained.size()));
  const Eigen::Index c = impl_->constrained.size();
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(impl_->equation_rows + 2 * c);
  const double w = std::sqrt(impl_->lambda);
  for (Eigen::Index j = 0; j < c; ++j) {
    rhs(impl_->equation_rows + 2 * j) = w * targets(j, 0);
    rhs(impl_->equation_rows + 2 * j + 1) = w * targets(j, 1);
  }
  const Eigen::VectorXd x = impl_->qr->solve(rhs);
  Points2 P(impl_->point_count, 2);
  for (Eigen::Index i = 0; i < impl_->point_count; ++i) P.row(i) << x(2 * i), x(2 * i + 1);
  return P;
}

const Eigen::VectorXi& ScaleAwareCurveSolver::constrained() const { return impl_->constrained; }

Result<CurveResult> deform_curve(CurveMethod method, const Polyline& rest,
                                 const Eigen::VectorXi& constrained, const Points2& targets,
                                 const CurveOptions& options) {
  MD_RETURN_IF_ERROR(validate_polyline(rest));
  MD_RETURN_IF_ERROR(validate_constrained(rest, constrained));
  MD_RETURN_IF_ERROR(validate_options(options));
  MD_RETURN_IF_ERROR(validate_targets(targets, constrained.size()));
  switch (method) {
    case CurveMethod::Laplacian:
      return deform_laplacian(rest, constrained, targets, options);
    case CurveMethod::Arap:
      return deform_arap(rest, constrained, targets, options);
    case CurveMethod::ScaleAware: {
      const auto start = Clock::now();
      MD_ASSIGN_OR_RETURN(const ScaleAwareCurveSolver solver,
                          ScaleAwareCurveSolver::create(rest, constrained, options));
      CurveResult result;
      MD_ASSIGN_OR_RETURN(result.P, solver.solve(targets));
      result.seconds = seconds_since(start);
      // Report the Eq. 12-style energy for symmetry with the other methods.
      MD_ASSIGN_OR_RETURN(const CurveMeasures m, curve_measures(rest));
      double energy = constraint_energy(result.P, constrained, targets, options.lambda);
      for (Eigen::Index k = 0; k < m.theta.size(); ++k) {
        const Joint jt = joint(rest, k);
        const Eigen::Vector2d e_prev = (result.P.row(jt.mid) - result.P.row(jt.prev)).transpose();
        const Eigen::Vector2d e_next = (result.P.row(jt.next) - result.P.row(jt.mid)).transpose();
        energy += (e_next - m.length_ratio(k) * rotate(m.theta(k), e_prev)).squaredNorm();
      }
      result.energy_history.push_back(energy);
      return result;
    }
  }
  return Error(ErrorCode::InvalidArgument,
               "unknown curve method " + std::to_string(static_cast<int>(method)));
}

// ---------------------------------------------------------------------------------------------
// Koch curve and the Fig. 9 edit.

Result<Polyline> make_koch_curve(int level) {
  if (level < 0 || level > kMaxKochLevel) {
    return Error(ErrorCode::InvalidArgument, "Koch level must be in [0, " +
                                                 std::to_string(kMaxKochLevel) + "], got " +
                                                 std::to_string(level));
  }
  std::vector<Eigen::Vector2d> points = {{0.0, 0.0}, {1.0, 0.0}};
  const double c = 0.5, s = std::sqrt(3.0) / 2;  // rotation by +60 degrees: bumps point up
  for (int l = 0; l < level; ++l) {
    std::vector<Eigen::Vector2d> next;
    next.reserve(4 * points.size());
    for (size_t i = 0; i + 1 < points.size(); ++i) {
      const Eigen::Vector2d a = points[i], d = (points[i + 1] - points[i]) / 3.0;
      const Eigen::Vector2d apex =
          a + d + Eigen::Vector2d(c * d.x() - s * d.y(), s * d.x() + c * d.y());
      next.push_back(a);
      next.push_back(a + d);
      next.push_back(apex);
      next.push_back(a + 2.0 * d);
    }
    next.push_back(points.back());
    points = std::move(next);
  }
  Polyline curve;
  curve.closed = false;
  curve.P.resize(static_cast<Eigen::Index>(points.size()), 2);
  for (size_t i = 0; i < points.size(); ++i) {
    curve.P.row(static_cast<Eigen::Index>(i)) = points[i].transpose();
  }
  return curve;
}

Result<CurveEdit> make_koch_edit(int level, double pull) {
  if (level < 1 || level > kMaxKochLevel) {
    return Error(ErrorCode::InvalidArgument,
                 "the Koch edit needs a level in [1, " + std::to_string(kMaxKochLevel) +
                     "] (level 0 is one segment, with no middle point), got " +
                     std::to_string(level));
  }
  if (!std::isfinite(pull)) {
    return Error(ErrorCode::InvalidArgument, "pull must be finite, got " + fmt_num(pull, "%g"));
  }
  CurveEdit edit;
  MD_ASSIGN_OR_RETURN(edit.rest, make_koch_curve(level));
  const int last = static_cast<int>(edit.rest.P.rows()) - 1;
  edit.handle = last / 2;
  edit.constrained.resize(3);
  edit.constrained << 0, edit.handle, last;
  edit.targets.resize(3, 2);
  for (int j = 0; j < 3; ++j) edit.targets.row(j) = edit.rest.P.row(edit.constrained(j));
  edit.targets(1, 1) += pull;
  return edit;
}

// ---------------------------------------------------------------------------------------------
// SVG figure.

namespace {

std::string xml_escape(const std::string& text) {
  std::string out;
  for (const char ch : text) {
    switch (ch) {
      case '&':
        out += "&amp;";
        break;
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += ch;
    }
  }
  return out;
}

}  // namespace

std::string curve_comparison_svg(const CurveEdit& edit, const std::vector<CurvePanel>& panels) {
  // One scale for every panel, so the results compare at a glance.
  Eigen::RowVector2d lo = edit.rest.P.colwise().minCoeff(), hi = edit.rest.P.colwise().maxCoeff();
  auto include = [&](const Points2& P) {
    if (P.rows() == 0) return;
    lo = lo.cwiseMin(P.colwise().minCoeff());
    hi = hi.cwiseMax(P.colwise().maxCoeff());
  };
  include(edit.targets);
  for (const CurvePanel& panel : panels) include(panel.P);
  const Eigen::RowVector2d extent = (hi - lo).cwiseMax(1e-9);
  constexpr double kPlotWidth = 300, kMargin = 20, kTitle = 28, kCaption = 30;
  const double scale = kPlotWidth / std::max(extent.x(), extent.y() * 0.5);
  const double plot_w = extent.x() * scale, plot_h = extent.y() * scale;
  const double panel_w = plot_w + 2 * kMargin;
  const double panel_h = kTitle + plot_h + 2 * kMargin + kCaption;
  const size_t panel_count = panels.size() + 1;
  const double total_w = panel_w * static_cast<double>(panel_count);

  auto xy = [&](size_t panel, double x, double y) {
    const double px = panel_w * static_cast<double>(panel) + kMargin + (x - lo.x()) * scale;
    const double py = kTitle + kMargin + (hi.y() - y) * scale;
    return std::make_pair(px, py);
  };
  auto polyline = [&](size_t panel, const Points2& P, const char* colour) {
    std::string s = "  <polyline fill=\"none\" stroke=\"" + std::string(colour) +
                    "\" stroke-width=\"1.2\" stroke-linejoin=\"round\" points=\"";
    for (Eigen::Index i = 0; i < P.rows(); ++i) {
      const auto [px, py] = xy(panel, P(i, 0), P(i, 1));
      s += fmt_num(px, "%.2f") + "," + fmt_num(py, "%.2f") + " ";
    }
    if (edit.rest.closed && P.rows() > 0) {
      const auto [px, py] = xy(panel, P(0, 0), P(0, 1));
      s += fmt_num(px, "%.2f") + "," + fmt_num(py, "%.2f");
    }
    return s + "\"/>\n";
  };
  auto circle = [&](size_t panel, double x, double y, const char* fill, const char* stroke) {
    const auto [px, py] = xy(panel, x, y);
    return "  <circle cx=\"" + fmt_num(px, "%.2f") + "\" cy=\"" + fmt_num(py, "%.2f") +
           "\" r=\"4\" fill=\"" + fill + "\" stroke=\"" + stroke + "\" stroke-width=\"1.5\"/>\n";
  };
  auto text = [&](size_t panel, double y, const std::string& content, int size) {
    const double cx = panel_w * (static_cast<double>(panel) + 0.5);
    return "  <text x=\"" + fmt_num(cx, "%.1f") + "\" y=\"" + fmt_num(y, "%.1f") +
           "\" text-anchor=\"middle\" font-family=\"sans-serif\" font-size=\"" +
           std::to_string(size) + "\">" + content + "</text>\n";
  };
  auto constraint_marks = [&](size_t panel, bool at_rest) {
    std::string s;
    for (Eigen::Index j = 0; j < edit.constrained.size(); ++j) {
      const bool is_handle = edit.constrained(j) == edit.handle;
      const Eigen::RowVector2d p =
          at_rest ? Eigen::RowVector2d(edit.rest.P.row(edit.constrained(j))) : edit.targets.row(j);
      s += circle(panel, p.x(), p.y(), is_handle ? "#d62728" : "#2ca02c", "black");
    }
    return s;
  };

  std::string svg;
  svg += "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
  svg += "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"" + fmt_num(total_w, "%.0f") +
         "\" height=\"" + fmt_num(panel_h, "%.0f") + "\" viewBox=\"0 0 " +
         fmt_num(total_w, "%.2f") + " " + fmt_num(panel_h, "%.2f") + "\">\n";
  svg += "  <title>2D curve editing (Liu et al., Fig. 9): original, then each method</title>\n";
  svg += "  <rect width=\"100%\" height=\"100%\" fill=\"white\"/>\n";
  const double caption_y = panel_h - kCaption / 2 + 4;

  // Panel 0: the original, fixed points green, the handle red with a dashed arrow to its target.
  svg += text(0, kTitle - 8, "(a) original", 15);
  svg += polyline(0, edit.rest.P, "#1f3b73");
  for (Eigen::Index j = 0; j < edit.constrained.size(); ++j) {
    if (edit.constrained(j) != edit.handle) continue;
    const auto [x0, y0] = xy(0, edit.rest.P(edit.handle, 0), edit.rest.P(edit.handle, 1));
    const auto [x1, y1] = xy(0, edit.targets(j, 0), edit.targets(j, 1));
    svg += "  <line x1=\"" + fmt_num(x0, "%.2f") + "\" y1=\"" + fmt_num(y0, "%.2f") + "\" x2=\"" +
           fmt_num(x1, "%.2f") + "\" y2=\"" + fmt_num(y1, "%.2f") +
           "\" stroke=\"#d62728\" stroke-width=\"1.5\" stroke-dasharray=\"4 3\"/>\n";
    svg += circle(0, edit.targets(j, 0), edit.targets(j, 1), "none", "#d62728");
  }
  svg += constraint_marks(0, true);
  svg += text(0, caption_y, std::to_string(edit.rest.P.rows()) + " points", 13);

  for (size_t k = 0; k < panels.size(); ++k) {
    const size_t panel = k + 1;
    const std::string label = "(" + std::string(1, static_cast<char>('b' + k % 25)) + ") ";
    svg += "  <line x1=\"" + fmt_num(panel_w * static_cast<double>(panel), "%.1f") +
           "\" y1=\"0\" x2=\"" + fmt_num(panel_w * static_cast<double>(panel), "%.1f") +
           "\" y2=\"" + fmt_num(panel_h, "%.1f") + "\" stroke=\"#cccccc\"/>\n";
    svg += text(panel, kTitle - 8, label + xml_escape(panels[k].title), 15);
    svg += polyline(panel, panels[k].P, "#1f3b73");
    svg += constraint_marks(panel, false);
    svg += text(panel, caption_y,
                "E<tspan font-style=\"italic\">&#952;</tspan> = " +
                    fmt_num(panels[k].e_theta, "%.4f") + " rad",
                13);
  }
  svg += "</svg>\n";
  return svg;
}

}  // namespace meshdeform::core
