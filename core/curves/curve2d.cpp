#include "core/curves/curve2d.h"

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

#include "core/base/format_number.h"

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

std::string fmt_point(double x, double y) {
  char buffer[96];
  std::snprintf(buffer, sizeof(buffer), "(%.17g, %.17g)", x, y);
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
                 "lambda must be positive and finite, got " + format_number(options.lambda, "%g"));
  }
  if (options.max_iterations < 0) {
    return Error(ErrorCode::InvalidArgument,
                 "max_iterations must be >= 0, got " + std::to_string(options.max_iterations));
  }
  if (!(options.tolerance >= 0)) {
    return Error(ErrorCode::InvalidArgument,
                 "tolerance must be >= 0, got " + format_number(options.tolerance, "%g"));
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

}  // namespace meshdeform::core
