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

/// First-in first-out task pool with a fixed number of threads and two priorities: a worker
/// takes background tasks (refinement) only when no normal task (an edit) waits.
class WorkerPool {
 public:
  /// @param[in] size  threads; values < 1 mean std::thread::hardware_concurrency() (at least 1).
  explicit WorkerPool(int size);
  /// Runs every normal task still queued, drops the background ones, then joins the threads.
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  /// Queues a task. Tasks must not throw (an escaping exception is swallowed).
  void submit(std::function<void()> task);
  /// Queues a low-priority task: it runs when no normal task waits; dropped at shutdown.
  void submit_background(std::function<void()> task);
  int size() const { return static_cast<int>(threads_.size()); }

 private:
  void run(std::stop_token stop);

  std::mutex mutex_;
  std::condition_variable_any cv_;
  std::deque<std::function<void()>> queue_;
  std::deque<std::function<void()>> background_;
  std::vector<std::jthread> threads_;
};

}  // namespace meshdeform::service
