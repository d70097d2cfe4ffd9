#include "core/mesh/measures.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include <Eigen/Geometry>

#include "core/mesh/fast_angle.h"
#include "core/mesh/topology.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

// Two right triangles sharing the edge (0,1)-(0,0)... folded along x = 0 by `fold` radians.
MeshData hinge(double fold) {
  MeshData m;
  m.V.resize(4, 3);
  m.V << 0, 0, 0,  //
      0, 1, 0,     //
      1, 0, 0,     //
      -std::cos(fold), 0, std::sin(fold);
  m.F.resize(2, 3);
  m.F << 0, 2, 1,  //
      0, 1, 3;
  return m;
}

TEST(Measures, CornerAnglesAndRatiosOfARightTriangle) {
  const MeshData t = test::make_triangle();
  auto topo = build_topology(t.F, 3);
  ASSERT_TRUE(topo.ok());
  const Measures m = compute_measures(t.V, t.F, *topo);
  EXPECT_NEAR(m.theta(0), M_PI / 2, 1e-15);
  EXPECT_NEAR(m.theta(1), M_PI / 4, 1e-15);
  EXPECT_NEAR(m.theta(2), M_PI / 4, 1e-15);
  EXPECT_NEAR(m.theta.sum(), M_PI, 1e-14);
  EXPECT_NEAR(m.ratio(0), 1.0, 1e-15);                 // |c-a| / |b-a|
  EXPECT_NEAR(m.ratio(1), 1.0 / std::sqrt(2.0), 1e-15);  // |a-b| / |c-b|
  EXPECT_NEAR(m.area(0), 0.5, 1e-15);
  EXPECT_EQ(m.phi.size(), 0);
}

TEST(Measures, DihedralAngleOfAHinge) {
  for (double fold : {0.0, 0.3, M_PI / 2, 2.5}) {
    const MeshData h = hinge(fold);
    auto topo = build_topology(h.F, 4);
    ASSERT_TRUE(topo.ok());
    ASSERT_EQ(topo->interior_edges.rows(), 1);
    const Measures m = compute_measures(h.V, h.F, *topo);
    EXPECT_NEAR(m.phi(0), fold, 1e-12) << "fold " << fold;
  }
}

TEST(Measures, FoldsAreDihedralChangesPastNinetyDegrees) {
  const MeshData flat = hinge(0.0);
  auto topo = build_topology(flat.F, 4);
  ASSERT_TRUE(topo.ok());
  const Eigen::VectorXd rest = dihedral_angles(flat.V, flat.F, *topo);
  EXPECT_EQ(rest, compute_measures(flat.V, flat.F, *topo).phi);
  for (double fold : {0.0, 0.3, 1.5, 1.6, 2.5, 3.1}) {
    const MeshData bent = hinge(fold);
    const Eigen::VectorXd phi = dihedral_angles(bent.V, bent.F, *topo);
    EXPECT_NEAR(phi(0), fold, 1e-12);
    EXPECT_EQ(count_folds(rest, phi), fold > M_PI / 2 ? 1 : 0) << "fold " << fold;
    // Measured from the rest: a hinge that rests folded unfolds by more than 90 degrees too.
    EXPECT_EQ(count_folds(phi, rest), fold > M_PI / 2 ? 1 : 0) << "fold " << fold;
  }
  // A rigid motion and a uniform scale fold nothing.
  const MeshData sharp = hinge(2.5);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(2.0, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  const Positions moved = (3.0 * sharp.V * R.transpose()).rowwise() + Eigen::RowVector3d(1, 2, 3);
  EXPECT_EQ(count_folds(dihedral_angles(sharp.V, sharp.F, *topo),
                        dihedral_angles(moved, sharp.F, *topo)),
            0);
}

TEST(Measures, ErrorsOfHandComputedCases) {
  const MeshData flat = hinge(0.0), bent = hinge(0.4);
  auto topo = build_topology(flat.F, 4);
  ASSERT_TRUE(topo.ok());
  const Measures a = compute_measures(flat.V, flat.F, *topo);
  const Measures b = compute_measures(bent.V, bent.F, *topo);
  const AngleErrors e = angle_errors(a, b);
  EXPECT_NEAR(e.e_phi, 0.4, 1e-12);   // one interior edge, off by 0.4
  EXPECT_NEAR(e.e_theta, 0.0, 1e-12);  // folding keeps every corner
  EXPECT_NEAR(e.area_log_rms, 0.0, 1e-12);

  // Stretch x by 2 on a single triangle: corners become atan(1/2)... checked against atan2.
  MeshData t = test::make_triangle();
  MeshData s = t;
  s.V.col(0) *= 2.0;
  auto tt = build_topology(t.F, 3);
  const Measures m0 = compute_measures(t.V, t.F, *tt), m1 = compute_measures(s.V, s.F, *tt);
  const double d1 = M_PI / 4 - std::atan2(1.0, 2.0), d2 = M_PI / 4 - std::atan2(2.0, 1.0);
  EXPECT_NEAR(angle_errors(m0, m1).e_theta, std::sqrt((d1 * d1 + d2 * d2) / 3.0), 1e-14);
  EXPECT_NEAR(angle_errors(m0, m1).area_log_rms, std::log(2.0), 1e-14);
}

TEST(Measures, AreInvariantUnderSimilarity) {
  const MeshData m = test::make_icosphere(2);
  auto topo = build_topology(m.F, int(m.V.rows()));
  ASSERT_TRUE(topo.ok());
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(1.1, Eigen::Vector3d(0.2, -1, 0.4).normalized()).toRotationMatrix();
  const Positions W = ((3.5 * m.V * R.transpose()).rowwise() + Eigen::RowVector3d(1, 2, 3)).eval();
  const Measures a = compute_measures(m.V, m.F, *topo), b = compute_measures(W, m.F, *topo);
  EXPECT_LT((a.theta - b.theta).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((a.ratio - b.ratio).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((a.phi - b.phi).cwiseAbs().maxCoeff(), 1e-12);
  const Distortion d = local_distortion(a, b, m.F, *topo);
  EXPECT_LT(d.per_vertex.maxCoeff(), 1e-12);
  EXPECT_LT(d.per_face.maxCoeff(), 1e-12);
}

TEST(Measures, SeveralThreadsGiveTheSameValues) {
  // 101 x 101 bumpy grid, 20,000 faces: above the size where the loops go parallel.
  MeshData mesh = test::make_grid(100, 0.05);
  for (Eigen::Index v = 0; v < mesh.V.rows(); ++v) mesh.V(v, 2) += 0.01 * std::sin(7.0 * v);
  const MeshTopology topology = *build_topology(mesh.F, static_cast<int>(mesh.V.rows()));
  const Measures one = compute_measures(mesh.V, mesh.F, topology);
  const Measures two = compute_measures(mesh.V, mesh.F, topology, 2);
  EXPECT_EQ(one.theta, two.theta);
  EXPECT_EQ(one.ratio, two.ratio);
  EXPECT_EQ(one.area, two.area);
  EXPECT_EQ(one.phi, two.phi);
  EXPECT_EQ(one.phi, dihedral_angles(mesh.V, mesh.F, topology, 2));
  EXPECT_GT(one.phi.cwiseAbs().maxCoeff(), 0.0);
}

TEST(Measures, BatchedAtan2IsWithinTwoUlpOfStdAtan2) {
  // Every octant's branch (swap, reduction past 0.66, second quadrant), tiny and huge ratios,
  // zeros, and the exact angles 0, pi/4, pi/2, 3pi/4 and pi.
  std::vector<double> y = {0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 1e-300, 1e300, 1e-20, 5.0, 0.66, 0.67};
  std::vector<double> x = {1.0, -1.0, -0.0, 0.0, 1.0, -1.0, 1e-300, 1.0, -1.0, -1.0, 3.0, 1.0, -1.0};
  std::mt19937_64 engine(7);
  std::uniform_real_distribution<double> unit(-1.0, 1.0);
  for (int i = 0; i < 200000; ++i) {
    const double scale = std::pow(10.0, 6.0 * unit(engine));
    y.push_back(std::abs(unit(engine)) * (i % 5 == 0 ? 1e-9 : 1.0));
    x.push_back(unit(engine) * scale);
  }
  const std::ptrdiff_t n = static_cast<std::ptrdiff_t>(y.size());
  std::vector<double> out(y.size());
  atan2_nonnegative(y.data(), x.data(), out.data(), n);
  double worst_ulp = 0;
  EXPECT_EQ(out[2], 0.0) << "atan2(0, -0) is 0 here (std::atan2: pi), as documented";
  for (std::ptrdiff_t i = 3; i < n; ++i) {
    const double want = std::atan2(y[i], x[i]);
    const double ulp = std::nextafter(want, 4.0) - want;
    ASSERT_LE(std::abs(out[i] - want), 2.0 * ulp + 1e-300)
        << "atan2(" << y[i] << ", " << x[i] << ") = " << want << ", got " << out[i];
    worst_ulp = std::max(worst_ulp, std::abs(out[i] - want) / ulp);
  }
  EXPECT_EQ(out[0], 0.0);
  EXPECT_NEAR(out[1], M_PI, 1e-15);
  EXPECT_EQ(out[4], M_PI / 4);
  EXPECT_EQ(out[3], M_PI / 2);
  EXPECT_GT(worst_ulp, 0.0) << "not an approximation: the test would not see one";
  // In place, as compute_measures calls it.
  std::vector<double> in_place = x;
  atan2_nonnegative(y.data(), in_place.data(), in_place.data(), n);
  EXPECT_EQ(in_place, out);
}

TEST(Measures, FusedErrorsEqualTheErrorsOfTheMeasuresAtAnyThreadCount) {
  // 101 x 101 grid, 20,000 faces (above the parallel size), bent and stretched unevenly.
  const MeshData rest = test::make_grid(100, 0.05);
  MeshData deformed = rest;
  for (Eigen::Index v = 0; v < deformed.V.rows(); ++v) {
    deformed.V(v, 2) += 0.02 * std::sin(7.0 * v) + 0.3 * deformed.V(v, 0) * deformed.V(v, 0);
    deformed.V(v, 1) *= 1.0 + 0.5 * deformed.V(v, 0);
  }
  const MeshTopology topology = *build_topology(rest.F, static_cast<int>(rest.V.rows()));
  const Measures rest_measures = compute_measures(rest.V, rest.F, topology);
  const AngleErrors want =
      angle_errors(rest_measures, compute_measures(deformed.V, deformed.F, topology));
  ASSERT_GT(want.e_theta, 1e-3);
  ASSERT_GT(want.e_phi, 1e-3);
  ASSERT_GT(want.area_log_rms, 1e-3);
  const AngleErrors one = angle_errors(rest_measures, deformed.V, deformed.F, topology);
  const AngleErrors two = angle_errors(rest_measures, deformed.V, deformed.F, topology, 2);
  EXPECT_NEAR(one.e_theta, want.e_theta, 1e-12 * want.e_theta);
  EXPECT_NEAR(one.e_phi, want.e_phi, 1e-12 * want.e_phi);
  EXPECT_NEAR(one.area_log_rms, want.area_log_rms, 1e-12 * want.area_log_rms);
  EXPECT_EQ(one.e_theta, two.e_theta);
  EXPECT_EQ(one.e_phi, two.e_phi);
  EXPECT_EQ(one.area_log_rms, two.area_log_rms);
  // The rest against itself: zero.
  const AngleErrors none = angle_errors(rest_measures, rest.V, rest.F, topology, 2);
  EXPECT_EQ(none.e_theta, 0.0);
  EXPECT_EQ(none.e_phi, 0.0);
  EXPECT_EQ(none.area_log_rms, 0.0);
}

TEST(Measures, LocalDistortionLocatesTheChange) {
  MeshData m = test::make_grid(6);
  auto topo = build_topology(m.F, int(m.V.rows()));
  ASSERT_TRUE(topo.ok());
  MeshData moved = m;
  moved.V(24, 2) += 0.2;  // one interior vertex lifted
  const Distortion d = local_distortion(compute_measures(m.V, m.F, *topo),
                                        compute_measures(moved.V, m.F, *topo), m.F, *topo);
  Eigen::Index worst = 0;
  d.per_vertex.maxCoeff(&worst);
  EXPECT_EQ(worst, 24);
  EXPECT_EQ(d.per_vertex(0), 0.0);  // far corner untouched
}

}  // namespace
}  // namespace meshdeform::core
