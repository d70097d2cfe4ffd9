#include "server/service/session_store.h"

#include <algorithm>
#include <string>
#include <vector>

namespace meshdeform::service {

SessionStore::SessionStore(const ServiceOptions& options)
    : options_(options),
      clock_(options.clock ? options.clock : Clock([] { return std::chrono::steady_clock::now(); })) {}

std::size_t SessionStore::total_bytes_locked() const {
  std::size_t total = 0;
  for (const auto& [id, session] : sessions_) total += session->estimated_bytes();
  return total;
}

bool SessionStore::is_expired_locked(const Session& session,
                                     std::chrono::steady_clock::time_point now) const {
  return session.inflight_count() == 0 && session.watcher_count() == 0 &&
         now - session.last_used() > options_.idle_ttl;
}

std::size_t SessionStore::evict_expired_locked(std::chrono::steady_clock::time_point now) {
  std::size_t removed = 0;
  for (auto it = sessions_.begin(); it != sessions_.end();) {
    if (is_expired_locked(*it->second, now)) {
      it->second->close();
      it = sessions_.erase(it);
      ++removed;
    } else {
      ++it;
    }
  }
  evicted_idle_ += removed;
  return removed;
}

bool SessionStore::make_room_locked(std::size_t bytes, const Session* keep) {
  std::size_t total = total_bytes_locked();
  if (total + bytes <= options_.memory_budget_bytes) return true;
  std::vector<std::shared_ptr<Session>> idle;
  for (const auto& [id, session] : sessions_) {
    if (session.get() != keep && session->inflight_count() == 0) idle.push_back(session);
  }
  std::sort(idle.begin(), idle.end(),
            [](const auto& a, const auto& b) { return a->last_used() < b->last_used(); });
  // Only evict if that is enough: refusing must not cost other clients their sessions.
  std::size_t reclaimable = 0;
  for (const auto& session : idle) reclaimable += session->estimated_bytes();
  if (total - std::min(total, reclaimable) + bytes > options_.memory_budget_bytes) return false;
  for (const auto& session : idle) {
    if (total + bytes <= options_.memory_budget_bytes) break;
    total -= std::min(total, session->estimated_bytes());
    session->close();
    sessions_.erase(session->id());
    ++evicted_lru_;
  }
  return true;
}

Status SessionStore::insert(std::shared_ptr<Session> session) {
  const auto now = clock_();
  std::lock_guard lock(mutex_);
  evict_expired_locked(now);
  if (static_cast<int>(sessions_.size()) >= options_.max_sessions) {
    return Error(ErrorCode::ResourceExhausted,
                 "too many sessions: " + std::to_string(sessions_.size()) + " open, the limit is " +
                     std::to_string(options_.max_sessions));
  }
  const std::size_t bytes = session->estimated_bytes();
  if (!make_room_locked(bytes, nullptr)) {
    return Error(ErrorCode::ResourceExhausted,
                 "memory budget exceeded: the session needs about " + std::to_string(bytes) +
                     " bytes, " + std::to_string(total_bytes_locked()) + " of " +
                     std::to_string(options_.memory_budget_bytes) +
                     " are used by sessions that are busy (the budget is the server's "
                     "--memory-budget-mib)");
  }
  session->touch(now);
  sessions_.emplace(session->id(), std::move(session));
  return Status::success();
}

std::shared_ptr<Session> SessionStore::find(const SessionId& id) {
  const auto now = clock_();
  std::lock_guard lock(mutex_);
  auto it = sessions_.find(id);
  if (it == sessions_.end()) return nullptr;
  if (it->second->is_closed()) {
    sessions_.erase(it);
    return nullptr;
  }
  // Expiry is decided on lookup too, so a TTL holds without a timer.
  if (is_expired_locked(*it->second, now)) {
    it->second->close();
    sessions_.erase(it);
    ++evicted_idle_;
    return nullptr;
  }
  it->second->touch(now);
  return it->second;
}

bool SessionStore::erase(const SessionId& id) {
  std::shared_ptr<Session> session;
  {
    std::lock_guard lock(mutex_);
    auto it = sessions_.find(id);
    if (it == sessions_.end()) return false;
    session = std::move(it->second);
    sessions_.erase(it);
  }
  session->close();
  return true;
}

Status SessionStore::reserve(std::size_t bytes, const Session& requester) {
  std::lock_guard lock(mutex_);
  if (!make_room_locked(bytes, &requester)) {
    return Error(ErrorCode::ResourceExhausted,
                 "memory budget exceeded: a new factorization needs about " +
                     std::to_string(bytes) + " bytes, " + std::to_string(total_bytes_locked()) +
                     " of " + std::to_string(options_.memory_budget_bytes) +
                     " are in use (the budget is the server's --memory-budget-mib)");
  }
  return Status::success();
}

std::size_t SessionStore::evict_expired(std::chrono::steady_clock::time_point now) {
  std::lock_guard lock(mutex_);
  return evict_expired_locked(now);
}

std::size_t SessionStore::size() const {
  std::lock_guard lock(mutex_);
  return sessions_.size();
}

std::size_t SessionStore::total_bytes() const {
  std::lock_guard lock(mutex_);
  return total_bytes_locked();
}

std::uint64_t SessionStore::evicted_lru() const {
  std::lock_guard lock(mutex_);
  return evicted_lru_;
}

std::uint64_t SessionStore::evicted_idle() const {
  std::lock_guard lock(mutex_);
  return evicted_idle_;
}

void SessionStore::clear() {
  std::map<SessionId, std::shared_ptr<Session>> sessions;
  {
    std::lock_guard lock(mutex_);
    sessions.swap(sessions_);
  }
  for (auto& [id, session] : sessions) session->close();
}

void SessionStore::close_all_watchers() {
  std::vector<std::shared_ptr<Session>> sessions;
  {
    std::lock_guard lock(mutex_);
    for (const auto& [id, session] : sessions_) sessions.push_back(session);
  }
  for (const auto& session : sessions) session->close_watchers();
}

std::vector<std::shared_ptr<Session>> SessionStore::watched() const {
  std::vector<std::shared_ptr<Session>> sessions;
  std::lock_guard lock(mutex_);
  for (const auto& [id, session] : sessions_) {
    if (session->watcher_count() > 0) sessions.push_back(session);
  }
  return sessions;
}

int SessionStore::watcher_count() const {
  std::lock_guard lock(mutex_);
  int count = 0;
  for (const auto& [id, session] : sessions_) count += session->watcher_count();
  return count;
}

}  // namespace meshdeform::service
