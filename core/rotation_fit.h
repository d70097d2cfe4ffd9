#pragma once
/// @file rotation_fit.h
/// Internal to core: the rotation closest to a 3x3 matrix, shared by ARAP's local step and the
/// scale control's face frames.

#include <Eigen/Core>

namespace meshdeform::core {

/// The rotation R maximising trace(R^T S) (the Kabsch / orthogonal Procrustes fit with the
/// reflection removed), in closed form; see rotation_fit.cpp.
Eigen::Matrix3d closest_rotation(const Eigen::Matrix3d& S);

}  // namespace meshdeform::core
