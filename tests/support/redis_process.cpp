#include "tests/support/redis_process.h"

#include "tests/support/nginx_process.h"  // accepts_connections

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string_view>
#include <thread>

namespace meshdeform::test {
namespace {

namespace fs = std::filesystem;

/// True when a Redis on 127.0.0.1:port answers a RESP PING within `timeout` as a ready server
/// does: +PONG, or -NOAUTH with a password (not -LOADING while it reads its append-only file).
bool answers_ping(int port, std::chrono::milliseconds timeout) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return false;
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = htons(static_cast<std::uint16_t>(port));
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  bool ok = false;
  if (::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0) {
    constexpr char kPing[] = "*1\r\n$4\r\nPING\r\n";
    if (::write(fd, kPing, sizeof kPing - 1) == static_cast<ssize_t>(sizeof kPing - 1)) {
      pollfd p{fd, POLLIN, 0};
      char reply[64] = {};
      if (::poll(&p, 1, static_cast<int>(timeout.count())) == 1) {
        const ssize_t n = ::read(fd, reply, sizeof reply - 1);
        const std::string_view answer(reply, n > 0 ? static_cast<std::size_t>(n) : 0);
        ok = answer.starts_with("+PONG") || answer.starts_with("-NOAUTH");
      }
    }
  }
  ::close(fd);
  return ok;
}

/// A TLS redis-server cannot be PINGed without a TLS client: it is ready once its log says so
/// and its port accepts a TCP connection.
bool tls_ready(int port, const std::string& log_path) {
  return read_text(log_path).find("Ready to accept connections") != std::string::npos &&
         accepts_connections(port);
}

}  // namespace

int free_loopback_port() {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return 0;
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_port = 0;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  int port = 0;
  socklen_t length = sizeof address;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0 &&
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&address), &length) == 0) {
    port = ntohs(address.sin_port);
  }
  ::close(fd);
  return port;
}

std::string RedisProcess::binary() {
  for (const char* candidate : {"/usr/bin/redis-server", "/usr/local/bin/redis-server"}) {
    if (::access(candidate, X_OK) == 0) return candidate;
  }
  return {};
}

std::unique_ptr<RedisProcess> RedisProcess::start(const RedisOptions& options, std::string& error) {
  const std::string server = binary();
  if (server.empty()) {
    error = "redis-server is not installed";
    return nullptr;
  }
  std::unique_ptr<RedisProcess> redis(new RedisProcess());
  if (options.dir.empty()) {
    std::random_device random;
    redis->dir_ = (fs::temp_directory_path() /
                   ("meshdeform-redis-" + std::to_string(random()) + std::to_string(random())))
                      .string();
    redis->own_dir_ = true;
  } else {
    redis->dir_ = options.dir;
  }
  std::error_code ignored;
  fs::create_directories(redis->dir_, ignored);
  // A port free a moment ago may be taken by the time redis binds it: a few attempts.
  for (int attempt = 0; attempt < 5; ++attempt) {
    const int port = options.port != 0 ? options.port : free_loopback_port();
    const bool tls = !options.tls_cert_file.empty();
    std::vector<std::string> args = {server,
                                     "--port", tls ? "0" : std::to_string(port),
                                     "--bind", "127.0.0.1",
                                     "--dir", redis->dir_,
                                     "--save", "",
                                     "--daemonize", "no",
                                     "--protected-mode", "yes",
                                     "--appendonly", options.appendonly ? "yes" : "no",
                                     "--appendfsync", "always"};
    if (!options.password.empty()) {
      args.push_back("--requirepass");
      args.push_back(options.password);
    }
    if (tls) {
      args.insert(args.end(), {"--tls-port", std::to_string(port), "--tls-cert-file",
                               options.tls_cert_file, "--tls-key-file", options.tls_key_file,
                               "--tls-ca-cert-file",
                               options.tls_ca_file.empty() ? options.tls_cert_file
                                                           : options.tls_ca_file,
                               "--tls-auth-clients", "no"});
    }
    ChildStreams streams;
    streams.stdout_path = redis->dir_ + "/redis.log";
    std::string spawn_error;
    std::optional<ChildProcess> child = ChildProcess::spawn(args, streams, spawn_error);
    if (!child) {
      error = "cannot start redis-server: " + spawn_error;
      return nullptr;
    }
    for (int i = 0; i < 500; ++i) {  // at most ~10 s
      if (tls ? tls_ready(port, streams.stdout_path)
              : answers_ping(port, std::chrono::milliseconds(200))) {
        redis->child_ = std::move(child);
        redis->port_ = port;
        redis->tls_ = tls;
        return redis;
      }
      if (child->wait(std::chrono::milliseconds(20))) break;  // exited (port taken?)
    }
    child->kill_and_reap();
    error = "redis-server did not answer on port " + std::to_string(port) + ":\n" +
            read_text(streams.stdout_path);
    if (options.port != 0) break;
  }
  return nullptr;
}

RedisProcess::~RedisProcess() {
  if (child_) child_->stop(SIGKILL, std::chrono::seconds(20));
  if (own_dir_) {
    std::error_code ignored;
    fs::remove_all(dir_, ignored);
  }
}

std::string RedisProcess::url() const {
  return (tls_ ? "rediss://127.0.0.1:" : "redis://127.0.0.1:") + std::to_string(port_);
}

bool RedisProcess::stop(int signal, std::chrono::milliseconds timeout) {
  if (!child_) return true;
  const bool exited = child_->stop(signal, timeout).has_value();
  if (exited) child_.reset();
  return exited;
}

std::string RedisProcess::log() const { return read_text(dir_ + "/redis.log"); }

}  // namespace meshdeform::test
