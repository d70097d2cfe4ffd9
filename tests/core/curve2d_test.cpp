// Tests of 2D curve editing (paper Section 6.1, Fig. 9): measures, the scale-aware solver's
// similarity exactness, the Laplacian and ARAP baselines, the Koch example, errors and the SVG.
#include "core/curves/curve2d.h"

#include <gtest/gtest.h>

#include <cmath>
#include <numbers>
#include <string>
#include <vector>

#include "core/curves/curve2d_svg.h"
#include "core/curves/koch.h"

namespace meshdeform::core {
namespace {

constexpr double kExact = 1e-9;  // similarity reproduction, rest reproduction
constexpr CurveMethod kAllMethods[] = {CurveMethod::Laplacian, CurveMethod::Arap,
                                       CurveMethod::ScaleAware};

/// A wobbly, non-uniformly sampled curve (open: an arc; closed: a full loop) with sharp and
/// smooth turns of both signs, so that no measure is trivially constant.
Polyline make_wobbly(int n, bool closed) {
  Polyline curve;
  curve.closed = closed;
  curve.P.resize(n, 2);
  const double span = closed ? 2 * std::numbers::pi : 1.5 * std::numbers::pi;
  for (int i = 0; i < n; ++i) {
    const double u = static_cast<double>(i) / (closed ? n : n - 1);
    const double t = span * (u + 0.03 * std::sin(7 * u));
    const double r = 1.0 + 0.25 * std::sin(5 * t) + 0.1 * ((i % 3) - 1);
    curve.P.row(i) << r * std::cos(t) + 0.2, r * std::sin(t) - 0.1;
  }
  return curve;
}

/// Applies z -> s R(angle) z + t to every row.
Points2 similarity(const Points2& P, double angle, double s, const Eigen::RowVector2d& t) {
  Eigen::Matrix2d R;
  R << std::cos(angle), -std::sin(angle), std::sin(angle), std::cos(angle);
  Points2 out = (s * (R * P.transpose())).transpose();
  out.rowwise() += t;
  return out;
}

Points2 rows_of(const Points2& P, const Eigen::VectorXi& indices) {
  Points2 out(indices.size(), 2);
  for (Eigen::Index j = 0; j < indices.size(); ++j) out.row(j) = P.row(indices(j));
  return out;
}

Eigen::VectorXi indices(std::initializer_list<int> list) {
  Eigen::VectorXi v(static_cast<Eigen::Index>(list.size()));
  Eigen::Index k = 0;
  for (const int i : list) v(k++) = i;
  return v;
}

double max_abs_diff(const Points2& a, const Points2& b) { return (a - b).cwiseAbs().maxCoeff(); }

// ---------------------------------------------------------------------------------------------
// Koch curve.

TEST(KochCurve, HasFourToTheLevelPlusOnePoints) {
  for (int level = 0; level <= 6; ++level) {
    SCOPED_TRACE(level);
    auto koch = make_koch_curve(level);
    ASSERT_TRUE(koch.ok()) << koch.status().to_string();
    EXPECT_EQ(koch->P.rows(), (1 << (2 * level)) + 1);
    EXPECT_FALSE(koch->closed);
    EXPECT_NEAR((koch->P.row(0) - Eigen::RowVector2d(0, 0)).norm(), 0, 1e-15);
    EXPECT_NEAR((koch->P.row(koch->P.rows() - 1) - Eigen::RowVector2d(1, 0)).norm(), 0, 1e-15);
    // Every segment has length 3^-level; the curve never dips below y = 0.
    for (Eigen::Index i = 0; i + 1 < koch->P.rows(); ++i) {
      EXPECT_NEAR((koch->P.row(i + 1) - koch->P.row(i)).norm(), std::pow(3.0, -level), 1e-12);
    }
    EXPECT_GE(koch->P.col(1).minCoeff(), -1e-15);
  }
  EXPECT_EQ(make_koch_curve(4)->P.rows(), 257);
}

TEST(KochCurve, TurningAnglesAreMultiplesOfSixtyDegrees) {
  auto koch = make_koch_curve(3);
  ASSERT_TRUE(koch.ok());
  auto m = curve_measures(*koch);
  ASSERT_TRUE(m.ok()) << m.status().to_string();
  ASSERT_EQ(m->theta.size(), 63);
  for (Eigen::Index k = 0; k < m->theta.size(); ++k) {
    const double sixths = m->theta(k) / (std::numbers::pi / 3);
    EXPECT_NEAR(sixths, std::round(sixths), 1e-9) << "joint " << k;
    EXPECT_NEAR(m->length_ratio(k), 1.0, 1e-12);
  }
  EXPECT_NEAR(m->theta(0), std::numbers::pi / 3, 1e-12);       // first bump: left turn
  EXPECT_NEAR(m->theta(1), -2 * std::numbers::pi / 3, 1e-12);  // its apex: right turn
}

TEST(KochCurve, LevelOutOfRangeIsInvalidArgument) {
  for (const int level : {-1, 11}) {
    auto koch = make_koch_curve(level);
    ASSERT_FALSE(koch.ok());
    EXPECT_EQ(koch.status().code(), ErrorCode::InvalidArgument);
    EXPECT_NE(koch.status().message().find("got " + std::to_string(level)), std::string::npos)
        << koch.status().message();
  }
}

TEST(KochEdit, FixesBothEndsAndPullsTheMiddleApexUp) {
  for (int level = 1; level <= 5; ++level) {
    SCOPED_TRACE(level);
    auto edit = make_koch_edit(level, 0.3);
    ASSERT_TRUE(edit.ok()) << edit.status().to_string();
    const int n = static_cast<int>(edit->rest.P.rows());
    EXPECT_EQ(edit->handle, (n - 1) / 2);
    EXPECT_EQ(edit->constrained, indices({0, (n - 1) / 2, n - 1}));
    // The middle point by index is the apex of the central bump at every level.
    EXPECT_NEAR(edit->rest.P(edit->handle, 0), 0.5, 1e-12);
    EXPECT_NEAR(edit->rest.P(edit->handle, 1), std::sqrt(3.0) / 6, 1e-12);
    EXPECT_NEAR(max_abs_diff(edit->targets.row(0), edit->rest.P.row(0)), 0, 0);
    EXPECT_NEAR(max_abs_diff(edit->targets.row(2), edit->rest.P.row(n - 1)), 0, 0);
    EXPECT_NEAR(edit->targets(1, 0), 0.5, 1e-12);
    EXPECT_NEAR(edit->targets(1, 1), std::sqrt(3.0) / 6 + 0.3, 1e-12);
  }
  auto level0 = make_koch_edit(0);
  ASSERT_FALSE(level0.ok());
  EXPECT_NE(level0.status().message().find("got 0"), std::string::npos);
  auto bad_pull = make_koch_edit(2, std::nan(""));
  ASSERT_FALSE(bad_pull.ok());
  EXPECT_NE(bad_pull.status().message().find("pull must be finite"), std::string::npos);
}

// ---------------------------------------------------------------------------------------------
// Measures.

TEST(CurveMeasures, ClosedSquareTurnsLeftByRightAngles) {
  Polyline square{Points2(4, 2), true};
  square.P << 0, 0, 2, 0, 2, 2, 0, 2;
  auto m = curve_measures(square);
  ASSERT_TRUE(m.ok());
  ASSERT_EQ(m->theta.size(), 4);
  for (Eigen::Index k = 0; k < 4; ++k) {
    EXPECT_NEAR(m->theta(k), std::numbers::pi / 2, 1e-15);
    EXPECT_NEAR(m->length_ratio(k), 1.0, 1e-15);
  }
  Polyline clockwise{square.P.colwise().reverse(), true};
  EXPECT_NEAR(curve_measures(clockwise)->theta(0), -std::numbers::pi / 2, 1e-15);
}

TEST(CurveMeasures, OpenCurveHasInteriorJointsOnly) {
  Polyline curve{Points2(4, 2), false};
  curve.P << 0, 0, 1, 0, 1, 2, 4, 2;  // left turn, then right turn; lengths 1, 2, 3
  auto m = curve_measures(curve);
  ASSERT_TRUE(m.ok());
  ASSERT_EQ(m->theta.size(), 2);
  EXPECT_NEAR(m->theta(0), std::numbers::pi / 2, 1e-15);
  EXPECT_NEAR(m->theta(1), -std::numbers::pi / 2, 1e-15);
  EXPECT_NEAR(m->length_ratio(0), 2.0, 1e-15);
  EXPECT_NEAR(m->length_ratio(1), 1.5, 1e-15);
}

TEST(CurveErrors, AreZeroUnderSimilarityAndWrapAngles) {
  const Polyline curve = make_wobbly(30, true);
  auto same = curve_errors(curve, similarity(curve.P, 2.1, 3.0, {5, -1}));
  ASSERT_TRUE(same.ok());
  EXPECT_NEAR(same->e_theta, 0, 1e-12);
  EXPECT_NEAR(same->scale_log_rms, 0, 1e-12);

  // A turn of +170 degrees becoming -170 degrees is a change of 20 degrees, not 340.
  Polyline rest{Points2(3, 2), false};
  const double a = 170 * std::numbers::pi / 180;
  rest.P << 0, 0, 1, 0, 1 + std::cos(a), std::sin(a);
  Points2 bent(3, 2);
  bent << 0, 0, 1, 0, 1 + std::cos(a), -2 * std::sin(a);  // -170ish degrees, longer last segment
  auto errors = curve_errors(rest, bent);
  ASSERT_TRUE(errors.ok());
  const Eigen::Vector2d e1(std::cos(a), -2 * std::sin(a));
  const double expected = 2 * std::numbers::pi - a - std::atan2(-e1.y(), e1.x());
  EXPECT_NEAR(errors->e_theta, std::abs(expected), 1e-12);
  EXPECT_LT(errors->e_theta, std::numbers::pi / 2);
  EXPECT_NEAR(errors->scale_log_rms, std::log(e1.norm()), 1e-12);
}

// ---------------------------------------------------------------------------------------------
// Exactness.

struct SimilarityCase {
  double degrees, scale;
  Eigen::RowVector2d translation;
};

const std::vector<SimilarityCase> kSimilarities = {
    {0, 1, {0, 0}},     {120, 1, {0, 0}},    {0, 2, {0, 0}},     {0, 1, {3, -2}},
    {120, 2, {0.5, 4}}, {-75, 0.3, {-1, 1}}, {180, 1.7, {0, 2}}, {33, 10, {100, -50}},
};

void expect_scale_aware_reproduces_similarities(const Polyline& rest,
                                                const Eigen::VectorXi& constrained) {
  auto solver = ScaleAwareCurveSolver::create(rest, constrained);
  ASSERT_TRUE(solver.ok()) << solver.status().to_string();
  for (const SimilarityCase& c : kSimilarities) {
    SCOPED_TRACE(testing::Message() << c.degrees << " deg, scale " << c.scale);
    const Points2 expected =
        similarity(rest.P, c.degrees * std::numbers::pi / 180, c.scale, c.translation);
    // The prefactored solver: one factorization, many target sets.
    auto P = solver->solve(rows_of(expected, constrained));
    ASSERT_TRUE(P.ok()) << P.status().to_string();
    EXPECT_LT(max_abs_diff(*P, expected), kExact * c.scale * 10);
    // The one-off entry point gives the same.
    auto one_off =
        deform_curve(CurveMethod::ScaleAware, rest, constrained, rows_of(expected, constrained));
    ASSERT_TRUE(one_off.ok()) << one_off.status().to_string();
    EXPECT_LT(max_abs_diff(one_off->P, expected), kExact * c.scale * 10);
    EXPECT_LT(one_off->energy_history.back(), 1e-18 * c.scale * c.scale);
    auto errors = curve_errors(rest, one_off->P);
    ASSERT_TRUE(errors.ok());
    EXPECT_LT(errors->e_theta, 1e-9);
  }
}

TEST(ScaleAwareCurve, SimilarityOfEndPointsMovesOpenCurvesBySimilarity) {
  {
    SCOPED_TRACE("Koch level 3");
    const Polyline koch = *make_koch_curve(3);
    expect_scale_aware_reproduces_similarities(koch, indices({0, 64}));
  }
  {
    SCOPED_TRACE("Koch level 5, three points");
    const Polyline koch = *make_koch_curve(5);
    expect_scale_aware_reproduces_similarities(koch, indices({0, 512, 1024}));
  }
  {
    SCOPED_TRACE("wobbly open curve");
    expect_scale_aware_reproduces_similarities(make_wobbly(50, false), indices({0, 49}));
  }
  {
    SCOPED_TRACE("two interior points");
    expect_scale_aware_reproduces_similarities(make_wobbly(50, false), indices({30, 11}));
  }
}

TEST(ScaleAwareCurve, SimilarityMovesClosedCurvesBySimilarity) {
  const Polyline loop = make_wobbly(60, true);
  expect_scale_aware_reproduces_similarities(loop, indices({0, 30}));
  expect_scale_aware_reproduces_similarities(loop, indices({5, 6}));  // two neighbours suffice
  Polyline triangle{Points2(3, 2), true};
  triangle.P << 0, 0, 1, 0, 0.2, 0.7;
  expect_scale_aware_reproduces_similarities(triangle, indices({2, 0}));
}

TEST(CurveEditing, RestTargetsReproduceRestForEveryMethod) {
  const std::vector<std::pair<Polyline, Eigen::VectorXi>> cases = {
      {*make_koch_curve(3), indices({0, 32, 64})},
      {make_wobbly(40, false), indices({0, 39})},
      {make_wobbly(40, true), indices({3, 17, 29})},
  };
  for (const auto& [rest, constrained] : cases) {
    for (const CurveMethod method : kAllMethods) {
      SCOPED_TRACE(testing::Message() << curve_method_name(method) << ", " << rest.P.rows()
                                      << " points, closed " << rest.closed);
      auto result = deform_curve(method, rest, constrained, rows_of(rest.P, constrained));
      ASSERT_TRUE(result.ok()) << result.status().to_string();
      EXPECT_LT(max_abs_diff(result->P, rest.P), kExact);
      EXPECT_TRUE(result->converged);
      EXPECT_LT(result->energy_history.back(), 1e-18);
    }
  }
}

TEST(CurveEditing, TranslationOfConstraintsTranslatesTheCurveForEveryMethod) {
  const Polyline rest = make_wobbly(40, false);
  const Eigen::VectorXi constrained = indices({0, 20, 39});
  const Points2 expected = similarity(rest.P, 0, 1, {0.7, -1.3});
  for (const CurveMethod method : kAllMethods) {
    SCOPED_TRACE(curve_method_name(method));
    auto result = deform_curve(method, rest, constrained, rows_of(expected, constrained));
    ASSERT_TRUE(result.ok()) << result.status().to_string();
    EXPECT_LT(max_abs_diff(result->P, expected), 1e-8);
  }
}

// ---------------------------------------------------------------------------------------------
// ARAP.

TEST(ArapCurve, EnergyNeverIncreasesAndPointsStayNearTargets) {
  for (const int level : {2, 3, 4}) {
    SCOPED_TRACE(level);
    const CurveEdit edit = *make_koch_edit(level, 0.3);
    CurveOptions options;
    options.max_iterations = 200;
    options.tolerance = 1e-9;
    auto result =
        deform_curve(CurveMethod::Arap, edit.rest, edit.constrained, edit.targets, options);
    ASSERT_TRUE(result.ok()) << result.status().to_string();
    const auto& h = result->energy_history;
    ASSERT_EQ(static_cast<int>(h.size()), result->iterations + 1);
    ASSERT_GE(h.size(), 3u);
    for (size_t k = 1; k < h.size(); ++k) {
      EXPECT_LE(h[k], h[k - 1] * (1 + 1e-12)) << "iteration " << k;
    }
    EXPECT_LT(h.back(), 0.5 * h.front());
    for (Eigen::Index j = 0; j < edit.constrained.size(); ++j) {
      EXPECT_LT((result->P.row(edit.constrained(j)) - edit.targets.row(j)).norm(), 0.01);
    }
  }
}

TEST(ArapCurve, StopsOnToleranceOrBudget) {
  const CurveEdit edit = *make_koch_edit(3, 0.3);
  CurveOptions options;
  options.max_iterations = 5;
  auto capped = deform_curve(CurveMethod::Arap, edit.rest, edit.constrained, edit.targets, options);
  ASSERT_TRUE(capped.ok());
  EXPECT_EQ(capped->iterations, 5);
  EXPECT_FALSE(capped->converged);
  options.max_iterations = 100000;
  options.tolerance = 1e-3;
  auto loose = deform_curve(CurveMethod::Arap, edit.rest, edit.constrained, edit.targets, options);
  ASSERT_TRUE(loose.ok());
  EXPECT_TRUE(loose->converged);
  EXPECT_LT(loose->iterations, 100000);
  const auto& h = loose->energy_history;
  EXPECT_LE(std::abs(h[h.size() - 2] - h.back()), 1e-3 * h[h.size() - 2]);
}

// ---------------------------------------------------------------------------------------------
// The paper's claim for Fig. 9.

TEST(KochEdit, ScaleAwareKeepsTurningAnglesBestAsInFigure9) {
  for (const int level : {3, 4}) {
    SCOPED_TRACE(level);
    const CurveEdit edit = *make_koch_edit(level, 0.3);
    std::vector<double> e_theta;
    for (const CurveMethod method : kAllMethods) {
      auto result = deform_curve(method, edit.rest, edit.constrained, edit.targets);
      ASSERT_TRUE(result.ok()) << result.status().to_string();
      auto errors = curve_errors(edit.rest, result->P);
      ASSERT_TRUE(errors.ok()) << errors.status().to_string();
      e_theta.push_back(errors->e_theta);
    }
    const double laplacian = e_theta[0], arap = e_theta[1], scale_aware = e_theta[2];
    EXPECT_LT(scale_aware, arap);
    EXPECT_LT(scale_aware, laplacian);
    EXPECT_GT(scale_aware, 0);  // the edit is not a similarity: some distortion must remain
    // Not an artefact of ARAP's 50-iteration budget: ARAP run to convergence still loses.
    CurveOptions converged;
    converged.max_iterations = 20000;
    converged.tolerance = 1e-10;
    auto arap_long =
        deform_curve(CurveMethod::Arap, edit.rest, edit.constrained, edit.targets, converged);
    ASSERT_TRUE(arap_long.ok());
    EXPECT_TRUE(arap_long->converged);
    EXPECT_LT(scale_aware, curve_errors(edit.rest, arap_long->P)->e_theta);
  }
}

// ---------------------------------------------------------------------------------------------
// Errors.

void expect_invalid(const Status& status, const std::string& fragment) {
  EXPECT_EQ(status.code(), ErrorCode::InvalidArgument) << status.to_string();
  EXPECT_NE(status.message().find(fragment), std::string::npos)
      << "message '" << status.message() << "' lacks '" << fragment << "'";
}

/// Every entry point that takes the input reports the same error.
void expect_invalid_everywhere(const Polyline& rest, const Eigen::VectorXi& constrained,
                               const Points2& targets, const std::string& fragment,
                               const CurveOptions& options = {}) {
  for (const CurveMethod method : kAllMethods) {
    SCOPED_TRACE(curve_method_name(method));
    expect_invalid(deform_curve(method, rest, constrained, targets, options).status(), fragment);
  }
}

TEST(CurveErrorsCases, TooFewPoints) {
  Polyline two{Points2(2, 2), false};
  two.P << 0, 0, 1, 0;
  expect_invalid(validate_polyline(two), "a polyline needs at least 3 points, got 2");
  expect_invalid(curve_measures(two).status(), "a polyline needs at least 3 points, got 2");
  expect_invalid_everywhere(two, indices({0, 1}), two.P,
                            "a polyline needs at least 3 points, got 2");
  expect_invalid(ScaleAwareCurveSolver::create(two, indices({0, 1})).status(),
                 "a polyline needs at least 3 points, got 2");
}

TEST(CurveErrorsCases, NonFinitePointOrTarget) {
  Polyline curve = make_wobbly(10, false);
  const Eigen::VectorXi constrained = indices({0, 9});
  const Points2 targets = rows_of(curve.P, constrained);
  Polyline bad = curve;
  bad.P(4, 1) = std::nan("");
  expect_invalid(validate_polyline(bad), "point 4 is not finite");
  expect_invalid_everywhere(bad, constrained, targets, "point 4 is not finite");
  Points2 bad_targets = targets;
  bad_targets(1, 0) = INFINITY;
  expect_invalid_everywhere(curve, constrained, bad_targets, "target 1 is not finite");
  auto solver = ScaleAwareCurveSolver::create(curve, constrained);
  ASSERT_TRUE(solver.ok());
  expect_invalid(solver->solve(bad_targets).status(), "target 1 is not finite");
}

TEST(CurveErrorsCases, ZeroLengthSegmentIsNamed) {
  Polyline open{Points2(4, 2), false};
  open.P << 0, 0, 1, 0, 1, 0, 2, 1;
  expect_invalid(validate_polyline(open), "segment 1 (points 1 -> 2) has zero length");
  expect_invalid_everywhere(open, indices({0, 3}), rows_of(open.P, indices({0, 3})),
                            "segment 1 (points 1 -> 2) has zero length");
  Polyline closed{Points2(4, 2), true};  // the closing segment 3 -> 0 collapses
  closed.P << 0, 0, 1, 0, 1, 1, 0, 0;
  expect_invalid(validate_polyline(closed), "segment 3 (points 3 -> 0) has zero length");
  closed.closed = false;  // open, the same points are fine
  EXPECT_TRUE(validate_polyline(closed).ok());
  // A deformation that collapses a segment cannot be measured either.
  Points2 collapsed = make_wobbly(10, false).P;
  collapsed.row(6) = collapsed.row(5);
  expect_invalid(curve_errors(make_wobbly(10, false), collapsed).status(),
                 "segment 5 (points 5 -> 6) has zero length");
}

TEST(CurveErrorsCases, ConstrainedIndices) {
  const Polyline curve = make_wobbly(5, false);
  const Points2 two = curve.P.topRows(2);
  expect_invalid_everywhere(curve, indices({0, 9}), two,
                            "constrained index 9 (entry 1) is out of range (#P=5)");
  expect_invalid_everywhere(curve, indices({-1, 2}), two,
                            "constrained index -1 (entry 0) is out of range (#P=5)");
  expect_invalid_everywhere(curve, indices({2, 2}), two,
                            "constrained index 2 is repeated (entries 0 and 1)");
  expect_invalid_everywhere(curve, indices({3}), curve.P.topRows(1),
                            "at least 2 constrained points");
  expect_invalid(ScaleAwareCurveSolver::create(curve, indices({3})).status(), "got 1");
  expect_invalid(ScaleAwareCurveSolver::create(curve, Eigen::VectorXi()).status(), "got 0");
  // Two constrained points at one rest position (a loop through itself) do not pin scale.
  Polyline figure{Points2(5, 2), false};
  figure.P << 0, 0, 1, 0, 1, 1, 0, 1, 0, 0;
  expect_invalid(ScaleAwareCurveSolver::create(figure, indices({0, 4})).status(),
                 "constrained points all lie at the rest position (0, 0)");
}

TEST(CurveErrorsCases, TargetRowsAndOptions) {
  const Polyline curve = make_wobbly(8, true);
  const Eigen::VectorXi constrained = indices({0, 3, 5});
  expect_invalid_everywhere(curve, constrained, curve.P.topRows(2),
                            "targets has 2 rows, expected 3 (one per constrained point)");
  auto solver = ScaleAwareCurveSolver::create(curve, constrained);
  ASSERT_TRUE(solver.ok());
  expect_invalid(solver->solve(curve.P).status(), "targets has 8 rows, expected 3");
  const Points2 targets = rows_of(curve.P, constrained);
  CurveOptions options;
  options.lambda = 0;
  expect_invalid_everywhere(curve, constrained, targets,
                            "lambda must be positive and finite, got 0", options);
  options = {};
  options.max_iterations = -1;
  expect_invalid_everywhere(curve, constrained, targets, "max_iterations must be >= 0, got -1",
                            options);
  options = {};
  options.tolerance = std::nan("");
  expect_invalid_everywhere(curve, constrained, targets, "tolerance must be >= 0", options);
  expect_invalid(curve_errors(curve, curve.P.topRows(4)).status(),
                 "deformed curve has 4 points, the rest curve 8");
}

// ---------------------------------------------------------------------------------------------
// SVG.

size_t count(const std::string& text, const std::string& word) {
  size_t n = 0;
  for (size_t pos = text.find(word); pos != std::string::npos; pos = text.find(word, pos + 1)) ++n;
  return n;
}

TEST(CurveSvg, DrawsTheOriginalAndEveryPanelWithCaptions) {
  const CurveEdit edit = *make_koch_edit(2, 0.3);
  std::vector<CurvePanel> panels;
  for (const CurveMethod method : kAllMethods) {
    auto result = deform_curve(method, edit.rest, edit.constrained, edit.targets);
    ASSERT_TRUE(result.ok());
    panels.push_back(
        {curve_method_name(method), result->P, curve_errors(edit.rest, result->P)->e_theta});
  }
  panels[0].title = "Laplacian <&>";  // escaped, not broken markup
  const std::string svg = curve_comparison_svg(edit, panels);
  EXPECT_EQ(svg.rfind("<?xml", 0), 0u);
  EXPECT_EQ(count(svg, "<svg"), 1u);
  EXPECT_EQ(count(svg, "</svg>"), 1u);
  EXPECT_EQ(count(svg, "<polyline"), 4u);         // the original plus three results
  EXPECT_EQ(count(svg, "fill=\"#2ca02c\""), 8u);  // two fixed ends in each of four panels
  EXPECT_EQ(count(svg, "fill=\"#d62728\""), 4u);  // the handle in each panel
  EXPECT_EQ(count(svg, " rad</text>"), 3u);
  EXPECT_NE(svg.find("Laplacian &lt;&amp;&gt;"), std::string::npos);
  char caption[64];
  std::snprintf(caption, sizeof(caption), "= %.4f rad", panels[2].e_theta);
  EXPECT_NE(svg.find(caption), std::string::npos) << caption;
  EXPECT_EQ(svg.find("nan"), std::string::npos);
}

}  // namespace
}  // namespace meshdeform::core
