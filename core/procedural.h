#pragma once
/// @file procedural.h
/// The paper's Table 1 test models, generated rather than downloaded, in the form of the
/// Botsch & Sorkine 2008 deformation benchmark: a mesh, a per-vertex selection (0 fixed, 1 free,
/// 2 handle) and one 4x4 affine transform applied to every handle vertex.

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/mesh_data.h"
#include "core/status.h"

namespace meshdeform::core {

/// Per-vertex roles of the .sel format.
enum class VertexRole : int { Fixed = 0, Free = 1, Handle = 2 };

/// One benchmark edit.
struct DeformationBenchmark {
  std::string name;            ///< "bumpy_plane", "cylinder", "bar", "cactus"
  MeshData mesh;
  Eigen::VectorXi selection;   ///< #V roles (VertexRole values)
  Eigen::Matrix4d transform;   ///< applied to handle vertices (row-major meaning: x' = T * [x;1])
};

/// Constrained vertices and their targets derived from a selection and a transform.
struct HandleSetup {
  Eigen::VectorXi constrained;  ///< #C indices: every fixed and handle vertex, ascending
  Positions targets;            ///< #C x 3: fixed at rest, handles transformed
};

/// Builds the constraints of a benchmark edit.
/// @return InvalidArgument when selection has the wrong length or a value outside {0,1,2}.
[[nodiscard]] Result<HandleSetup> constraints_from_selection(const Positions& V,
                                                             const Eigen::VectorXi& selection,
                                                             const Eigen::Matrix4d& transform);

/// Bumpy plane: n x n grid on [-1,1]^2 with bumps; border fixed, centre region lifted (pure
/// translation). n = 201 gives the paper's 40,401 vertices.
[[nodiscard]] DeformationBenchmark make_bumpy_plane(int n = 201);
/// Cylinder (open, with surface detail), bottom ring region fixed, top region bent by 120 degrees.
/// Default resolution gives about the paper's 4,802 vertices.
[[nodiscard]] DeformationBenchmark make_cylinder(int rings = 49, int segments = 98);
/// Closed rectangular bar, one end fixed, the other twisted by 135 degrees about its axis.
/// Default resolution gives about the paper's 2,602 vertices.
[[nodiscard]] DeformationBenchmark make_bar(int length_segments = 64, int width_segments = 10);
/// Branching cactus-like surface (trunk and two arms), base fixed, top bent by 70 degrees.
/// `resolution` scales the tessellation; the default gives about the paper's 5,261 vertices.
[[nodiscard]] DeformationBenchmark make_cactus(int resolution = 4);

/// Suite sizes: Paper matches Table 1's vertex counts; Small is for unit tests (< ~1,000 vertices each).
enum class SuiteScale { Paper, Small };
[[nodiscard]] std::vector<DeformationBenchmark> make_suite(SuiteScale scale);

}  // namespace meshdeform::core
