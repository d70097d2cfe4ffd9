#pragma once
// Shared by the benchmarks: Spot at a Loop-subdivision level with one of its edits, and the
// powers of an edit's 4x4 transform (to continue an edit, or to drag its handles there in steps).

#include <string>

#include <Eigen/Core>
#include <unsupported/Eigen/MatrixFunctions>

#include "core/io/mesh_io.h"
#include "core/samples/generators.h"
#include "core/base/status.h"

namespace meshdeform::bench {

/// tests/data/spot.obj (or `path`) after `level` Loop subdivisions (~2,930 x 4^level vertices),
/// with a bounding-box edit (core::make_spot_edit).
inline Result<core::DeformationBenchmark> load_spot_edit(const std::string& path, int level,
                                                         core::SpotEdit edit) {
  MD_ASSIGN_OR_RETURN(MeshData spot, io::read_mesh(path));
  MD_ASSIGN_OR_RETURN(MeshData fine, core::subdivide_loop(spot, level));
  return core::make_spot_edit(fine, edit);
}

/// T^p for an affine 4x4 T: p = 1 + f continues the edit along the same screw motion (or
/// translation), p in [0, 1] goes part of the way. Falls back to scaling the displacement when
/// the matrix logarithm is not real (sets *used_fallback when given).
inline Eigen::Matrix4d affine_power(const Eigen::Matrix4d& T, double p,
                                    bool* used_fallback = nullptr) {
  const Eigen::Matrix4d result = Eigen::MatrixPower<Eigen::Matrix4d>(T)(p);
  const bool is_affine =
      result.allFinite() &&
      (result.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() < 1e-9;
  if (used_fallback != nullptr) *used_fallback = !is_affine;
  if (is_affine) return result;
  return Eigen::Matrix4d::Identity() + p * (T - Eigen::Matrix4d::Identity());
}

}  // namespace meshdeform::bench
