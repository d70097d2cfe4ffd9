#include "tests/support/nginx_process.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <fstream>
#include <sstream>
#include <thread>

namespace meshdeform::test {
namespace {

namespace fs = std::filesystem;
using std::chrono::milliseconds;
using std::chrono::seconds;
using Clock = std::chrono::steady_clock;

}  // namespace

std::string find_nginx() {
  if (const char* env = std::getenv("MESHDEFORM_NGINX"); env != nullptr && *env != '\0') {
    return ::access(env, X_OK) == 0 ? std::string(env) : std::string();
  }
  return ::access("/usr/sbin/nginx", X_OK) == 0 ? std::string("/usr/sbin/nginx") : std::string();
}

bool accepts_connections(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  if (fd < 0) return false;
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  address.sin_port = htons(static_cast<std::uint16_t>(port));
  const bool ok = ::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0;
  ::close(fd);
  return ok;
}

std::optional<std::string> render_template(std::string text,
                                           const std::map<std::string, std::string>& values,
                                           std::string& error) {
  for (const auto& [key, value] : values) {
    const std::string placeholder = "${" + key + "}";
    std::size_t at = text.find(placeholder);
    if (at == std::string::npos) {
      error = "the template has no " + placeholder;
      return std::nullopt;
    }
    for (; at != std::string::npos; at = text.find(placeholder, at + value.size())) {
      text.replace(at, placeholder.size(), value);
    }
  }
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);) {
    const std::size_t first = line.find_first_not_of(" \t");
    if (first == std::string::npos || line[first] == '#') continue;
    if (line.find("${") != std::string::npos) {
      error = "unrendered placeholder in: " + line;
      return std::nullopt;
    }
  }
  return text;
}

std::vector<pid_t> children_of(pid_t pid) {
  std::vector<pid_t> children;
  std::error_code ec;
  for (const fs::directory_entry& entry : fs::directory_iterator("/proc", ec)) {
    const std::string name = entry.path().filename().string();
    if (name.empty() || name.find_first_not_of("0123456789") != std::string::npos) continue;
    const std::string stat = read_text(entry.path() / "stat");
    const std::size_t paren = stat.rfind(')');
    if (paren == std::string::npos) continue;
    std::istringstream fields(stat.substr(paren + 1));
    std::string state;
    pid_t parent = 0;
    fields >> state >> parent;
    if (parent == pid) children.push_back(static_cast<pid_t>(std::stoi(name)));
  }
  return children;
}

std::unique_ptr<NginxProcess> NginxProcess::start(const std::string& binary, const fs::path& prefix,
                                                  const fs::path& conf, std::vector<int> ports,
                                                  std::string& error) {
  const fs::path out = prefix / "nginx.out";
  std::vector<std::string> words = {
      binary, "-p", prefix.string() + "/", "-c", conf.string(), "-e",
      (prefix / "error.log").string(), "-g",
      // One process, no workers: PR_SET_PDEATHSIG reaches the only process, so a test binary
      // that crashes leaves no nginx worker behind (they would outlive a killed master).
      "daemon off; master_process off; pid " + (prefix / "nginx.pid").string() + ";"};
  ChildStreams streams;  // nginx dies with the test (PR_SET_PDEATHSIG)
  streams.stdout_path = out.string();
  streams.stderr_path = (prefix / "nginx.err").string();
  std::string spawn_error;
  std::optional<ChildProcess> child = ChildProcess::spawn(words, streams, spawn_error);
  if (!child) {
    error = "cannot spawn " + binary + ": " + spawn_error;
    return nullptr;
  }
  std::unique_ptr<NginxProcess> nginx(new NginxProcess(std::move(*child)));
  const auto deadline = Clock::now() + seconds(30);
  while (Clock::now() < deadline) {
    if (nginx->child_.wait(milliseconds(0))) {
      error = "nginx exited at start: " + read_text(out) + read_text(prefix / "nginx.err") +
              read_text(prefix / "error.log");
      return nullptr;
    }
    bool all = true;
    for (const int port : ports) all = all && accepts_connections(port);
    if (all) return nginx;
    std::this_thread::sleep_for(milliseconds(20));
  }
  error = "nginx did not accept connections within 30 s: " + read_text(out) +
          read_text(prefix / "error.log");
  return nullptr;  // the destructor stops it
}

NginxProcess::~NginxProcess() {
  if (!child_.is_running()) return;
  const pid_t master = child_.pid();
  const std::vector<pid_t> workers = children_of(master);
  if (!child_.stop(SIGTERM, seconds(5))) {
    for (const pid_t worker : children_of(master)) ::kill(worker, SIGKILL);
    child_.kill_and_reap();
  }
  // Workers orphaned by a master that died anyway (they are not our children: just signal).
  for (const pid_t worker : workers) {
    if (::kill(worker, 0) == 0) ::kill(worker, SIGKILL);
  }
}

}  // namespace meshdeform::test
