#pragma once
/// @file edge_table.h
/// Internal to core: the half-edges of a triangle list grouped by undirected edge, in O(#F)
/// (a counting sort by the smaller vertex, then the few half-edges of each vertex by the larger
/// one), for validate_triangle_mesh and build_topology. At 187k vertices this replaced a hash map
/// and a sort of 1.1 million tuples that took most of the 0.66 s those two spent per session.

#include <vector>

#include "core/mesh/mesh_data.h"

namespace meshdeform::core {

/// Corner c = 3 f + k is the half-edge from F(f, k) to F(f, (k + 1) % 3).
struct EdgeTable {
  /// The undirected edges' vertices, lo < hi, sorted by (lo, hi).
  std::vector<int> lo, hi;
  /// The half-edges of edge e are corners[offsets[e] .. offsets[e + 1]), in ascending corner
  /// order (so by face).
  std::vector<int> offsets, corners;
  /// Edge of each corner (3 #F).
  std::vector<int> edge_of;
  int edge_count() const { return static_cast<int>(lo.size()); }
  int half_edge_count(int e) const { return offsets[e + 1] - offsets[e]; }
};

/// Builds the table. @pre every index of F is in [0, vertex_count) and no face repeats a vertex.
EdgeTable build_edge_table(const Triangles& F, int vertex_count);

}  // namespace meshdeform::core
