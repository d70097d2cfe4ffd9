// The direct OpenMesh construction from a validated mesh and its topology against add_face's.

#include "core/mesh/openmesh_adapter.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "core/io/mesh_io.h"
#include "core/samples/generators.h"
#include "core/mesh/topology.h"
#include "core/mesh/validate.h"

namespace meshdeform::core {
namespace {

/// Every handle both constructions set: each half-edge's vertices, face and next, each face's
/// half-edge, and on the boundary each vertex's outgoing half-edge (add_face's choice for
/// interior vertices depends on the order faces were added, so only its validity is compared).
void expect_same_connectivity(const MeshData& mesh) {
  ASSERT_TRUE(validate_triangle_mesh(mesh.V, mesh.F).ok());
  const MeshTopology topology = build_topology(mesh.F, static_cast<int>(mesh.V.rows())).value();
  const detail::OmMesh by_add_face = detail::to_openmesh(mesh).value();
  const detail::OmMesh direct = detail::to_openmesh(mesh.V, mesh.F, topology);
  ASSERT_EQ(direct.n_vertices(), by_add_face.n_vertices());
  ASSERT_EQ(direct.n_edges(), by_add_face.n_edges());
  ASSERT_EQ(direct.n_faces(), by_add_face.n_faces());
  int boundary = 0;
  for (const auto h : by_add_face.halfedges()) {
    SCOPED_TRACE("half-edge " + std::to_string(h.idx()));
    ASSERT_EQ(direct.to_vertex_handle(h), by_add_face.to_vertex_handle(h));
    ASSERT_EQ(direct.from_vertex_handle(h), by_add_face.from_vertex_handle(h));
    ASSERT_EQ(direct.face_handle(h), by_add_face.face_handle(h));
    ASSERT_EQ(direct.next_halfedge_handle(h), by_add_face.next_halfedge_handle(h));
    ASSERT_EQ(direct.prev_halfedge_handle(h), by_add_face.prev_halfedge_handle(h));
    boundary += by_add_face.is_boundary(h) ? 1 : 0;
  }
  for (const auto f : by_add_face.faces()) {
    ASSERT_EQ(direct.halfedge_handle(f), by_add_face.halfedge_handle(f)) << "face " << f.idx();
  }
  for (const auto v : by_add_face.vertices()) {
    SCOPED_TRACE("vertex " + std::to_string(v.idx()));
    ASSERT_TRUE(direct.halfedge_handle(v).is_valid());
    ASSERT_EQ(direct.from_vertex_handle(direct.halfedge_handle(v)), v);
    ASSERT_EQ(direct.is_boundary(v), by_add_face.is_boundary(v));
    if (by_add_face.is_boundary(v)) {
      ASSERT_EQ(direct.halfedge_handle(v), by_add_face.halfedge_handle(v));
    }
  }
  EXPECT_EQ(boundary, topology.boundary_edge_count);
}

TEST(OpenMeshAdapter, DirectConstructionMatchesAddFaceOnAClosedMesh) {
  const MeshData spot = io::read_mesh(std::string(MESHDEFORM_TEST_DATA_DIR) + "/spot.obj").value();
  ASSERT_EQ(build_topology(spot.F, static_cast<int>(spot.V.rows()))->boundary_edge_count, 0);
  expect_same_connectivity(spot);
}

TEST(OpenMeshAdapter, DirectConstructionMatchesAddFaceOnOpenAndIrregularMeshes) {
  // The plane has one border, the tube and the cactus two; the irregular variants have uneven
  // valences.
  for (const DeformationBenchmark& regular :
       {make_bumpy_plane(21), make_cylinder(12, 9), make_cactus(2)}) {
    SCOPED_TRACE(regular.name);
    ASSERT_GT(build_topology(regular.mesh.F, static_cast<int>(regular.mesh.V.rows()))
                  ->boundary_edge_count,
              0);
    expect_same_connectivity(regular.mesh);
    expect_same_connectivity(make_irregular(regular, 3).value().mesh);
  }
}

}  // namespace
}  // namespace meshdeform::core
