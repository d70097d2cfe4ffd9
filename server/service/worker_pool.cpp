#include "server/service/worker_pool.h"

#include <algorithm>

namespace meshdeform::service {

WorkerPool::WorkerPool(int size) {
  if (size < 1) size = std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  threads_.reserve(static_cast<std::size_t>(size));
  for (int i = 0; i < size; ++i) {
    threads_.emplace_back([this](std::stop_token stop) { run(stop); });
  }
}

WorkerPool::~WorkerPool() {
  for (std::jthread& thread : threads_) thread.request_stop();
  threads_.clear();  // joins; run() drains the queue before returning
}

void WorkerPool::submit(std::function<void()> task) {
  {
    std::lock_guard lock(mutex_);
    queue_.push_back(std::move(task));
  }
  cv_.notify_one();
}

void WorkerPool::submit_background(std::function<void()> task) {
  {
    std::lock_guard lock(mutex_);
    background_.push_back(std::move(task));
  }
  cv_.notify_one();
}

void WorkerPool::run(std::stop_token stop) {
  while (true) {
    std::function<void()> task;
    {
      std::unique_lock lock(mutex_);
      cv_.wait(lock, stop, [this] { return !queue_.empty() || !background_.empty(); });
      if (!queue_.empty()) {
        task = std::move(queue_.front());
        queue_.pop_front();
      } else if (stop.stop_requested()) {
        background_.clear();
        return;  // stop requested and no normal task left to drain
      } else {
        task = std::move(background_.front());
        background_.pop_front();
      }
    }
    try {
      task();
    } catch (...) {
      // Tasks report their own errors; a pool thread must survive a buggy one.
    }
  }
}

}  // namespace meshdeform::service
