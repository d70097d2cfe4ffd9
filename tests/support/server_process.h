#pragma once
/// @file server_process.h
/// Runs the real meshdeform-server binary on a loopback port for integration tests: spawns it
/// with `--listen 127.0.0.1:0` plus extra flags, reads its stderr (on a thread, so the server
/// never blocks on a full pipe) until the structured `"event":"listening"` line gives the bound
/// port, and stops it (SIGTERM, then SIGKILL after a bound) when destroyed. Every wait is bounded.
/// The server is a ChildProcess: it dies with the test process however that ends, and its stdout
/// goes to /dev/null.
/// POSIX only; no gRPC here.

#include <chrono>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "tests/support/child_process.h"

namespace meshdeform::test {

class ServerProcess {
 public:
  /// Starts `binary` and waits at most `startup` for its listening line.
  /// @param[in] max_open_files  >= 0: the server's RLIMIT_NOFILE (ChildStreams::max_open_files).
  /// @return the running server, or nullptr with `error` set (the stderr seen so far included).
  static std::unique_ptr<ServerProcess> start(
      const std::string& binary, const std::vector<std::string>& extra_flags, std::string& error,
      std::chrono::seconds startup = std::chrono::seconds(30), long max_open_files = -1);
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;
  /// Stops the server if it still runs (SIGTERM, then SIGKILL after 20 s).
  ~ServerProcess();

  int port() const { return port_; }
  /// The server's pid, or -1 once it has exited and been reaped.
  int pid() const { return child_ ? child_->pid() : -1; }
  /// "127.0.0.1:PORT", for grpc::CreateChannel.
  std::string address() const;
  /// The --http-listen port, from the `"event":"http_listening"` line (logged just after the
  /// listening line), waiting at most `timeout` for it.
  /// @return the port, or 0 when the line did not come (no --http-listen, or the server exited).
  int http_port(std::chrono::milliseconds timeout = std::chrono::seconds(10)) const;

  /// Sends `signal` (e.g. SIGTERM or SIGKILL) and waits at most `timeout` for the exit.
  /// @return the wait status (use WIFEXITED / WEXITSTATUS / WIFSIGNALED), or nullopt if it did
  ///         not exit in time (or was already reaped).
  std::optional<int> stop(int signal, std::chrono::milliseconds timeout);

  /// Everything the server wrote to stderr so far (its structured log lines).
  std::string log() const;
  /// Waits at most `timeout` for `needle` to appear in the log. @return whether it did.
  bool wait_for_log(const std::string& needle, std::chrono::milliseconds timeout) const;

  /// Expires every idle session now: needs the server started with --test-hooks (SIGUSR1), an
  /// explicit trigger instead of a short --idle-ttl-seconds that a loaded machine would trip.
  /// Waits at most `timeout` for the server to log that it did. @return whether it did.
  bool expire_idle_sessions(std::chrono::milliseconds timeout = std::chrono::seconds(60));

 private:
  ServerProcess() = default;
  void read_stderr();

  std::optional<ChildProcess> child_;
  int stderr_fd_ = -1;
  int port_ = 0;
  mutable std::mutex mutex_;
  mutable std::condition_variable changed_;
  std::string log_;
  bool eof_ = false;
  std::thread reader_;
};

}  // namespace meshdeform::test
