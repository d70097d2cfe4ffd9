#include "server/service/admission.h"

#include <algorithm>
#include <utility>

namespace meshdeform::service {

HeavyWorkAdmission::Ticket& HeavyWorkAdmission::Ticket::operator=(Ticket&& other) noexcept {
  if (this != &other) {
    release();
    state_ = std::move(other.state_);
    client_ = std::move(other.client_);
  }
  return *this;
}

void HeavyWorkAdmission::Ticket::release() {
  if (!state_) return;
  {
    const std::lock_guard lock(state_->mutex);
    const auto it = state_->per_client.find(client_);
    if (it != state_->per_client.end() && --it->second <= 0) state_->per_client.erase(it);
    --state_->total;
  }
  state_.reset();
}

HeavyWorkAdmission::HeavyWorkAdmission(HeavyWorkLimits limits)
    : limits_{std::max(1, limits.per_client), std::max(1, limits.total)},
      state_(std::make_shared<State>()) {}

Result<HeavyWorkAdmission::Ticket> HeavyWorkAdmission::admit(std::string_view client,
                                                             std::string_view what) {
  const std::lock_guard lock(state_->mutex);
  if (state_->total >= limits_.total) {
    ++state_->rejected;
    return Error(ErrorCode::ResourceExhausted,
                 "server busy: " + std::to_string(state_->total) +
                     " uploads/precomputes are queued or running (limit " +
                     std::to_string(limits_.total) + "); " + std::string(what) +
                     " refused, retry later");
  }
  const auto it = state_->per_client.find(client);
  const int mine = it == state_->per_client.end() ? 0 : it->second;
  if (mine >= limits_.per_client) {
    ++state_->rejected;
    return Error(ErrorCode::ResourceExhausted,
                 "this client already has " + std::to_string(mine) +
                     " uploads/precomputes queued or running (limit " +
                     std::to_string(limits_.per_client) + " per client); " + std::string(what) +
                     " refused, retry when one finishes");
  }
  ++state_->per_client[std::string(client)];
  ++state_->total;
  return Ticket(state_, std::string(client));
}

int HeavyWorkAdmission::admitted() const {
  const std::lock_guard lock(state_->mutex);
  return state_->total;
}

std::uint64_t HeavyWorkAdmission::rejected() const {
  const std::lock_guard lock(state_->mutex);
  return state_->rejected;
}

}  // namespace meshdeform::service
