#include "server/service/worker_pool.h"

#include <algorithm>

#include "server/service/guard.h"

namespace meshdeform::service {
namespace {
/// The pool whose worker this thread is (null elsewhere), and whether it is running a task at
/// a yield point (which does not yield again).
thread_local const WorkerPool* tl_pool = nullptr;
thread_local bool tl_in_yield = false;
}  // namespace

WorkerPool::WorkerPool(int size, int heavy_lanes) {
  if (size < 1) size = std::max(2, static_cast<int>(std::thread::hardware_concurrency()));
  heavy_lanes_ = heavy_lanes < 1 ? std::max(1, size - 1) : heavy_lanes;
  if (size > 1) heavy_lanes_ = std::min(heavy_lanes_, size - 1);
  size_ = size;
  threads_.reserve(static_cast<std::size_t>(size));
  for (int i = 0; i < size; ++i) {
    // With one thread it must run everything; it still prefers normal tasks (see run()).
    const bool heavy_lane = i < heavy_lanes_;
    threads_.emplace_back([this, heavy_lane](std::stop_token stop) { run(stop, heavy_lane); });
  }
}

WorkerPool::~WorkerPool() {
  for (std::jthread& thread : threads_) thread.request_stop();
  threads_.clear();  // joins; run() drains the queues before returning
}

void WorkerPool::submit(std::function<void()> task, TaskClass task_class, std::string client) {
  {
    std::lock_guard lock(mutex_);
    switch (task_class) {
      case TaskClass::Normal:
        queue_.push_back({std::move(task), false});
        break;
      case TaskClass::Heavy:
        heavy_.push_back({std::move(client), std::move(task)});
        break;
      case TaskClass::Background:
        background_.push_back(std::move(task));
        break;
    }
  }
  // Not every worker may take every class: wake them all and let each check.
  cv_.notify_all();
}

void WorkerPool::submit_short(std::function<void()> task) {
  {
    std::lock_guard lock(mutex_);
    queue_.push_back({std::move(task), true});
  }
  cv_.notify_all();
}

bool WorkerPool::run_short_here() {
  if (tl_pool != this || tl_in_yield) return false;
  std::function<void()> task;
  {
    std::lock_guard lock(mutex_);
    const auto it = std::find_if(queue_.begin(), queue_.end(),
                                 [](const NormalTask& t) { return t.is_short; });
    if (it == queue_.end()) return false;
    task = std::move(it->task);
    queue_.erase(it);
  }
  ran_at_yield_.fetch_add(1);
  tl_in_yield = true;
  (void)run_guarded("worker task", [&task] {
    task();
    return Status::success();
  });
  tl_in_yield = false;
  return true;
}

QueueDepths WorkerPool::depths() const {
  std::lock_guard lock(mutex_);
  return {queue_.size(), heavy_.size(), background_.size(), heavy_running_};
}

void WorkerPool::run(std::stop_token stop, bool heavy_lane) {
  // A single worker must run heavy tasks too, but after the light ones.
  const bool only_worker = size_ == 1;
  tl_pool = this;
  while (true) {
    std::function<void()> task;
    bool is_heavy = false;
    {
      std::unique_lock lock(mutex_);
      cv_.wait(lock, stop, [&] {
        return !queue_.empty() || (heavy_lane && !heavy_.empty()) || !background_.empty();
      });
      if (heavy_lane && !heavy_.empty() && !(only_worker && !queue_.empty())) {
        // Fair between clients: the oldest task of the client served least recently (the
        // queue is bounded by admission control, so the scan is short).
        auto pick = heavy_.begin();
        std::uint64_t best = UINT64_MAX;
        for (auto it = heavy_.begin(); it != heavy_.end(); ++it) {
          const auto served = last_served_.find(it->client);
          const std::uint64_t tick = served == last_served_.end() ? 0 : served->second;
          if (tick < best) {
            best = tick;
            pick = it;
          }
        }
        last_served_[pick->client] = ++serve_tick_;
        task = std::move(pick->task);
        heavy_.erase(pick);
        if (heavy_.empty()) last_served_.clear();  // nothing to be fair about: forget
        is_heavy = true;
        ++heavy_running_;
      } else if (!queue_.empty()) {
        task = std::move(queue_.front().task);
        queue_.pop_front();
      } else if (stop.stop_requested()) {
        background_.clear();
        return;  // stop requested and no normal or heavy task left to drain
      } else if (!background_.empty()) {
        task = std::move(background_.front());
        background_.pop_front();
      } else {
        continue;  // woken for a heavy task that another lane took
      }
    }
    // Tasks report their own errors; a pool thread must survive (and log) a buggy one.
    (void)run_guarded("worker task", [&task] {
      task();
      return Status::success();
    });
    if (is_heavy) {
      std::lock_guard lock(mutex_);
      --heavy_running_;
    }
  }
}

}  // namespace meshdeform::service
