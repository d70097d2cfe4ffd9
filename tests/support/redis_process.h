#pragma once
/// @file redis_process.h
/// A real redis-server for tests (issue 16): on 127.0.0.1 at a free port, with its own temporary
/// directory, started as a ChildProcess (so it dies with the test however that ends) and stopped
/// when destroyed. Every wait is bounded. POSIX only; no Redis client library here (readiness is
/// a raw PING over a socket; for a TLS server, its
/// "Ready to accept connections" log line and an accepted TCP connection).

#include <chrono>
#include <memory>
#include <optional>
#include <string>

#include "tests/support/child_process.h"

namespace meshdeform::test {

struct RedisOptions {
  std::string password;        ///< requirepass (empty: none)
  bool appendonly = true;      ///< AOF with appendfsync always
  std::string dir;             ///< data directory (empty: a new temporary one, removed at the end)
  int port = 0;                ///< 0: a free port
  /// TLS only (--tls-port, plain port closed) when set: PEM certificate and key of the server,
  /// and the CA file redis-server insists on (clients are not asked for certificates).
  std::string tls_cert_file;
  std::string tls_key_file;
  std::string tls_ca_file;
};

class RedisProcess {
 public:
  /// The redis-server binary, or empty when it is not installed.
  static std::string binary();
  /// Starts redis-server and waits (bounded) until it answers.
  /// @return the server, or nullptr with `error` set (its log included).
  static std::unique_ptr<RedisProcess> start(const RedisOptions& options, std::string& error);
  RedisProcess(const RedisProcess&) = delete;
  RedisProcess& operator=(const RedisProcess&) = delete;
  ~RedisProcess();

  int port() const { return port_; }
  const std::string& dir() const { return dir_; }
  /// "redis://127.0.0.1:PORT" ("rediss://" for a TLS server).
  std::string url() const;
  /// Stops it with `signal` (SIGKILL: a crash) and waits at most `timeout`. @return whether it
  /// exited.
  bool stop(int signal, std::chrono::milliseconds timeout = std::chrono::seconds(20));
  /// Its log so far.
  std::string log() const;

 private:
  RedisProcess() = default;
  std::optional<ChildProcess> child_;
  int port_ = 0;
  bool tls_ = false;
  std::string dir_;
  bool own_dir_ = false;
};

/// A TCP port on 127.0.0.1 that was free a moment ago (bind to 0, read, close).
int free_loopback_port();

}  // namespace meshdeform::test
