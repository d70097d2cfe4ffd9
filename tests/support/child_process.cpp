#include "tests/support/child_process.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <fstream>
#include <functional>
#include <future>
#include <mutex>
#include <sstream>
#include <thread>

#include <gtest/gtest.h>

extern char** environ;

namespace meshdeform::test {
namespace {

/// Everything a forked child needs, prepared before fork() (the child may only make
/// async-signal-safe calls: no allocation).
struct SpawnPlan {
  std::vector<std::string> args;
  std::vector<std::string> env;
  std::vector<std::string> unset_env;
  std::string stdout_path;
  std::string stderr_path;
  int stderr_fd = -1;
  long max_open_files = -1;
  std::string working_dir;
};

pid_t fork_and_exec(const SpawnPlan& plan, std::string& error) {
  std::vector<char*> argv;
  for (const std::string& arg : plan.args) argv.push_back(const_cast<char*>(arg.c_str()));
  argv.push_back(nullptr);
  std::vector<std::string> env_storage;
  for (char** e = environ; *e != nullptr; ++e) {
    const std::string entry(*e);
    const std::string name = entry.substr(0, entry.find('='));
    bool replaced = false;
    for (const std::string& extra : plan.env) {
      replaced = replaced || extra.substr(0, extra.find('=')) == name;
    }
    for (const std::string& unset : plan.unset_env) replaced = replaced || unset == name;
    if (!replaced) env_storage.push_back(entry);
  }
  env_storage.insert(env_storage.end(), plan.env.begin(), plan.env.end());
  std::vector<char*> envp;
  for (std::string& entry : env_storage) envp.push_back(entry.data());
  envp.push_back(nullptr);
  const char* out = plan.stdout_path.empty() ? "/dev/null" : plan.stdout_path.c_str();
  const char* err = plan.stderr_path.empty() ? "/dev/null" : plan.stderr_path.c_str();
  const pid_t parent = getpid();

  const pid_t pid = fork();
  if (pid < 0) {
    error = std::string("fork: ") + std::strerror(errno);
    return -1;
  }
  if (pid == 0) {
    // The child: die with the spawner thread, i.e. with the test process.
    if (prctl(PR_SET_PDEATHSIG, SIGKILL) != 0) _exit(126);
    if (getppid() != parent) _exit(126);  // the parent died before prctl took effect
    const int in_fd = open("/dev/null", O_RDONLY);
    const int out_fd = open(out, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
    const int err_fd =
        plan.stderr_fd >= 0 ? plan.stderr_fd : open(err, O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (in_fd < 0 || out_fd < 0 || err_fd < 0) _exit(126);
    if (dup2(in_fd, STDIN_FILENO) < 0 || dup2(out_fd, STDOUT_FILENO) < 0 ||
        dup2(err_fd, STDERR_FILENO) < 0) {
      _exit(126);
    }
    if (!plan.working_dir.empty() && chdir(plan.working_dir.c_str()) != 0) _exit(126);
    if (plan.max_open_files >= 0) {
      const struct rlimit limit {
        static_cast<rlim_t>(plan.max_open_files), static_cast<rlim_t>(plan.max_open_files)
      };
      if (setrlimit(RLIMIT_NOFILE, &limit) != 0) _exit(126);
    }
    // Unblock the signals a test may have blocked (the child must honour SIGTERM).
    sigset_t none;
    sigemptyset(&none);
    sigprocmask(SIG_SETMASK, &none, nullptr);
    execve(argv[0], argv.data(), envp.data());
    _exit(127);
  }
  return pid;
}

/// The one thread that forks every child: PR_SET_PDEATHSIG fires when the *thread* that forked
/// exits, so the spawner must live as long as the process (it is never joined; it ends with it).
class Spawner {
 public:
  static Spawner& instance() {
    static Spawner* spawner = new Spawner();  // leaked on purpose: see the class comment
    return *spawner;
  }

  pid_t spawn(SpawnPlan plan, std::string& error) {
    std::packaged_task<std::pair<pid_t, std::string>()> task([plan = std::move(plan)] {
      std::string err;
      const pid_t pid = fork_and_exec(plan, err);
      return std::make_pair(pid, err);
    });
    std::future<std::pair<pid_t, std::string>> result = task.get_future();
    {
      std::lock_guard lock(mutex_);
      queue_.push_back(std::move(task));
    }
    cv_.notify_one();
    auto [pid, err] = result.get();
    error = err;
    return pid;
  }

 private:
  Spawner() {
    std::thread([this] {
      while (true) {
        std::packaged_task<std::pair<pid_t, std::string>()> task;
        {
          std::unique_lock lock(mutex_);
          cv_.wait(lock, [this] { return !queue_.empty(); });
          task = std::move(queue_.front());
          queue_.pop_front();
        }
        task();
      }
    }).detach();
  }

  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<std::packaged_task<std::pair<pid_t, std::string>()>> queue_;
};

}  // namespace

std::optional<ChildProcess> ChildProcess::spawn(const std::vector<std::string>& args,
                                                const ChildStreams& streams, std::string& error) {
  if (args.empty()) {
    error = "no program to spawn";
    return std::nullopt;
  }
  SpawnPlan plan{args,
                 streams.env,
                 streams.unset_env,
                 streams.stdout_path,
                 streams.stderr_path,
                 streams.stderr_fd,
                 streams.max_open_files,
                 streams.working_dir};
  const pid_t pid = Spawner::instance().spawn(std::move(plan), error);
  if (pid <= 0) return std::nullopt;
  return ChildProcess(pid);
}

ChildProcess& ChildProcess::operator=(ChildProcess&& other) noexcept {
  if (this != &other) {
    kill_and_reap();
    pid_ = other.pid_;
    other.pid_ = -1;
  }
  return *this;
}

std::optional<int> ChildProcess::wait(std::chrono::milliseconds timeout) {
  if (pid_ <= 0) return std::nullopt;
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (true) {
    int status = 0;
    const pid_t waited = waitpid(pid_, &status, WNOHANG);
    if (waited == pid_ || (waited < 0 && errno == ECHILD)) {
      pid_ = -1;
      return status;
    }
    if (std::chrono::steady_clock::now() >= deadline) return std::nullopt;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

std::optional<int> ChildProcess::stop(int signal, std::chrono::milliseconds timeout) {
  if (pid_ <= 0) return std::nullopt;
  kill(pid_, signal);
  return wait(timeout);
}

void ChildProcess::kill_and_reap() {
  if (pid_ <= 0) return;
  kill(pid_, SIGKILL);
  int status = 0;
  while (waitpid(pid_, &status, 0) < 0 && errno == EINTR) {
  }
  pid_ = -1;
}

CapturedRun run_captured(const std::vector<std::string>& args, const std::filesystem::path& dir,
                         std::chrono::milliseconds timeout) {
  CapturedRun result;
  ChildStreams streams;
  streams.stdout_path = (dir / "stdout.txt").string();
  streams.stderr_path = (dir / "stderr.txt").string();
  streams.working_dir = dir.string();
  std::optional<ChildProcess> child = ChildProcess::spawn(args, streams, result.spawn_error);
  if (!child) {
    if (result.spawn_error.empty()) result.spawn_error = "cannot start " + args.front();
    return result;
  }
  const std::optional<int> status = child->wait(timeout);
  if (!status) {
    result.is_timed_out = true;
    child->kill_and_reap();
  } else if (WIFEXITED(*status)) {
    result.exit_code = WEXITSTATUS(*status);
  }
  result.out = read_text(streams.stdout_path);
  result.err = read_text(streams.stderr_path);
  return result;
}

std::string read_text(const std::filesystem::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream buffer;
  buffer << in.rdbuf();
  return buffer.str();
}

std::filesystem::path make_test_dir(const std::string& prefix) {
  const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
  const std::string test = info != nullptr ? info->name() : "no_test";
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    (prefix + "_" + std::to_string(::getpid()) + "_" + test);
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  return dir;
}

void remove_test_dir(const std::filesystem::path& dir, bool test_failed) {
  std::error_code ignored;
  if (!test_failed) std::filesystem::remove_all(dir, ignored);
}

}  // namespace meshdeform::test
