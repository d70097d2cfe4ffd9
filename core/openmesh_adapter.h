#pragma once
/// @file openmesh_adapter.h
/// Internal to core: include from .cpp files only (core's public headers stay Eigen-only).
/// The OpenMesh mesh type core uses (double precision, status attributes for the decimater and
/// the subdivider) and conversions to and from V/F.

#include <cstddef>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <OpenMesh/Core/Mesh/TriMesh_ArrayKernelT.hh>

#include "core/mesh_data.h"
#include "core/status.h"

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
