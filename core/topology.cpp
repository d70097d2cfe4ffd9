#include "core/topology.h"

#include <algorithm>
#include <array>
#include <numeric>
#include <string>
#include <tuple>

namespace meshdeform::core {
namespace {

int find_root(std::vector<int>& parent, int x) {
  while (parent[x] != x) {
    parent[x] = parent[parent[x]];
    x = parent[x];
  }
  return x;
}

// CSR from (key, value) pairs sorted by key then value.
void build_csr(std::vector<std::pair<int, int>>& pairs, int n, std::vector<int>& offsets,
               std::vector<int>& values) {
  std::sort(pairs.begin(), pairs.end());
  pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
  offsets.assign(n + 1, 0);
  for (const auto& [k, v] : pairs) ++offsets[k + 1];
  std::partial_sum(offsets.begin(), offsets.end(), offsets.begin());
  values.resize(pairs.size());
  for (size_t i = 0; i < pairs.size(); ++i) values[i] = pairs[i].second;
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

  // Edges as (min, max, face), sorted: runs of equal (min, max) are one edge.
  std::vector<std::tuple<int, int, int>> half;
  half.reserve(3 * t.face_count);
  for (int f = 0; f < t.face_count; ++f) {
    for (int k = 0; k < 3; ++k) {
      const int a = F(f, k), b = F(f, (k + 1) % 3);
      half.emplace_back(std::min(a, b), std::max(a, b), f);
    }
  }
  std::sort(half.begin(), half.end());
  std::vector<std::array<int, 4>> interior;  // i, j, f0, f1
  for (size_t s = 0; s < half.size();) {
    size_t e = s + 1;
    while (e < half.size() && std::get<0>(half[e]) == std::get<0>(half[s]) &&
           std::get<1>(half[e]) == std::get<1>(half[s])) {
      ++e;
    }
    const auto [i, j, f0] = half[s];
    if (e - s > 2) {
      return Error(ErrorCode::InvalidArgument,
                   "edge (" + std::to_string(i) + ", " + std::to_string(j) + ") is non-manifold: " +
                       std::to_string(e - s) + " faces share it (first: face " +
                       std::to_string(f0) + ")");
    }
    if (e - s == 2) {
      interior.push_back({i, j, f0, std::get<2>(half[s + 1])});
    } else {
      ++t.boundary_edge_count;
    }
    s = e;
  }
  const int ne = static_cast<int>(interior.size());
  t.interior_edges.resize(ne, 2);
  t.edge_faces.resize(ne, 2);
  for (int e = 0; e < ne; ++e) {
    t.interior_edges.row(e) << interior[e][0], interior[e][1];
    t.edge_faces.row(e) << interior[e][2], interior[e][3];
  }

  std::vector<std::pair<int, int>> vf, vv;
  vf.reserve(3 * t.face_count);
  vv.reserve(6 * t.face_count);
  std::vector<int> parent(vertex_count);
  std::iota(parent.begin(), parent.end(), 0);
  for (int f = 0; f < t.face_count; ++f) {
    for (int k = 0; k < 3; ++k) {
      const int a = F(f, k), b = F(f, (k + 1) % 3);
      vf.emplace_back(a, f);
      vv.emplace_back(a, b);
      vv.emplace_back(b, a);
      parent[find_root(parent, a)] = find_root(parent, b);
    }
  }
  build_csr(vf, vertex_count, t.vf_offsets, t.vf_faces);
  build_csr(vv, vertex_count, t.vv_offsets, t.vv_neighbors);

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
