#pragma once
/// @file watcher.h
/// Per-watcher mailbox of size one: a slow watcher skips to the newest revision, so the editor
/// never waits for it and memory per watcher stays bounded (one shared DeformResult).

#include <chrono>
#include <condition_variable>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>

#include "core/base/status.h"
#include "server/service/types.h"

namespace meshdeform::service {

class Session;

/// The receiving end of a watch. Thread-safe.
class Watcher {
 public:
  /// The pending update, if any, without waiting.
  std::optional<DeformUpdate> try_take();
  /// Waits for an update at most `timeout`.
  /// @return the newest pending update; nullopt on timeout, when `stop` is requested, or when
  ///         the session is closed and nothing is pending.
  std::optional<DeformUpdate> wait_take(std::chrono::milliseconds timeout, std::stop_token stop = {});
  /// True once the session was closed or evicted (no further updates).
  bool closed() const;
  /// Why the watch ended once closed(): success when its session was closed (the stream ends
  /// OK), otherwise what ended it (e.g. Unavailable: the server shuts down).
  Status close_status() const;
  /// Called when an update becomes pending while none was (and on close), on the committing
  /// thread (a worker): it must be quick and must not block, e.g. start an async write that
  /// calls try_take(). Setting it when an update is already pending calls it once at once.
  void set_notify(std::function<void()> notify);

  /// Service side: offers a new revision; a pending one is replaced (the next take is a snapshot).
  void publish(std::shared_ptr<const DeformResult> result);
  /// Service side: offers the join snapshot.
  void publish_snapshot(std::shared_ptr<const DeformResult> result);
  /// Service side: no more updates; `reason` as close_status() (success: the session closed).
  void close(Status reason = Status::success());
  /// Service side: the session copy that publishes to this watcher (a stale copy hands its
  /// watchers over to the fresh one); Subscription unsubscribes from it.
  void set_owner(std::weak_ptr<Session> owner);
  std::shared_ptr<Session> owner() const;

 private:
  void offer(std::shared_ptr<const DeformResult> result, bool snapshot);

  mutable std::mutex mutex_;
  std::condition_variable_any cv_;
  std::optional<DeformUpdate> pending_;
  std::uint64_t newest_revision_ = 0;
  bool has_any_ = false;
  bool closed_ = false;
  Status close_status_;
  std::function<void()> notify_;
  std::weak_ptr<Session> owner_;
};

/// Owns a watch; unsubscribes when destroyed. Move-only.
class Subscription {
 public:
  Subscription() = default;
  /// @param[in] watcher  a watcher whose owner() is the session it watches.
  explicit Subscription(std::shared_ptr<Watcher> watcher);
  Subscription(Subscription&&) noexcept = default;
  Subscription& operator=(Subscription&& other) noexcept;
  Subscription(const Subscription&) = delete;
  Subscription& operator=(const Subscription&) = delete;
  ~Subscription();

  Watcher& watcher() { return *watcher_; }
  Watcher* operator->() { return watcher_.get(); }
  /// Unsubscribes now (idempotent).
  void reset();

 private:
  std::shared_ptr<Watcher> watcher_;
};

}  // namespace meshdeform::service
