// The link emulator on real loopback sockets: bytes arrive intact and in order both ways (with
// jitter), never faster than the link's rate (a one-sided check a busy machine cannot break),
// a full queue pushes back on the sender, half-closes pass through, a refused target is counted.
// Every wait is a bounded condition; every thread is joined.
#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstring>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include "linkemu/link_emulator.h"

namespace meshdeform::linkemu {
namespace {

using namespace std::chrono_literals;
using Clock = std::chrono::steady_clock;

/// A loopback listener whose first accepted connection is handed to `handler` on a thread.
class OneShotServer {
 public:
  explicit OneShotServer(std::function<void(int)> handler) {
    fd_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&address), sizeof address), 0);
    EXPECT_EQ(::listen(fd_, 4), 0);
    socklen_t length = sizeof address;
    ::getsockname(fd_, reinterpret_cast<sockaddr*>(&address), &length);
    port_ = ntohs(address.sin_port);
    thread_ = std::jthread([this, handler = std::move(handler)] {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 60'000) <= 0) return;
      const int client = ::accept4(fd_, nullptr, nullptr, SOCK_CLOEXEC);
      if (client < 0) return;
      handler(client);
      ::close(client);
    });
  }
  ~OneShotServer() {
    if (thread_.joinable()) thread_.join();
    ::close(fd_);
  }
  int port() const { return port_; }

 private:
  int fd_ = -1;
  int port_ = 0;
  std::jthread thread_;
};

int connect_to(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  address.sin_port = htons(static_cast<std::uint16_t>(port));
  EXPECT_EQ(::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address), 0);
  timeval timeout{60, 0};  // a stuck read fails the test instead of hanging it
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout);
  ::setsockopt(fd, SOL_SOCKET, SO_SNDTIMEO, &timeout, sizeof timeout);
  return fd;
}

bool send_all(int fd, const std::string& bytes) {
  std::size_t sent = 0;
  while (sent < bytes.size()) {
    const ssize_t n = ::send(fd, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
    if (n <= 0) return false;
    sent += static_cast<std::size_t>(n);
  }
  return true;
}

/// Reads until EOF or `limit` bytes (or a 60 s timeout).
std::string read_all(int fd, std::size_t limit) {
  std::string out;
  char buffer[65536];
  while (out.size() < limit) {
    const ssize_t n = ::recv(fd, buffer, std::min(sizeof buffer, limit - out.size()), 0);
    if (n <= 0) break;
    out.append(buffer, static_cast<std::size_t>(n));
  }
  return out;
}

std::string pattern(std::size_t bytes) {
  std::string out(bytes, '\0');
  std::uint32_t x = 12345;
  for (char& c : out) {
    x = x * 1664525u + 1013904223u;
    c = static_cast<char>(x >> 24);
  }
  return out;
}

LinkSettings spec(const std::string& text) {
  std::string error;
  std::optional<LinkSettings> s = parse_link_spec(text, error);
  EXPECT_TRUE(s) << error;
  return s.value_or(LinkSettings{});
}

TEST(LinkEmulator, BytesArriveIntactAndInOrderBothWaysUnderJitter) {
  const std::string data = pattern(2 * 1024 * 1024);
  OneShotServer echo([&](int fd) {
    char buffer[65536];
    for (;;) {
      const ssize_t n = ::recv(fd, buffer, sizeof buffer, 0);
      if (n <= 0) break;
      if (!send_all(fd, std::string(buffer, static_cast<std::size_t>(n)))) break;
    }
    ::shutdown(fd, SHUT_WR);
  });
  std::string error;
  auto link = LinkEmulator::start(spec("400mbit,4ms,jitter=2ms"), "127.0.0.1", echo.port(), error);
  ASSERT_TRUE(link) << error;
  const int fd = connect_to(link->port());
  std::string echoed;
  std::jthread reader([&] { echoed = read_all(fd, data.size()); });
  ASSERT_TRUE(send_all(fd, data));
  ::shutdown(fd, SHUT_WR);
  reader.join();
  ::close(fd);
  ASSERT_EQ(echoed.size(), data.size());
  EXPECT_TRUE(echoed == data) << "bytes reordered or corrupted";
  const LinkCounters c = link->counters();
  EXPECT_EQ(c.up.bytes_in, data.size());
  EXPECT_EQ(c.up.bytes_delivered, data.size());
  EXPECT_EQ(c.down.bytes_delivered, data.size());
  EXPECT_EQ(c.connections_accepted, 1u);
}

TEST(LinkEmulator, NeverDeliversFasterThanTheRatePlusTheDelay) {
  constexpr double kRate = 8e6;  // 1,000,000 bytes/s
  const std::string data = pattern(400'000);
  struct Sample {
    Clock::time_point when;
    std::size_t bytes;
  };
  std::vector<Sample> samples;
  OneShotServer sink([&](int fd) {
    char buffer[65536];
    std::size_t total = 0;
    for (;;) {
      const ssize_t n = ::recv(fd, buffer, sizeof buffer, 0);
      if (n <= 0) break;
      total += static_cast<std::size_t>(n);
      samples.push_back({Clock::now(), total});
    }
  });
  std::string error;
  auto link = LinkEmulator::start(spec("8mbit,20ms"), "127.0.0.1", sink.port(), error);
  ASSERT_TRUE(link) << error;
  const int fd = connect_to(link->port());
  const Clock::time_point start = Clock::now();
  ASSERT_TRUE(send_all(fd, data));
  ::shutdown(fd, SHUT_WR);
  // The sink ends at EOF, once everything is through.
  for (int i = 0; i < 600 && link->counters().up.bytes_delivered < data.size(); ++i) {
    std::this_thread::sleep_for(100ms);
  }
  ::close(fd);
  ASSERT_EQ(link->counters().up.bytes_delivered, data.size());
  // Wait for the sink thread through the counters of the model: every byte delivered means the
  // sink has them or will read them; join happens in ~OneShotServer. Check the samples after it.
  for (int i = 0; i < 600 && (samples.empty() || samples.back().bytes < data.size()); ++i) {
    std::this_thread::sleep_for(50ms);
  }
  ASSERT_FALSE(samples.empty());
  ASSERT_EQ(samples.back().bytes, data.size());
  // One-sided: by any moment t the sink can have at most what the link could carry since the
  // first byte entered it (rate x (t - start - one-way delay)) plus one read's chunk in flight.
  for (const Sample& s : samples) {
    const double seconds = std::chrono::duration<double>(s.when - start).count() - 0.010;
    const double allowed = kRate / 8 * seconds + 65536;
    EXPECT_LE(static_cast<double>(s.bytes), allowed) << "at " << seconds << " s";
  }
  // And the whole transfer took at least its transmission time plus the one-way delay.
  const double total = std::chrono::duration<double>(samples.back().when - start).count();
  EXPECT_GE(total, 400'000 * 8 / kRate + 0.010);
}

TEST(LinkEmulator, AFullQueuePushesBackOnTheSender) {
  std::atomic<bool> release{false};
  std::size_t drained = 0;
  OneShotServer stalled([&](int fd) {
    // Read nothing until released, then drain to EOF.
    for (int i = 0; i < 1200 && !release.load(); ++i) std::this_thread::sleep_for(50ms);
    drained = read_all(fd, std::string::npos).size();
  });
  std::string error;
  auto link = LinkEmulator::start(spec("1gbit,2ms,queue=64kb"), "127.0.0.1", stalled.port(), error);
  ASSERT_TRUE(link) << error;
  const int fd = connect_to(link->port());
  ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL, 0) | O_NONBLOCK);
  const std::string chunk = pattern(64 * 1024);
  std::size_t sent = 0;
  // Send until the kernel refuses more (bounded: 64 MiB or 30 s).
  const Clock::time_point until = Clock::now() + 30s;
  int refusals = 0;
  while (sent < 64u * 1024 * 1024 && Clock::now() < until && refusals < 20) {
    const ssize_t n = ::send(fd, chunk.data(), chunk.size(), MSG_NOSIGNAL);
    if (n > 0) {
      sent += static_cast<std::size_t>(n);
      refusals = 0;
    } else {
      ++refusals;
      std::this_thread::sleep_for(20ms);
    }
  }
  EXPECT_LT(sent, 64u * 1024 * 1024) << "nothing pushed back";
  LinkCounters c = link->counters();
  for (int i = 0; i < 300 && c.up.full_queue_waits == 0; ++i) {
    std::this_thread::sleep_for(20ms);
    c = link->counters();
  }
  EXPECT_GE(c.up.full_queue_waits, 1u);
  // The emulator holds at most its queue: the receiver took what the kernel buffers hold.
  EXPECT_LE(c.up.bytes_in - c.up.bytes_delivered, 64u * 1024);
  EXPECT_LT(c.up.bytes_in, sent + 1);
  release = true;
  // Drain the rest (blocking send of nothing more; close ends the stream).
  ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL, 0) & ~O_NONBLOCK);
  ::shutdown(fd, SHUT_WR);
  for (int i = 0; i < 600 && link->counters().up.bytes_delivered < sent; ++i) {
    std::this_thread::sleep_for(50ms);
  }
  EXPECT_EQ(link->counters().up.bytes_delivered, sent);
  ::close(fd);
}

TEST(LinkEmulator, AHalfCloseStillCarriesTheReply) {
  OneShotServer server([](int fd) {
    const std::string request = read_all(fd, 1 << 20);  // to EOF
    send_all(fd, "reply to " + request);
  });
  std::string error;
  auto link = LinkEmulator::start(spec("10mbit,10ms"), "127.0.0.1", server.port(), error);
  ASSERT_TRUE(link) << error;
  const int fd = connect_to(link->port());
  ASSERT_TRUE(send_all(fd, "ping"));
  ::shutdown(fd, SHUT_WR);
  EXPECT_EQ(read_all(fd, 1 << 20), "reply to ping");
  ::close(fd);
}

TEST(LinkEmulator, ARefusedTargetIsCountedAndTheClientClosed) {
  // A port nobody listens on: bind one and close it.
  const int probe = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  ::bind(probe, reinterpret_cast<sockaddr*>(&address), sizeof address);
  socklen_t length = sizeof address;
  ::getsockname(probe, reinterpret_cast<sockaddr*>(&address), &length);
  const int dead_port = ntohs(address.sin_port);
  ::close(probe);
  std::string error;
  auto link = LinkEmulator::start(spec("10mbit,10ms"), "127.0.0.1", dead_port, error);
  ASSERT_TRUE(link) << error;
  const int fd = connect_to(link->port());
  EXPECT_EQ(read_all(fd, 100), "");
  ::close(fd);
  EXPECT_EQ(link->counters().connect_failures, 1u);
}

}  // namespace
}  // namespace meshdeform::linkemu
