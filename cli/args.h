#pragma once
/// @file args.h
/// meshdeform-cli's options on top of CLI11 (common/command_line.h): `--name value`,
/// `--name=value` and boolean `--flag` options, checked against a per-command list, with
/// meshdeform-cli's own messages; strict number parsing.

#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace meshdeform::cli {

/// One accepted option of a subcommand.
struct OptionSpec {
  std::string name;         ///< without the leading "--", e.g. "mesh"
  bool takes_value = true;  ///< false for boolean flags such as --verbose
};

/// Parsed options of one subcommand.
class ParsedArgs {
 public:
  bool has(const std::string& name) const { return values_.count(name) != 0; }
  /// The value of `name`, or nullopt when it was not given.
  std::optional<std::string> get(const std::string& name) const;
  void set(const std::string& name, std::string value) { values_[name] = std::move(value); }

 private:
  std::map<std::string, std::string> values_;
};

/// A usage error (exit code 2): what was wrong, in one line.
struct UsageError {
  std::string message;
};

/// Parses `args` (the words after the subcommand) against `specs` with CLI11. "-h" is accepted as
/// "--help" when "help" is in `specs`.
/// @return the options; a UsageError naming an unknown option, a missing value, an option given
///         twice, or a positional argument.
[[nodiscard]] std::optional<UsageError> parse_args(const std::vector<std::string>& args,
                                                   const std::vector<OptionSpec>& specs,
                                                   ParsedArgs& out);

/// Strict integer parse of a whole string ("12"; not "12x", "", "1e3").
std::optional<long long> parse_integer(std::string_view text);
/// Strict finite floating-point parse of a whole string ("1e-4", "0.5"; not "nan", "1.0x").
std::optional<double> parse_double(std::string_view text);

}  // namespace meshdeform::cli
