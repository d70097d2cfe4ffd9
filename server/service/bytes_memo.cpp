#include "server/service/bytes_memo.h"

#include <algorithm>

namespace meshdeform::service {

std::shared_ptr<const std::string> BytesMemo::get(int key,
                                                  const std::function<std::string()>& make) {
  std::unique_lock lock(mutex_);
  for (;;) {
    for (const auto& [k, bytes] : entries_) {
      if (k == key) return bytes;
    }
    // Nobody is making it: this reader will. Otherwise wait for that reader (a second encoding
    // of the same value is the waste this memo is for).
    if (std::find(making_.begin(), making_.end(), key) == making_.end()) break;
    made_.wait(lock);
  }
  making_.push_back(key);
  const std::uint64_t generation = generation_;
  lock.unlock();
  auto finish = [&](std::shared_ptr<const std::string> bytes) {
    lock.lock();
    making_.erase(std::find(making_.begin(), making_.end(), key));
    if (bytes && generation == generation_) entries_.emplace_back(key, std::move(bytes));
    made_.notify_all();
  };
  std::shared_ptr<const std::string> bytes;
  try {
    bytes = std::make_shared<const std::string>(make());
  } catch (...) {
    finish(nullptr);  // waiting readers try again themselves
    throw;
  }
  finish(bytes);
  return bytes;
}

void BytesMemo::clear() {
  const std::lock_guard lock(mutex_);
  entries_.clear();
  ++generation_;
}

std::size_t BytesMemo::bytes() const {
  const std::lock_guard lock(mutex_);
  std::size_t total = 0;
  for (const auto& entry : entries_) total += entry.second->size();
  return total;
}

}  // namespace meshdeform::service
