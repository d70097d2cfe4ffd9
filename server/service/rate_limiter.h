#pragma once
/// @file rate_limiter.h
/// Per-client token buckets for the calls that cost the server the most to admit: creating a
/// session (a parse, a mesh in memory) and moving handles (a solve). Each client (a network
/// address, as the transport names it) has one bucket per kind of call, refilled continuously at
/// `per_second` up to `burst`; a call takes one token or is refused with the time until one is
/// there. Memory is bounded: at most `max_clients` clients are tracked; beyond that the bucket
/// touched longest ago is dropped (a full, idle bucket forgets nothing). Thread-safe.

#include <chrono>
#include <cstddef>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <unordered_map>

#include "server/service/types.h"

namespace meshdeform::service {

class RateLimiter {
 public:
  /// @param[in] clock  steady time source (tests inject one); empty = steady_clock::now.
  RateLimiter(RateLimit create, RateLimit move, Clock clock = {}, std::size_t max_clients = 10'000);

  /// Takes a token for `client`'s `call`.
  /// @return nullopt when admitted; otherwise the time until the call would be admitted
  ///         (rounded up to a millisecond, at least 1 ms).
  std::optional<std::chrono::milliseconds> admit(std::string_view client, RateLimitedCall call);

  /// Clients currently tracked (tests).
  std::size_t tracked_clients() const;

 private:
  struct Bucket {
    double tokens = 0;
    std::chrono::steady_clock::time_point updated;
  };
  struct Client {
    Bucket create, move;
    std::chrono::steady_clock::time_point touched;
  };
  std::chrono::steady_clock::time_point now() const;
  void make_room();

  RateLimit create_, move_;
  Clock clock_;
  std::size_t max_clients_;
  mutable std::mutex mutex_;
  std::unordered_map<std::string, Client> clients_;
};

}  // namespace meshdeform::service
