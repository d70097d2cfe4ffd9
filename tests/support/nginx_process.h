#pragma once
/// @file nginx_process.h
/// Real nginx for tests (the scale-out tests of issues 6 and 16): the shipped
/// docker/nginx.conf.template rendered with loopback ports, nginx run in the foreground as a
/// ChildProcess (its master dies with the test; its workers are signalled in teardown). POSIX
/// (Linux /proc) only; every wait is bounded.

#include <sys/types.h>

#include <filesystem>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "tests/support/child_process.h"

namespace meshdeform::test {

/// The nginx binary to use ($MESHDEFORM_NGINX, else /usr/sbin/nginx), or "" when there is none.
std::string find_nginx();

/// Substitutes every `${KEY}` of `values` in `text` (as envsubst does in the nginx image).
/// @return the rendered text, or nullopt with `error` set when a key does not occur in the
///         template or a `${` placeholder is left on a non-comment line.
std::optional<std::string> render_template(std::string text,
                                           const std::map<std::string, std::string>& values,
                                           std::string& error);

/// Direct children of `pid` (from /proc), e.g. nginx's workers.
std::vector<pid_t> children_of(pid_t pid);

/// True when something accepts TCP connections on 127.0.0.1:port.
bool accepts_connections(int port);

/// nginx in the foreground (`daemon off`) as our child, with every path under `prefix`.
class NginxProcess {
 public:
  /// Starts nginx on `conf` and waits (at most 30 s) until every port of `ports` accepts.
  /// @return the process, or nullptr with `error` set (nginx's output included).
  static std::unique_ptr<NginxProcess> start(const std::string& binary,
                                             const std::filesystem::path& prefix,
                                             const std::filesystem::path& conf,
                                             std::vector<int> ports, std::string& error);
  NginxProcess(const NginxProcess&) = delete;
  NginxProcess& operator=(const NginxProcess&) = delete;
  /// Fast shutdown (SIGTERM); after 5 s SIGKILL of the master and of its workers.
  ~NginxProcess();

 private:
  explicit NginxProcess(ChildProcess child) : child_(std::move(child)) {}
  ChildProcess child_;
};

}  // namespace meshdeform::test
