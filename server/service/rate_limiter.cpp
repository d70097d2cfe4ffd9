#include "server/service/rate_limiter.h"

#include <algorithm>
#include <cmath>

namespace meshdeform::service {

RateLimiter::RateLimiter(RateLimit create, RateLimit move, Clock clock, std::size_t max_clients)
    : create_(create), move_(move), clock_(std::move(clock)),
      max_clients_(std::max<std::size_t>(max_clients, 1)) {
  create_.burst = std::max(create_.burst, 1.0);
  move_.burst = std::max(move_.burst, 1.0);
}

std::chrono::steady_clock::time_point RateLimiter::now() const {
  return clock_ ? clock_() : std::chrono::steady_clock::now();
}

std::optional<std::chrono::milliseconds> RateLimiter::admit(std::string_view client,
                                                             RateLimitedCall call) {
  const RateLimit& limit = call == RateLimitedCall::CreateSession ? create_ : move_;
  if (!(limit.per_second > 0)) return std::nullopt;
  const auto t = now();
  const std::lock_guard lock(mutex_);
  auto it = clients_.find(std::string(client));
  if (it == clients_.end()) {
    if (clients_.size() >= max_clients_) make_room();
    Client fresh;
    fresh.create = Bucket{create_.burst, t};
    fresh.move = Bucket{move_.burst, t};
    it = clients_.emplace(std::string(client), fresh).first;
  }
  it->second.touched = t;
  Bucket& bucket = call == RateLimitedCall::CreateSession ? it->second.create : it->second.move;
  const double elapsed = std::chrono::duration<double>(t - bucket.updated).count();
  if (elapsed > 0) {
    bucket.tokens = std::min(limit.burst, bucket.tokens + elapsed * limit.per_second);
    bucket.updated = t;
  }
  if (bucket.tokens >= 1.0) {
    bucket.tokens -= 1.0;
    return std::nullopt;
  }
  const double wait_ms = std::ceil((1.0 - bucket.tokens) / limit.per_second * 1e3);
  return std::chrono::milliseconds(std::max<long long>(1, static_cast<long long>(wait_ms)));
}

void RateLimiter::make_room() {
  // O(#clients), only when the table is full: drop the client touched longest ago.
  auto oldest = clients_.begin();
  for (auto it = clients_.begin(); it != clients_.end(); ++it) {
    if (it->second.touched < oldest->second.touched) oldest = it;
  }
  if (oldest != clients_.end()) clients_.erase(oldest);
}

std::size_t RateLimiter::tracked_clients() const {
  const std::lock_guard lock(mutex_);
  return clients_.size();
}

}  // namespace meshdeform::service
