#include "server/service/bytes_memo.h"

namespace meshdeform::service {

std::shared_ptr<const std::string> BytesMemo::get(int key,
                                                  const std::function<std::string()>& make) {
  // Held while making: a second reader of the same value waits instead of encoding it again.
  const std::lock_guard lock(mutex_);
  for (const auto& [k, bytes] : entries_) {
    if (k == key) return bytes;
  }
  auto bytes = std::make_shared<const std::string>(make());
  entries_.emplace_back(key, bytes);
  return bytes;
}

void BytesMemo::clear() {
  const std::lock_guard lock(mutex_);
  entries_.clear();
}

std::size_t BytesMemo::bytes() const {
  const std::lock_guard lock(mutex_);
  std::size_t total = 0;
  for (const auto& entry : entries_) total += entry.second->size();
  return total;
}

}  // namespace meshdeform::service
