#include "server/service/watcher.h"

#include "server/service/session.h"

namespace meshdeform::service {

std::optional<DeformUpdate> Watcher::try_take() {
  std::lock_guard lock(mutex_);
  std::optional<DeformUpdate> out = std::move(pending_);
  pending_.reset();
  return out;
}

std::optional<DeformUpdate> Watcher::wait_take(std::chrono::milliseconds timeout,
                                               std::stop_token stop) {
  std::unique_lock lock(mutex_);
  cv_.wait_for(lock, stop, timeout, [this] { return pending_.has_value() || closed_; });
  std::optional<DeformUpdate> out = std::move(pending_);
  pending_.reset();
  return out;
}

bool Watcher::closed() const {
  std::lock_guard lock(mutex_);
  return closed_;
}

Status Watcher::close_status() const {
  std::lock_guard lock(mutex_);
  return close_status_;
}

void Watcher::set_owner(std::weak_ptr<Session> owner) {
  std::lock_guard lock(mutex_);
  owner_ = std::move(owner);
}

std::shared_ptr<Session> Watcher::owner() const {
  std::lock_guard lock(mutex_);
  return owner_.lock();
}

void Watcher::set_notify(std::function<void()> notify) {
  bool call_now = false;
  {
    std::lock_guard lock(mutex_);
    notify_ = std::move(notify);
    call_now = notify_ && (pending_.has_value() || closed_);
  }
  if (call_now) notify_();
}

void Watcher::publish(std::shared_ptr<const DeformResult> result) {
  offer(std::move(result), false);
}

void Watcher::publish_snapshot(std::shared_ptr<const DeformResult> result) {
  offer(std::move(result), true);
}

void Watcher::offer(std::shared_ptr<const DeformResult> result, bool snapshot) {
  std::function<void()> notify;
  {
    std::lock_guard lock(mutex_);
    if (closed_) return;
    // The join snapshot and a concurrent commit can race: never go back in revisions.
    if (has_any_ && result->revision <= newest_revision_) return;
    has_any_ = true;
    newest_revision_ = result->revision;
    const bool was_empty = !pending_.has_value();
    if (was_empty) {
      pending_ = DeformUpdate{std::move(result), snapshot, 0};
    } else {
      // Skip to the newest: the watcher never saw the replaced revision, so the changed lists
      // of the new one are not enough for it; deliver a snapshot.
      const std::uint64_t skipped = pending_->skipped_revisions + 1;
      pending_ = DeformUpdate{std::move(result), true, skipped};
    }
    if (was_empty) notify = notify_;
  }
  cv_.notify_all();
  if (notify) notify();
}

void Watcher::close(Status reason) {
  std::function<void()> notify;
  {
    std::lock_guard lock(mutex_);
    if (closed_) return;
    closed_ = true;
    close_status_ = std::move(reason);
    notify = notify_;
  }
  cv_.notify_all();
  if (notify) notify();
}

Subscription::Subscription(std::shared_ptr<Watcher> watcher) : watcher_(std::move(watcher)) {}

Subscription& Subscription::operator=(Subscription&& other) noexcept {
  if (this != &other) {
    reset();
    watcher_ = std::move(other.watcher_);
  }
  return *this;
}

Subscription::~Subscription() { reset(); }

void Subscription::reset() {
  if (watcher_) {
    if (std::shared_ptr<Session> session = watcher_->owner()) {
      session->remove_watcher(watcher_.get());
    }
    watcher_->close();
  }
  watcher_.reset();
}

}  // namespace meshdeform::service
