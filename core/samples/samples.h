#pragma once
/// @file samples.h
/// The paper's Table 1 test models (the server's sample meshes, the CLI's and the tests' edits), generated rather than downloaded, in the form of the
/// Botsch & Sorkine 2008 deformation benchmark: a mesh, a per-vertex selection (0 fixed, 1 free,
/// 2 handle) and one 4x4 affine transform applied to every handle vertex.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "core/mesh/mesh_data.h"
#include "core/base/status.h"

namespace meshdeform::core {

/// Per-vertex roles of the .sel format.
enum class VertexRole : int { Fixed = 0, Free = 1, Handle = 2 };

/// One benchmark edit.
struct DeformationBenchmark {
  std::string name;  ///< "bumpy_plane", "cylinder", "bar", "cactus"
  MeshData mesh;
  Eigen::VectorXi selection;  ///< #V roles (VertexRole values)
  Eigen::Matrix4d transform;  ///< applied to handle vertices (row-major meaning: x' = T * [x;1])
};

/// Constrained vertices and their targets derived from a selection and a transform.
struct HandleSetup {
  Eigen::VectorXi constrained;  ///< #C indices: every fixed and handle vertex, ascending
  Positions targets;            ///< #C x 3: fixed at rest, handles transformed
};

/// Builds the constraints of a benchmark edit.
/// @param[in] V          #V x 3 rest positions.
/// @param[in] selection  #V roles (0 fixed, 1 free, 2 handle).
/// @param[in] transform  affine map for the handles (last row 0 0 0 1).
/// @return constrained = every vertex with role 0 or 2, ascending; targets = the rest position for
///         fixed vertices and T * [x; 1] for handles. InvalidArgument when selection has the wrong
///         length, a value outside {0,1,2} (naming the vertex), or the transform is not a finite
///         affine matrix.
[[nodiscard]] Result<HandleSetup> constraints_from_selection(const Positions& V,
                                                             const Eigen::VectorXi& selection,
                                                             const Eigen::Matrix4d& transform);

/// Bumpy plane: n x n grid on [-1,1]^2, z = a sum of Gaussian bumps of three sizes (heights 0.08,
/// 0.04, 0.015), normals +z. The outer band (max(2, n/50) rows) is fixed, the disc of radius 0.15
/// around the centre is the handle, lifted by +0.5 in z (pure translation).
/// @param[in] n  vertices per side (at least 5); 201 gives the paper's 40,401 vertices.
[[nodiscard]] DeformationBenchmark make_bumpy_plane(int n = 201);
/// Open tube along z (radius 0.2, height 2) with 7 lengthwise ridges and 6 circumferential waves,
/// faces outward. The bottom max(2, rings/12) rings are fixed and as many top rings form the
/// handle; the transform rotates the handle by 120 degrees about a horizontal axis (parallel to y)
/// through the pivot that makes the free part bend into a circular arc toward +x.
/// @param[in] rings     vertex rings along z (at least 6).
/// @param[in] segments  vertices per ring (at least 6). rings * segments vertices: the defaults
///                      give the paper's 4,802.
[[nodiscard]] DeformationBenchmark make_cylinder(int rings = 98, int segments = 49);
/// Closed bar along z (length 2, square cross-section 0.4 x 0.4) with 6 ridges around it and two
/// lengthwise grooves per side; a closed, welded 2-manifold (genus 0), faces outward. The end
/// region z = 0 (max(2, length_segments/20) rings and the cap) is fixed, the z = 2 region is the
/// handle, twisted by 135 degrees about the bar's axis.
/// @param[in] length_segments  quads along z (at least 4).
/// @param[in] width_segments   quads across each side (at least 2).
/// Vertices: 4 w (L + 1) + 2 (w - 1)^2; the defaults give the paper's 2,602.
[[nodiscard]] DeformationBenchmark make_bar(int length_segments = 60, int width_segments = 10);
/// Saguaro-like surface: a ribbed trunk (open tube, base in z = 0, domed top) with two arms that
/// leave it sideways at different heights, turn up and end in domes; one connected genus-0
/// surface with a single boundary loop (the base), welded by construction, faces outward. The
/// base rows are fixed, the top rows and the dome are the handle, and the transform rotates the
/// handle by 70 degrees about a horizontal axis (parallel to the arms) through the pivot that
/// makes the trunk bend into an arc, perpendicular to the plane of the arms.
/// @param[in] resolution  scales the tessellation (at least 1): 1 gives 336 vertices, the
///                        default 4 gives 5,289 (the paper's model has 5,261).
[[nodiscard]] DeformationBenchmark make_cactus(int resolution = 4);

/// Suite sizes: Paper matches Table 1's vertex counts; Small is for unit tests (< ~1,000 vertices
/// each).
enum class SuiteScale { Paper, Small };
/// The four benchmarks in the order bumpy_plane, cylinder, bar, cactus.
/// Paper: 40,401 / 4,802 / 2,602 / 5,289 vertices; Small: 441 / 420 / 554 / 336 vertices.
[[nodiscard]] std::vector<DeformationBenchmark> make_suite(SuiteScale scale);

}  // namespace meshdeform::core
