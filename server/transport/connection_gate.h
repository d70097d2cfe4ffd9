#pragma once
/// @file connection_gate.h
/// Caps on open connections, per client address and in total, shared by the listeners of one
/// port (issue 40): one address cannot take every connection a port serves (nor every file
/// descriptor of the process), so other clients, health checks and metrics scrapes keep getting
/// in. A refused connection is closed at once; connections that say nothing are closed at the
/// listener's header deadline (HttpServerOptions::header_timeout_seconds, the gRPC front door's
/// first-bytes deadline). Thread-safe.

#include <atomic>
#include <cstddef>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace meshdeform::transport {

/// The caps; 0 means no cap.
struct ConnectionLimits {
  std::size_t per_address = 64;  ///< open connections from one client address
  std::size_t total = 1024;      ///< open connections on the port
};

/// What a gate has admitted and refused.
struct ConnectionStats {
  std::size_t open = 0;
  std::uint64_t refused_per_address = 0;  ///< refused: the address had per_address open
  std::uint64_t refused_total = 0;        ///< refused: the port had total open
  std::uint64_t header_timeouts = 0;      ///< closed because nothing (or too little) came in time
};

class ConnectionGate {
  struct State;

 public:
  /// Held by an admitted connection; destroying it frees its place.
  class Ticket {
   public:
    Ticket(Ticket&&) noexcept = default;
    Ticket& operator=(Ticket&& other) noexcept;
    Ticket(const Ticket&) = delete;
    Ticket& operator=(const Ticket&) = delete;
    ~Ticket() { release(); }
    void release();

   private:
    friend class ConnectionGate;
    Ticket(std::shared_ptr<State> state, std::string address)
        : state_(std::move(state)), address_(std::move(address)) {}
    std::shared_ptr<State> state_;
    std::string address_;
  };

  explicit ConnectionGate(ConnectionLimits limits = {});

  /// Admits a new connection from `address` (gRPC's peer() form without the port).
  /// @return its ticket, or nullopt (counted) when a cap is reached.
  std::optional<Ticket> admit(const std::string& address);
  /// Counts a connection closed at the header deadline.
  void note_header_timeout();
  ConnectionStats stats() const;
  const ConnectionLimits& limits() const { return limits_; }

 private:
  struct State {
    std::mutex mutex;
    std::map<std::string, std::size_t> per_address;
    std::size_t open = 0;
    std::uint64_t refused_per_address = 0;
    std::uint64_t refused_total = 0;
    std::atomic<std::uint64_t> header_timeouts{0};
  };
  ConnectionLimits limits_;
  std::shared_ptr<State> state_;
};

/// Raises this process's soft descriptor limit to its hard limit. @return the soft limit now.
long raise_descriptor_limit();

/// The caps of the gRPC port (each relayed connection costs three descriptors: the client's,
/// the relay's upstream and the gRPC server's) and of the HTTP port (one each), lowered in
/// proportion where together they would not leave `reserve` of `descriptors` free for state
/// files, the gRPC server's own and the rest. Unchanged when they fit.
/// @return whether they were lowered.
bool fit_connection_limits(long descriptors, long reserve, ConnectionLimits& grpc,
                           ConnectionLimits* http);

/// Appends the Prometheus text blocks of the ports' connection counters (`port` label:
/// "grpc", "http"): meshdeform_connections_open, meshdeform_connections_refused_total (by
/// reason: per_address, total) and meshdeform_connections_header_timeouts_total.
void render_connection_metrics(const std::vector<std::pair<std::string, ConnectionStats>>& ports,
                               std::string& out);

}  // namespace meshdeform::transport
