#pragma once
/// @file validate.h
/// Mesh validation and lossless cleaning. Every error names the first offending element.

#include <Eigen/Core>

#include "core/mesh_data.h"
#include "core/status.h"

namespace meshdeform::core {

/// Checks the rules every solver relies on: non-empty, finite coordinates, indices in range,
/// no degenerate faces (repeated index, zero-length edge, zero area relative to the bounding box),
/// no duplicate faces, manifold edges (at most two faces, consistently oriented) and manifold
/// vertices (one fan per vertex), and no unreferenced vertices.
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
/// @return the report, or the first validation error of the cleaned mesh (mesh untouched).
[[nodiscard]] Result<CleanReport> clean_mesh(MeshData& mesh, bool weld);

}  // namespace meshdeform::core
