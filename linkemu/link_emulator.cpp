#include "linkemu/link_emulator.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstring>
#include <sstream>

namespace meshdeform::linkemu {
namespace {

using Clock = std::chrono::steady_clock;

void set_nonblocking(int fd) { ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL, 0) | O_NONBLOCK); }

void tune_socket(int fd) {
  const int one = 1;
  ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof one);
  const int size = kSocketBufferBytes;
  ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &size, sizeof size);
  ::setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &size, sizeof size);
}

/// Fills `storage` for host:port. @return its length, 0 when the host is not numeric.
socklen_t make_address(const std::string& host, int port, sockaddr_storage& storage) {
  std::memset(&storage, 0, sizeof storage);
  auto* v4 = reinterpret_cast<sockaddr_in*>(&storage);
  if (::inet_pton(AF_INET, host.c_str(), &v4->sin_addr) == 1) {
    v4->sin_family = AF_INET;
    v4->sin_port = htons(static_cast<std::uint16_t>(port));
    return sizeof(sockaddr_in);
  }
  auto* v6 = reinterpret_cast<sockaddr_in6*>(&storage);
  if (::inet_pton(AF_INET6, host.c_str(), &v6->sin6_addr) == 1) {
    v6->sin6_family = AF_INET6;
    v6->sin6_port = htons(static_cast<std::uint16_t>(port));
    return sizeof(sockaddr_in6);
  }
  return 0;
}

// ---- spec parsing ----------------------------------------------------------------------------

std::string lower(std::string_view text) {
  std::string out(text);
  for (char& c : out) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

/// Splits "12.5mbit" into 12.5 and "mbit". @return false without a leading number.
bool number_and_unit(const std::string& text, double& value, std::string& unit) {
  std::size_t used = 0;
  try {
    value = std::stod(text, &used);
  } catch (...) {
    return false;
  }
  if (!std::isfinite(value) || value < 0) return false;
  unit = text.substr(used);
  return true;
}

std::optional<double> parse_rate(const std::string& text) {
  double value = 0;
  std::string unit;
  if (!number_and_unit(text, value, unit)) return std::nullopt;
  if (unit == "bit" || unit == "bps") return value;
  if (unit == "kbit" || unit == "kbps") return value * 1e3;
  if (unit == "mbit" || unit == "mbps") return value * 1e6;
  if (unit == "gbit" || unit == "gbps") return value * 1e9;
  return std::nullopt;
}

std::optional<Duration> parse_duration(const std::string& text) {
  double value = 0;
  std::string unit;
  if (!number_and_unit(text, value, unit)) return std::nullopt;
  double seconds = 0;
  if (unit == "s") {
    seconds = value;
  } else if (unit == "ms") {
    seconds = value * 1e-3;
  } else if (unit == "us") {
    seconds = value * 1e-6;
  } else {
    return std::nullopt;
  }
  if (seconds > 3600) return std::nullopt;
  return std::chrono::duration_cast<Duration>(std::chrono::duration<double>(seconds));
}

std::optional<std::size_t> parse_bytes(const std::string& text) {
  double value = 0;
  std::string unit;
  if (!number_and_unit(text, value, unit)) return std::nullopt;
  double scale = 0;
  if (unit.empty() || unit == "b") scale = 1;
  if (unit == "kb" || unit == "kib") scale = 1024;
  if (unit == "mb" || unit == "mib") scale = 1024 * 1024;
  if (scale == 0 || value * scale < 1 || value * scale > 1e10) return std::nullopt;
  return static_cast<std::size_t>(value * scale);
}

std::optional<double> parse_probability(const std::string& text) {
  double value = 0;
  std::string unit;
  if (!number_and_unit(text, value, unit)) return std::nullopt;
  if (unit == "%") value /= 100.0;
  else if (!unit.empty()) return std::nullopt;
  if (!(value >= 0 && value < 1)) return std::nullopt;
  return value;
}

std::string format_rate(double bits) {
  if (bits <= 0) return "unlimited";
  std::ostringstream out;
  out << bits / 1e6 << " Mbit/s";
  return out.str();
}

double ms(Duration d) { return std::chrono::duration<double, std::milli>(d).count(); }

/// Adds one direction's counters to a total (the live links' and the closed ones').
void add(DirectionCounters& to, const DirectionCounters& from) {
  to.bytes_in += from.bytes_in;
  to.bytes_delivered += from.bytes_delivered;
  to.chunks += from.chunks;
  to.losses += from.losses;
  to.full_queue_waits += from.full_queue_waits;
  to.queue_delay_ns_sum += from.queue_delay_ns_sum;
  to.queue_delay_ns_max = std::max(to.queue_delay_ns_max, from.queue_delay_ns_max);
}

}  // namespace

std::optional<LinkSettings> parse_link_spec(std::string_view spec, std::string& error) {
  LinkSettings out;
  std::optional<Duration> rtt;
  std::optional<Duration> delay_up, delay_down;
  std::string text = lower(spec);
  if (text.empty()) {
    error = "empty link description";
    return std::nullopt;
  }
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t comma = text.find(',', start);
    const std::string item =
        text.substr(start, comma == std::string::npos ? std::string::npos : comma - start);
    start = comma == std::string::npos ? text.size() + 1 : comma + 1;
    if (item.empty()) continue;
    const std::size_t eq = item.find('=');
    const std::string key = eq == std::string::npos ? "" : item.substr(0, eq);
    const std::string value = eq == std::string::npos ? item : item.substr(eq + 1);
    auto bad = [&](const char* what) {
      error = "link item '" + item + "': " + what;
      return std::nullopt;
    };
    if (key.empty()) {
      if (std::optional<double> rate = parse_rate(value)) {
        out.up.rate_bits_per_second = out.down.rate_bits_per_second = *rate;
      } else if (std::optional<Duration> d = parse_duration(value)) {
        rtt = *d;
      } else {
        return bad("expected a rate (20mbit) or a round-trip time (40ms)");
      }
    } else if (key == "up" || key == "down") {
      const std::optional<double> rate = parse_rate(value);
      if (!rate) return bad("expected a rate such as 20mbit");
      (key == "up" ? out.up : out.down).rate_bits_per_second = *rate;
    } else if (key == "rtt") {
      rtt = parse_duration(value);
      if (!rtt) return bad("expected a duration such as 40ms");
    } else if (key == "delay-up" || key == "delay-down") {
      const std::optional<Duration> d = parse_duration(value);
      if (!d) return bad("expected a duration such as 20ms");
      (key == "delay-up" ? delay_up : delay_down) = *d;
    } else if (key == "jitter" || key == "stall") {
      const std::optional<Duration> d = parse_duration(value);
      if (!d) return bad("expected a duration such as 5ms");
      if (key == "jitter") out.up.jitter = out.down.jitter = *d;
      else out.up.stall = out.down.stall = *d;
    } else if (key == "loss") {
      const std::optional<double> p = parse_probability(value);
      if (!p) return bad("expected a probability in [0, 1) such as 0.01 or 1%");
      out.up.loss = out.down.loss = *p;
    } else if (key == "queue") {
      const std::optional<std::size_t> bytes = parse_bytes(value);
      if (!bytes) return bad("expected a size such as 256kb");
      out.up.queue_bytes = out.down.queue_bytes = *bytes;
    } else {
      return bad("unknown key (rate, RTT, up, down, rtt, delay-up, delay-down, jitter, loss, "
                 "stall, queue)");
    }
  }
  if (rtt) out.up.delay = out.down.delay = *rtt / 2;
  if (delay_up) out.up.delay = *delay_up;
  if (delay_down) out.down.delay = *delay_down;
  return out;
}

LinkSummary summarize_link(const LinkSettings& s) {
  LinkSummary out;
  out.down_mbit = s.down.rate_bits_per_second / 1e6;
  out.up_mbit = s.up.rate_bits_per_second / 1e6;
  out.rtt_ms = ms(s.up.delay) + ms(s.down.delay);
  out.jitter_ms = std::max(ms(s.up.jitter), ms(s.down.jitter));
  out.loss = std::max(s.up.loss, s.down.loss);
  out.stall_ms = std::max(ms(s.up.stall), ms(s.down.stall));
  out.queue_bytes_down = s.down.effective_queue_bytes();
  out.queue_bytes_up = s.up.effective_queue_bytes();
  return out;
}

std::string describe_link(const LinkSettings& s) {
  const LinkSummary m = summarize_link(s);
  std::ostringstream out;
  out << "down " << format_rate(s.down.rate_bits_per_second) << ", up "
      << format_rate(s.up.rate_bits_per_second) << ", RTT " << m.rtt_ms << " ms, jitter "
      << m.jitter_ms << " ms, loss " << m.loss * 100 << "%";
  if (m.loss > 0) out << " (stall " << m.stall_ms << " ms)";
  out << ", queue " << m.queue_bytes_down / 1024 << " KiB down / " << m.queue_bytes_up / 1024
      << " KiB up";
  return out.str();
}

bool split_host_port(std::string_view address, std::string& host, int& port) {
  const std::size_t colon = address.rfind(':');
  if (colon == std::string_view::npos || colon + 1 >= address.size()) return false;
  std::string_view h = address.substr(0, colon);
  if (h.size() >= 2 && h.front() == '[' && h.back() == ']') h = h.substr(1, h.size() - 2);
  if (h == "localhost") h = "127.0.0.1";
  try {
    std::size_t used = 0;
    const std::string p(address.substr(colon + 1));
    port = std::stoi(p, &used);
    if (used != p.size() || port < 0 || port > 65535) return false;
  } catch (...) {
    return false;
  }
  host = std::string(h);
  return !host.empty();
}

// ---- the relay -------------------------------------------------------------------------------

/// One relayed connection: two sockets and a direction model each way, with the bytes the model
/// holds (read from the source, not yet written to the destination) in a FIFO buffer.
struct LinkEmulator::Connection {
  struct Direction {
    Direction(const DirectionSettings& settings, std::uint64_t seed) : model(settings, seed) {}
    DirectionModel model;
    std::string buffer;       // model.queued() bytes from `head` on
    std::size_t head = 0;
    bool source_eof = false;  // the source closed its side: shut the destination down once empty
    bool shut_down = false;   // the destination was shut down for writing
    bool full = false;        // the queue was full at the last look (counts each time it fills)
  };
  Connection(const LinkSettings& s, std::uint64_t seed) : up(s.up, seed), down(s.down, seed + 1) {}
  int client = -1;
  int target = -1;
  Direction up;    // client -> target
  Direction down;  // target -> client
  bool failed = false;
};

std::unique_ptr<LinkEmulator> LinkEmulator::start(const LinkSettings& settings,
                                                  const std::string& target_host, int target_port,
                                                  std::string& error,
                                                  const std::string& listen_host, int listen_port,
                                                  std::uint64_t seed) {
  std::unique_ptr<LinkEmulator> emulator(new LinkEmulator());
  emulator->settings_ = settings;
  emulator->listen_host_ = listen_host;
  emulator->target_host_ = target_host == "localhost" ? "127.0.0.1" : target_host;
  emulator->target_port_ = target_port;
  emulator->seed_ = seed;
  sockaddr_storage target{};
  if (make_address(emulator->target_host_, target_port, target) == 0) {
    error = "link emulator: target host '" + target_host + "' is not a numeric address";
    return nullptr;
  }
  sockaddr_storage address{};
  const socklen_t length = make_address(listen_host, listen_port, address);
  if (length == 0) {
    error = "link emulator: listen host '" + listen_host + "' is not a numeric address";
    return nullptr;
  }
  const int fd = ::socket(address.ss_family, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) {
    error = std::string("link emulator: socket: ") + std::strerror(errno);
    return nullptr;
  }
  const int one = 1;
  ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
  // Accepted sockets inherit the listener's buffer sizes (they must be set before the
  // handshake to bound the window the client sees).
  const int size = kSocketBufferBytes;
  ::setsockopt(fd, SOL_SOCKET, SO_RCVBUF, &size, sizeof size);
  ::setsockopt(fd, SOL_SOCKET, SO_SNDBUF, &size, sizeof size);
  if (::bind(fd, reinterpret_cast<sockaddr*>(&address), length) != 0 || ::listen(fd, 128) != 0) {
    error = "link emulator: cannot listen on " + listen_host + ":" + std::to_string(listen_port) +
            ": " + std::strerror(errno);
    ::close(fd);
    return nullptr;
  }
  sockaddr_storage bound{};
  socklen_t bound_length = sizeof bound;
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&bound), &bound_length);
  emulator->port_ = ntohs(bound.ss_family == AF_INET
                              ? reinterpret_cast<sockaddr_in*>(&bound)->sin_port
                              : reinterpret_cast<sockaddr_in6*>(&bound)->sin6_port);
  set_nonblocking(fd);
  emulator->listen_fd_ = fd;
  int pipe_fds[2];
  if (::pipe2(pipe_fds, O_CLOEXEC | O_NONBLOCK) != 0) {
    error = std::string("link emulator: pipe: ") + std::strerror(errno);
    return nullptr;  // the destructor closes the listener
  }
  emulator->wake_read_ = pipe_fds[0];
  emulator->wake_write_ = pipe_fds[1];
  emulator->thread_ = std::thread([raw = emulator.get()] { raw->run(); });
  return emulator;
}

LinkEmulator::~LinkEmulator() {
  {
    const std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  if (wake_write_ >= 0) {
    const char byte = 0;
    (void)!::write(wake_write_, &byte, 1);
  }
  if (thread_.joinable()) thread_.join();
  for (std::size_t i = connections_.size(); i > 0; --i) close_connection(i - 1);
  for (int fd : {listen_fd_, wake_read_, wake_write_}) {
    if (fd >= 0) ::close(fd);
  }
}

std::string LinkEmulator::address() const {
  const bool v6 = listen_host_.find(':') != std::string::npos;
  return (v6 ? "[" + listen_host_ + "]" : listen_host_) + ":" + std::to_string(port_);
}

LinkCounters LinkEmulator::counters() const {
  const std::lock_guard lock(mutex_);
  LinkCounters out = closed_;
  for (const auto& c : connections_) {
    add(out.up, c->up.model.counters());
    add(out.down, c->down.model.counters());
  }
  out.connections_open = connections_.size();
  return out;
}

void LinkEmulator::accept_one() {
  const int client = ::accept4(listen_fd_, nullptr, nullptr, SOCK_CLOEXEC | SOCK_NONBLOCK);
  if (client < 0) return;
  tune_socket(client);
  sockaddr_storage target{};
  const socklen_t length = make_address(target_host_, target_port_, target);
  const int upstream = ::socket(target.ss_family, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (upstream < 0) {
    ::close(client);
    ++closed_.connect_failures;
    return;
  }
  tune_socket(upstream);
  // Loopback connects complete at once; a refused target closes the client.
  if (::connect(upstream, reinterpret_cast<sockaddr*>(&target), length) != 0) {
    ::close(upstream);
    ::close(client);
    ++closed_.connect_failures;
    return;
  }
  set_nonblocking(upstream);
  auto connection = std::make_unique<Connection>(settings_, seed_ + 2 * closed_.connections_accepted);
  connection->client = client;
  connection->target = upstream;
  ++closed_.connections_accepted;
  connections_.push_back(std::move(connection));
}

void LinkEmulator::close_connection(std::size_t index) {
  Connection& c = *connections_[index];
  if (c.client >= 0) ::close(c.client);
  if (c.target >= 0) ::close(c.target);
  add(closed_.up, c.up.model.counters());
  add(closed_.down, c.down.model.counters());
  connections_.erase(connections_.begin() + static_cast<std::ptrdiff_t>(index));
}

void LinkEmulator::run() {
  std::vector<pollfd> fds;
  std::vector<char> scratch(64 * 1024);
  for (;;) {
    std::unique_lock lock(mutex_);
    if (stopping_) return;
    const TimePoint now = Clock::now();

    // Move data: read what the queues have room for, write what is due.
    for (auto& owned : connections_) {
      Connection& c = *owned;
      auto pump = [&](Connection::Direction& d, int from, int to, short from_events,
                      short to_events) {
        if ((from_events & (POLLIN | POLLHUP | POLLERR)) && !d.source_eof) {
          const std::size_t room = d.model.room();
          if (room > 0) {
            const ssize_t got = ::recv(from, scratch.data(), std::min(room, scratch.size()), 0);
            if (got > 0) {
              // Compact now and then: the buffer holds model.queued() bytes from head on.
              if (d.head > 0 && d.head >= d.buffer.size() / 2) {
                d.buffer.erase(0, d.head);
                d.head = 0;
              }
              d.buffer.append(scratch.data(), static_cast<std::size_t>(got));
              d.model.push(static_cast<std::size_t>(got), now);
            } else if (got == 0) {
              d.source_eof = true;
            } else if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
              c.failed = true;
            }
          }
        }
        (void)to_events;
        const std::size_t due = d.model.deliverable(now);
        if (due > 0) {
          const ssize_t sent = ::send(to, d.buffer.data() + d.head, due, MSG_NOSIGNAL);
          if (sent > 0) {
            d.head += static_cast<std::size_t>(sent);
            d.model.delivered(static_cast<std::size_t>(sent), now);
          } else if (sent < 0 && errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) {
            c.failed = true;
          }
        }
        if (d.source_eof && d.model.queued() == 0 && !d.shut_down) {
          ::shutdown(to, SHUT_WR);
          d.shut_down = true;
        }
      };
      short client_events = 0, target_events = 0;
      // Events from the last poll, looked up by fd (fds was built for the same connections).
      for (const pollfd& p : fds) {
        if (p.fd == c.client) client_events = p.revents;
        if (p.fd == c.target) target_events = p.revents;
      }
      pump(c.up, c.client, c.target, client_events, target_events);
      pump(c.down, c.target, c.client, target_events, client_events);
    }
    for (std::size_t i = connections_.size(); i > 0; --i) {
      const Connection& c = *connections_[i - 1];
      const bool both_done = c.up.shut_down && c.down.shut_down;
      if (c.failed || both_done) close_connection(i - 1);
    }

    // Next wake-up: the earliest due byte that is not yet deliverable.
    TimePoint wake = TimePoint::max();
    fds.clear();
    fds.push_back(pollfd{wake_read_, POLLIN, 0});
    fds.push_back(pollfd{listen_fd_, POLLIN, 0});
    const TimePoint after = Clock::now();
    for (auto& owned : connections_) {
      Connection& c = *owned;
      short client_events = 0, target_events = 0;
      auto want = [&](Connection::Direction& d, short& from_events, short& to_events) {
        if (!d.source_eof) {
          if (d.model.room() > 0) {
            from_events |= POLLIN;
            d.full = false;
          } else if (!d.full) {
            d.full = true;
            d.model.note_full_queue();
          }
        }
        if (d.model.queued() > 0) {
          if (d.model.deliverable(after) > 0) {
            to_events |= POLLOUT;
          } else {
            wake = std::min(wake, d.model.next_due());
          }
        }
      };
      want(c.up, client_events, target_events);
      want(c.down, target_events, client_events);
      fds.push_back(pollfd{c.client, client_events, 0});
      fds.push_back(pollfd{c.target, target_events, 0});
    }
    lock.unlock();

    // Sub-millisecond wake-ups (ppoll): a 1 ms granularity would add up to 1 ms per chunk.
    timespec timeout{1, 0};
    if (wake != TimePoint::max()) {
      const std::int64_t ns = std::clamp<std::int64_t>(
          std::chrono::duration_cast<Duration>(wake - Clock::now()).count(), 0, 1'000'000'000);
      timeout.tv_sec = static_cast<time_t>(ns / 1'000'000'000);
      timeout.tv_nsec = static_cast<long>(ns % 1'000'000'000);
    }
    ::ppoll(fds.data(), fds.size(), &timeout, nullptr);
    if (fds[0].revents & POLLIN) {
      char drain[16];
      while (::read(wake_read_, drain, sizeof drain) > 0) {
      }
    }
    if (fds[1].revents & POLLIN) {
      const std::lock_guard relock(mutex_);
      for (int i = 0; i < 16; ++i) {
        const std::size_t before = connections_.size();
        const std::uint64_t failures = closed_.connect_failures;
        accept_one();
        if (connections_.size() == before && closed_.connect_failures == failures) break;
      }
    }
  }
}

}  // namespace meshdeform::linkemu
