#pragma once
/// @file openmesh_adapter.h
/// Internal to core: include from .cpp files only (core's public headers stay Eigen-only).
/// The OpenMesh mesh type core uses (double precision, status attributes for the decimater and
/// the subdivider) and conversions to and from V/F.

#include <algorithm>
#include <cstddef>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

#include "core/mesh/mesh_data.h"
#include "core/base/status.h"
#include "core/mesh/topology.h"

namespace meshdeform::core::detail {

struct OmTraits : public OpenMesh::DefaultTraits {
  using Point = OpenMesh::Vec3d;
  using Normal = OpenMesh::Vec3d;
  VertexAttributes(OpenMesh::Attributes::Status);
  HalfedgeAttributes(OpenMesh::Attributes::Status);
  EdgeAttributes(OpenMesh::Attributes::Status);
  FaceAttributes(OpenMesh::Attributes::Status);
};
using OmMesh = OpenMesh::TriMesh_ArrayKernelT<OmTraits>;

inline Eigen::Vector3d to_eigen(const OpenMesh::Vec3d& p) { return {p[0], p[1], p[2]}; }
inline OpenMesh::Vec3d to_om(const Eigen::Vector3d& p) { return {p.x(), p.y(), p.z()}; }

/// V/F -> OpenMesh, vertex and face k of the result are row k of V and F.
/// @return InvalidArgument naming the first face OpenMesh rejects (non-manifold input).
inline Result<OmMesh> to_openmesh(const MeshData& mesh) {
  OmMesh om;
  om.reserve(static_cast<size_t>(mesh.V.rows()), static_cast<size_t>(3 * mesh.F.rows() / 2 + 16),
             static_cast<size_t>(mesh.F.rows()));
  std::vector<OmMesh::VertexHandle> vh(static_cast<size_t>(mesh.V.rows()));
  for (Eigen::Index v = 0; v < mesh.V.rows(); ++v) {
    vh[static_cast<size_t>(v)] = om.add_vertex(to_om(mesh.V.row(v).transpose()));
  }
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    const auto face =
        om.add_face(vh[static_cast<size_t>(mesh.F(f, 0))], vh[static_cast<size_t>(mesh.F(f, 1))],
                    vh[static_cast<size_t>(mesh.F(f, 2))]);
    if (!face.is_valid()) {
      return Error(ErrorCode::InvalidArgument,
                   "OpenMesh rejected face " + std::to_string(f) + " (non-manifold input)");
    }
  }
  return om;
}

/// V/F of a validated mesh (validate_triangle_mesh ok) and its topology -> OpenMesh, with the
/// connectivity of to_openmesh(MeshData{V, F}) (the same vertex, edge, half-edge and face indices, each
/// face's half-edge its third one, boundary vertices' outgoing half-edge on the boundary), set
/// directly from the faces instead of by add_face, which searches each vertex's outgoing
/// half-edges for every face corner (0.09-0.16 s at 187k vertices). Interior vertices may keep
/// another of their outgoing half-edges than add_face leaves, which only moves where a
/// circulation around them starts.
inline OmMesh to_openmesh(const Positions& V, const Triangles& F, const MeshTopology& topology) {
  using HalfedgeHandle = OmMesh::HalfedgeHandle;
  using VertexHandle = OmMesh::VertexHandle;
  const auto nv = static_cast<int>(V.rows());
  const auto nf = static_cast<int>(F.rows());
  const auto ne = static_cast<size_t>(topology.interior_edges.rows() +
                                      topology.boundary_edge_count);
  OmMesh om;
  om.reserve(static_cast<size_t>(nv), ne, static_cast<size_t>(nf));
  for (int v = 0; v < nv; ++v) om.add_vertex(to_om(V.row(v).transpose()));
  // The half-edge a -> b, through the slot of b among a's sorted neighbours: edges are created
  // in the order add_face creates them (faces in order, corners 0-1, 1-2, 2-0).
  std::vector<int> first_halfedge(topology.vv_neighbors.size(), -1);
  const auto slot = [&](int a, int b) {
    const auto first = topology.vv_neighbors.begin() + topology.vv_offsets[a];
    const auto last = topology.vv_neighbors.begin() + topology.vv_offsets[a + 1];
    return static_cast<size_t>(std::lower_bound(first, last, b) - topology.vv_neighbors.begin());
  };
  const auto halfedge = [&](int a, int b) {
    const size_t ab = slot(a, b);
    if (first_halfedge[ab] < 0) {
      const HalfedgeHandle h = om.new_edge(VertexHandle(a), VertexHandle(b));
      first_halfedge[ab] = h.idx();
      first_halfedge[slot(b, a)] = om.opposite_halfedge_handle(h).idx();
    }
    return HalfedgeHandle(first_halfedge[ab]);
  };
  for (int f = 0; f < nf; ++f) {
    HalfedgeHandle h[3];
    for (int k = 0; k < 3; ++k) h[k] = halfedge(F(f, k), F(f, (k + 1) % 3));
    const auto fh = om.new_face();
    om.set_halfedge_handle(fh, h[2]);
    for (int k = 0; k < 3; ++k) {
      om.set_face_handle(h[k], fh);
      om.set_next_halfedge_handle(h[k], h[(k + 1) % 3]);
      om.set_halfedge_handle(VertexHandle(F(f, k)), h[k]);
    }
  }
  // Boundary half-edges: each boundary vertex has exactly one outgoing one (a validated mesh),
  // which is the vertex's outgoing half-edge and the next of the boundary half-edge into it.
  std::vector<HalfedgeHandle> boundary_into;
  for (const auto h : om.halfedges()) {
    if (!om.face_handle(h).is_valid()) {
      om.set_halfedge_handle(om.from_vertex_handle(h), h);
      boundary_into.push_back(h);
    }
  }
  for (const HalfedgeHandle h : boundary_into) {
    om.set_next_halfedge_handle(h, om.halfedge_handle(om.to_vertex_handle(h)));
  }
  return om;
}

/// Compacted OpenMesh -> MeshData (garbage_collection must have run).
inline MeshData from_openmesh(const OmMesh& om) {
  MeshData mesh;
  mesh.V.resize(static_cast<Eigen::Index>(om.n_vertices()), 3);
  for (const auto v : om.vertices()) mesh.V.row(v.idx()) = to_eigen(om.point(v)).transpose();
  mesh.F.resize(static_cast<Eigen::Index>(om.n_faces()), 3);
  for (const auto f : om.faces()) {
    int k = 0;
    for (const auto v : om.fv_range(f)) mesh.F(f.idx(), k++) = v.idx();
  }
  return mesh;
}

}  // namespace meshdeform::core::detail
