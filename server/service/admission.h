#pragma once
/// @file admission.h
/// Admission control for heavy work (parsing an upload, a SetHandles precompute): a bounded
/// number admitted per client and in total, RESOURCE_EXHAUSTED beyond, so that a few clients
/// cannot queue unbounded work and light calls keep their workers (WorkerPool's heavy lanes).

#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <string_view>

#include "core/base/status.h"

namespace meshdeform::service {

/// Limits of heavy work. A task counts from admission until it finishes (queued or running).
struct HeavyWorkLimits {
  int per_client = 4;  ///< admitted at once per client (>= 1)
  int total = 16;      ///< admitted at once over all clients (>= 1): running lanes + queue bound
};

/// Counts admitted heavy tasks per client; thread-safe.
class HeavyWorkAdmission {
  struct State;

 public:
  /// Held by an admitted task; releasing it (destruction) frees the client's and the total slot.
  class Ticket {
   public:
    Ticket() = default;
    Ticket(Ticket&& other) noexcept = default;
    Ticket& operator=(Ticket&& other) noexcept;
    Ticket(const Ticket&) = delete;
    Ticket& operator=(const Ticket&) = delete;
    ~Ticket() { release(); }
    void release();

   private:
    friend class HeavyWorkAdmission;
    Ticket(std::shared_ptr<State> state, std::string client)
        : state_(std::move(state)), client_(std::move(client)) {}
    std::shared_ptr<State> state_;
    std::string client_;
  };

  explicit HeavyWorkAdmission(HeavyWorkLimits limits);

  /// Admits one heavy task of `client` (the front end's name for the caller; empty is one
  /// anonymous client). `what` names the work in the refusal ("CreateSession upload").
  /// @return the ticket; ResourceExhausted naming the limit when the client has per_client tasks
  ///         admitted, or when `total` are admitted over all clients.
  [[nodiscard]] Result<Ticket> admit(std::string_view client, std::string_view what);

  /// Tasks admitted now (queued or running).
  int admitted() const;
  /// Refusals since start.
  std::uint64_t rejected() const;
  const HeavyWorkLimits& limits() const { return limits_; }

 private:
  struct State {
    std::mutex mutex;
    std::map<std::string, int, std::less<>> per_client;
    int total = 0;
    std::uint64_t rejected = 0;
  };
  HeavyWorkLimits limits_;
  std::shared_ptr<State> state_;
};

}  // namespace meshdeform::service
