#pragma once
/// @file cgal_arap.h
/// The peer for the Table 1 benchmark: CGAL's Surface_mesh_deformation (As-Rigid-As-Possible,
/// Sorkine & Alexa 2007) run on the same V/F and the same edit as our solver. The interface is
/// Eigen only, so CGAL's slow-to-compile headers stay in cgal_arap.cpp.

#include <string>

#include <Eigen/Core>

#include "core/mesh/mesh_data.h"
#include "core/base/status.h"

namespace meshdeform::bench {

/// CGAL's energy variants (CGAL::Deformation_algorithm_tag).
enum class CgalArapVariant {
  SpokesAndRims,  ///< CGAL's default: edge sets are the spokes and rims of each one-ring
  Original,       ///< Sorkine & Alexa's spokes only, negative cotangents clamped to zero
  Sre,            ///< smooth rotation enhanced ARAP (Levi & Gotsman 2014), alpha = CGAL default
};

/// "spokes_and_rims", "original", "sre".
const char* cgal_arap_variant_name(CgalArapVariant variant);
/// Parses the names of cgal_arap_variant_name (also "spokes" and "sre_arap").
[[nodiscard]] Result<CgalArapVariant> parse_cgal_arap_variant(const std::string& name);

/// How the CGAL run is driven.
struct CgalArapOptions {
  CgalArapVariant variant = CgalArapVariant::SpokesAndRims;
  int fixed_iterations = 15;        ///< the timed run: exactly this many iterations, tolerance 0
  int max_converge_iterations = 100;  ///< cap of the convergence run
  double converge_tolerance = 1e-4;   ///< CGAL's relative energy change tolerance (its default)
  bool run_convergence = true;      ///< also run deform(max, tolerance) from the rest pose
  int move_iterations = 2;          ///< iterations of the warm move
};

/// Timings and results of one CGAL edit.
struct CgalArapResult {
  double build_seconds = 0;        ///< Surface_mesh construction from V/F (not part of ARAP)
  double preprocess_seconds = 0;   ///< ROI/control set-up + preprocess() (Laplacian + factorization)
  double fixed_seconds = 0;        ///< deform(fixed_iterations, 0)
  int fixed_iterations = 0;
  Positions V_fixed;               ///< #V x 3 positions after the fixed run
  double converge_seconds = 0;     ///< deform(max_converge_iterations, tolerance) from the rest pose
  int converge_iterations = 0;     ///< iterations that run took (counted through the rotation traits)
  Positions V_converged;           ///< #V x 3 positions after the convergence run (empty if not run)
  double move_seconds = 0;         ///< deform(move_iterations, 0) after moving the handles, warm
  Positions V_move;                ///< #V x 3 positions after the warm move
};

/// Runs CGAL ARAP on (V, F): every vertex in the region of interest, the constrained vertices as
/// control vertices with `targets` (fixed vertices at rest, handles transformed); then the warm move
/// to `move_targets` from the state the fixed run left.
/// @param[in] V             #V x 3 rest positions.
/// @param[in] F             #F x 3 triangles (an oriented 2-manifold, with or without boundary).
/// @param[in] constrained   #C vertex indices.
/// @param[in] targets       #C x 3 targets of the edit.
/// @param[in] move_targets  #C x 3 targets of the warm move (may be empty: no move is run).
/// @return the result; InvalidArgument when CGAL's Surface_mesh rejects a face (non-manifold or
///         inconsistently oriented) or shapes disagree; NumericalFailure when preprocess() fails.
[[nodiscard]] Result<CgalArapResult> run_cgal_arap(const Positions& V, const Triangles& F,
                                                   const Eigen::VectorXi& constrained,
                                                   const Positions& targets,
                                                   const Positions& move_targets,
                                                   const CgalArapOptions& options = {});

}  // namespace meshdeform::bench
