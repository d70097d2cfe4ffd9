#pragma once
/// @file mesh_factories.h
/// Small procedural meshes and named tolerances for tests.

#include "core/mesh_data.h"

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
/// One triangle (0,0,0), (1,0,0), (0,1,0).
MeshData make_triangle();
/// Axis-aligned bounding-box diagonal length.
double bbox_diagonal(const MeshData& mesh);

}  // namespace meshdeform::test
