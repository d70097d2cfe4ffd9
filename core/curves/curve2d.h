#pragma once
/// @file curve2d.h
/// 2D curve editing (paper Section 6.1, Fig. 9; docs/algorithm.md section 7): polylines, their
/// scale-invariant measures (turning angles and length ratios), the scale-aware curve solver and
/// two baselines (Laplacian editing and ARAP) behind one interface, and the edit they share.
/// The Koch-curve example is in core/curves/koch.h, the SVG figure of the comparison in
/// core/curves/curve2d_svg.h.
///
/// In 2D the scale-aware equations e_i = l_i R(theta_i) e_{i-1} (paper Eq. 1) need no normals, so
/// the method is ONE constant linear least-squares problem: factor once per handle set, solve once
/// per target set.

#include <Eigen/Core>
#include <memory>
#include <string>
#include <vector>

#include "core/base/status.h"

namespace meshdeform::core {

/// #P x 2 point positions, one point per row.
using Points2 = Eigen::Matrix<double, Eigen::Dynamic, 2>;

/// A 2D polyline: points P.row(0) .. P.row(n-1), joined in order; `closed` adds the segment
/// from the last point back to the first.
struct Polyline {
  Points2 P;
  bool closed = false;
};

/// The deformation methods compared in Fig. 9.
enum class CurveMethod {
  Laplacian,   ///< Laplacian editing [Sorkine et al. 2004] with the uniform polyline Laplacian
  Arap,        ///< as-rigid-as-possible [Sorkine & Alexa 2007] with one rotation per point
  ScaleAware,  ///< the paper's scale-aware equations in 2D (one linear solve)
};

/// "laplacian", "arap" or "scale_aware".
const char* curve_method_name(CurveMethod method);

/// Settings of every curve method (each uses the ones that apply to it).
struct CurveOptions {
  double lambda = 100.0;    ///< weight of the soft point constraints (like Eq. 12)
  int max_iterations = 50;  ///< ARAP local/global iterations, the budget
  double tolerance = 1e-6;  ///< ARAP stops when the relative energy change falls below this
};

/// The result of deforming a curve.
struct CurveResult {
  Points2 P;              ///< #P x 2 deformed points
  int iterations = 0;     ///< ARAP iterations run (0 for the linear methods)
  bool converged = true;  ///< ARAP stopped on tolerance (always true for linear methods)
  /// The minimised energy: for ARAP the starting value then one value per iteration (each
  /// evaluated with the best rotations for the positions, so it never increases); for the linear
  /// methods the single final value.
  std::vector<double> energy_history;
  double seconds = 0;  ///< wall time of setup, factorization and solve(s)
};

/// Per-joint measures of a polyline. Joint k is point k+1 of an open polyline (interior points
/// 1 .. n-2) and point k of a closed one (all points, neighbours taken cyclically).
struct CurveMeasures {
  Eigen::VectorXd theta;         ///< signed turning angle from e_{i-1} to e_i, in (-pi, pi]
  Eigen::VectorXd length_ratio;  ///< l_i = |e_i| / |e_{i-1}|
};

/// Scale-invariant distortion of a deformed curve against its rest shape.
struct CurveErrors {
  double e_theta = 0;        ///< RMS of turning-angle changes, wrapped to (-pi, pi], radians
  double scale_log_rms = 0;  ///< RMS of log(l_deformed / l_rest): change of the length ratios
};

/// Checks a polyline: at least 3 points, all finite, no zero-length segment (including the
/// closing segment of a closed polyline).
/// @return ok; InvalidArgument naming the point count, the non-finite point or the zero-length
///         segment (a segment shorter than 1e-12 times the bounding-box diagonal).
[[nodiscard]] Status validate_polyline(const Polyline& curve);

/// Turning angles and length ratios at every joint.
/// @param[in] curve  the polyline.
/// @return the measures; InvalidArgument as for validate_polyline().
[[nodiscard]] Result<CurveMeasures> curve_measures(const Polyline& curve);

/// E_theta and the length-ratio measure of `deformed` (same connectivity as `rest`).
/// @param[in] rest      the rest polyline.
/// @param[in] deformed  #P x 2 deformed points.
/// @return the errors; InvalidArgument if `deformed` has a different point count, or either
///         curve fails validate_polyline() (a deformation that collapsed a segment, say).
[[nodiscard]] Result<CurveErrors> curve_errors(const Polyline& rest, const Points2& deformed);

/// Scale-aware curve editing, prefactored for one curve and one constrained set:
///   min_P  sum_i ||(p_{i+1} - p_i) - l_i R(theta_i)(p_i - p_{i-1})||^2
///          + lambda sum_{j in C} ||p_j - p*_j||^2
/// with theta_i, l_i measured on the rest curve (paper Eqs. 1-3, 12 in 2D). The rotation couples
/// x and y, so the 2#P unknowns are interleaved (x0, y0, x1, ...); the normal matrix is constant.
/// Any rotation + uniform scale + translation of the rest constrained points is reproduced
/// exactly on the whole curve (the energy reaches zero there and the minimiser is unique).
class ScaleAwareCurveSolver {
 public:
  /// Measures the rest curve and factors the normal equations.
  /// @param[in] rest         the rest polyline.
  /// @param[in] constrained  #C distinct point indices, #C >= 2, not all at the same rest position
  ///                         (the energy is invariant to translation, rotation and scale).
  /// @param[in] options      uses `lambda`.
  /// @return the solver; InvalidArgument for a bad polyline (see validate_polyline()), an index
  ///         out of range or repeated, fewer than 2 constrained points, constrained points that
  ///         all coincide, or lambda not positive and finite; NumericalFailure if the
  ///         factorization fails.
  [[nodiscard]] static Result<ScaleAwareCurveSolver> create(const Polyline& rest,
                                                            const Eigen::VectorXi& constrained,
                                                            const CurveOptions& options = {});

  /// Deforms toward #C x 2 targets (row j for constrained(j)): one back-substitution.
  /// @return #P x 2 positions; InvalidArgument for a wrong row count or a non-finite target.
  [[nodiscard]] Result<Points2> solve(const Points2& targets) const;

  /// The constrained indices given to create().
  const Eigen::VectorXi& constrained() const;

  ScaleAwareCurveSolver(ScaleAwareCurveSolver&&) noexcept;
  ScaleAwareCurveSolver& operator=(ScaleAwareCurveSolver&&) noexcept;
  ~ScaleAwareCurveSolver();

 private:
  struct Impl;
  explicit ScaleAwareCurveSolver(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// Deforms a curve with one method (one-off: set-up, factorization and solve).
///   Laplacian:  min ||L P - L P0||^2 + lambda sum_C ||p_j - p*_j||^2 with the uniform polyline
///               Laplacian delta_i = p_i - (p_{i-1} + p_{i+1}) / 2. An open curve's two end points
///               have NO Laplacian row (a one-sided row would pull them toward their neighbour);
///               a closed curve has a row at every point. x and y are solved separately.
///   Arap:       min sum_i sum_{j in N(i)} ||(p_i - p_j) - R_i (p0_i - p0_j)||^2
///               + lambda sum_C ||p_j - p*_j||^2, one 2D rotation per point fitted to its one or
///               two incident segments (local step), then one constant sparse solve (global
///               step), starting from the rest curve; at most `max_iterations` iterations, stops
///               when the relative energy change is below `tolerance`. The energy never increases.
///   ScaleAware: ScaleAwareCurveSolver::create + solve.
/// @param[in] method       the method.
/// @param[in] rest         the rest polyline.
/// @param[in] constrained  #C distinct point indices, #C >= 2 for every method (one rule for the
///                         comparison; an open Laplacian and the scale-aware energy need two).
/// @param[in] targets      #C x 2 target positions, row j for constrained(j).
/// @param[in] options      lambda for all methods, iteration settings for ARAP.
/// @return the result; InvalidArgument for a bad polyline, an index out of range or repeated,
///         fewer than 2 constrained points, constrained points that all coincide at rest, a wrong
///         target row count, a non-finite target, lambda not positive and finite, max_iterations
///         negative or tolerance negative; NumericalFailure if a factorization fails.
[[nodiscard]] Result<CurveResult> deform_curve(CurveMethod method, const Polyline& rest,
                                               const Eigen::VectorXi& constrained,
                                               const Points2& targets,
                                               const CurveOptions& options = {});

/// An edit: a rest curve, the constrained points and their targets.
struct CurveEdit {
  Polyline rest;
  Eigen::VectorXi constrained;  ///< #C point indices
  Points2 targets;              ///< #C x 2, row j for constrained(j)
  int handle = -1;              ///< the moved point (drawn red); the others are fixed (green)
};

}  // namespace meshdeform::core
