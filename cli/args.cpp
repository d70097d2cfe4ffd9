#include "cli/args.h"

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdlib>

namespace meshdeform::cli {

std::optional<std::string> ParsedArgs::get(const std::string& name) const {
  const auto it = values_.find(name);
  if (it == values_.end()) return std::nullopt;
  return it->second;
}

std::optional<UsageError> parse_args(const std::vector<std::string>& args,
                                     const std::vector<OptionSpec>& specs, ParsedArgs& out) {
  auto find_spec = [&](const std::string& name) -> const OptionSpec* {
    const auto it = std::find_if(specs.begin(), specs.end(),
                                 [&](const OptionSpec& spec) { return spec.name == name; });
    return it == specs.end() ? nullptr : &*it;
  };
  for (size_t k = 0; k < args.size(); ++k) {
    std::string word = args[k];
    if (word == "-h") word = "--help";
    if (word.size() < 3 || word.rfind("--", 0) != 0) {
      return UsageError{"unexpected argument '" + word + "' (options start with --)"};
    }
    std::string name = word.substr(2);
    std::optional<std::string> inline_value;
    if (const auto eq = name.find('='); eq != std::string::npos) {
      inline_value = name.substr(eq + 1);
      name = name.substr(0, eq);
    }
    const OptionSpec* spec = find_spec(name);
    if (spec == nullptr) return UsageError{"unknown option '--" + name + "'"};
    if (out.has(name)) return UsageError{"option '--" + name + "' given twice"};
    if (!spec->takes_value) {
      if (inline_value) return UsageError{"option '--" + name + "' takes no value"};
      out.set(name, "");
      continue;
    }
    if (inline_value) {
      out.set(name, *inline_value);
      continue;
    }
    if (k + 1 >= args.size()) return UsageError{"option '--" + name + "' needs a value"};
    out.set(name, args[++k]);
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
