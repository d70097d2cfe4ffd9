#pragma once
/// @file scripted_drag.h
/// The scripted drag of one load-test session: the handle group sways smoothly back and forth
/// across the mesh's long axis, lifting a little and tilting with the sway, as a user dragging a
/// handle would. Absolute targets (GroupMove is absolute), a pure function of time.

#include <array>

namespace meshdeform::loadtest {

/// A rigid move of the handle group relative to its anchors (rotation about the group centroid).
struct DragPose {
  std::array<double, 3> translation{};
  std::array<double, 4> rotation{1.0, 0.0, 0.0, 0.0};  ///< unit quaternion w, x, y, z
};

class ScriptedDrag {
 public:
  /// One sway cycle lasts this long.
  static constexpr double kPeriodSeconds = 4.0;

  /// @param[in] bbox_min, bbox_max  the rest mesh's bounding box (sets the axes and amplitude).
  /// @param[in] phase               offset in cycles, so sessions do not move in lockstep.
  ScriptedDrag(const std::array<double, 3>& bbox_min, const std::array<double, 3>& bbox_max,
               double phase);

  /// The target at `seconds` after the drag started: translation 0.15 L sin(2 pi s) across the
  /// long axis plus a lift of 0.08 L (1 - cos(2 pi s)), and a tilt of 0.35 sin(2 pi s) rad,
  /// where s = seconds / kPeriodSeconds + phase and L is the longest bounding-box extent.
  DragPose pose_at(double seconds) const;

 private:
  std::array<double, 3> sway_{};  ///< unit, the middle bbox axis
  std::array<double, 3> lift_{};  ///< unit, the shortest bbox axis
  std::array<double, 3>
      tilt_axis_{};  ///< long axis x sway axis: a positive tilt leans toward the sway
  double length_ = 1.0;
  double phase_ = 0.0;
};

}  // namespace meshdeform::loadtest
