#pragma once
/// @file delay_queue.h
/// Runs short callbacks after a delay, on one thread of its own (callbacks should only hand work
/// on, e.g. to the worker pool). Destruction drops what has not run yet and joins the thread.

#include <chrono>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <queue>
#include <stop_token>
#include <thread>
#include <vector>

namespace meshdeform::service {

class DelayQueue {
 public:
  DelayQueue();
  ~DelayQueue();
  DelayQueue(const DelayQueue&) = delete;
  DelayQueue& operator=(const DelayQueue&) = delete;

  /// Runs `task` on the queue's thread once `delay` has passed (at once for zero or less).
  void post_after(std::chrono::steady_clock::duration delay, std::function<void()> task);

 private:
  struct Entry {
    std::chrono::steady_clock::time_point due;
    std::uint64_t order;  ///< ties run in posting order
    std::function<void()> task;
    bool operator>(const Entry& other) const {
      return due != other.due ? due > other.due : order > other.order;
    }
  };
  void run(std::stop_token stop);

  std::mutex mutex_;
  std::condition_variable_any changed_;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<Entry>> entries_;
  std::uint64_t next_order_ = 0;
  std::jthread thread_;  ///< last: started after the members it uses
};

}  // namespace meshdeform::service
