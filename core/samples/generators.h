#pragma once
/// @file generators.h
/// Generators for benchmarks and tests, outside the library the server links
/// (meshdeform::generators): irregular, scan-like variants of the sample edits (a remesher),
/// Loop subdivision, and edits on Keenan Crane's Spot.

#include <cstdint>
#include <vector>

#include "core/base/status.h"
#include "core/mesh/mesh_data.h"
#include "core/samples/samples.h"

namespace meshdeform::core {

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
