// Every method behind the one Deformer interface: same edit, same calls, method-specific
// guarantees (ARAP pins handles exactly, the soft-constraint methods within their tolerance).
#include "core/methods/deformer.h"

#include <gtest/gtest.h>

#include <stop_token>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

using test::bbox_diagonal;

constexpr Method kMethods[] = {Method::ScaleAware, Method::Arap, Method::Laplacian};

const auto& rows_of = test::gather_rows;

// Left column fixed, right column rotated by 60 degrees about y and lifted.
using test::make_bend;
using Bend = test::BendEdit;

TEST(Deformer, MethodNamesRoundTrip) {
  for (Method method : kMethods) {
    auto parsed = parse_method(method_name(method));
    ASSERT_TRUE(parsed.ok()) << method_name(method);
    EXPECT_EQ(*parsed, method);
  }
  EXPECT_STREQ(method_name(Method::ScaleAware), "scale_aware");
  EXPECT_STREQ(method_name(Method::Arap), "arap");
  EXPECT_STREQ(method_name(Method::Laplacian), "laplacian");
  auto dashed = parse_method("scale-aware");
  ASSERT_TRUE(dashed.ok());
  EXPECT_EQ(*dashed, Method::ScaleAware);
  for (const char* bad : {"bogus", "", "ARAP", "scale aware"}) {
    auto result = parse_method(bad);
    ASSERT_FALSE(result.ok()) << bad;
    EXPECT_EQ(result.status().code(), ErrorCode::InvalidArgument);
    std::string quoted = "\"";  // appended piecewise: GCC 12 warns on "lit" + string (-Wrestrict)
    quoted.append(bad).append("\"");
    EXPECT_NE(result.status().message().find(quoted), std::string::npos)
        << result.status().message();
  }
}

TEST(Deformer, EveryMethodBendsTowardTheTargets) {
  const Bend bend = make_bend(16);
  const double diag = bbox_diagonal(bend.mesh);
  for (Method method : kMethods) {
    SCOPED_TRACE(method_name(method));
    auto deformer = make_deformer(method, bend.mesh.V, bend.mesh.F, bend.constrained);
    ASSERT_TRUE(deformer.ok()) << deformer.status().to_string();
    Deformer& d = **deformer;
    EXPECT_EQ(d.method(), method);
    EXPECT_EQ(d.constrained(), bend.constrained);
    EXPECT_EQ(d.positions(), bend.mesh.V);
    int calls = 0;
    auto report = d.solve(bend.targets, {}, [&](const IterationInfo& info) {
      if (info.phase == SolvePhase::Fine) ++calls;  // the rigid start reports as Start
    });
    ASSERT_TRUE(report.ok()) << report.status().to_string();
    ASSERT_TRUE(report->V.allFinite());
    ASSERT_FALSE(report->history.empty());
    EXPECT_EQ(calls, static_cast<int>(report->history.size()));
    const double handle_error =
        (rows_of(report->V, bend.constrained) - bend.targets).cwiseAbs().maxCoeff();
    if (method == Method::Arap) {
      EXPECT_EQ(handle_error, 0.0);  // hard constraints
    } else {
      EXPECT_LT(handle_error, 1e-2 * diag);  // soft constraints, lambda = 100
    }
    // A bend distorts angles, and every method reports it.
    EXPECT_GT(report->history.back().e_theta, 0.0);
    EXPECT_GT(report->history.back().e_phi, 0.0);
    EXPECT_EQ(d.positions(), report->V);
    d.reset();
    EXPECT_EQ(d.positions(), bend.mesh.V);
  }
}

TEST(Deformer, AGivenTopologyGivesTheSameDeformerAsValidatingAgain) {
  // What a server session does: validate and build the topology once at upload, then hand the
  // topology to every make_deformer (multiresolution forced on this small mesh).
  const Bend bend = make_bend(16);
  auto topology = build_topology(bend.mesh.F, static_cast<int>(bend.mesh.V.rows()));
  ASSERT_TRUE(topology.ok());
  DeformerSettings multires;
  multires.multires_above = 100;
  multires.multires_coarse_vertices = 120;
  ASSERT_GT(bend.mesh.V.rows(), 2 * multires.multires_coarse_vertices);
  for (const auto& [method, settings] :
       {std::pair{Method::ScaleAware, DeformerSettings{}}, std::pair{Method::ScaleAware, multires},
        std::pair{Method::Arap, DeformerSettings{}},
        std::pair{Method::Laplacian, DeformerSettings{}}}) {
    SCOPED_TRACE(std::string(method_name(method)) +
                 (settings.multires_above > 0 ? " multires" : ""));
    auto validated = make_deformer(method, bend.mesh.V, bend.mesh.F, bend.constrained, settings);
    auto given = make_deformer(method, bend.mesh.V, bend.mesh.F, *topology, bend.constrained,
                               settings);
    ASSERT_TRUE(validated.ok()) << validated.status().to_string();
    ASSERT_TRUE(given.ok()) << given.status().to_string();
    auto a = (*validated)->solve(bend.targets);
    auto b = (*given)->solve(bend.targets);
    ASSERT_TRUE(a.ok() && b.ok());
    EXPECT_EQ(a->V, b->V);
    EXPECT_GT((a->V - bend.mesh.V).cwiseAbs().maxCoeff(), 0.0);
    // The constrained indices are still checked.
    Eigen::VectorXi bad = bend.constrained;
    bad(0) = static_cast<int>(bend.mesh.V.rows());
    EXPECT_EQ(make_deformer(method, bend.mesh.V, bend.mesh.F, *topology, bad, settings)
                  .status()
                  .code(),
              ErrorCode::InvalidArgument);
  }
}

TEST(Deformer, RestTargetsReproduceTheRestMeshForEveryMethod) {
  const MeshData m = test::make_grid(12, 0.08);
  Eigen::VectorXi c(5);
  c << 0, 12, 13 * 12, 13 * 13 - 1, 2 * 13 + 2;
  const double diag = bbox_diagonal(m);
  for (Method method : kMethods) {
    SCOPED_TRACE(method_name(method));
    auto deformer = make_deformer(method, m.V, m.F, c);
    ASSERT_TRUE(deformer.ok()) << deformer.status().to_string();
    auto report = (*deformer)->solve(rows_of(m.V, c));
    ASSERT_TRUE(report.ok()) << report.status().to_string();
    EXPECT_LT((report->V - m.V).cwiseAbs().maxCoeff(), test::kExactTol * diag);
    EXPECT_LT(report->history.back().e_theta, 1e-9);
    EXPECT_LT(report->history.back().e_phi, 1e-9);
    EXPECT_TRUE(report->converged);
  }
}

TEST(Deformer, LaplacianIsOneDirectSolve) {
  const Bend bend = make_bend(10);
  auto deformer = make_deformer(Method::Laplacian, bend.mesh.V, bend.mesh.F, bend.constrained);
  ASSERT_TRUE(deformer.ok()) << deformer.status().to_string();
  auto report = (*deformer)->solve(bend.targets);
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  ASSERT_EQ(report->history.size(), 1u);
  EXPECT_EQ(report->history[0].iteration, 0);
  EXPECT_EQ(report->iterations, 0);
  EXPECT_TRUE(report->converged);
  // Start options do not matter: the same solve from a warm state gives the same result.
  SolveOptions options;
  options.start = StartFrom::Previous;
  auto again = (*deformer)->solve(bend.targets, options);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->V, report->V);
  options.track_metrics = false;
  auto untracked = (*deformer)->solve(bend.targets, options);
  ASSERT_TRUE(untracked.ok());
  EXPECT_EQ(untracked->history[0].e_theta, 0.0);
}

TEST(Deformer, SoftConstraintMethodsRejectALambdaOtherThanTheSettings) {
  const Bend bend = make_bend(6);
  DeformerSettings settings;
  settings.lambda = 1000;
  SolveOptions options;  // lambda 100
  for (Method method : kMethods) {
    SCOPED_TRACE(method_name(method));
    auto deformer = make_deformer(method, bend.mesh.V, bend.mesh.F, bend.constrained, settings);
    ASSERT_TRUE(deformer.ok()) << deformer.status().to_string();
    auto mismatched = (*deformer)->solve(bend.targets, options);
    if (method == Method::Arap) {
      EXPECT_TRUE(mismatched.ok()) << mismatched.status().to_string();  // no lambda in ARAP
    } else {
      ASSERT_FALSE(mismatched.ok());
      EXPECT_EQ(mismatched.status().code(), ErrorCode::InvalidArgument);
      EXPECT_NE(mismatched.status().message().find("lambda"), std::string::npos);
    }
    options.lambda = settings.lambda;
    EXPECT_TRUE((*deformer)->solve(bend.targets, options).ok());
    options.lambda = 100;
  }
}

TEST(Deformer, OraAndMagnificationBelongToTheScaleAwareMethod) {
  const Bend bend = make_bend(6);
  for (Method method : kMethods) {
    SCOPED_TRACE(method_name(method));
    auto deformer = make_deformer(method, bend.mesh.V, bend.mesh.F, bend.constrained);
    ASSERT_TRUE(deformer.ok()) << deformer.status().to_string();
    SolveOptions ora;
    ora.ora = true;
    SolveOptions magnify;
    magnify.face_scale = Eigen::VectorXd::Ones(bend.mesh.F.rows());
    for (const SolveOptions& options : {ora, magnify}) {
      auto report = (*deformer)->solve(bend.targets, options);
      if (method == Method::ScaleAware) {
        ASSERT_TRUE(report.ok()) << report.status().to_string();
        EXPECT_TRUE(report->stitch.applied);
      } else {
        ASSERT_FALSE(report.ok());
        EXPECT_EQ(report.status().code(), ErrorCode::InvalidArgument);
        EXPECT_NE(report.status().message().find("scale-aware"), std::string::npos)
            << report.status().message();
      }
    }
  }
}

TEST(Deformer, ConstructionErrorsFollowEachMethodsPinningRule) {
  const MeshData m = test::make_icosphere(1);
  Eigen::VectorXi one(1);
  one << 0;
  for (Method method : kMethods) {
    SCOPED_TRACE(method_name(method));
    auto single = make_deformer(method, m.V, m.F, one);
    if (method == Method::ScaleAware) {
      ASSERT_FALSE(single.ok());  // translation and scale are free with one vertex
      EXPECT_EQ(single.status().code(), ErrorCode::InvalidArgument);
    } else {
      EXPECT_TRUE(single.ok()) << single.status().to_string();
    }
    auto none = make_deformer(method, m.V, m.F, Eigen::VectorXi());
    ASSERT_FALSE(none.ok());
    EXPECT_EQ(none.status().code(), ErrorCode::InvalidArgument);
    EXPECT_NE(none.status().message().find("component 0"), std::string::npos)
        << none.status().message();

    Eigen::VectorXi bad(2);
    bad << 3, 99;
    auto out_of_range = make_deformer(method, m.V, m.F, bad);
    ASSERT_FALSE(out_of_range.ok());
    EXPECT_NE(out_of_range.status().message().find("99"), std::string::npos)
        << out_of_range.status().message();

    MeshData broken = m;
    broken.F(4, 2) = broken.F(4, 1);
    Eigen::VectorXi two(2);
    two << 0, 3;
    auto invalid = make_deformer(method, broken.V, broken.F, two);
    ASSERT_FALSE(invalid.ok());
    EXPECT_NE(invalid.status().message().find("face 4"), std::string::npos)
        << invalid.status().message();
  }
}

TEST(Deformer, TargetErrorsAndCancellationLeaveTheStateAlone) {
  const Bend bend = make_bend(8);
  for (Method method : kMethods) {
    SCOPED_TRACE(method_name(method));
    auto deformer = make_deformer(method, bend.mesh.V, bend.mesh.F, bend.constrained);
    ASSERT_TRUE(deformer.ok()) << deformer.status().to_string();
    Deformer& d = **deformer;
    Positions nan_targets = bend.targets;
    nan_targets(2, 0) = std::nan("");
    auto nan_result = d.solve(nan_targets);
    ASSERT_FALSE(nan_result.ok());
    EXPECT_EQ(nan_result.status().code(), ErrorCode::InvalidArgument);
    EXPECT_NE(nan_result.status().message().find("target 2"), std::string::npos)
        << nan_result.status().message();
    auto wrong_rows = d.solve(Positions::Zero(2, 3));
    ASSERT_FALSE(wrong_rows.ok());
    EXPECT_EQ(wrong_rows.status().code(), ErrorCode::InvalidArgument);

    std::stop_source source;
    source.request_stop();
    auto cancelled = d.solve(bend.targets, {}, {}, source.get_token());
    ASSERT_FALSE(cancelled.ok());
    EXPECT_EQ(cancelled.status().code(), ErrorCode::Cancelled);
    EXPECT_EQ(d.positions(), bend.mesh.V);
  }
}

}  // namespace
}  // namespace meshdeform::core
