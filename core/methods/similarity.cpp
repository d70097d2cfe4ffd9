#include "core/methods/similarity.h"

#include <cmath>

namespace meshdeform::core {

Eigen::Vector3d similarity_pivot(const GroupSimilarity& transform, const Positions& points) {
  if (transform.pivot) return *transform.pivot;
  return points.colwise().mean().transpose();
}

Positions apply_similarity(const GroupSimilarity& transform, const Positions& points) {
  const Eigen::RowVector3d pivot = similarity_pivot(transform, points).transpose();
  const Eigen::Matrix3d sR = transform.scale * transform.rotation;
  Positions out(points.rows(), 3);
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    out.row(i) = pivot + (sR * (points.row(i) - pivot).transpose()).transpose() +
                 transform.translation.transpose();
  }
  return out;
}

std::optional<GroupSimilarity> similarity_from_matrix(const Eigen::Matrix4d& T) {
  const Eigen::Vector4d last_row = T.row(3).transpose();
  if ((last_row - Eigen::Vector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff() > 1e-12) return std::nullopt;
  const Eigen::Matrix3d A = T.topLeftCorner<3, 3>();
  const double det = A.determinant();
  if (!(det > 0)) return std::nullopt;
  const double s = std::cbrt(det);
  const Eigen::Matrix3d R = A / s;
  if ((R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-9) {
    return std::nullopt;
  }
  GroupSimilarity out;
  out.rotation = R;
  out.scale = s;
  out.pivot = Eigen::Vector3d::Zero();
  out.translation = T.topRightCorner<3, 1>();
  return out;
}

}  // namespace meshdeform::core
