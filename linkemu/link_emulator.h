#pragma once
/// @file link_emulator.h
/// A small loopback TCP proxy that makes a network link out of loopback (this machine's kernel
/// has no netem): each accepted connection is relayed to a target, and each direction goes
/// through its own DirectionModel (link_model.h): bandwidth, one-way delay, jitter, and loss as
/// a stall, behind a bounded queue. Used by the load tester (`--via-link`), the bench scripts
/// (`meshdeform-link`) and the tests.
///
/// Directions: "up" is client to target (requests), "down" target to client (responses and
/// stream updates). A full queue stops the emulator reading that side's socket, so the sender's
/// TCP flow control sees the bottleneck; the emulator's own sockets have small kernel buffers
/// (kSocketBufferBytes) so that little data hides in the kernel before the model sees it.
/// One thread, poll(2), no allocation per byte. Connections are relayed until either side
/// closes (the other is half-closed once its queue has drained) or fails (both are closed).

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "linkemu/link_model.h"

namespace meshdeform::linkemu {

/// SO_RCVBUF / SO_SNDBUF of the emulator's sockets.
inline constexpr int kSocketBufferBytes = 64 * 1024;

/// Both directions of a link.
struct LinkSettings {
  DirectionSettings up;    ///< client -> target
  DirectionSettings down;  ///< target -> client
};

/// Parses a link description: comma-separated items, e.g. "20mbit,40ms" or
/// "100mbit,20ms,jitter=2ms,loss=0.1%":
///  - a rate ("20mbit", "512kbit", "1gbit", "2500000bit"; "mbps" and "kbps" mean the same as
///    "mbit" and "kbit") sets both directions' rate; `up=RATE` / `down=RATE` one direction's;
///  - a duration ("40ms", "0.04s", "500us") is the round-trip time, half of it each way;
///    `delay-up=DUR` / `delay-down=DUR` set one way's delay;
///  - `jitter=DUR` (per direction, uniform in [0, DUR]), `loss=P` ("0.01" or "1%", per packet),
///    `stall=DUR` (what a loss costs, default 200ms), `queue=BYTES` ("256kb", "1mb": per
///    direction; default the bandwidth-delay product + 64 KiB, at least 256 KiB).
/// @return the settings, or nullopt with `error` naming the item.
std::optional<LinkSettings> parse_link_spec(std::string_view spec, std::string& error);

/// One line for reports: "down 20 Mbit/s, up 20 Mbit/s, RTT 40 ms, jitter 0 ms, loss 0%, ...".
std::string describe_link(const LinkSettings& settings);
/// The same as JSON-friendly numbers (used by the load tester's report), see LinkSummary.
struct LinkSummary {
  double down_mbit = 0, up_mbit = 0;  ///< 0 = unlimited
  double rtt_ms = 0;                  ///< delay up + delay down
  double jitter_ms = 0;               ///< per direction (the larger)
  double loss = 0;                    ///< per packet (the larger)
  double stall_ms = 0;
  std::uint64_t queue_bytes_down = 0, queue_bytes_up = 0;
};
LinkSummary summarize_link(const LinkSettings& settings);

/// Counters of an emulator since it started (both directions summed over connections).
struct LinkCounters {
  DirectionCounters up;
  DirectionCounters down;
  std::uint64_t connections_accepted = 0;
  std::uint64_t connections_open = 0;
  std::uint64_t connect_failures = 0;  ///< the target refused or was unreachable
};

class LinkEmulator {
 public:
  /// Listens on `listen_host`:`listen_port` (0: any free port) and relays every connection to
  /// `target_host`:`target_port` through `settings`. Hosts are numeric IPv4/IPv6 addresses.
  /// @return the running emulator, or nullptr with `error` set.
  static std::unique_ptr<LinkEmulator> start(const LinkSettings& settings,
                                             const std::string& target_host, int target_port,
                                             std::string& error,
                                             const std::string& listen_host = "127.0.0.1",
                                             int listen_port = 0, std::uint64_t seed = 1);
  /// Stops relaying and closes every socket.
  ~LinkEmulator();
  LinkEmulator(const LinkEmulator&) = delete;
  LinkEmulator& operator=(const LinkEmulator&) = delete;

  int port() const { return port_; }
  /// "HOST:PORT" of the listening socket (a gRPC target).
  std::string address() const;
  const LinkSettings& settings() const { return settings_; }
  LinkCounters counters() const;

 private:
  struct Connection;
  LinkEmulator() = default;
  void run();
  void accept_one();
  void close_connection(std::size_t index);

  LinkSettings settings_;
  std::string listen_host_;
  std::string target_host_;
  int target_port_ = 0;
  int port_ = 0;
  int listen_fd_ = -1;
  int wake_read_ = -1, wake_write_ = -1;
  std::uint64_t seed_ = 1;
  mutable std::mutex mutex_;  // guards connections_ and the counters
  std::vector<std::unique_ptr<Connection>> connections_;
  LinkCounters closed_;       // counters of closed connections
  bool stopping_ = false;
  std::thread thread_;
};

/// Splits "HOST:PORT" / "[v6]:PORT". @return false when it does not parse.
bool split_host_port(std::string_view address, std::string& host, int& port);

}  // namespace meshdeform::linkemu
