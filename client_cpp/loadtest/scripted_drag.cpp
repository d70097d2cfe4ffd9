#include "client_cpp/loadtest/scripted_drag.h"

#include <algorithm>
#include <cmath>
#include <numbers>

namespace meshdeform::loadtest {

ScriptedDrag::ScriptedDrag(const std::array<double, 3>& bbox_min,
                           const std::array<double, 3>& bbox_max, double phase)
    : phase_(phase) {
  std::array<int, 3> axes{0, 1, 2};
  std::array<double, 3> extent{};
  for (int k = 0; k < 3; ++k) extent[k] = std::abs(bbox_max[k] - bbox_min[k]);
  // Longest first; ties keep x, y, z order so the choice is deterministic.
  std::stable_sort(axes.begin(), axes.end(), [&](int a, int b) { return extent[a] > extent[b]; });
  const int long_axis = axes[0];
  sway_[axes[1]] = 1.0;
  lift_[axes[2]] = 1.0;
  std::array<double, 3> along{};
  along[long_axis] = 1.0;
  tilt_axis_ = {along[1] * sway_[2] - along[2] * sway_[1],
                along[2] * sway_[0] - along[0] * sway_[2],
                along[0] * sway_[1] - along[1] * sway_[0]};
  length_ = extent[long_axis] > 0.0 ? extent[long_axis] : 1.0;
}

DragPose ScriptedDrag::pose_at(double seconds) const {
  const double angle = 2.0 * std::numbers::pi * (seconds / kPeriodSeconds + phase_);
  const double sway = 0.15 * length_ * std::sin(angle);
  const double lift = 0.08 * length_ * (1.0 - std::cos(angle));
  DragPose pose;
  for (int k = 0; k < 3; ++k) pose.translation[k] = sway * sway_[k] + lift * lift_[k];
  const double half_tilt = 0.5 * 0.35 * std::sin(angle);
  pose.rotation = {std::cos(half_tilt), std::sin(half_tilt) * tilt_axis_[0],
                   std::sin(half_tilt) * tilt_axis_[1], std::sin(half_tilt) * tilt_axis_[2]};
  return pose;
}

}  // namespace meshdeform::loadtest
