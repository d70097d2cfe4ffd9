#include "core/curves/koch.h"

#include <cmath>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include "core/base/format_number.h"

namespace meshdeform::core {
namespace {

constexpr int kMaxKochLevel = 10;

}  // namespace

Result<Polyline> make_koch_curve(int level) {
  if (level < 0 || level > kMaxKochLevel) {
    return Error(ErrorCode::InvalidArgument, "Koch level must be in [0, " +
                                                 std::to_string(kMaxKochLevel) + "], got " +
                                                 std::to_string(level));
  }
  std::vector<Eigen::Vector2d> points = {{0.0, 0.0}, {1.0, 0.0}};
  const double c = 0.5, s = std::sqrt(3.0) / 2;  // rotation by +60 degrees: bumps point up
  for (int l = 0; l < level; ++l) {
    std::vector<Eigen::Vector2d> next;
    next.reserve(4 * points.size());
    for (size_t i = 0; i + 1 < points.size(); ++i) {
      const Eigen::Vector2d a = points[i], d = (points[i + 1] - points[i]) / 3.0;
      const Eigen::Vector2d apex =
          a + d + Eigen::Vector2d(c * d.x() - s * d.y(), s * d.x() + c * d.y());
      next.push_back(a);
      next.push_back(a + d);
      next.push_back(apex);
      next.push_back(a + 2.0 * d);
    }
    next.push_back(points.back());
    points = std::move(next);
  }
  Polyline curve;
  curve.closed = false;
  curve.P.resize(static_cast<Eigen::Index>(points.size()), 2);
  for (size_t i = 0; i < points.size(); ++i) {
    curve.P.row(static_cast<Eigen::Index>(i)) = points[i].transpose();
  }
  return curve;
}

Result<CurveEdit> make_koch_edit(int level, double pull) {
  if (level < 1 || level > kMaxKochLevel) {
    return Error(ErrorCode::InvalidArgument,
                 "the Koch edit needs a level in [1, " + std::to_string(kMaxKochLevel) +
                     "] (level 0 is one segment, with no middle point), got " +
                     std::to_string(level));
  }
  if (!std::isfinite(pull)) {
    return Error(ErrorCode::InvalidArgument, "pull must be finite, got " + format_number(pull, "%g"));
  }
  CurveEdit edit;
  MD_ASSIGN_OR_RETURN(edit.rest, make_koch_curve(level));
  const int last = static_cast<int>(edit.rest.P.rows()) - 1;
  edit.handle = last / 2;
  edit.constrained.resize(3);
  edit.constrained << 0, edit.handle, last;
  edit.targets.resize(3, 2);
  for (int j = 0; j < 3; ++j) edit.targets.row(j) = edit.rest.P.row(edit.constrained(j));
  edit.targets(1, 1) += pull;
  return edit;
}

}  // namespace meshdeform::core
