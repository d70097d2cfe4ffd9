#pragma once
/// @file read_control.h
/// What every reader of untrusted bytes (mesh files, .sel, .def, JSON edit specs) takes to be
/// stopped early and to have its work counted. The rule the readers follow, "work bounded by
/// bytes", is stated in mesh_io.h.

#include <cstdint>
#include <stop_token>

#include "core/base/status.h"

namespace meshdeform::io {

/// Stops and observes a reader's work (see "Work bounded by bytes" in mesh_io.h).
struct ReadControl {
  /// When requested (a call's deadline or cancellation), the reader or the cleaning step returns
  /// Cancelled within a few thousand loop steps.
  std::stop_token stop;
  /// If set, incremented by the number of loop steps done (vertices, faces, list items, tokens,
  /// lines, skipped rows, cleaning passes): tests check it against the input size.
  std::uint64_t* work_steps = nullptr;
};

/// The most nested JSON arrays/objects a reader accepts (glTF, edit specs): deeper input is
/// refused before parsing, since JSON tree walks recurse.
inline constexpr int kMaxJsonDepth = 64;

/// Counts a reader's loop steps into ReadControl::work_steps and polls its stop token every few
/// thousand of them. Readers call step() in every loop, so the counter is the evidence for "work
/// bounded by bytes". Internal to meshdeform::io's readers.
class WorkMeter {
 public:
  explicit WorkMeter(const ReadControl& control) : control_(control) {}
  ~WorkMeter() {
    if (control_.work_steps != nullptr) *control_.work_steps += steps_;
  }
  WorkMeter(const WorkMeter&) = delete;
  WorkMeter& operator=(const WorkMeter&) = delete;
  /// Counts `n` steps. @return Cancelled once the stop is requested, else success.
  Status step(std::uint64_t n = 1) {
    steps_ += n;
    if (steps_ < next_poll_) return Status::success();
    next_poll_ = steps_ + kPollInterval;
    return poll();
  }
  /// Cancelled if the stop is requested now, else success.
  Status poll() const {
    if (!control_.stop.stop_requested()) return Status::success();
    return Error(ErrorCode::Cancelled, "reading was cancelled (deadline or client)");
  }

 private:
  static constexpr std::uint64_t kPollInterval = 4096;
  const ReadControl& control_;
  std::uint64_t steps_ = 0;
  std::uint64_t next_poll_ = kPollInterval;
};

}  // namespace meshdeform::io
