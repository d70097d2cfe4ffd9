#pragma once
/// @file ora.h
/// Optimal rigidity approximation (ORA, paper Section 5.3, Eqs. 13-15) and region
/// magnification (Figs. 12-13). Both rescale every triangle of a deformed mesh about its centroid
/// to a target area and stitch the triangles back into one mesh under the handle constraints:
///   ORA:          target area = original area (tau_t = sqrt(Area_t / Area'_t), Eq. 14 read as
///                 v-hat = c + tau (v' - c));
///   magnification: target area = k^2 x original area on the faces of a region with scale k.
/// The stitch (Eq. 15) min sum_t sum_j ||(v_{j+1} - v_j) - (v-hat_{j+1} - v-hat_j)||^2
///   + lambda sum_{j in C} ||v_j - v*_j||^2 has a constant per-coordinate matrix (an edge-count
/// weighted graph Laplacian plus lambda on the constrained vertices): factored once per handle
/// set, three back-solves per use.

#include <memory>
#include <vector>

#include <Eigen/Core>

#include "core/mesh/mesh_data.h"
#include "core/mesh/topology.h"
#include "core/base/status.h"

namespace meshdeform::core {

/// Per-triangle scale factors sigma_t = Area'_t / Area_t (Eq. 13).
/// @param[in] V0  #V x 3 rest positions.  @param[in] V  #V x 3 deformed positions.
/// @return #F factors; a rest face of zero area gives +inf (validation rejects such meshes).
Eigen::VectorXd triangle_scale_factors(const Positions& V0, const Positions& V, const Triangles& F);

/// A region to magnify: faces (or the faces whose three vertices are all in `vertices`) and a
/// linear scale k (areas grow by k^2).
struct MagnifyRegion {
  Eigen::VectorXi faces;     ///< face indices; used when non-empty
  Eigen::VectorXi vertices;  ///< vertex indices; faces with all three corners inside are the region
  double scale = 1.0;        ///< k > 0
};

/// Resolves regions into a #F per-face linear scale (1 outside every region; a face in several
/// regions takes the last one's scale).
/// @return InvalidArgument for k <= 0 or non-finite, an empty region (no faces, or vertices
///         covering no whole face), or an index out of range, naming the region and the index.
[[nodiscard]] Result<Eigen::VectorXd> face_scales_from_regions(const std::vector<MagnifyRegion>& regions,
                                                               const Triangles& F, int vertex_count);

/// Prefactored stitching for one mesh and one handle set.
class RigidityStitcher {
 public:
  /// @param[in] V0           #V x 3 rest positions (their areas are the targets).
  /// @param[in] F            #F x 3 triangles, validate_triangle_mesh(V0, F) ok.
  /// @param[in] constrained  #C distinct vertex indices, at least one per connected component.
  /// @return the stitcher; InvalidArgument for a bad mesh or index or an unconstrained component;
  ///         NumericalFailure if the factorization fails.
  [[nodiscard]] static Result<RigidityStitcher> create(const Positions& V0, const Triangles& F,
                                                       const Eigen::VectorXi& constrained,
                                                       double lambda = 100.0);
  /// The same for a mesh the caller has validated (validate_triangle_mesh) and whose topology
  /// it has built (build_topology(F, #V)): neither is done again (the scale-aware solver's ORA).
  [[nodiscard]] static Result<RigidityStitcher> create(const Positions& V0, const Triangles& F,
                                                       const MeshTopology& topology,
                                                       const Eigen::VectorXi& constrained,
                                                       double lambda = 100.0);

  /// Rescales every triangle of V to (face_scale_t)^2 times its rest area and stitches them.
  /// @param[in] V           #V x 3 deformed positions (e.g. the scale-aware result).
  /// @param[in] targets     #C x 3 handle targets.
  /// @param[in] face_scale  #F linear scales, or empty for all 1 (plain ORA).
  /// @return #V x 3 stitched positions; InvalidArgument for wrong shapes or non-finite values.
  [[nodiscard]] Result<Positions> stitch(const Positions& V, const Positions& targets,
                                         const Eigen::VectorXd& face_scale = {}) const;

  RigidityStitcher(RigidityStitcher&&) noexcept;
  RigidityStitcher& operator=(RigidityStitcher&&) noexcept;
  ~RigidityStitcher();

 private:
  struct Impl;
  explicit RigidityStitcher(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace meshdeform::core
