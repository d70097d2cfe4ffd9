#pragma once
// What every benchmark executable shares: its flags on CLI11 (BenchFlags), comma lists, bounded
// integers, writing a results file, and a main() that prints usage for --help (and after a bad
// flag) and turns errors into exit code 1.

#include <exception>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>
#include <utility>
#include <vector>

#include "common/command_line.h"
#include "core/base/allocator.h"
#include "core/base/status.h"

namespace meshdeform::bench {

/// "a,b,,c" -> {"a", "b", "c"}.
inline std::vector<std::string> split_commas(const std::string& text) {
  std::vector<std::string> out;
  std::stringstream in(text);
  std::string item;
  while (std::getline(in, item, ',')) {
    if (!item.empty()) out.push_back(item);
  }
  return out;
}

/// All of `text` as an integer >= min_value; InvalidArgument naming `flag` otherwise.
template <typename Integer>
Result<Integer> parse_integer(const std::string& flag, const std::string& text, Integer min_value) {
  try {
    std::size_t used = 0;
    const long long value = std::stoll(text, &used);
    if (used == text.size() && value >= static_cast<long long>(min_value)) {
      return static_cast<Integer>(value);
    }
  } catch (const std::exception&) {
  }
  return Error(ErrorCode::InvalidArgument,
               flag + " wants an integer >= " + std::to_string(min_value) + ", got '" + text + "'");
}

/// A benchmark's flags on CLI11 (common/command_line.h): "--flag value", "--flag=value" and
/// value-less flags, the last of a repeated flag winning. Each value goes through a handler that
/// stores it or returns InvalidArgument naming the flag; the first bad value on the line is the
/// one reported. --help/-h is bench_main's (it wins anywhere on the line).
class BenchFlags {
 public:
  BenchFlags() { command_line::configure(app_); }
  BenchFlags(const BenchFlags&) = delete;
  BenchFlags& operator=(const BenchFlags&) = delete;

  /// "--name VALUE": `apply` stores VALUE or says why it is refused.
  void value(const std::string& name, std::function<Status(const std::string&)> apply) {
    command_line::add_checked(app_, name,
                              [this, apply = std::move(apply)](
                                  const std::string& text) -> std::optional<std::string> {
                                Status status = apply(text);
                                if (status.ok()) return std::nullopt;
                                refused_ = status;
                                return status.message();
                              });
  }
  /// "--name VALUE" stored as it is.
  void text(const std::string& name, std::string& out) {
    value(name, [&out](const std::string& text) {
      out = text;
      return Status::success();
    });
  }
  /// "--name VALUE": an integer >= min_value (parse_integer).
  template <typename Integer>
  void integer(const std::string& name, Integer& out, Integer min_value) {
    value(name, [name, &out, min_value](const std::string& text) {
      Result<Integer> parsed = parse_integer<Integer>(name, text, min_value);
      if (!parsed.ok()) return parsed.status();
      out = *parsed;
      return Status::success();
    });
  }
  /// "--name a,b,c" stored as its comma-separated items (split_commas).
  void list(const std::string& name, std::vector<std::string>& out) {
    value(name, [&out](const std::string& text) {
      out = split_commas(text);
      return Status::success();
    });
  }
  /// "--name 2,3": comma-separated integers, each >= min_value (parse_integer).
  template <typename Integer>
  void integer_list(const std::string& name, std::vector<Integer>& out, Integer min_value) {
    value(name, [name, &out, min_value](const std::string& text) -> Status {
      out.clear();
      for (const std::string& item : split_commas(text)) {
        MD_ASSIGN_OR_RETURN(const Integer parsed, parse_integer<Integer>(name, item, min_value));
        out.push_back(parsed);
      }
      return Status::success();
    });
  }
  /// "--name" without a value: runs `on`.
  void flag(const std::string& name, std::function<void()> on) {
    app_.add_flag_callback(name, std::move(on))->disable_flag_override();
  }

  /// Parses argv. @return InvalidArgument naming an unknown option, a missing value or a bad one.
  Status parse(int argc, char** argv) {
    const std::optional<command_line::Problem> problem = command_line::parse(
        app_, std::vector<std::string>(argv + 1, argv + argc), command_line::Repeats::LastWins);
    if (!problem) return Status::success();
    using Kind = command_line::Problem::Kind;
    switch (problem->kind) {
      case Kind::BadValue:
        return refused_;
      case Kind::MissingValue:
        return Error(ErrorCode::InvalidArgument, problem->word + " needs a value");
      case Kind::TakesNoValue:
        return Error(ErrorCode::InvalidArgument, problem->word + " takes no value");
      case Kind::UnknownOption:
      case Kind::Unexpected:
        return Error(ErrorCode::InvalidArgument, "unknown option '" + problem->word + "'");
      case Kind::Repeated:
      case Kind::Other:
        break;
    }
    return Error(ErrorCode::InvalidArgument, problem->message);
  }

 private:
  CLI::App app_;
  Status refused_ = Status::success();
};

/// Whether -h or --help is anywhere on the line, even where a flag's value would be (as it always
/// was for the benchmarks): CLI11 with only that flag known.
inline bool wants_help(int argc, char** argv) {
  CLI::App app;
  command_line::configure(app);
  bool help = false;
  command_line::add_help(app, help, true);
  (void)command_line::parse(app, std::vector<std::string>(argv + 1, argv + argc),
                            command_line::Repeats::LastWins);
  return help;
}

/// Writes a results file. @return Internal naming the path if it cannot be written.
inline Status write_file(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  if (!out) return Error(ErrorCode::Internal, "cannot write " + path.string());
  return Status::success();
}

/// main() of a benchmark, after the solvers' heap settings (core/base/allocator.h): --help/-h prints
/// `usage` and exits 0; `run` returning an error prints it (and the usage, for a bad flag) and
/// exits 1, as does an escaped exception.
template <typename Usage, typename Run>
int bench_main(int argc, char** argv, const char* name, Usage&& usage, Run&& run) {
  core::keep_freed_heap_for_solver_arrays();  // as the server and the CLI do
  try {
    if (wants_help(argc, argv)) {
      usage(std::cout);
      return 0;
    }
    const Status status = run(argc, argv);
    if (!status.ok()) {
      std::cerr << name << ": " << status.to_string() << "\n";
      if (status.code() == ErrorCode::InvalidArgument) usage(std::cerr);
      return 1;
    }
  } catch (const std::exception& e) {
    std::cerr << name << ": " << e.what() << "\n";
    return 1;
  }
  return 0;
}

}  // namespace meshdeform::bench
