// core/methods/similarity.h: the group similarity shared by the service, the edit specs and the client.
#include <cmath>
#include <numbers>

#include <gtest/gtest.h>

#include "core/methods/similarity.h"
#include "core/mesh/topology.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

TEST(SimilarityTest, AppliesScaleRotationAndTranslationAboutTheCentroid) {
  Positions points(3, 3);
  points << 0, 0, 0, 2, 0, 0, 1, 3, 0;
  GroupSimilarity t;
  t.rotation = Eigen::AngleAxisd(std::numbers::pi / 2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  t.scale = 2.0;
  t.translation = Eigen::Vector3d(0, 0, 5);
  const Eigen::Vector3d centroid(1, 1, 0);
  EXPECT_TRUE(similarity_pivot(t, points).isApprox(centroid));
  const Positions moved = apply_similarity(t, points);
  for (Eigen::Index i = 0; i < 3; ++i) {
    const Eigen::Vector3d expected =
        centroid + 2.0 * (t.rotation * (points.row(i).transpose() - centroid)) + t.translation;
    EXPECT_LT((moved.row(i).transpose() - expected).norm(), 1e-12);
  }
  // Distances scale by s, the centroid moves by t only.
  EXPECT_NEAR((moved.row(0) - moved.row(1)).norm(), 4.0, 1e-12);
  EXPECT_TRUE(moved.colwise().mean().transpose().isApprox(centroid + t.translation));
}

TEST(SimilarityTest, MatrixRoundTripAndRefusals) {
  GroupSimilarity t;
  t.rotation = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  t.scale = 1.5;
  t.translation = Eigen::Vector3d(1, -2, 0.5);
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() = t.scale * t.rotation;
  T.topRightCorner<3, 1>() = t.translation;
  const std::optional<GroupSimilarity> back = similarity_from_matrix(T);
  ASSERT_TRUE(back.has_value());
  EXPECT_NEAR(back->scale, 1.5, 1e-12);
  EXPECT_TRUE(back->rotation.isApprox(t.rotation, 1e-12));
  EXPECT_TRUE(back->translation.isApprox(t.translation));
  ASSERT_TRUE(back->pivot.has_value());
  EXPECT_EQ(*back->pivot, Eigen::Vector3d::Zero());
  Positions p = Positions::Random(5, 3);
  const Positions via_matrix = (T.topLeftCorner<3, 3>() * p.transpose()).transpose().rowwise() +
                               T.topRightCorner<3, 1>().transpose();
  EXPECT_LT((apply_similarity(*back, p) - via_matrix).cwiseAbs().maxCoeff(), 1e-12);

  Eigen::Matrix4d shear = Eigen::Matrix4d::Identity();
  shear(0, 1) = 0.3;
  EXPECT_FALSE(similarity_from_matrix(shear).has_value());
  Eigen::Matrix4d mirror = Eigen::Matrix4d::Identity();
  mirror(0, 0) = -1;
  EXPECT_FALSE(similarity_from_matrix(mirror).has_value());
  Eigen::Matrix4d projective = Eigen::Matrix4d::Identity();
  projective(3, 0) = 0.1;
  EXPECT_FALSE(similarity_from_matrix(projective).has_value());
}

TEST(TopologyTest, CountsBoundaryLoops) {
  const MeshData grid = test::make_grid(4, 0.0);  // an open square: one loop
  EXPECT_EQ(count_boundary_loops(grid.F, static_cast<int>(grid.V.rows())), 1);
  Triangles tetra(4, 3);  // closed: none
  tetra << 0, 2, 1, 0, 1, 3, 1, 2, 3, 0, 3, 2;
  EXPECT_EQ(count_boundary_loops(tetra, 4), 0);
  Triangles strip(2, 3);  // two triangles sharing an edge: one loop of four edges
  strip << 0, 1, 2, 2, 1, 3;
  EXPECT_EQ(count_boundary_loops(strip, 4), 1);
}

}  // namespace
}  // namespace meshdeform::core
