// Tests of the checks every solver runs on its constrained vertices and their targets
// (core/methods/constraints.h): indices in range and distinct, enough of them in every connected
// component, targets of the right shape, finite, and not all coincident per component.
#include "core/methods/constraints.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "core/mesh/topology.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

Eigen::VectorXi indices(std::vector<int> list) {
  return Eigen::Map<const Eigen::VectorXi>(list.data(), static_cast<Eigen::Index>(list.size()));
}

/// Two separate meshes in one: a 3 x 3 grid (vertices 0..15, component 0) and one triangle
/// (vertices 16..18, component 1).
struct TwoComponents {
  MeshData mesh;
  MeshTopology topology;
};

TwoComponents make_two_components() {
  TwoComponents out;
  const MeshData grid = test::make_grid(3);
  out.mesh.V.resize(grid.V.rows() + 3, 3);
  out.mesh.V.topRows(grid.V.rows()) = grid.V;
  out.mesh.V.bottomRows(3) << 5, 0, 0, 6, 0, 0, 5, 1, 0;
  out.mesh.F.resize(grid.F.rows() + 1, 3);
  out.mesh.F.topRows(grid.F.rows()) = grid.F;
  out.mesh.F.bottomRows(1) << 16, 17, 18;
  out.topology = *build_topology(out.mesh.F, static_cast<int>(out.mesh.V.rows()));
  return out;
}

bool mentions(const Status& status, const std::string& text) {
  return status.message().find(text) != std::string::npos;
}

TEST(CheckConstrained, AcceptsDistinctInRangeIndicesCoveringEveryComponent) {
  const TwoComponents two = make_two_components();
  ASSERT_EQ(two.topology.component_count, 2);
  EXPECT_TRUE(check_constrained(indices({0, 15, 17}), two.topology, 1).ok());
  EXPECT_TRUE(check_constrained(indices({18, 3, 16, 5}), two.topology, 2).ok());
  // No minimum: an empty set, or a component without handles, is fine.
  EXPECT_TRUE(check_constrained(indices({}), two.topology, 0).ok());
  EXPECT_TRUE(check_constrained(indices({2}), two.topology, 0).ok());
}

TEST(CheckConstrained, RejectsAnIndexOutOfRange) {
  const TwoComponents two = make_two_components();
  for (const int bad : {-1, 19, 1000}) {
    SCOPED_TRACE(bad);
    const Status s = check_constrained(indices({0, 17, bad}), two.topology, 1);
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.code(), ErrorCode::InvalidArgument);
    EXPECT_TRUE(mentions(s, "constrained vertex 2 is " + std::to_string(bad))) << s.to_string();
    EXPECT_TRUE(mentions(s, "#V=19")) << s.to_string();
  }
}

TEST(CheckConstrained, RejectsARepeatedIndexNamingBothEntries) {
  const TwoComponents two = make_two_components();
  const Status s = check_constrained(indices({4, 17, 9, 4}), two.topology, 1);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.code(), ErrorCode::InvalidArgument);
  EXPECT_TRUE(mentions(s, "vertex 4 is constrained twice (entries 0 and 3)")) << s.to_string();
}

TEST(CheckConstrained, RejectsAComponentWithTooFewHandles) {
  const TwoComponents two = make_two_components();
  {
    // Nothing on the triangle: it would float freely.
    const Status s = check_constrained(indices({0, 15}), two.topology, 1);
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.code(), ErrorCode::InvalidArgument);
    EXPECT_TRUE(mentions(s, "connected component 1 (containing vertex 16) has 0")) << s.message();
  }
  {
    // Two per component required, the grid has only one.
    const Status s = check_constrained(indices({7, 16, 18}), two.topology, 2);
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.code(), ErrorCode::InvalidArgument);
    EXPECT_TRUE(mentions(s, "connected component 0 (containing vertex 0) has 1")) << s.message();
  }
  {
    const Status s = check_constrained(indices({}), two.topology, 1);
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.code(), ErrorCode::InvalidArgument);
  }
}

TEST(CheckTargets, AcceptsFiniteTargetsOfTheRightShape) {
  const TwoComponents two = make_two_components();
  const Eigen::VectorXi constrained = indices({0, 15, 16, 18});
  const Positions rest = test::gather_rows(two.mesh.V, constrained);
  EXPECT_TRUE(check_targets(rest, constrained, two.topology, 1.0, true).ok());
  EXPECT_TRUE(check_targets(rest, constrained, two.topology, 1.0, false).ok());
}

TEST(CheckTargets, RejectsAWrongRowCount) {
  const TwoComponents two = make_two_components();
  const Eigen::VectorXi constrained = indices({0, 15, 16});
  for (const int rows : {0, 2, 4}) {
    SCOPED_TRACE(rows);
    const Status s = check_targets(Positions::Zero(rows, 3), constrained, two.topology, 1.0, false);
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.code(), ErrorCode::InvalidArgument);
    EXPECT_TRUE(mentions(s, "expected 3 target rows")) << s.message();
  }
}

TEST(CheckTargets, RejectsANonFiniteTargetNamingItsVertex) {
  const TwoComponents two = make_two_components();
  const Eigen::VectorXi constrained = indices({0, 15, 16, 18});
  const Positions rest = test::gather_rows(two.mesh.V, constrained);
  for (const double bad : {std::nan(""), std::numeric_limits<double>::infinity(),
                           -std::numeric_limits<double>::infinity()}) {
    SCOPED_TRACE(bad);
    Positions targets = rest;
    targets(2, 1) = bad;
    const Status s = check_targets(targets, constrained, two.topology, 1.0, false);
    ASSERT_FALSE(s.ok());
    EXPECT_EQ(s.code(), ErrorCode::InvalidArgument);
    EXPECT_TRUE(mentions(s, "target 2 (vertex 16) is not finite")) << s.message();
  }
}

TEST(CheckTargets, RejectsCoincidentTargetsPerComponentOnlyWhenAsked) {
  const TwoComponents two = make_two_components();
  const Eigen::VectorXi constrained = indices({0, 15, 16, 18});
  Positions targets = test::gather_rows(two.mesh.V, constrained);
  // The triangle's two targets collapse onto one point; the grid's stay apart.
  targets.row(3) = targets.row(2);
  EXPECT_TRUE(check_targets(targets, constrained, two.topology, 1.0, false).ok());
  const Status s = check_targets(targets, constrained, two.topology, 1.0, true);
  ASSERT_FALSE(s.ok());
  EXPECT_EQ(s.code(), ErrorCode::InvalidArgument);
  EXPECT_TRUE(mentions(s, "all targets of connected component 1 coincide (vertex 16)"))
      << s.message();

  // A component with a single handle has nothing to spread: it passes only if it has another.
  const Eigen::VectorXi one_each = indices({0, 16});
  const Positions rest_one_each = test::gather_rows(two.mesh.V, one_each);
  EXPECT_FALSE(check_targets(rest_one_each, one_each, two.topology, 1.0, true).ok());
  EXPECT_TRUE(check_targets(rest_one_each, one_each, two.topology, 1.0, false).ok());

  // A component without handles is not checked.
  const Eigen::VectorXi grid_only = indices({0, 15});
  EXPECT_TRUE(
      check_targets(test::gather_rows(two.mesh.V, grid_only), grid_only, two.topology, 1.0, true)
          .ok());
}

TEST(CheckTargets, CoincidenceIsRelativeToTheLengthScale) {
  const TwoComponents two = make_two_components();
  const Eigen::VectorXi constrained = indices({0, 15});
  for (const double scale : {1e-6, 1.0, 1e6}) {
    SCOPED_TRACE(scale);
    Positions targets(2, 3);
    targets.row(0) = scale * Eigen::RowVector3d(1, 2, 3);
    targets.row(1) = targets.row(0) + Eigen::RowVector3d(1e-13 * scale, 0, 0);
    EXPECT_FALSE(check_targets(targets, constrained, two.topology, scale, true).ok());
    targets.row(1) = targets.row(0) + Eigen::RowVector3d(0, 1e-11 * scale, 0);
    EXPECT_TRUE(check_targets(targets, constrained, two.topology, scale, true).ok());
  }
}

}  // namespace
}  // namespace meshdeform::core
