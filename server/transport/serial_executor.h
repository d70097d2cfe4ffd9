#pragma once
/// @file serial_executor.h
/// One thread running posted tasks in order: the Watch streams' per-stream delta encoding runs
/// here (issue 45), not on the worker that committed the revision (its notify must be quick)
/// nor on a gRPC thread. Tasks may also be posted to run at a time point (a stream's delayed
/// continuation). Destroying it runs what is due and queued, drops timed tasks not yet due,
/// then joins.

#include <chrono>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <thread>

namespace meshdeform::transport {

class SerialExecutor {
 public:
  using Clock = std::chrono::steady_clock;

  SerialExecutor();
  ~SerialExecutor();
  SerialExecutor(const SerialExecutor&) = delete;
  SerialExecutor& operator=(const SerialExecutor&) = delete;

  /// Queues `task` (must not throw; it runs on the executor's thread).
  void post(std::function<void()> task);
  /// Runs `task` at `when` or later (after the tasks queued by then).
  void post_at(Clock::time_point when, std::function<void()> task);

 private:
  void run(std::stop_token stop);

  std::mutex mutex_;
  std::condition_variable_any cv_;
  std::deque<std::function<void()>> tasks_;
  std::multimap<Clock::time_point, std::function<void()>> timed_;
  std::jthread thread_;  // last: started after the members it uses
};

}  // namespace meshdeform::transport
