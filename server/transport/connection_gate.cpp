#include "server/transport/connection_gate.h"

#include <sys/resource.h>

#include <algorithm>
#include <cstdio>
#include <utility>

namespace meshdeform::transport {

ConnectionGate::Ticket& ConnectionGate::Ticket::operator=(Ticket&& other) noexcept {
  if (this != &other) {
    release();
    state_ = std::move(other.state_);
    address_ = std::move(other.address_);
  }
  return *this;
}

void ConnectionGate::Ticket::release() {
  if (!state_) return;
  {
    const std::lock_guard lock(state_->mutex);
    auto it = state_->per_address.find(address_);
    if (it != state_->per_address.end() && --it->second == 0) state_->per_address.erase(it);
    --state_->open;
  }
  state_.reset();
}

ConnectionGate::ConnectionGate(ConnectionLimits limits)
    : limits_(limits), state_(std::make_shared<State>()) {}

std::optional<ConnectionGate::Ticket> ConnectionGate::admit(const std::string& address) {
  const std::lock_guard lock(state_->mutex);
  if (limits_.total > 0 && state_->open >= limits_.total) {
    ++state_->refused_total;
    return std::nullopt;
  }
  std::size_t& from_address = state_->per_address[address];
  if (limits_.per_address > 0 && from_address >= limits_.per_address) {
    ++state_->refused_per_address;
    return std::nullopt;
  }
  ++from_address;
  ++state_->open;
  return Ticket(state_, address);
}

void ConnectionGate::note_header_timeout() { state_->header_timeouts.fetch_add(1); }

ConnectionStats ConnectionGate::stats() const {
  const std::lock_guard lock(state_->mutex);
  return {state_->open, state_->refused_per_address, state_->refused_total,
          state_->header_timeouts.load()};
}

long raise_descriptor_limit() {
  rlimit limit{};
  if (::getrlimit(RLIMIT_NOFILE, &limit) != 0) return 1024;
  if (limit.rlim_cur < limit.rlim_max) {
    rlimit raised = limit;
    raised.rlim_cur = limit.rlim_max;
    if (::setrlimit(RLIMIT_NOFILE, &raised) == 0) limit = raised;
  }
  return limit.rlim_cur == RLIM_INFINITY ? 1L << 20 : static_cast<long>(limit.rlim_cur);
}

bool fit_connection_limits(long descriptors, long reserve, ConnectionLimits& grpc,
                           ConnectionLimits* http) {
  const long budget = std::max(8L, descriptors - reserve);
  const long need = 3 * static_cast<long>(grpc.total) +
                    (http != nullptr ? static_cast<long>(http->total) : 0L);
  if (need <= budget) return false;
  const double share = static_cast<double>(budget) / static_cast<double>(need);
  auto lower = [share](ConnectionLimits& limits) {
    limits.total = std::max<std::size_t>(
        1, static_cast<std::size_t>(static_cast<double>(limits.total) * share));
    limits.per_address = std::min(limits.per_address, limits.total);
  };
  lower(grpc);
  if (http != nullptr) lower(*http);
  return true;
}

void render_connection_metrics(const std::vector<std::pair<std::string, ConnectionStats>>& ports,
                               std::string& out) {
  auto block = [&](const char* name, const char* type, const char* help, auto sample) {
    out += std::string("# HELP ") + name + " " + help + "\n# TYPE " + name + " " + type + "\n";
    for (const auto& [port, stats] : ports) sample(port, stats);
  };
  auto line = [&out](const std::string& name, const std::string& labels, double value) {
    char number[64];
    std::snprintf(number, sizeof number, "%.17g", value);
    out += name + "{" + labels + "} " + number + "\n";
  };
  block("meshdeform_connections_open", "gauge", "Open connections, by port.",
        [&](const std::string& port, const ConnectionStats& s) {
          line("meshdeform_connections_open", "port=\"" + port + "\"", static_cast<double>(s.open));
        });
  block("meshdeform_connections_refused_total", "counter",
        "Connections closed on accept because a cap was reached, by port and cap.",
        [&](const std::string& port, const ConnectionStats& s) {
          line("meshdeform_connections_refused_total",
               "port=\"" + port + "\",reason=\"per_address\"",
               static_cast<double>(s.refused_per_address));
          line("meshdeform_connections_refused_total", "port=\"" + port + "\",reason=\"total\"",
               static_cast<double>(s.refused_total));
        });
  block("meshdeform_connections_header_timeouts_total", "counter",
        "Connections closed because their first bytes (a request header, a TLS handshake) did "
        "not arrive in time, by port.",
        [&](const std::string& port, const ConnectionStats& s) {
          line("meshdeform_connections_header_timeouts_total", "port=\"" + port + "\"",
               static_cast<double>(s.header_timeouts));
        });
}

}  // namespace meshdeform::transport
