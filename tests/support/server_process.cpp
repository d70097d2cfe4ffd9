#include "tests/support/server_process.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <regex>

namespace meshdeform::test {

std::unique_ptr<ServerProcess> ServerProcess::start(const std::string& binary,
                                                    const std::vector<std::string>& extra_flags,
                                                    std::string& error,
                                                    std::chrono::seconds startup,
                                                    long max_open_files) {
  int pipe_fds[2];
  if (pipe2(pipe_fds, O_CLOEXEC) != 0) {
    error = std::string("pipe: ") + std::strerror(errno);
    return nullptr;
  }
  std::vector<std::string> args = {binary, "--listen", "127.0.0.1:0"};
  args.insert(args.end(), extra_flags.begin(), extra_flags.end());
  // stdout goes nowhere (the server logs to stderr): a child holding the test's stdout kept
  // ctest waiting on the pipe for minutes after a test crashed.
  ChildStreams streams;
  streams.stderr_fd = pipe_fds[1];
  streams.max_open_files = max_open_files;
  std::string spawn_error;
  std::optional<ChildProcess> child = ChildProcess::spawn(args, streams, spawn_error);
  close(pipe_fds[1]);
  if (!child) {
    close(pipe_fds[0]);
    error = "cannot spawn " + binary + ": " + spawn_error;
    return nullptr;
  }

  std::unique_ptr<ServerProcess> server(new ServerProcess());
  server->child_ = std::move(child);
  server->stderr_fd_ = pipe_fds[0];
  server->reader_ = std::thread([raw = server.get()] { raw->read_stderr(); });

  const std::regex listening(R"re("event":"listening".*"port":([0-9]+))re");
  std::unique_lock lock(server->mutex_);
  const bool found = server->changed_.wait_for(lock, startup, [&] {
    std::smatch match;
    if (std::regex_search(server->log_, match, listening)) {
      server->port_ = std::stoi(match[1].str());
      return true;
    }
    return server->eof_;
  });
  if (found && server->port_ > 0) return server;
  error = binary + (server->eof_ ? " exited before listening"
                                 : " did not report a port within " +
                                       std::to_string(startup.count()) + " s") +
          "; its stderr:\n" + server->log_;
  lock.unlock();
  return nullptr;  // ~ServerProcess stops it
}

ServerProcess::~ServerProcess() {
  if (child_ && child_->is_running() && !stop(SIGTERM, std::chrono::seconds(20))) {
    child_->kill_and_reap();
  }
  if (reader_.joinable()) reader_.join();  // EOF once the process (and its pipe) is gone
  if (stderr_fd_ >= 0) close(stderr_fd_);
}

std::string ServerProcess::address() const { return "127.0.0.1:" + std::to_string(port_); }

int ServerProcess::http_port(std::chrono::milliseconds timeout) const {
  const std::regex listening(R"re("event":"http_listening".*"port":([0-9]+))re");
  int port = 0;
  std::unique_lock lock(mutex_);
  changed_.wait_for(lock, timeout, [&] {
    std::smatch match;
    if (std::regex_search(log_, match, listening)) {
      port = std::stoi(match[1].str());
      return true;
    }
    return eof_;
  });
  return port;
}

std::optional<int> ServerProcess::stop(int signal, std::chrono::milliseconds timeout) {
  if (!child_) return std::nullopt;
  return child_->stop(signal, timeout);
}

std::string ServerProcess::log() const {
  const std::lock_guard lock(mutex_);
  return log_;
}

bool ServerProcess::wait_for_log(const std::string& needle,
                                 std::chrono::milliseconds timeout) const {
  std::unique_lock lock(mutex_);
  return changed_.wait_for(lock, timeout,
                           [&] { return log_.find(needle) != std::string::npos || eof_; }) &&
         log_.find(needle) != std::string::npos;
}

bool ServerProcess::expire_idle_sessions(std::chrono::milliseconds timeout) {
  const std::string needle = "\"event\":\"expired_by_signal\"";
  auto count = [&] {
    std::size_t n = 0;
    for (std::size_t at = log_.find(needle); at != std::string::npos;
         at = log_.find(needle, at + 1)) {
      ++n;
    }
    return n;
  };
  std::unique_lock lock(mutex_);
  const std::size_t before = count();
  lock.unlock();
  if (pid() <= 0 || kill(pid(), SIGUSR1) != 0) return false;
  lock.lock();
  return changed_.wait_for(lock, timeout, [&] { return count() > before || eof_; }) &&
         count() > before;
}

void ServerProcess::read_stderr() {
  char buffer[4096];
  while (true) {
    const ssize_t n = read(stderr_fd_, buffer, sizeof buffer);
    if (n < 0 && errno == EINTR) continue;
    const std::lock_guard lock(mutex_);
    if (n <= 0) {
      eof_ = true;
      changed_.notify_all();
      return;
    }
    log_.append(buffer, static_cast<std::size_t>(n));
    changed_.notify_all();
  }
}

}  // namespace meshdeform::test
