#pragma once
/// @file normals_step.h
/// Internal to core: step one of the scale-aware solver (paper Section 4.1.1), an
/// as-rigid-as-possible update of the face normals on the Gauss map.
///   local:  per vertex v, R_v = argmin sum_{f ni v} ||N_f - R N0_f||^2 (Kabsch; the paper's Eq. 8
///           has the covariance transposed), uniform weights over the fan;
///   global: N_f = normalize(mean over the corners v of f of R_v N0_f)   (Eq. 11).

#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/mesh/mesh_data.h"
#include "core/mesh/topology.h"

namespace meshdeform::core {

using RowPositions = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// Rotation R maximising trace(R^T B) (the rotation of B's polar decomposition), refined from
/// `q` by the iteration of Mueller et al. 2016 ("A robust method to extract the rotational part
/// of deformations"): cheap, and exact at convergence when warm-started.
void refine_rotation(const Eigen::Matrix3d& B, Eigen::Quaterniond& q, int max_iterations);

/// The same rotation from an SVD (Kabsch, reflection removed): closest_rotation()'s fallback
/// where the best rotation is not unique.
Eigen::Quaterniond kabsch_rotation(const Eigen::Matrix3d& B);

/// Runs local/global sweeps until the normals move less than `tolerance` (max over faces of the
/// change of N_f) or `max_sweeps` is reached.
/// @param[in]     N0         #F x 3 rest unit normals.
/// @param[in,out] N          #F x 3 current unit normals, updated.
/// @param[in,out] rotations  #V per-vertex rotations, warm start and result.
/// @param[in]     warm       whether `rotations` hold a previous result (else a closed-form fit,
///                           closest_rotations(), first).
/// @return the number of sweeps run.
int update_normals(const RowPositions& N0, const Triangles& F, const MeshTopology& topology,
                   RowPositions& N, std::vector<Eigen::Quaterniond>& rotations, bool warm,
                   int max_sweeps, double tolerance, int threads);

}  // namespace meshdeform::core
