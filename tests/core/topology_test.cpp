#include "core/topology.h"

#include <gtest/gtest.h>

#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

TEST(Topology, ClosedSphereHasOnlyInteriorEdges) {
  const MeshData m = test::make_icosphere(2);
  auto t = build_topology(m.F, int(m.V.rows()));
  ASSERT_TRUE(t.ok());
  EXPECT_EQ(t->boundary_edge_count, 0);
  EXPECT_EQ(t->interior_edges.rows(), 3 * m.F.rows() / 2);
  EXPECT_EQ(t->component_count, 1);
  // Euler: V - E + F = 2.
  EXPECT_EQ(m.V.rows() - t->interior_edges.rows() + m.F.rows(), 2);
  for (int v = 0; v < t->vertex_count; ++v) {
    EXPECT_EQ(t->vv_offsets[v + 1] - t->vv_offsets[v], t->vf_offsets[v + 1] - t->vf_offsets[v]);
  }
}

TEST(Topology, GridBoundaryAndComponents) {
  const int n = 5;
  MeshData m = test::make_grid(n);
  auto t = build_topology(m.F, int(m.V.rows()));
  ASSERT_TRUE(t.ok());
  EXPECT_EQ(t->boundary_edge_count, 4 * n);
  MeshData two = m;
  two.V.conservativeResize(2 * m.V.rows(), 3);
  two.V.bottomRows(m.V.rows()) = m.V;
  two.F.conservativeResize(2 * m.F.rows(), 3);
  two.F.bottomRows(m.F.rows()) = m.F.array() + int(m.V.rows());
  auto t2 = build_topology(two.F, int(two.V.rows()));
  ASSERT_TRUE(t2.ok());
  EXPECT_EQ(t2->component_count, 2);
  EXPECT_EQ(t2->component(0), 0);
  EXPECT_EQ(t2->component(int(m.V.rows())), 1);
}

TEST(Topology, ReportsTheFirstBadElement) {
  Triangles F(2, 3);
  F << 0, 1, 2, 0, 2, 9;
  auto r = build_topology(F, 4);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().message(), "face 1 references vertex 9 (#V=4)");

  Triangles fan(3, 3);  // three faces on edge (0,1)
  fan << 0, 1, 2, 1, 0, 3, 0, 1, 4;
  auto nm = build_topology(fan, 5);
  ASSERT_FALSE(nm.ok());
  EXPECT_NE(nm.status().message().find("edge (0, 1) is non-manifold"), std::string::npos);
}

}  // namespace
}  // namespace meshdeform::core
