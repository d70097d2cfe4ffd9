#pragma once
/// @file call_stop.h
/// The one stop of a call on the service: requested when the caller's token is (a cancelled or
/// timed-out RPC), when the service shuts down, or once the call's deadline passes. Sessions and
/// core's solvers get its token and look at nothing else to stop.

#include <chrono>
#include <optional>
#include <stop_token>

#include "server/service/delay_queue.h"

namespace meshdeform::service {

class CallStop {
 public:
  /// Stops with `call` or `shutdown`.
  CallStop(std::stop_token call, std::stop_token shutdown);
  /// ... and at `deadline` (nullopt: none; already passed: at once), timed on `timers`.
  CallStop(std::stop_token call, std::stop_token shutdown,
           std::optional<std::chrono::steady_clock::time_point> deadline, DelayQueue& timers);
  CallStop(const CallStop&) = delete;
  CallStop& operator=(const CallStop&) = delete;

  std::stop_token token() const { return source_.get_token(); }
  /// The stop itself, for whoever must be able to request it as well (refinement preemption).
  std::stop_source source() const { return source_; }

 private:
  struct Forward {
    std::stop_source source;
    void operator()() { source.request_stop(); }
  };
  std::stop_source source_;
  std::stop_callback<Forward> call_, shutdown_;
};

}  // namespace meshdeform::service
