#pragma once
// Shared by the benchmarks that measure memory: each measured method runs in its own forked child
// so that its peak resident set (VmHWM) is its own, plus the timing statistics they report.

#include <malloc.h>
#include <sys/resource.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <exception>
#include <fstream>
#include <functional>
#include <iostream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/mesh/measures.h"
#include "core/base/status.h"

namespace meshdeform::bench {

/// A field of /proc/self/status in KiB ("VmHWM", "VmRSS"), or -1.
inline long proc_status_kib(const std::string& field) {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(field + ":", 0) == 0) return std::atol(line.c_str() + field.size() + 1);
  }
  return -1;
}

/// Resets the peak resident set (VmHWM) to the current one (Linux >= 4.0); false if not allowed.
inline bool reset_peak_rss() {
  std::ofstream out("/proc/self/clear_refs");
  out << "5";
  out.flush();
  return static_cast<bool>(out);
}

/// The peak resident set so far (since the last reset), in KiB.
inline long peak_rss_kib() { return proc_status_kib("VmHWM"); }

inline double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

/// The q-quantile (0..1, linear interpolation between order statistics); NaN when empty.
inline double quantile(std::vector<double> values, double q) {
  if (values.empty()) return std::nan("");
  std::sort(values.begin(), values.end());
  const double position = q * static_cast<double>(values.size() - 1);
  const auto lo = static_cast<size_t>(std::floor(position));
  const size_t hi = std::min(lo + 1, values.size() - 1);
  return values[lo] + (position - static_cast<double>(lo)) * (values[hi] - values[lo]);
}

inline double median(std::vector<double> values) { return quantile(std::move(values), 0.5); }

inline nlohmann::json errors_json(const core::AngleErrors& e) {
  return {{"e_theta", e.e_theta}, {"e_phi", e.e_phi}, {"area", e.area_log_rms}};
}

/// Runs `body` in a forked child and returns what it returned (JSON) plus the child's peak RSS.
/// In the child: give the parent's free heap back (malloc_trim), reset VmHWM, note the baseline,
/// run, and report VmHWM as the method's peak (its input mesh and the libraries included).
/// @return Internal if the child dies (e.g. out of memory) or `body` throws (with its message).
inline Result<nlohmann::json> run_in_child(const std::function<nlohmann::json()>& body) {
  using nlohmann::json;
  int fds[2];
  if (pipe(fds) != 0) return Error(ErrorCode::Internal, "pipe failed");
  std::cout.flush();
  std::cerr.flush();
  const pid_t pid = fork();
  if (pid < 0) return Error(ErrorCode::Internal, "fork failed");
  if (pid == 0) {
    close(fds[0]);
    malloc_trim(0);
    const bool reset = reset_peak_rss();
    json out;
    out["baseline_rss_kib"] = proc_status_kib("VmRSS");
    try {
      json result = body();
      out.update(result);
      out["hwm_reset"] = reset;
    } catch (const std::exception& e) {
      out["error"] = e.what();
    }
    const std::string text = out.dump();
    size_t written = 0;
    while (written < text.size()) {
      const ssize_t n = write(fds[1], text.data() + written, text.size() - written);
      if (n <= 0) break;
      written += static_cast<size_t>(n);
    }
    close(fds[1]);
    _exit(0);
  }
  close(fds[1]);
  std::string text;
  char buffer[65536];
  for (;;) {
    const ssize_t n = read(fds[0], buffer, sizeof(buffer));
    if (n <= 0) break;
    text.append(buffer, static_cast<size_t>(n));
  }
  close(fds[0]);
  int status = 0;
  struct rusage usage {};
  wait4(pid, &status, 0, &usage);
  if (!WIFEXITED(status) || text.empty()) {
    return Error(ErrorCode::Internal,
                 "child died (status " + std::to_string(status) + ", e.g. out of memory)");
  }
  json out = json::parse(text);
  out["ru_maxrss_kib"] = usage.ru_maxrss;
  if (out.contains("error")) return Error(ErrorCode::Internal, out["error"].get<std::string>());
  return out;
}

}  // namespace meshdeform::bench
