#pragma once
/// @file rotation_fit.h
/// Internal to core: the rotation closest to a 3x3 matrix, shared by ARAP's local step and the
/// scale control's face frames.

#include <Eigen/Core>

namespace meshdeform::core {

/// The rotation R maximising trace(R^T S) (the Kabsch / orthogonal Procrustes fit with the
/// reflection removed), in closed form; see rotation_fit.cpp.
Eigen::Matrix3d closest_rotation(const Eigen::Matrix3d& S);
/// R[i] = closest_rotation(S[i]) for i < count, to round-off: several at a time (the scalar
/// function is a chain of dependent steps; independent matrices side by side keep the core busy).
void closest_rotations(const Eigen::Matrix3d* S, Eigen::Matrix3d* R, int count);

}  // namespace meshdeform::core
