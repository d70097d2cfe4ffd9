// Optimal rigidity approximation and magnification (paper Section 5.3, Figs. 12-13).
#include "core/methods/ora.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "core/mesh/measures.h"
#include "core/methods/scale_aware.h"
#include "core/mesh/topology.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

const auto& rows_of = test::gather_rows;

double edge_length(const Positions& V, int a, int b) { return (V.row(a) - V.row(b)).norm(); }

TEST(Ora, ScaleFactorsAreAreaRatios) {
  const MeshData m = test::make_icosphere(1);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(0.7, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const Positions W = (3.0 * m.V * R.transpose()).eval();
  const Eigen::VectorXd sigma = triangle_scale_factors(m.V, W, m.F);
  ASSERT_EQ(sigma.size(), m.F.rows());
  EXPECT_LT((sigma.array() - 9.0).abs().maxCoeff(), 1e-12);
}

TEST(Ora, UniformlyScaledMeshComesBackToItsOriginalSize) {
  // A rotated copy at twice the size, with one vertex held at its rest position: the constraints
  // allow the original size, so every triangle must get its rest area back.
  const MeshData m = test::make_icosphere(2);
  Eigen::VectorXi constrained(1);
  constrained << 0;
  auto stitcher = RigidityStitcher::create(m.V, m.F, constrained);
  ASSERT_TRUE(stitcher.ok()) << stitcher.status().to_string();
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(1.2, Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix();
  const Positions big = ((2.0 * (m.V.rowwise() - m.V.row(0))) * R.transpose()).rowwise() +
                        m.V.row(0);
  auto result = stitcher->stitch(big, rows_of(m.V, constrained));
  ASSERT_TRUE(result.ok()) << result.status().to_string();
  const Eigen::VectorXd sigma = triangle_scale_factors(m.V, *result, m.F);
  EXPECT_LT((sigma.array() - 1.0).abs().maxCoeff(), 1e-9);
  // And it is the rotated copy at rest size, anchored at vertex 0.
  const Positions expected = ((m.V.rowwise() - m.V.row(0)) * R.transpose()).rowwise() + m.V.row(0);
  EXPECT_LT((*result - expected).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(Ora, ThroughTheSolverItTradesAngleErrorForArea) {
  // Stretch a bumpy strip: the scale-aware result grows its details; ORA brings areas back.
  auto [m, constrained, targets] = test::make_strip_edit(16);
  for (Eigen::Index j = 1; j < targets.rows(); j += 2) targets(j, 0) += 0.6;  // pull right side
  auto solver = ScaleAwareSolver::create(m.V, m.F, constrained);
  ASSERT_TRUE(solver.ok());
  SolveOptions options;
  options.ora = true;
  auto report = solver->solve(targets, options);
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  ASSERT_TRUE(report->stitch.applied);
  EXPECT_LT(report->stitch.area_after, report->stitch.area_before);
  EXPECT_GT(report->stitch.area_before, 0.05);
  // The solver's history ends at the pre-ORA result; report.V is the stitched one.
  EXPECT_NEAR(report->history.back().e_theta, report->stitch.e_theta_before, 1e-12);
  EXPECT_EQ(solver->positions(), report->V);
}

// Open tube along z: `rings` rings of `segments` vertices, radius 1, ring spacing 0.3.
MeshData make_tube(int rings, int segments) {
  MeshData m;
  m.V.resize(rings * segments, 3);
  for (int r = 0; r < rings; ++r) {
    for (int s = 0; s < segments; ++s) {
      const double t = 2.0 * M_PI * s / segments;
      m.V.row(r * segments + s) << std::cos(t), std::sin(t), 0.3 * r;
    }
  }
  m.F.resize(2 * (rings - 1) * segments, 3);
  int f = 0;
  for (int r = 0; r + 1 < rings; ++r) {
    for (int s = 0; s < segments; ++s) {
      const int a = r * segments + s, b = r * segments + (s + 1) % segments;
      const int c = a + segments, d = b + segments;
      m.F.row(f++) << a, b, d;
      m.F.row(f++) << a, d, c;
    }
  }
  return m;
}

TEST(Ora, MagnifyingAProtrudingRegionScalesItsEdgesByAboutK) {
  // The top of a tube (like the paper's head or tail) magnified by k with the bottom ring fixed:
  // away from the seam, its edges grow by k and the rest keeps its size.
  const int rings = 24, segments = 16;
  const MeshData m = make_tube(rings, segments);
  std::vector<int> top;
  for (int v = 12 * segments; v < rings * segments; ++v) top.push_back(v);
  MagnifyRegion region;
  region.vertices = Eigen::Map<Eigen::VectorXi>(top.data(), int(top.size()));
  Eigen::VectorXi constrained(segments);
  for (int s = 0; s < segments; ++s) constrained(s) = s;
  auto stitcher = RigidityStitcher::create(m.V, m.F, constrained);
  ASSERT_TRUE(stitcher.ok());
  for (double k : {1.5, 2.0, 3.0}) {
    SCOPED_TRACE(k);
    region.scale = k;
    auto scales = face_scales_from_regions({region}, m.F, int(m.V.rows()));
    ASSERT_TRUE(scales.ok()) << scales.status().to_string();
    auto result = stitcher->stitch(m.V, rows_of(m.V, constrained), *scales);
    ASSERT_TRUE(result.ok());
    auto ring_edge_ratio = [&](int r) {
      double sum = 0;
      for (int s = 0; s < segments; ++s) {
        const int a = r * segments + s, b = r * segments + (s + 1) % segments;
        sum += edge_length(*result, a, b) / edge_length(m.V, a, b);
      }
      return sum / segments;
    };
    EXPECT_NEAR(ring_edge_ratio(rings - 2), k, 0.1 * k);  // deep in the region
    EXPECT_NEAR(ring_edge_ratio(2), 1.0, 0.1);             // deep outside it
  }
}

TEST(Ora, BadRegionsAreRejected) {
  const MeshData m = test::make_grid(4);
  MagnifyRegion bad_scale;
  bad_scale.faces = Eigen::VectorXi::Constant(1, 0);
  bad_scale.scale = 0.0;
  auto r1 = face_scales_from_regions({bad_scale}, m.F, int(m.V.rows()));
  ASSERT_FALSE(r1.ok());
  EXPECT_NE(r1.status().message().find("magnify region 0: scale must be positive"),
            std::string::npos);

  MagnifyRegion empty;
  empty.scale = 2.0;
  auto r2 = face_scales_from_regions({empty}, m.F, int(m.V.rows()));
  ASSERT_FALSE(r2.ok());
  EXPECT_NE(r2.status().message().find("is empty"), std::string::npos);

  MagnifyRegion lonely;  // one vertex covers no whole face
  lonely.vertices = Eigen::VectorXi::Constant(1, 6);
  lonely.scale = 2.0;
  EXPECT_FALSE(face_scales_from_regions({lonely}, m.F, int(m.V.rows())).ok());

  MagnifyRegion out_of_range;
  out_of_range.vertices = Eigen::VectorXi::Constant(1, 99);
  out_of_range.scale = 2.0;
  auto r3 = face_scales_from_regions({empty, out_of_range}, m.F, int(m.V.rows()));
  ASSERT_FALSE(r3.ok());  // the first bad region is reported
  EXPECT_NE(r3.status().message().find("region 0"), std::string::npos);
  auto r4 = face_scales_from_regions({out_of_range}, m.F, int(m.V.rows()));
  ASSERT_FALSE(r4.ok());
  EXPECT_NE(r4.status().message().find("vertex 99 out of range (#V=25)"), std::string::npos);

  // And through the solver: a face_scale of the wrong length or sign.
  Eigen::VectorXi c(2);
  c << 0, 24;
  auto solver = ScaleAwareSolver::create(m.V, m.F, c);
  ASSERT_TRUE(solver.ok());
  SolveOptions options;
  options.face_scale = Eigen::VectorXd::Ones(3);
  EXPECT_EQ(solver->solve(rows_of(m.V, c), options).status().code(), ErrorCode::InvalidArgument);
  options.face_scale = Eigen::VectorXd::Ones(m.F.rows());
  options.face_scale(4) = -1;
  auto negative = solver->solve(rows_of(m.V, c), options);
  ASSERT_FALSE(negative.ok());
  EXPECT_NE(negative.status().message().find("face 4"), std::string::npos);
}

}  // namespace
}  // namespace meshdeform::core
