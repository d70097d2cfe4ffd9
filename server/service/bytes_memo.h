#pragma once
/// @file bytes_memo.h
/// Bytes derived from an immutable value, made once and shared by every reader: a result's
/// positions in a wire encoding are the same for the move's response and for every watcher's
/// update, and at 187k vertices one meshopt encoding costs about 6 ms of the move's latency
/// (measured through the server: the watcher's copy was made on the worker before the response).

#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

namespace meshdeform::service {

/// A small thread-safe map from a caller's key to bytes. The keys mean what the caller says
/// (the transport uses encoding and field); the service only owns the memo's lifetime.
class BytesMemo {
 public:
  /// The bytes for `key`: made by `make` the first time, shared afterwards. Callers asking
  /// for the same key at once wait for one `make` (which must not use this memo).
  std::shared_ptr<const std::string> get(int key, const std::function<std::string()>& make);

  /// Forgets every entry (e.g. when a newer revision supersedes the value): the memory goes
  /// once no reader holds it; later get()s make the bytes again.
  void clear();

  /// Bytes held now (for tests and memory accounting).
  std::size_t bytes() const;

 private:
  mutable std::mutex mutex_;
  std::vector<std::pair<int, std::shared_ptr<const std::string>>> entries_;
};

}  // namespace meshdeform::service
