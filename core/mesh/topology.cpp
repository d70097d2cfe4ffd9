#include "core/mesh/topology.h"

#include <algorithm>
#include <array>
#include <numeric>
#include <string>

#include "core/mesh/edge_table.h"

namespace meshdeform::core {
namespace {

int find_root(std::vector<int>& parent, int x) {
  while (parent[x] != x) {
    parent[x] = parent[parent[x]];
    x = parent[x];
  }
  return x;
}

}  // namespace

Result<MeshTopology> build_topology(const Triangles& F, int vertex_count) {
  MeshTopology t;
  t.vertex_count = vertex_count;
  t.face_count = static_cast<int>(F.rows());
  for (int f = 0; f < t.face_count; ++f) {
    for (int k = 0; k < 3; ++k) {
      if (F(f, k) < 0 || F(f, k) >= vertex_count) {
        return Error(ErrorCode::InvalidArgument,
                     "face " + std::to_string(f) + " references vertex " + std::to_string(F(f, k)) +
                         " (#V=" + std::to_string(vertex_count) + ")");
      }
    }
    if (F(f, 0) == F(f, 1) || F(f, 1) == F(f, 2) || F(f, 2) == F(f, 0)) {
      return Error(ErrorCode::InvalidArgument,
                   "face " + std::to_string(f) + " repeats a vertex (" + std::to_string(F(f, 0)) +
                       ", " + std::to_string(F(f, 1)) + ", " + std::to_string(F(f, 2)) + ")");
    }
  }

  // Edges sorted by (min, max), each with its faces in ascending order.
  const EdgeTable edges = build_edge_table(F, vertex_count);
  std::vector<std::array<int, 4>> interior;  // i, j, f0, f1
  interior.reserve(static_cast<std::size_t>(edges.edge_count()));
  for (int e = 0; e < edges.edge_count(); ++e) {
    const int count = edges.half_edge_count(e);
    const int f0 = edges.corners[static_cast<std::size_t>(edges.offsets[e])] / 3;
    if (count > 2) {
      return Error(ErrorCode::InvalidArgument,
                   "edge (" + std::to_string(edges.lo[e]) + ", " + std::to_string(edges.hi[e]) +
                       ") is non-manifold: " + std::to_string(count) +
                       " faces share it (first: face " + std::to_string(f0) + ")");
    }
    if (count == 2) {
      const int f1 = edges.corners[static_cast<std::size_t>(edges.offsets[e]) + 1] / 3;
      interior.push_back({edges.lo[e], edges.hi[e], f0, f1});
    } else {
      ++t.boundary_edge_count;
    }
  }
  const int ne = static_cast<int>(interior.size());
  t.interior_edges.resize(ne, 2);
  t.edge_faces.resize(ne, 2);
  for (int e = 0; e < ne; ++e) {
    t.interior_edges.row(e) << interior[e][0], interior[e][1];
    t.edge_faces.row(e) << interior[e][2], interior[e][3];
  }

  // Vertex -> faces: a counting sort of the corners, faces ascending.
  const auto nvs = static_cast<std::size_t>(vertex_count);
  t.vf_offsets.assign(nvs + 1, 0);
  for (int f = 0; f < t.face_count; ++f) {
    for (int k = 0; k < 3; ++k) ++t.vf_offsets[static_cast<std::size_t>(F(f, k)) + 1];
  }
  std::partial_sum(t.vf_offsets.begin(), t.vf_offsets.end(), t.vf_offsets.begin());
  t.vf_faces.resize(static_cast<std::size_t>(3 * t.face_count));
  std::vector<int> fill(t.vf_offsets.begin(), t.vf_offsets.end() - 1);
  for (int f = 0; f < t.face_count; ++f) {
    for (int k = 0; k < 3; ++k) {
      t.vf_faces[static_cast<std::size_t>(fill[static_cast<std::size_t>(F(f, k))]++)] = f;
    }
  }
  // Vertex -> neighbours from the sorted edges: a vertex v meets its smaller neighbours (edges
  // (u, v), u < v) before its larger ones (edges (v, w)), each group ascending: sorted lists.
  t.vv_offsets.assign(nvs + 1, 0);
  for (int e = 0; e < edges.edge_count(); ++e) {
    ++t.vv_offsets[static_cast<std::size_t>(edges.lo[e]) + 1];
    ++t.vv_offsets[static_cast<std::size_t>(edges.hi[e]) + 1];
  }
  std::partial_sum(t.vv_offsets.begin(), t.vv_offsets.end(), t.vv_offsets.begin());
  t.vv_neighbors.resize(static_cast<std::size_t>(t.vv_offsets.back()));
  fill.assign(t.vv_offsets.begin(), t.vv_offsets.end() - 1);
  for (int e = 0; e < edges.edge_count(); ++e) {
    const int a = edges.lo[e], b = edges.hi[e];
    t.vv_neighbors[static_cast<std::size_t>(fill[static_cast<std::size_t>(a)]++)] = b;
    t.vv_neighbors[static_cast<std::size_t>(fill[static_cast<std::size_t>(b)]++)] = a;
  }

  std::vector<int> parent(nvs);
  std::iota(parent.begin(), parent.end(), 0);
  for (int f = 0; f < t.face_count; ++f) {
    for (int k = 0; k < 3; ++k) {
      parent[find_root(parent, F(f, k))] = find_root(parent, F(f, (k + 1) % 3));
    }
  }

  // Component ids in order of first appearance, so they are deterministic.
  t.component.setConstant(vertex_count, -1);
  std::vector<int> root_id(vertex_count, -1);
  for (int v = 0; v < vertex_count; ++v) {
    const int r = find_root(parent, v);
    if (root_id[r] < 0) root_id[r] = t.component_count++;
    t.component(v) = root_id[r];
  }
  return t;
}

int count_boundary_loops(const Triangles& F, int vertex_count) {
  std::unordered_map<long long, int> undirected;
  auto key = [vertex_count](int a, int b) {
    return static_cast<long long>(std::min(a, b)) * vertex_count + std::max(a, b);
  };
  for (int f = 0; f < F.rows(); ++f)
    for (int k = 0; k < 3; ++k) ++undirected[key(F(f, k), F(f, (k + 1) % 3))];
  std::vector<int> next(static_cast<std::size_t>(vertex_count), -1);
  for (int f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int a = F(f, k), b = F(f, (k + 1) % 3);
      if (undirected[key(a, b)] == 1) next[static_cast<std::size_t>(a)] = b;
    }
  }
  int loops = 0;
  std::vector<char> seen(next.size(), 0);
  for (std::size_t start = 0; start < next.size(); ++start) {
    if (next[start] < 0 || seen[start]) continue;
    ++loops;
    for (int v = static_cast<int>(start); v >= 0 && !seen[static_cast<std::size_t>(v)];
         v = next[static_cast<std::size_t>(v)]) {
      seen[static_cast<std::size_t>(v)] = 1;
    }
  }
  return loops;
}

}  // namespace meshdeform::core
