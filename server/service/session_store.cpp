#include "server/service/session_store.h"

#include <algorithm>
#include <map>
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

std::size_t SessionStore::bytes_of_locked(const std::string& owner) const {
  std::size_t total = 0;
  for (const auto& [id, session] : sessions_) {
    if (session->owner() == owner) total += session->estimated_bytes();
  }
  return total;
}

std::size_t SessionStore::per_client_bytes() const {
  // Three quarters: one multiresolution session of ~240k vertices fits a client of the default
  // budget (a 187k one is charged 1.25 GB; half of 2 GiB no longer held it once its deformer
  // was charged the refinement cascade's 6.2 KB per vertex).
  return options_.memory_budget_per_client_bytes > 0 ? options_.memory_budget_per_client_bytes
                                                     : options_.memory_budget_bytes / 4 * 3;
}

Status SessionStore::make_room_locked(std::size_t bytes, const Session* keep,
                                      const std::string& owner) {
  const std::size_t budget = options_.memory_budget_bytes;
  const std::size_t quota = per_client_bytes();
  std::size_t total = total_bytes_locked();
  // The owner's own quota (the empty owner, an in-process caller, has none).
  const bool limited = !owner.empty();
  std::size_t owned = limited ? bytes_of_locked(owner) : 0;
  if (total + bytes <= budget && (!limited || owned + bytes <= quota)) return Status::success();

  // Candidates by tier: 0 the owner's own, 1 clients over their quota, 2 anyone (lossless only).
  std::map<std::string, std::size_t> bytes_by_owner;
  for (const auto& [id, session] : sessions_) bytes_by_owner[session->owner()] += session->estimated_bytes();
  struct Candidate {
    int tier;
    std::shared_ptr<Session> session;
  };
  std::vector<Candidate> candidates;
  for (const auto& [id, session] : sessions_) {
    if (session.get() == keep || session->inflight_count() != 0 || session->watcher_count() != 0) {
      continue;  // busy or watched: never evicted
    }
    const std::string& whose = session->owner();
    int tier = -1;
    if (whose == owner) {
      tier = 0;
    } else if (!whose.empty() && bytes_by_owner[whose] > quota) {
      tier = 1;
    } else if (lossless_) {
      tier = 2;
    }
    if (tier >= 0) candidates.push_back({tier, session});
  }
  std::sort(candidates.begin(), candidates.end(), [](const Candidate& a, const Candidate& b) {
    return a.tier != b.tier ? a.tier < b.tier : a.session->last_used() < b.session->last_used();
  });
  // Plan first: evict only if that is enough (refusing must not cost anyone a session).
  std::size_t planned_total = total, planned_owned = owned;
  std::size_t count = 0;
  auto fits = [&] {
    return planned_total + bytes <= budget && (!limited || planned_owned + bytes <= quota);
  };
  while (!fits() && count < candidates.size()) {
    const Candidate& c = candidates[count++];
    const std::size_t b = c.session->estimated_bytes();
    planned_total -= std::min(planned_total, b);
    if (c.tier == 0) planned_owned -= std::min(planned_owned, b);
  }
  if (!fits()) {
    if (limited && owned + bytes > quota && planned_owned + bytes > quota) {
      return Error(ErrorCode::ResourceExhausted,
                   "memory quota per client exceeded: this client's sessions hold about " +
                       std::to_string(owned) + " bytes and need " + std::to_string(bytes) +
                       " more, the quota is " + std::to_string(quota) +
                       " (the server's --memory-budget-per-client-mib)");
    }
    return Error(ErrorCode::ResourceExhausted,
                 "memory budget exceeded: about " + std::to_string(bytes) + " bytes more are " +
                     "needed, " + std::to_string(total) + " of " + std::to_string(budget) +
                     " are held by sessions that are busy, watched or other clients' (the "
                     "budget is the server's --memory-budget-mib)");
  }
  for (std::size_t i = 0; i < count; ++i) {
    const std::shared_ptr<Session>& session = candidates[i].session;
    session->close();
    sessions_.erase(session->id());
    ++evicted_lru_;
  }
  return Status::success();
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
  const std::string& owner = session->owner();
  if (!owner.empty()) {
    const int per_client = options_.max_sessions_per_client > 0
                               ? options_.max_sessions_per_client
                               : std::max(1, options_.max_sessions / 4);
    const auto open = std::count_if(sessions_.begin(), sessions_.end(), [&owner](const auto& e) {
      return e.second->owner() == owner;
    });
    if (open >= per_client) {
      return Error(ErrorCode::ResourceExhausted,
                   "too many sessions per client: this client has " + std::to_string(open) +
                       " open, the limit is " + std::to_string(per_client) +
                       " (the server's --max-sessions-per-client); close one first");
    }
  }
  MD_RETURN_IF_ERROR(make_room_locked(session->estimated_bytes(), nullptr, owner));
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

std::shared_ptr<Session> SessionStore::erase_without_closing(const SessionId& id) {
  std::lock_guard lock(mutex_);
  auto it = sessions_.find(id);
  if (it == sessions_.end()) return nullptr;
  std::shared_ptr<Session> session = std::move(it->second);
  sessions_.erase(it);
  return session;
}

Status SessionStore::reserve(std::size_t bytes, const Session& requester) {
  std::lock_guard lock(mutex_);
  const Status room = make_room_locked(bytes, &requester, requester.owner());
  if (room.ok()) return room;
  return Error(ErrorCode::ResourceExhausted, "a new factorization does not fit: " + room.message());
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

void SessionStore::close_all_watchers(const Status& reason) {
  std::vector<std::shared_ptr<Session>> sessions;
  {
    std::lock_guard lock(mutex_);
    for (const auto& [id, session] : sessions_) sessions.push_back(session);
  }
  for (const auto& session : sessions) session->close_watchers(reason);
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
