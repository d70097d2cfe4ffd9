#include "core/mesh/validate.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "core/methods/deform_types.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

using test::make_grid;
using test::make_icosphere;
using test::make_open_cone;
using test::make_triangle;

// Asserts an InvalidArgument whose message contains every fragment.
void expect_invalid(const Status& status, std::initializer_list<std::string> fragments) {
  ASSERT_FALSE(status.ok());
  EXPECT_EQ(status.code(), ErrorCode::InvalidArgument) << status.to_string();
  for (const std::string& fragment : fragments) {
    EXPECT_NE(status.message().find(fragment), std::string::npos)
        << "message '" << status.message() << "' lacks '" << fragment << "'";
  }
}

// Two triangles sharing edge (1, 2), consistently oriented.
MeshData make_quad() {
  MeshData m;
  m.V.resize(4, 3);
  m.V << 0, 0, 0, 1, 0, 0, 0, 1, 0, 1, 1, 0;
  m.F.resize(2, 3);
  m.F << 0, 1, 2, 2, 1, 3;
  return m;
}

TEST(ValidateTest, AcceptsValidMeshes) {
  for (const MeshData& m : {make_triangle(), make_quad(), make_grid(4), make_grid(6, 0.2),
                            make_icosphere(2), make_open_cone(8)}) {
    const Status s = validate_triangle_mesh(m.V, m.F);
    EXPECT_TRUE(s.ok()) << s.to_string();
  }
}

TEST(ValidateTest, RejectsMeshWithoutVertices) {
  expect_invalid(validate_triangle_mesh(Positions(0, 3), Triangles(0, 3)), {"no vertices"});
}

TEST(ValidateTest, RejectsMeshWithoutFaces) {
  const MeshData m = make_triangle();
  expect_invalid(validate_triangle_mesh(m.V, Triangles(0, 3)), {"no faces"});
}

TEST(ValidateTest, RejectsNaNNamingVertexAndCoordinate) {
  MeshData m = make_grid(3);
  m.V(5, 1) = std::numeric_limits<double>::quiet_NaN();
  expect_invalid(validate_triangle_mesh(m.V, m.F), {"vertex 5", "y coordinate"});
}

TEST(ValidateTest, RejectsInfinityNamingVertexAndCoordinate) {
  MeshData m = make_grid(3);
  m.V(7, 2) = -std::numeric_limits<double>::infinity();
  expect_invalid(validate_triangle_mesh(m.V, m.F), {"vertex 7", "z coordinate", "inf"});
}

TEST(ValidateTest, RejectsIndexOutOfRangeWithHouseStyleMessage) {
  MeshData m = make_grid(3);  // 16 vertices
  m.F(4, 2) = 902;
  expect_invalid(validate_triangle_mesh(m.V, m.F), {"face 4 references vertex 902 (#V=16)"});
}

TEST(ValidateTest, RejectsNegativeIndex) {
  MeshData m = make_grid(2);
  m.F(1, 0) = -1;
  expect_invalid(validate_triangle_mesh(m.V, m.F), {"face 1 references vertex -1"});
}

TEST(ValidateTest, RejectsFaceRepeatingAVertex) {
  MeshData m = make_quad();
  m.F.row(1) << 2, 1, 1;
  expect_invalid(validate_triangle_mesh(m.V, m.F), {"face 1", "repeats vertex 1"});
}

TEST(ValidateTest, RejectsZeroLengthEdge) {
  MeshData m = make_quad();
  m.V.row(3) = m.V.row(1);  // face 1 = (2, 1, 3): edge (1, 3) collapses
  expect_invalid(validate_triangle_mesh(m.V, m.F), {"face 1", "zero-length edge", "1 and 3"});
}

TEST(ValidateTest, RejectsZeroAreaFace) {
  MeshData m = make_quad();
  m.V.row(3) << 2, -1, 0;  // collinear with vertices 2 = (0,1,0) and 1 = (1,0,0)
  expect_invalid(validate_triangle_mesh(m.V, m.F), {"face 1", "zero area"});
}

TEST(ValidateTest, AreaThresholdIsRelativeToBoundingBox) {
  // A tiny but well-shaped mesh is fine; the same sliver relative to a big bbox is rejected.
  MeshData small = make_grid(3);
  small.V *= 1e-9;
  EXPECT_TRUE(validate_triangle_mesh(small.V, small.F).ok());

  MeshData sliver = make_quad();
  sliver.V.row(3) << 1e3, 1e3, 0;          // bbox diagonal ~ 1.4e3
  sliver.V.row(0) << 0.5, 0.5 - 1e-12, 0;  // face 0 = (0, 1, 2) has area ~ 5e-13
  expect_invalid(validate_triangle_mesh(sliver.V, sliver.F), {"face 0", "zero area"});
}

TEST(ValidateTest, RejectsDuplicateFaceInAnyOrder) {
  MeshData m = make_grid(2);
  const Eigen::Index n = m.F.rows();
  m.F.conservativeResize(n + 1, 3);
  m.F.row(n) << m.F(3, 1), m.F(3, 2), m.F(3, 0);  // same triangle, rotated
  expect_invalid(validate_triangle_mesh(m.V, m.F),
                 {"face " + std::to_string(n), "duplicates face 3"});

  m.F.row(n) << m.F(3, 0), m.F(3, 2), m.F(3, 1);  // same vertex set, flipped
  expect_invalid(validate_triangle_mesh(m.V, m.F), {"duplicates face 3"});
}

TEST(ValidateTest, RejectsNonManifoldEdge) {
  // Three triangles around edge (0, 1): a "book" with three pages.
  MeshData m;
  m.V.resize(5, 3);
  m.V << 0, 0, 0, 1, 0, 0, 0.5, 1, 0, 0.5, -1, 0, 0.5, 0, 1;
  m.F.resize(3, 3);
  m.F << 0, 1, 2, 1, 0, 3, 1, 0, 4;
  expect_invalid(validate_triangle_mesh(m.V, m.F),
                 {"non-manifold edge (0, 1)", "3 faces", "0, 1, 2"});
}

TEST(ValidateTest, RejectsInconsistentOrientation) {
  MeshData m = make_quad();
  m.F.row(1) << 1, 2, 3;  // traverses 1 -> 2 like face 0
  expect_invalid(validate_triangle_mesh(m.V, m.F),
                 {"edge (1, 2)", "same direction", "faces 0 and 1"});
}

TEST(ValidateTest, RejectsNonManifoldVertex) {
  // Two triangles touching only at vertex 0 (bow tie): two fans around vertex 0.
  MeshData m;
  m.V.resize(5, 3);
  m.V << 0, 0, 0, 1, 0, 0, 1, 1, 0, -1, 0, 0, -1, -1, 0;
  m.F.resize(2, 3);
  m.F << 0, 1, 2, 0, 3, 4;
  expect_invalid(validate_triangle_mesh(m.V, m.F),
                 {"vertex 0", "non-manifold", "more than one fan"});
}

TEST(ValidateTest, AcceptsClosedFanAroundVertex) {
  // A closed disc of 6 triangles around a centre vertex: one fan, not two.
  MeshData m;
  m.V.resize(7, 3);
  m.V.row(0) << 0, 0, 0;
  for (int i = 0; i < 6; ++i) m.V.row(i + 1) << std::cos(i * M_PI / 3), std::sin(i * M_PI / 3), 0;
  m.F.resize(6, 3);
  for (int i = 0; i < 6; ++i) m.F.row(i) << 0, 1 + i, 1 + (i + 1) % 6;
  EXPECT_TRUE(validate_triangle_mesh(m.V, m.F).ok());
}

TEST(ValidateTest, RejectsUnreferencedVertex) {
  MeshData m = make_quad();
  m.V.conservativeResize(5, 3);
  m.V.row(4) << 5, 5, 5;
  expect_invalid(validate_triangle_mesh(m.V, m.F), {"vertex 4", "not referenced"});
}

// Triangle soup of the quad: every face has its own three vertices.
MeshData make_quad_soup() {
  const MeshData quad = make_quad();
  MeshData soup;
  soup.V.resize(6, 3);
  soup.F.resize(2, 3);
  for (int f = 0; f < 2; ++f) {
    for (int k = 0; k < 3; ++k) {
      soup.V.row(3 * f + k) = quad.V.row(quad.F(f, k));
      soup.F(f, k) = 3 * f + k;
    }
  }
  return soup;
}

TEST(CleanMeshTest, WeldsExactlyCoincidentVerticesKeepingTheFirst) {
  MeshData soup = make_quad_soup();
  const auto report = clean_mesh(soup, /*weld=*/true);
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  EXPECT_EQ(report->welded_vertices, 2);
  EXPECT_EQ(report->dropped_unreferenced, 0);
  EXPECT_EQ(soup.V.rows(), 4);
  EXPECT_EQ(soup.F.rows(), 2);
  // Soup vertices 3 = (0,1,0) and 4 = (1,0,0) merge into 2 and 1.
  const Eigen::VectorXi expected = (Eigen::VectorXi(6) << 0, 1, 2, 2, 1, 3).finished();
  EXPECT_EQ(report->old_to_new, expected);
  EXPECT_TRUE(validate_triangle_mesh(soup.V, soup.F).ok());
}

TEST(CleanMeshTest, WeldsSignedZeros) {
  MeshData soup = make_quad_soup();
  soup.V(3, 0) = -0.0;  // (−0, 1, 0) equals (0, 1, 0)
  const auto report = clean_mesh(soup, true);
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  EXPECT_EQ(report->welded_vertices, 2);
}

TEST(CleanMeshTest, WithoutWeldASoupIsCleanButNotWelded) {
  MeshData soup = make_quad_soup();
  const auto report = clean_mesh(soup, /*weld=*/false);
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  EXPECT_EQ(report->welded_vertices, 0);
  EXPECT_EQ(soup.V.rows(), 6);
}

TEST(CleanMeshTest, DropsUnreferencedVerticesAndRenumbers) {
  MeshData m = make_quad();
  // Insert an unreferenced vertex at index 1: old 1, 2, 3 move to 2, 3, 4.
  MeshData padded;
  padded.V.resize(5, 3);
  padded.V << 0, 0, 0, 9, 9, 9, 1, 0, 0, 0, 1, 0, 1, 1, 0;
  padded.F.resize(2, 3);
  padded.F << 0, 2, 3, 3, 2, 4;
  const auto report = clean_mesh(padded, false);
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  EXPECT_EQ(report->dropped_unreferenced, 1);
  const Eigen::VectorXi expected = (Eigen::VectorXi(5) << 0, -1, 1, 2, 3).finished();
  EXPECT_EQ(report->old_to_new, expected);
  EXPECT_EQ(padded.V, m.V);
  EXPECT_EQ(padded.F, m.F);
}

TEST(CleanMeshTest, FaceDegenerateAfterWeldingIsAnErrorAndMeshIsUntouched) {
  MeshData m = make_quad();
  m.V.conservativeResize(5, 3);
  m.V.row(4) = m.V.row(1);  // a copy of vertex 1
  m.F.row(1) << 2, 4, 3;    // before welding fine, afterwards still fine: (2, 1, 3)
  m.F.conservativeResize(3, 3);
  m.F.row(2) << 1, 4, 3;  // repeats vertex 1 once 4 is welded onto it
  const MeshData before = m;
  const auto report = clean_mesh(m, true);
  ASSERT_FALSE(report.ok());
  EXPECT_EQ(report.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(report.status().message().find("repeats vertex 1"), std::string::npos)
      << report.status().message();
  EXPECT_EQ(m.V, before.V);
  EXPECT_EQ(m.F, before.F);
}

TEST(CleanMeshTest, ReportsIndexOutOfRangeOnInputNumbering) {
  MeshData m = make_quad();
  m.F(1, 2) = 17;
  const MeshData before = m;
  const auto report = clean_mesh(m, true);
  ASSERT_FALSE(report.ok());
  EXPECT_NE(report.status().message().find("face 1 references vertex 17 (#V=4)"), std::string::npos)
      << report.status().message();
  EXPECT_EQ(m.F, before.F);
}

TEST(CleanMeshTest, NonFiniteVertexIsReportedNotWelded) {
  MeshData m = make_quad();
  m.V(2, 0) = std::numeric_limits<double>::quiet_NaN();
  const auto report = clean_mesh(m, true);
  ASSERT_FALSE(report.ok());
  EXPECT_NE(report.status().message().find("vertex 2 has a non-finite x coordinate"),
            std::string::npos)
      << report.status().message();
}

}  // namespace
}  // namespace meshdeform::core

// One check of a scale control serves the library (no upper bound), the CLI and the service
// (its cap as the upper bound).
TEST(CheckRigidity, AcceptsFiniteValuesInRangeAndRejectsTheRestNamingThem) {
  const double inf = std::numeric_limits<double>::infinity();
  const double nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_TRUE(meshdeform::core::check_rigidity(0).ok());
  EXPECT_TRUE(meshdeform::core::check_rigidity(1e12).ok());
  EXPECT_TRUE(meshdeform::core::check_rigidity(1e4, 1e4).ok());
  for (double bad : {-1e-9, nan, inf, -inf}) {
    const meshdeform::Status status = meshdeform::core::check_rigidity(bad);
    EXPECT_EQ(status.code(), meshdeform::ErrorCode::InvalidArgument) << bad;
    EXPECT_NE(status.message().find("finite number >= 0"), std::string::npos) << status.message();
  }
  const meshdeform::Status capped = meshdeform::core::check_rigidity(2e4, 1e4);
  EXPECT_EQ(capped.code(), meshdeform::ErrorCode::InvalidArgument);
  EXPECT_EQ(capped.message(), "rigidity 20000 is outside [0, 10000]");
  EXPECT_FALSE(meshdeform::core::check_rigidity(nan, 1e4).ok());
}
