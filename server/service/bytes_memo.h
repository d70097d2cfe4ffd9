#pragma once
/// @file bytes_memo.h
/// Bytes derived from an immutable value, made once and shared by every reader: a result's
/// positions in a wire encoding are the same for the move's response and for every watcher's
/// update, and at 187k vertices one meshopt encoding costs about 6 ms of the move's latency
/// (measured through the server: the watcher's copy was made on the worker before the response).

#include <condition_variable>
#include <cstdint>
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
  /// The bytes for `key`: made by `make` the first time, shared afterwards. A reader asking
  /// for a key another reader is making waits for that one `make` (no lock is held while it
  /// runs: other keys and clear() do not wait). `make` must not use this memo.
  std::shared_ptr<const std::string> get(int key, const std::function<std::string()>& make);

  /// Forgets every entry (e.g. when a newer revision supersedes the value) without waiting for
  /// a `make` in progress, whose bytes then go to its readers only. The memory goes once no
  /// reader holds it; later get()s make the bytes again.
  void clear();

  /// Bytes held now (for tests and memory accounting).
  std::size_t bytes() const;

 private:
  mutable std::mutex mutex_;
  std::condition_variable made_;  // a make finished (or failed)
  std::vector<std::pair<int, std::shared_ptr<const std::string>>> entries_;
  std::vector<int> making_;      // keys whose make is running
  std::uint64_t generation_ = 0;  // clear() count: a make that started before a clear keeps out
};

}  // namespace meshdeform::service
