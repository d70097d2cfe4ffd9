#include "core/mesh/topology.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <numeric>
#include <random>
#include <vector>

#include "core/mesh/edge_table.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

// The edge table against its definition: every half-edge sorted by (min, max, corner), grouped.
void expect_edge_table_matches_sort(const Triangles& F, int vertex_count) {
  const EdgeTable t = build_edge_table(F, vertex_count);
  std::vector<std::array<int, 3>> half;  // min, max, corner
  for (int f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int a = F(f, k), b = F(f, (k + 1) % 3);
      half.push_back({std::min(a, b), std::max(a, b), 3 * f + k});
    }
  }
  std::sort(half.begin(), half.end());
  std::vector<int> lo, hi, offsets, corners, edge_of(half.size());
  for (std::size_t i = 0; i < half.size(); ++i) {
    if (i == 0 || half[i][0] != half[i - 1][0] || half[i][1] != half[i - 1][1]) {
      offsets.push_back(static_cast<int>(i));
      lo.push_back(half[i][0]);
      hi.push_back(half[i][1]);
    }
    corners.push_back(half[i][2]);
    edge_of[static_cast<std::size_t>(half[i][2])] = static_cast<int>(lo.size()) - 1;
  }
  offsets.push_back(static_cast<int>(half.size()));
  EXPECT_EQ(t.lo, lo);
  EXPECT_EQ(t.hi, hi);
  EXPECT_EQ(t.offsets, offsets);
  EXPECT_EQ(t.corners, corners);
  EXPECT_EQ(t.edge_of, edge_of);
}

TEST(Topology, EdgeTableGroupsHalfEdgesAsASortOfAllOfThemWould) {
  expect_edge_table_matches_sort(test::make_icosphere(2).F, 162);
  const MeshData grid = test::make_grid(6);
  expect_edge_table_matches_sort(grid.F, static_cast<int>(grid.V.rows()));
  // A fan of 300 triangles around vertex 0 (past the insertion sort), spokes in shuffled order,
  // and 5 extra faces on one edge (non-manifold: the table groups them, callers report them).
  std::vector<int> rim(301);
  std::iota(rim.begin(), rim.end(), 1);
  std::shuffle(rim.begin(), rim.end(), std::mt19937(5));
  Triangles fan(305, 3);
  for (int i = 0; i < 300; ++i) {
    fan.row(i) << 0, rim[static_cast<std::size_t>(i)], rim[static_cast<std::size_t>(i) + 1];
  }
  for (int i = 0; i < 5; ++i) fan.row(300 + i) << 302 + i, rim[7], 0;
  expect_edge_table_matches_sort(fan, 307);
  // The fan's topology: vertex 0's neighbours sorted, each edge once.
  Triangles manifold_fan = fan.topRows(300);
  auto t = build_topology(manifold_fan, 302);
  ASSERT_TRUE(t.ok()) << t.status().to_string();
  std::vector<int> around(t->vv_neighbors.begin() + t->vv_offsets[0],
                          t->vv_neighbors.begin() + t->vv_offsets[1]);
  std::vector<int> want(301);
  std::iota(want.begin(), want.end(), 1);
  EXPECT_EQ(around, want);
  EXPECT_EQ(t->interior_edges.rows(), 299);
  EXPECT_EQ(t->boundary_edge_count, 302);
}

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
