#pragma once
/// @file validate.h
/// Mesh validation and lossless cleaning. Every error names the first offending element.

#include <stop_token>

#include <Eigen/Core>

#include "core/mesh/mesh_data.h"
#include "core/base/status.h"

namespace meshdeform::core {

/// Checks the rules every solver relies on: non-empty, finite coordinates, indices in range,
/// no degenerate faces (repeated index, zero-length edge, zero area relative to the bounding box),
/// no duplicate faces, manifold edges (at most two faces, consistently oriented) and manifold
/// vertices (one fan per vertex), and no unreferenced vertices.
/// Rules are checked in this order and the first failure is reported (faces in index order):
///  1. at least one vertex and one face;
///  2. finite coordinates ("vertex 5 has a non-finite y coordinate (nan)");
///  3. indices in [0, #V) ("face 17 references vertex 902 (#V=900)");
///  4. no repeated index in a face ("face 3 (4, 7, 7) repeats vertex 7");
///  5. no zero-length edge (two corners at exactly the same position);
///  6. no (near) zero area: area < 1e-14 * (bounding-box diagonal)^2;
///  7. no duplicate faces (same vertex set, any order or orientation);
///  8. manifold edges: at most two incident faces ("non-manifold edge (3, 9) is shared by 3 faces");
///  9. consistent orientation: two faces never traverse an edge in the same direction;
/// 10. manifold vertices: the faces around a vertex form one fan (edge-connected);
/// 11. every vertex is referenced by a face.
/// @param[in] V  #V x 3 vertex positions.
/// @param[in] F  #F x 3 triangle indices into V.
/// @return success, or InvalidArgument naming the first offending element, e.g.
///         "face 17 references vertex 902 (#V=900)".
[[nodiscard]] Status validate_triangle_mesh(const Positions& V, const Triangles& F);

/// What clean_mesh changed.
struct CleanReport {
  int welded_vertices = 0;        ///< vertices merged into an earlier one at the same position
  int dropped_unreferenced = 0;   ///< vertices no face referenced
  /// #V_in: index in the cleaned mesh of each input vertex, -1 if dropped.
  Eigen::VectorXi old_to_new;
};

/// Lossless cleaning: welds vertices at exactly equal positions (STL triangle soup) and drops
/// unreferenced vertices, then validates the result.
/// @param[in,out] mesh  cleaned in place only when the result is ok.
/// @param[in] weld      merge exactly coincident vertices (on for STL, optional elsewhere).
/// A face that repeats a vertex after welding is not dropped: it is reported like any other
/// validation error. Errors found after renumbering are prefixed with "after cleaning (...)"
/// because they name indices of the cleaned mesh; indices out of range are reported on the input.
/// @param[in] stop      checked between passes and every few thousand vertices of the weld.
/// @return the report, or InvalidArgument with the first validation error of the cleaned mesh
///         (mesh untouched); Cancelled when `stop` is requested (mesh untouched).
[[nodiscard]] Result<CleanReport> clean_mesh(MeshData& mesh, bool weld,
                                             std::stop_token stop = {});

}  // namespace meshdeform::core
