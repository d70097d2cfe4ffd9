#pragma once
/// @file worker_pool.h
/// A fixed pool of std::jthread workers: solves run here, never on transport threads.

#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <deque>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

namespace meshdeform::service {

/// What a task costs, for scheduling.
enum class TaskClass {
  Normal,      ///< light and latency-bound: a move, a quick read
  Heavy,       ///< long and bounded by admission: parsing an upload, a SetHandles precompute
  Background,  ///< refinement: only when nothing else waits
};

/// Tasks waiting per class (for /metrics).
struct QueueDepths {
  std::size_t normal = 0;
  std::size_t heavy = 0;
  std::size_t background = 0;
  int heavy_running = 0;
};

/// A task pool with a fixed number of threads and three task classes. Normal and background
/// tasks run first in, first out. Heavy tasks run only on the first `heavy_lanes` workers (at
/// most size - 1 when size > 1), which take heavy tasks first; the other workers never take
/// them, so light tasks (moves) always have a worker however many uploads and precomputes wait.
/// Heavy tasks are fair between clients: the next one is the oldest of the client served least
/// recently, so one client's queued uploads do not hold up another's. Background tasks run only
/// when no normal task waits (and, on a heavy lane, no heavy task).
class WorkerPool {
 public:
  /// @param[in] size         threads; values < 1 mean std::thread::hardware_concurrency(), at
  ///                         least 2 (one for heavy work, one kept for light work).
  /// @param[in] heavy_lanes  workers that may run heavy tasks; values < 1 mean size - 1
  ///                         (at least 1); clamped to size - 1 when size > 1.
  explicit WorkerPool(int size, int heavy_lanes = 0);
  /// Runs every normal and heavy task still queued, drops the background ones, then joins the
  /// threads.
  ~WorkerPool();
  WorkerPool(const WorkerPool&) = delete;
  WorkerPool& operator=(const WorkerPool&) = delete;

  /// Queues a task of the given class. Tasks must not throw (an escaping exception is swallowed).
  /// @param[in] client  who asked, for fairness between clients (heavy tasks only).
  void submit(std::function<void()> task, TaskClass task_class = TaskClass::Normal,
              std::string client = {});
  /// Queues a low-priority task: it runs when no normal task waits; dropped at shutdown.
  void submit_background(std::function<void()> task) {
    submit(std::move(task), TaskClass::Background);
  }
  /// Queues a normal task that is short (a drag's move of a few iterations): besides running on
  /// a free worker like any normal task, it may run on a busy worker at a long task's yield
  /// point (run_short_here), so that long solves do not hold it up.
  void submit_short(std::function<void()> task);
  /// A yield point of a long task: runs the oldest waiting short task on this thread, now.
  /// Only on this pool's workers and not from inside a task run here (no nesting).
  /// @return whether a task ran.
  bool run_short_here();
  /// Tasks run by run_short_here since start (counted before each runs).
  std::uint64_t ran_at_yield_points() const { return ran_at_yield_.load(); }
  int size() const { return size_; }
  int heavy_lanes() const { return heavy_lanes_; }
  QueueDepths depths() const;

 private:
  void run(std::stop_token stop, bool heavy_lane);

  mutable std::mutex mutex_;
  std::condition_variable_any cv_;
  struct NormalTask {
    std::function<void()> task;
    bool is_short = false;
  };
  std::deque<NormalTask> queue_;
  struct HeavyTask {
    std::string client;
    std::function<void()> task;
  };
  std::deque<HeavyTask> heavy_;
  std::map<std::string, std::uint64_t> last_served_;  ///< heavy: client -> serve tick
  std::uint64_t serve_tick_ = 0;
  std::deque<std::function<void()>> background_;
  int size_ = 1;
  int heavy_lanes_ = 1;
  int heavy_running_ = 0;
  std::atomic<std::uint64_t> ran_at_yield_{0};
  std::vector<std::jthread> threads_;
};

}  // namespace meshdeform::service
