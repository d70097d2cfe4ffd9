#include "cli/args.h"

#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdlib>

#include "common/command_line.h"

namespace meshdeform::cli {

std::optional<std::string> ParsedArgs::get(const std::string& name) const {
  const auto it = values_.find(name);
  if (it == values_.end()) return std::nullopt;
  return it->second;
}

std::optional<UsageError> parse_args(const std::vector<std::string>& args,
                                     const std::vector<OptionSpec>& specs, ParsedArgs& out) {
  namespace command_line = meshdeform::command_line;
  CLI::App app;
  command_line::configure(app);
  // std::map: the bound values keep their addresses while the App holds references to them.
  std::map<std::string, std::optional<std::string>> values;
  std::map<std::string, bool> flags;
  for (const OptionSpec& spec : specs) {
    const std::string names = (spec.name == "help" ? "-h,--" : "--") + spec.name;
    if (spec.takes_value) {
      command_line::add_text(app, names, values[spec.name]);
    } else {
      command_line::add_flag(app, names, flags[spec.name]);
    }
  }
  using Kind = command_line::Problem::Kind;
  if (const auto problem = command_line::parse(app, args, command_line::Repeats::Refuse)) {
    const std::string& word = problem->word;
    switch (problem->kind) {
      case Kind::UnknownOption:
        if (word.size() >= 3 && word.rfind("--", 0) == 0) {
          return UsageError{"unknown option '" + word + "'"};
        }
        [[fallthrough]];
      case Kind::Unexpected:
        return UsageError{"unexpected argument '" + word + "' (options start with --)"};
      case Kind::MissingValue:
        return UsageError{"option '" + word + "' needs a value"};
      case Kind::Repeated:
        return UsageError{"option '" + word + "' given twice"};
      case Kind::TakesNoValue:
        return UsageError{"option '" + word + "' takes no value"};
      case Kind::BadValue:  // no add_checked() options here
      case Kind::Other:
        break;
    }
    return UsageError{problem->message};
  }
  for (const auto& [name, value] : values) {
    if (value) out.set(name, *value);
  }
  for (const auto& [name, given] : flags) {
    if (given) out.set(name, "");
  }
  return std::nullopt;
}

std::optional<long long> parse_integer(std::string_view text) {
  long long value = 0;
  const char* end = text.data() + text.size();
  const auto [ptr, ec] = std::from_chars(text.data(), end, value);
  if (text.empty() || ec != std::errc() || ptr != end) return std::nullopt;
  return value;
}

std::optional<double> parse_double(std::string_view text) {
  // strtod rather than from_chars<double>: both are fine on GCC 12, but strtod also accepts the
  // leading '+' users type; the whole string must be consumed and the value finite.
  if (text.empty() || std::isspace(static_cast<unsigned char>(text.front()))) return std::nullopt;
  const std::string copy(text);
  char* end = nullptr;
  const double value = std::strtod(copy.c_str(), &end);
  if (end != copy.c_str() + copy.size() || !std::isfinite(value)) return std::nullopt;
  return value;
}

}  // namespace meshdeform::cli
