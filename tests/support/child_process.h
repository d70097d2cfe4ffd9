#pragma once
/// @file child_process.h
/// Child processes of tests (the server, the CLI, the load tester, nginx) that die with the test:
/// every child is forked by one spawner thread that lives as long as the test process and asks
/// the kernel for SIGKILL when its parent dies (PR_SET_PDEATHSIG), so a test binary that crashes
/// or is killed with SIGKILL leaves no child behind, and no child holds the test's stdout (ctest
/// would wait on that pipe). ChildProcess reaps on every path. POSIX (Linux) only; no gRPC here.

#include <sys/types.h>

#include <chrono>
#include <optional>
#include <string>
#include <vector>

namespace meshdeform::test {

/// Where a child's standard streams go. stdin is always /dev/null.
struct ChildStreams {
  std::string stdout_path;  ///< a file (truncated), or empty for /dev/null: never the test's own
  std::string stderr_path;  ///< a file (truncated), or empty for /dev/null (unless stderr_fd)
  int stderr_fd = -1;       ///< the write end of a pipe, used instead of stderr_path when >= 0
  std::vector<std::string> env;  ///< "NAME=value" entries added to (or replacing in) environ
  std::vector<std::string> unset_env;  ///< names removed from the inherited environment
  /// Set: the child's RLIMIT_NOFILE (soft and hard), e.g. to run a server short of descriptors.
  long max_open_files = -1;
};

/// A running child, killed (SIGKILL) and reaped when destroyed unless already waited for.
class ChildProcess {
 public:
  /// Starts args[0] (a path) with `args` as argv.
  /// @return the child; nullopt with `error` set if it could not be started.
  static std::optional<ChildProcess> spawn(const std::vector<std::string>& args,
                                           const ChildStreams& streams, std::string& error);
  ChildProcess(ChildProcess&& other) noexcept : pid_(other.pid_) { other.pid_ = -1; }
  ChildProcess& operator=(ChildProcess&& other) noexcept;
  ChildProcess(const ChildProcess&) = delete;
  ChildProcess& operator=(const ChildProcess&) = delete;
  ~ChildProcess() { kill_and_reap(); }

  pid_t pid() const { return pid_; }
  bool is_running() const { return pid_ > 0; }
  /// Waits at most `timeout` for the exit. @return the wait status (WIFEXITED, ...) once it has
  /// exited (then the child is reaped), nullopt while it still runs.
  std::optional<int> wait(std::chrono::milliseconds timeout);
  /// Sends `signal`, then waits at most `timeout`. @return as wait().
  std::optional<int> stop(int signal, std::chrono::milliseconds timeout);
  /// SIGKILL and reap (no-op once reaped).
  void kill_and_reap();

 private:
  explicit ChildProcess(pid_t pid) : pid_(pid) {}
  pid_t pid_ = -1;
};

}  // namespace meshdeform::test
