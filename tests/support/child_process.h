#pragma once
/// @file child_process.h
/// Child processes of tests (the server, the CLI, the load tester, nginx) that die with the test:
/// every child is forked by one spawner thread that lives as long as the test process and asks
/// the kernel for SIGKILL when its parent dies (PR_SET_PDEATHSIG), so a test binary that crashes
/// or is killed with SIGKILL leaves no child behind, and no child holds the test's stdout (ctest
/// would wait on that pipe). ChildProcess reaps on every path. POSIX (Linux) only; no gRPC here.

#include <sys/types.h>

#include <chrono>
#include <filesystem>
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
  /// The child's working directory (after its streams are opened); empty: the test's.
  std::string working_dir;
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

/// How a child run to its end went (run_captured).
struct CapturedRun {
  int exit_code = -1;         ///< -1: ended by a signal, timed out, or never started
  bool is_timed_out = false;  ///< still running after the timeout: killed
  std::string spawn_error;    ///< why it did not start (empty: it did)
  std::string out;            ///< what it wrote on stdout
  std::string err;            ///< and on stderr
};

/// Runs `args` (args[0] a path) in directory `dir` (stdin /dev/null, stdout and stderr to
/// dir/stdout.txt and dir/stderr.txt, read back into the result) and waits at most `timeout`;
/// a child still running then is killed. Like every ChildProcess it dies with the test.
CapturedRun run_captured(const std::vector<std::string>& args, const std::filesystem::path& dir,
                         std::chrono::milliseconds timeout);

/// The whole file as bytes ("" when it cannot be read).
std::string read_text(const std::filesystem::path& path);

/// A directory of the running test's own: <temp>/<prefix>_<pid>_<test name>, created empty.
/// Pass it to remove_test_dir at the end.
std::filesystem::path make_test_dir(const std::string& prefix);
/// Removes a make_test_dir directory, unless the test failed (it is kept to look at).
void remove_test_dir(const std::filesystem::path& dir, bool test_failed);

}  // namespace meshdeform::test
