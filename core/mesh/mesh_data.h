#pragma once
/// @file mesh_data.h
/// The basic mesh type shared by every layer (libigl style V/F).

#include <Eigen/Core>

namespace meshdeform {

/// Row-major-free, plain #V x 3 positions and #F x 3 0-based triangle indices.
using Positions = Eigen::Matrix<double, Eigen::Dynamic, 3>;
using Triangles = Eigen::Matrix<int, Eigen::Dynamic, 3>;

/// A triangle mesh: vertices and faces, nothing else.
struct MeshData {
  Positions V;  ///< #V x 3 vertex positions.
  Triangles F;  ///< #F x 3 triangle indices into V, counter-clockwise seen from outside.
};

}  // namespace meshdeform
