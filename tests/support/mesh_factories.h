#pragma once
/// @file mesh_factories.h
/// Small procedural meshes and named tolerances for tests.

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/mesh/mesh_data.h"

namespace meshdeform::test {

/// Named tolerances (relative to the bounding-box diagonal unless said otherwise).
inline constexpr double kExactTol = 1e-9;      ///< round-off of one direct solve
inline constexpr double kConvergedTol = 1e-6;  ///< an iterative solve run to convergence

/// (n+1) x (n+1) vertex grid on [0,1]^2 at z = 0, with optional bumps of height `bump`.
MeshData make_grid(int n, double bump = 0.0);
/// Open cone (apex at the top, open ring at the bottom) with `segments` around.
MeshData make_open_cone(int segments);
/// Closed icosphere after `subdivisions` 1:4 subdivisions (12, 42, 162, 642 ... vertices).
MeshData make_icosphere(int subdivisions);
/// OBJ text of a rows x rows vertex grid (unit spacing, small integer heights), built as text
/// directly: big uploads for tests of parsing limits and cancellation (rows 700: ~12 MB).
std::string make_grid_obj_text(int rows);
/// One triangle (0,0,0), (1,0,0), (0,1,0).
MeshData make_triangle();
/// Axis-aligned bounding-box diagonal length.
double bbox_diagonal(const MeshData& mesh);

/// Rows idx(0), idx(1), ... of V (e.g. the rest positions of constrained vertices).
Positions gather_rows(const Positions& V, const Eigen::VectorXi& idx);

/// A strip edit: the bumpy grid make_grid(n, 0.05) with its left and right columns constrained
/// (interleaved: even rows of `targets` on the left, odd rows on the right), targets at rest.
struct StripEdit {
  MeshData mesh;
  Eigen::VectorXi constrained;
  Positions targets;  ///< #C x 3, the rest positions: move the odd rows to pull the right side
};
StripEdit make_strip_edit(int n);

/// A test mesh with a constrained set that pins a similarity, reflections included: the angle
/// measures are unsigned, so a mirror image is an exact zero of the scale-aware energy as well,
/// and a constrained set inside one plane cannot tell the two apart.
struct PinnedMesh {
  const char* name;
  MeshData mesh;
  Eigen::VectorXi constrained;
};

/// A bumpy grid (corners and a bump top), an icosphere (6 vertices) and an open cone (4).
std::vector<PinnedMesh> pinned_test_meshes();

/// A bend edit: an n x n bumpy grid with its left column fixed and its right column rotated by
/// 60 degrees about y and lifted (targets alternate left, right per row).
struct BendEdit {
  MeshData mesh;
  Eigen::VectorXi constrained;
  Positions targets;
};
BendEdit make_bend(int n);

}  // namespace meshdeform::test
