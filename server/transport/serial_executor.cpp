#include "server/transport/serial_executor.h"

namespace meshdeform::transport {

SerialExecutor::SerialExecutor() : thread_([this](std::stop_token stop) { run(stop); }) {}

SerialExecutor::~SerialExecutor() {
  thread_.request_stop();
  cv_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void SerialExecutor::post(std::function<void()> task) {
  {
    const std::lock_guard lock(mutex_);
    tasks_.push_back(std::move(task));
  }
  cv_.notify_one();
}

void SerialExecutor::post_at(Clock::time_point when, std::function<void()> task) {
  {
    const std::lock_guard lock(mutex_);
    timed_.emplace(when, std::move(task));
  }
  cv_.notify_one();
}

void SerialExecutor::run(std::stop_token stop) {
  for (;;) {
    std::function<void()> task;
    {
      std::unique_lock lock(mutex_);
      for (;;) {
        // Timed tasks whose time has come join the queue in time order.
        const Clock::time_point now = Clock::now();
        while (!timed_.empty() && timed_.begin()->first <= now) {
          tasks_.push_back(std::move(timed_.begin()->second));
          timed_.erase(timed_.begin());
        }
        if (!tasks_.empty()) break;
        if (stop.stop_requested()) return;  // nothing due: timed tasks not yet due are dropped
        if (timed_.empty()) {
          cv_.wait(lock, stop, [this] { return !tasks_.empty() || !timed_.empty(); });
        } else {
          // Also wake for a timed task posted meanwhile that is due earlier.
          const Clock::time_point deadline = timed_.begin()->first;
          cv_.wait_until(lock, stop, deadline, [this, deadline] {
            return !tasks_.empty() || timed_.begin()->first < deadline;
          });
        }
      }
      task = std::move(tasks_.front());
      tasks_.pop_front();
    }
    task();
  }
}

}  // namespace meshdeform::transport
