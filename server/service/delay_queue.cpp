#include "server/service/delay_queue.h"

namespace meshdeform::service {

DelayQueue::DelayQueue() : thread_([this](std::stop_token stop) { run(stop); }) {}

DelayQueue::~DelayQueue() {
  thread_.request_stop();
  changed_.notify_all();
  thread_.join();
}

void DelayQueue::post_after(std::chrono::steady_clock::duration delay, std::function<void()> task) {
  {
    const std::lock_guard lock(mutex_);
    entries_.push(Entry{std::chrono::steady_clock::now() + delay, next_order_++, std::move(task)});
  }
  changed_.notify_all();
}

void DelayQueue::run(std::stop_token stop) {
  std::unique_lock lock(mutex_);
  while (!stop.stop_requested()) {
    if (entries_.empty()) {
      changed_.wait(lock, stop, [this] { return !entries_.empty(); });
      continue;
    }
    const auto due = entries_.top().due;
    if (std::chrono::steady_clock::now() < due) {
      changed_.wait_until(lock, stop, due, [this, due] {
        return !entries_.empty() && entries_.top().due < due;  // an earlier entry arrived
      });
      continue;
    }
    std::function<void()> task = std::move(const_cast<Entry&>(entries_.top()).task);
    entries_.pop();
    lock.unlock();
    task();
    lock.lock();
  }
}

}  // namespace meshdeform::service
