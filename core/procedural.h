#pragma once
/// @file procedural.h
/// The paper's Table 1 test models, generated rather than downloaded, in the form of the
/// Botsch & Sorkine 2008 deformation benchmark: a mesh, a per-vertex selection (0 fixed, 1 free,
/// 2 handle) and one 4x4 affine transform applied to every handle vertex.

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "core/mesh_data.h"
#include "core/status.h"

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

/// Knobs of make_irregular. The defaults give "scanned-style" triangulations: density varying by
/// 4x in edge length across the surface, about 3% of the faces split into slivers, every interior
/// vertex jittered in its tangent plane, and some edges flipped (irregular valences).
struct IrregularOptions {
  /// Ratio of the largest to the smallest target edge length (>= 1); 1 keeps the density.
  double density_contrast = 4.0;
  /// Smooth random bumps (half refine, half coarsen) that make up the density field.
  int density_blobs = 8;
  /// Fraction of faces whose longest edge is split close to one end (a sliver on each side).
  double skinny_fraction = 0.03;
  /// Tangential jitter amplitude, as a fraction of each vertex's shortest incident edge.
  double jitter = 0.3;
  /// Fraction of interior edges flipped (only where the surface is locally flat).
  double flip_fraction = 0.1;
};

/// Irregular variant of a benchmark edit, as real (scanned, remeshed) input looks: non-uniform
/// density (edges split where a random smooth density field asks for small triangles, collapsed
/// where it asks for large ones), random edge flips, tangential jitter and a fraction of skinny
/// triangles. The mesh stays a valid 2-manifold (validate_triangle_mesh) with the input's
/// topology and boundary, and about the input's vertex count. Roles keep their geometric regions:
/// vertices on a role border and on the mesh boundary are never collapsed, a vertex created on an
/// edge takes its endpoints' role when they agree (else Free), and the transform is unchanged.
/// Deterministic for a seed (own uniform draws from std::mt19937_64; no std distributions).
/// @param[in] regular  a benchmark from make_* (or any valid mesh with a selection).
/// @param[in] seed     random seed.
/// @return the variant, named `<name>_irregular`; InvalidArgument when the input mesh is invalid
///         or the selection has the wrong size; Internal if the result fails validation.
[[nodiscard]] Result<DeformationBenchmark> make_irregular(const DeformationBenchmark& regular,
                                                          std::uint64_t seed,
                                                          const IrregularOptions& options = {});

/// make_irregular of every make_suite(scale) model with the default options, in the same order.
/// @return Internal if a variant fails validation (never expected).
[[nodiscard]] Result<std::vector<DeformationBenchmark>> make_irregular_suite(
    SuiteScale scale, std::uint64_t seed = 1);

/// Loop subdivision (OpenMesh's Subdivider::Uniform::LoopT), `levels` times: about 4^levels times
/// the vertices. @return InvalidArgument for an invalid mesh or levels outside [0, 6].
[[nodiscard]] Result<MeshData> subdivide_loop(const MeshData& mesh, int levels);

/// Edits on Keenan Crane's Spot (tests/data/spot.obj: y up, head toward -z, tail at +z), defined
/// by regions of the bounding box so that they carry across subdivision levels. The handle is the
/// head (normalised z < 0.12), the fixed region the rear half of the body with the hind legs and
/// the tail (normalised z > 0.6).
enum class SpotEdit {
  Stretch,  ///< head pulled forward by 20% of the body length (pure translation)
  Bend,     ///< head nodded down by 60 degrees about a horizontal axis through the neck
  Twist,    ///< head twisted by 135 degrees about the body's long axis
};
/// Name of an edit: "stretch", "bend", "twist".
[[nodiscard]] const char* spot_edit_name(SpotEdit edit);
/// A Spot benchmark named `spot<V/1000>k_<edit>`.
/// @param[in] spot  Spot at any subdivision level (the regions are bounding-box relative).
/// @return InvalidArgument when a region is empty.
[[nodiscard]] Result<DeformationBenchmark> make_spot_edit(const MeshData& spot, SpotEdit edit);

}  // namespace meshdeform::core
