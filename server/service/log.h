#pragma once
/// @file log.h
/// Structured logs: one JSON object per line on stderr (or a sink installed by tests), e.g.
///   {"ts":"2026-11-22T10:00:00.123Z","level":"info","event":"rpc","method":"MoveHandles",...}
/// Keys are fixed identifiers; values are escaped. Secrets (tokens) are never passed here.
/// Thread-safe: each line is written whole.

#include <cstdint>
#include <functional>
#include <string>
#include <string_view>

namespace meshdeform::service {

enum class LogLevel { Debug = 0, Info = 1, Warn = 2, Error = 3 };

/// Builds the fields of one log line.
class LogFields {
 public:
  LogFields& add(std::string_view key, std::string_view value);
  LogFields& add(std::string_view key, const char* value) { return add(key, std::string_view(value)); }
  LogFields& add(std::string_view key, const std::string& value) {
    return add(key, std::string_view(value));
  }
  LogFields& add(std::string_view key, std::int64_t value);
  LogFields& add(std::string_view key, std::uint64_t value);
  LogFields& add(std::string_view key, int value) { return add(key, std::int64_t{value}); }
  LogFields& add(std::string_view key, double value);  ///< non-finite values are written as null
  LogFields& add(std::string_view key, bool value);
  const std::string& json() const { return json_; }  ///< ",\"k\":v,..." (leading comma)

 private:
  std::string json_;
};

/// Lines below this level are dropped (default Info).
void set_log_level(LogLevel level);
/// Replaces the output (default: stderr); an empty function restores stderr. For tests.
void set_log_sink(std::function<void(std::string_view line)> sink);
/// Writes one line: timestamp, level, event, then the fields.
void log_event(LogLevel level, std::string_view event, const LogFields& fields = {});

/// JSON string escaping (quotes, backslash, control characters as \u00XX). For the logger and
/// other hand-written JSON.
std::string json_escape(std::string_view text);

}  // namespace meshdeform::service
