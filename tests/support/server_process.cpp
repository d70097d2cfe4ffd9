#include "tests/support/server_process.h"

#include <fcntl.h>
#include <signal.h>
#include <spawn.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <regex>

extern char** environ;

namespace meshdeform::test {

std::unique_ptr<ServerProcess> ServerProcess::start(const std::string& binary,
                                                    const std::vector<std::string>& extra_flags,
                                                    std::string& error,
                                                    std::chrono::seconds startup) {
  int pipe_fds[2];
  if (pipe2(pipe_fds, O_CLOEXEC) != 0) {
    error = std::string("pipe: ") + std::strerror(errno);
    return nullptr;
  }
  std::vector<std::string> args = {binary, "--listen", "127.0.0.1:0"};
  args.insert(args.end(), extra_flags.begin(), extra_flags.end());
  std::vector<char*> argv;
  for (std::string& arg : args) argv.push_back(arg.data());
  argv.push_back(nullptr);

  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_adddup2(&actions, pipe_fds[1], STDERR_FILENO);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, binary.c_str(), &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  close(pipe_fds[1]);
  if (rc != 0) {
    close(pipe_fds[0]);
    error = "cannot spawn " + binary + ": " + std::strerror(rc);
    return nullptr;
  }

  std::unique_ptr<ServerProcess> server(new ServerProcess());
  server->pid_ = pid;
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
  if (pid_ > 0 && !stop(SIGTERM, std::chrono::seconds(20))) {
    stop(SIGKILL, std::chrono::seconds(20));
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
  if (pid_ <= 0) return std::nullopt;
  kill(pid_, signal);
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (true) {
    int status = 0;
    if (waitpid(pid_, &status, WNOHANG) == pid_) {
      pid_ = -1;
      return status;
    }
    if (std::chrono::steady_clock::now() >= deadline) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
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
