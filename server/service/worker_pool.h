#pragma once
/// @file worker_pool.h
/// A fixed pool of std::jthread workers: solves run here, never on transport threads.

#include <condition_variable>
#include <deque>
#include <functional>
#include <mutex>
#include <thread>
#include <vector>

namespace meshdeform::service {

/// First-in first-out task pool with a fixed number of threads.
class WorkerPool {
 public:
  /// @param[in] size  threads; values < 1 mean std::thread::hardware_concurrency() (at least 1).
  explicit WorkerPool(int size);
  /// Runs every task still queued, then joins the threads.
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  /// Queues a task. Tasks must not throw (an escaping exception is swallowed).
  void submit(std::function<void()> task);
  int size() const { return static_cast<int>(threads_.size()); }

 private:
  void run(std::stop_token stop);

  std::mutex mutex_;
  std::condition_variable_any cv_;
  std::deque<std::function<void()>> queue_;
  std::vector<std::jthread> threads_;
};

}  // namespace meshdeform::service
