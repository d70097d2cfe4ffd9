#pragma once
/// @file similarity.h
/// The similarity transform of a handle group about a pivot, x' = pivot + s R (x - pivot) + t:
/// what a service GroupMove, a JSON edit spec's rigid handle and a client's .def matrix all
/// mean. One implementation of the forward map and of its inverse (recovering s, R, t from a
/// 4x4 matrix), shared by the service, core/io and the client CLI.

#include <optional>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/mesh/mesh_data.h"

namespace meshdeform::core {

/// x' = pivot + scale * rotation * (x - pivot) + translation.
struct GroupSimilarity {
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  ///< orthonormal, det +1
  double scale = 1.0;                                      ///< > 0
  std::optional<Eigen::Vector3d> pivot;  ///< default: the centroid of the points moved
};

/// The pivot a transform uses for `points`: its own, else their centroid.
/// @param[in] points  #P x 3, #P > 0.
Eigen::Vector3d similarity_pivot(const GroupSimilarity& transform, const Positions& points);

/// Applies `transform` to every row of `points` (#P x 3, #P > 0). @return #P x 3.
Positions apply_similarity(const GroupSimilarity& transform, const Positions& points);

/// Splits a 4x4 affine matrix (last row 0 0 0 1 to 1e-12) whose linear part is a rotation times
/// a positive uniform scale (orthonormal to 1e-9) into a transform about the origin.
/// @return the transform (pivot = origin); nullopt for any other matrix (shear, non-uniform
///         scale, reflection, projective row).
std::optional<GroupSimilarity> similarity_from_matrix(const Eigen::Matrix4d& T);

}  // namespace meshdeform::core
