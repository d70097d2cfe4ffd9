#include "server/service/log.h"

#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <mutex>

namespace meshdeform::service {
namespace {

std::atomic<int> g_level{static_cast<int>(LogLevel::Info)};
std::mutex g_mutex;
std::function<void(std::string_view)>& sink() {
  static std::function<void(std::string_view)> instance;
  return instance;
}

const char* level_name(LogLevel level) {
  switch (level) {
    case LogLevel::Debug: return "debug";
    case LogLevel::Info: return "info";
    case LogLevel::Warn: return "warn";
    case LogLevel::Error: return "error";
  }
  return "info";
}

std::string utc_timestamp() {
  const auto now = std::chrono::system_clock::now();
  const std::time_t seconds = std::chrono::system_clock::to_time_t(now);
  const auto millis =
      std::chrono::duration_cast<std::chrono::milliseconds>(now.time_since_epoch()).count() % 1000;
  std::tm tm{};
  gmtime_r(&seconds, &tm);
  char buffer[96];  // generous: the compiler cannot bound tm_year
  std::snprintf(buffer, sizeof buffer, "%04d-%02d-%02dT%02d:%02d:%02d.%03dZ", tm.tm_year + 1900,
                tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec,
                static_cast<int>(millis));
  return buffer;
}

}  // namespace

std::string json_escape(std::string_view text) {
  std::string out;
  out.reserve(text.size() + 2);
  for (const char c : text) {
    switch (c) {
      case '"': out += "\\\""; break;
      case '\\': out += "\\\\"; break;
      case '\n': out += "\\n"; break;
      case '\r': out += "\\r"; break;
      case '\t': out += "\\t"; break;
      default:
        if (static_cast<unsigned char>(c) < 0x20) {
          char buffer[8];
          std::snprintf(buffer, sizeof buffer, "\\u%04x", static_cast<unsigned>(c));
          out += buffer;
        } else {
          out += c;
        }
    }
  }
  return out;
}

LogFields& LogFields::add(std::string_view key, std::string_view value) {
  json_ += ",\"" + json_escape(key) + "\":\"" + json_escape(value) + "\"";
  return *this;
}
LogFields& LogFields::add(std::string_view key, std::int64_t value) {
  json_ += ",\"" + json_escape(key) + "\":" + std::to_string(value);
  return *this;
}
LogFields& LogFields::add(std::string_view key, std::uint64_t value) {
  json_ += ",\"" + json_escape(key) + "\":" + std::to_string(value);
  return *this;
}
LogFields& LogFields::add(std::string_view key, double value) {
  json_ += ",\"" + json_escape(key) + "\":";
  if (std::isfinite(value)) {
    char buffer[32];
    std::snprintf(buffer, sizeof buffer, "%.6g", value);
    json_ += buffer;
  } else {
    json_ += "null";
  }
  return *this;
}
LogFields& LogFields::add(std::string_view key, bool value) {
  json_ += ",\"" + json_escape(key) + "\":" + (value ? "true" : "false");
  return *this;
}

void set_log_level(LogLevel level) { g_level.store(static_cast<int>(level)); }

void set_log_sink(std::function<void(std::string_view line)> new_sink) {
  const std::lock_guard lock(g_mutex);
  sink() = std::move(new_sink);
}

void log_event(LogLevel level, std::string_view event, const LogFields& fields) {
  if (static_cast<int>(level) < g_level.load()) return;
  std::string line = "{\"ts\":\"" + utc_timestamp() + "\",\"level\":\"" + level_name(level) +
                     "\",\"event\":\"" + json_escape(event) + "\"" + fields.json() + "}\n";
  const std::lock_guard lock(g_mutex);
  if (sink()) {
    sink()(line);
    return;
  }
  std::size_t written = 0;
  while (written < line.size()) {
    const ssize_t n = ::write(STDERR_FILENO, line.data() + written, line.size() - written);
    if (n <= 0) return;  // stderr closed: logs are best effort
    written += static_cast<std::size_t>(n);
  }
}

}  // namespace meshdeform::service
