#include "server/service/call_stop.h"

#include <utility>

namespace meshdeform::service {

CallStop::CallStop(std::stop_token call, std::stop_token shutdown)
    : call_(std::move(call), Forward{source_}), shutdown_(std::move(shutdown), Forward{source_}) {}

CallStop::CallStop(std::stop_token call, std::stop_token shutdown,
                   std::optional<std::chrono::steady_clock::time_point> deadline,
                   DelayQueue& timers)
    : CallStop(std::move(call), std::move(shutdown)) {
  if (!deadline || source_.stop_requested()) return;
  const auto left = *deadline - std::chrono::steady_clock::now();
  if (left <= std::chrono::steady_clock::duration::zero()) {
    source_.request_stop();
    return;
  }
  // The timer holds its own handle of the stop state: it may fire after the call has ended
  // (then it stops nothing anyone listens to).
  timers.post_after(left, [source = source_]() mutable { source.request_stop(); });
}

}  // namespace meshdeform::service
