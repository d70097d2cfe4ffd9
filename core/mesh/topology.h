#pragma once
/// @file topology.h
/// Connectivity derived once from F: interior edges with their two faces, vertex-face and
/// vertex-vertex adjacency (CSR), connected components. Plain arrays, no OpenMesh.

#include <vector>

#include <Eigen/Core>

#include "core/mesh/mesh_data.h"
#include "core/base/status.h"

namespace meshdeform::core {

/// Connectivity of a validated triangle mesh.
struct MeshTopology {
  int vertex_count = 0;
  int face_count = 0;
  /// #IE x 2 vertex pairs (i < j) of interior edges (exactly two incident faces).
  Eigen::Matrix<int, Eigen::Dynamic, 2> interior_edges;
  /// #IE x 2 the two faces of each interior edge.
  Eigen::Matrix<int, Eigen::Dynamic, 2> edge_faces;
  int boundary_edge_count = 0;
  /// Vertex -> incident faces, CSR: faces of v are vf_faces[vf_offsets[v] .. vf_offsets[v+1]).
  std::vector<int> vf_offsets, vf_faces;
  /// Vertex -> neighbouring vertices (sorted, without v), CSR like vf_*.
  std::vector<int> vv_offsets, vv_neighbors;
  /// #V component id of each vertex (connected through faces), ids 0..component_count-1.
  Eigen::VectorXi component;
  int component_count = 0;
};

/// Builds the connectivity of F.
/// @param[in] F             #F x 3 triangle indices.
/// @param[in] vertex_count  #V.
/// @return the topology; InvalidArgument for an index out of range, a face that repeats a vertex,
///         or a non-manifold edge (shared by more than two faces), naming the first one.
[[nodiscard]] Result<MeshTopology> build_topology(const Triangles& F, int vertex_count);

/// The closed loops of boundary edges (holes and open borders) of a validated mesh (manifold,
/// consistently oriented, manifold vertices: every boundary vertex has exactly one outgoing
/// boundary half-edge). @param[in] F #F x 3; vertex_count #V. @return the number of loops.
int count_boundary_loops(const Triangles& F, int vertex_count);

}  // namespace meshdeform::core
