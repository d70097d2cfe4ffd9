#pragma once
/// @file session_store.h
/// Owns the sessions and enforces the session-count limit, the memory budget (least recently used
/// idle sessions are evicted first) and the idle TTL.

#include <chrono>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "server/service/session.h"
#include "server/service/types.h"

namespace meshdeform::service {

/// Thread-safe map SessionId -> Session. `find` hands out a shared_ptr that the caller holds for
/// one request only (TF Serving's ServableHandle rule): eviction removes a session from the map
/// and closes it, and an in-flight request on it then ends with NotFound.
class SessionStore {
 public:
  explicit SessionStore(const ServiceOptions& options);

  /// Adds a session charged `estimated_bytes()`; first drops expired sessions, then makes room
  /// by eviction (ServiceOptions::memory_budget_per_client_bytes says whose sessions go first).
  /// Sessions with an edit in flight or a watcher are never evicted.
  /// @return ResourceExhausted naming the limit when max_sessions are open, when the session's
  ///         owner has max_sessions_per_client open or would pass its memory quota, or when the
  ///         budget cannot be met by eviction.
  [[nodiscard]] Status insert(std::shared_ptr<Session> session);
  /// The session, touched (last used = now); nullptr if unknown, closed or expired.
  std::shared_ptr<Session> find(const SessionId& id);
  /// Removes and closes a session; false if unknown.
  bool erase(const SessionId& id);
  /// Removes a session without closing it (a stale copy whose watchers move to its successor).
  /// @return the session, or nullptr if unknown.
  std::shared_ptr<Session> erase_without_closing(const SessionId& id);
  /// Makes room for `bytes` more on behalf of `requester` (never evicted here), within its
  /// owner's memory quota.
  /// @return ResourceExhausted with the estimate and the budget when eviction is not enough.
  [[nodiscard]] Status reserve(std::size_t bytes, const Session& requester);
  /// Removes sessions idle (no edit in flight, no watcher) for longer than the TTL at `now`.
  /// @return how many were removed.
  std::size_t evict_expired(std::chrono::steady_clock::time_point now);

  std::size_t size() const;
  std::size_t total_bytes() const;
  /// Open Watch subscriptions over all sessions.
  int watcher_count() const;
  /// The sessions with at least one watcher.
  std::vector<std::shared_ptr<Session>> watched() const;
  /// Ends every session's watches with `reason` (Session::close_watchers).
  void close_all_watchers(const Status& reason);
  std::uint64_t evicted_lru() const;
  std::uint64_t evicted_idle() const;
  std::chrono::steady_clock::time_point now() const { return clock_(); }
  /// Whether an evicted session can come back (a state directory or a shared store holds it):
  /// then idle sessions of any client may be evicted for room, else only the requester's own
  /// and those of clients over their quota.
  void set_eviction_lossless(bool lossless) { lossless_ = lossless; }
  /// Closes every session (service shutdown).
  void clear();

 private:
  std::size_t total_bytes_locked() const;
  bool is_expired_locked(const Session& session, std::chrono::steady_clock::time_point now) const;
  std::size_t evict_expired_locked(std::chrono::steady_clock::time_point now);
  /// Evicts idle sessions (not `keep`) until `bytes` more fit the budget (and `owner`'s quota):
  /// `owner`'s own first, then those of clients over their quota, then (lossless_ only) the
  /// rest, each tier least recently used first. Evicts nothing unless that is enough.
  /// @return an empty status, or ResourceExhausted saying what could not be met.
  Status make_room_locked(std::size_t bytes, const Session* keep, const std::string& owner);
  std::size_t bytes_of_locked(const std::string& owner) const;
  std::size_t per_client_bytes() const;

  ServiceOptions options_;
  Clock clock_;
  mutable std::mutex mutex_;
  std::map<SessionId, std::shared_ptr<Session>> sessions_;
  bool lossless_ = false;
  std::uint64_t evicted_lru_ = 0;
  std::uint64_t evicted_idle_ = 0;
};

}  // namespace meshdeform::service
