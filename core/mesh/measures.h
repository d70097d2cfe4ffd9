#pragma once
/// @file measures.h
/// The scale-invariant measures of Liu et al. (Section 3.1): corner angles theta, length ratios l,
/// and dihedral edge angles phi; the error metrics E_theta / E_phi (Section 5.1); per-vertex,
/// per-face and area distortion.

#include <Eigen/Core>

#include "core/mesh/mesh_data.h"
#include "core/mesh/topology.h"

namespace meshdeform::core {

/// Omega of a mesh. Corner k of face f is stored at 3 f + k; it is the corner at F(f,k) between
/// e1 = F(f,k+1) - F(f,k) and e2 = F(f,k+2) - F(f,k) (indices mod 3).
struct Measures {
  Eigen::VectorXd theta;   ///< 3#F corner angles in [0, pi].
  Eigen::VectorXd ratio;   ///< 3#F length ratios |e2| / |e1| at each corner.
  Eigen::VectorXd phi;     ///< #IE dihedral angles in [0, pi], unsigned angle between face normals.
  Eigen::VectorXd area;    ///< #F triangle areas.
};

/// Unit face normals normalize((b - a) x (c - a)); a zero-area face gets (0, 0, 0).
Positions face_normals(const Positions& V, const Triangles& F);

/// Computes Omega (and areas) of the mesh (V, F).
/// @param[in] threads  OpenMP threads of the per-face and per-edge loops (the same values at any
///                     count: every entry is written by one iteration).
Measures compute_measures(const Positions& V, const Triangles& F, const MeshTopology& topology,
                          int threads = 1);

/// The dihedral angles alone (Measures::phi: #IE, in [0, pi]), the same values as
/// compute_measures' at any thread count.
Eigen::VectorXd dihedral_angles(const Positions& V, const Triangles& F,
                                const MeshTopology& topology, int threads = 1);

/// Folds: interior edges whose dihedral angle moved by more than 90 degrees from the rest, i.e.
/// creases (or sheets turned over) that the rest shape does not have.
/// @param[in] rest_phi, phi  dihedral angles of the same edges (dihedral_angles), rest and
///                           deformed.
int count_folds(const Eigen::VectorXd& rest_phi, const Eigen::VectorXd& phi);

/// E_theta, E_phi (RMS radians, paper Section 5.1) and the RMS of log(area'/area) over faces.
struct AngleErrors {
  double e_theta = 0;
  double e_phi = 0;
  double area_log_rms = 0;
};

/// Errors of `deformed` against `rest` (both from compute_measures on the same F).
AngleErrors angle_errors(const Measures& rest, const Measures& deformed);

/// angle_errors(rest, compute_measures(V, F, topology, threads)) without building the deformed
/// measures: no per-corner arrays and no length ratios (which the errors do not use), so about
/// half the time at 10^5 faces. Equal to round-off (the sums run block by block), and the same
/// value at any thread count.
/// @param[in] rest  compute_measures of the rest mesh with the same F and topology.
AngleErrors angle_errors(const Measures& rest, const Positions& V, const Triangles& F,
                         const MeshTopology& topology, int threads = 1);

/// Local distortion for heat maps, in radians: RMS of the theta errors of a face's corners, and
/// per vertex the RMS of the theta errors at its corners and the phi errors of its interior edges.
struct Distortion {
  Eigen::VectorXd per_vertex;  ///< #V
  Eigen::VectorXd per_face;    ///< #F
};

Distortion local_distortion(const Measures& rest, const Measures& deformed, const Triangles& F,
                            const MeshTopology& topology);

}  // namespace meshdeform::core
