#pragma once
/// @file command_line.h
/// What the command-line tools (meshdeform-server, meshdeform-cli, meshdeform-client,
/// meshdeform-loadtest, the benches) share on top of CLI11: an App that only parses (each tool
/// prints its own usage text and words its own errors, so neither changes with the library), and
/// parse(), which runs it and reports the first problem as a Problem naming the flag or word, for
/// the tool to print in its own style with its own exit code.

#include <CLI/CLI.hpp>

#include <algorithm>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

namespace meshdeform::command_line {

/// Why a command line was refused.
struct Problem {
  enum class Kind {
    UnknownOption,  ///< a word that looks like an option the tool does not have ("--bogus", "-x")
    Unexpected,     ///< a word that is neither an option nor an option's value ("stray")
    MissingValue,   ///< an option that takes a value, last on the line without one
    Repeated,       ///< an option given more than once (only when repeats are refused)
    TakesNoValue,   ///< "--flag=value" for a flag that takes none
    BadValue,       ///< an add_checked() option's check refused its value
    Other,          ///< anything else CLI11 refused; `message` says what
  };
  Kind kind = Kind::Other;
  /// The option as it is spelled on the command line ("--mesh", without any "=value"), or the
  /// word itself for Unexpected.
  std::string word;
  /// BadValue: the refused value.
  std::string value;
  /// BadValue: the check's message; otherwise CLI11's own description (the only one for Other).
  std::string message;
};

/// Whether an option given twice is a usage error or the last one wins.
enum class Repeats {
  Refuse,        ///< any option, value-less flags included
  RefuseValues,  ///< options taking a value; a flag may be repeated
  LastWins,
};

/// Makes `app` a pure parser: no generated --help (the tools add their own -h/--help flag and
/// print their own usage text), unknown words collected for parse() to report, and flags that
/// refuse a value ("--verbose=0").
inline void configure(CLI::App& app) {
  app.set_help_flag();
  app.allow_extras();
  app.option_defaults()->disable_flag_override();
}

/// Adds a value-less flag (e.g. "--verbose") to `app`; `out` becomes true when it is given.
inline CLI::Option* add_flag(CLI::App& app, const std::string& names, bool& out) {
  return app.add_flag(names, out)->disable_flag_override();
}

/// Adds an option taking one value, kept as text: the tools check values themselves so that
/// their range checks and messages stay as they were. `out` is set when the option is on the line
/// (to the last value given; "--name=" gives an empty one) and left alone otherwise.
inline CLI::Option* add_text(CLI::App& app, const std::string& names,
                             std::optional<std::string>& out) {
  return app
      .add_option_function<std::string>(names, [&out](const std::string& value) { out = value; })
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);
}

/// Adds the tool's own "-h, --help" flag: `help` becomes true when it is given. With
/// `stops_parsing`, parse() stops right there and returns no problem for whatever follows (the
/// tool prints its usage and exits 0, as the servers and benches always did); otherwise the rest
/// of the line must parse too.
inline CLI::Option* add_help(CLI::App& app, bool& help, bool stops_parsing) {
  CLI::Option* option = add_flag(app, "-h,--help", help);
  if (stops_parsing) {
    option->trigger_on_parse()->each([&help](const std::string&) {
      help = true;
      throw CLI::CallForHelp();
    });
  }
  return option;
}

/// What an add_checked() option does with its value: nothing (it is fine, and stored), or a
/// message saying why it is refused.
using Check = std::function<std::optional<std::string>(const std::string& value)>;

/// Thrown by add_checked() options out of parse() (which turns it into a BadValue problem).
struct BadValueThrown {
  std::string option, value, message;
};

/// Adds an option taking one value that `check` validates and stores (a repeatable option's check
/// collects every value). Every occurrence is checked as soon as it is read, so the first bad
/// value on the line is the one reported, as the hand-written loops did.
inline CLI::Option* add_checked(CLI::App& app, const std::string& name, Check check) {
  return app
      .add_option_function<std::string>(
          name,
          [name, check = std::move(check)](const std::string& value) {
            if (auto error = check(value)) throw BadValueThrown{name, value, *error};
          })
      ->multi_option_policy(CLI::MultiOptionPolicy::TakeLast)
      ->trigger_on_parse();
}

namespace detail {

/// "--name=value" -> "--name".
inline std::string option_word(const std::string& word) {
  if (word.size() > 2 && word.compare(0, 2, "--") == 0) return word.substr(0, word.find('='));
  return word;
}

/// The option a CLI11 message starting with its name is about ("--mesh: 1 required TEXT
/// missing", "--verbose was given a disallowed flag override"); empty if none of `app`'s.
inline std::string named_option(const CLI::App& app, const std::string& message) {
  std::string best;
  auto consider = [&](const CLI::App& in) {
    for (const CLI::Option* option : in.get_options()) {
      const std::string name = option->get_name();
      if (!name.empty() && message.compare(0, name.size(), name) == 0 && name.size() > best.size()) {
        best = name;
      }
    }
  };
  consider(app);
  for (const CLI::App* sub : app.get_subcommands([](const CLI::App*) { return true; })) {
    consider(*sub);
  }
  return best;
}

inline void collect_apps(CLI::App& app, std::vector<CLI::App*>& out) {
  out.push_back(&app);
  for (CLI::App* sub : app.get_subcommands()) collect_apps(*sub, out);
}

}  // namespace detail

/// Parses `args` (argv without the program name) with `app` (set up with configure()).
/// @return nothing when the line is fine (the bound variables are set), else the first problem:
///         a missing value, then a word CLI11 did not take, then (with Repeats::Refuse) the first
///         option given twice.
inline std::optional<Problem> parse(CLI::App& app, const std::vector<std::string>& args,
                                    Repeats repeats) {
  // CLI11 consumes from the back. "--name=" (an empty value) becomes "--name" "": CLI11 would
  // otherwise take the next word as the value.
  std::vector<std::string> reversed;
  reversed.reserve(args.size() + 1);
  for (auto it = args.rbegin(); it != args.rend(); ++it) {
    const std::string& word = *it;
    if (word.size() > 3 && word.compare(0, 2, "--") == 0 && word.find('=') == word.size() - 1) {
      reversed.emplace_back();
      reversed.push_back(word.substr(0, word.size() - 1));
    } else {
      reversed.push_back(word);
    }
  }
  try {
    app.parse(reversed);
  } catch (const CLI::ArgumentMismatch& e) {
    const std::string message = e.what();
    const std::string name = detail::named_option(app, message);
    Problem problem{Problem::Kind::Other, name, "", message};
    if (!name.empty() && message.find(" required ") != std::string::npos &&
        message.find(" missing") != std::string::npos) {
      problem.kind = Problem::Kind::MissingValue;
    } else if (const auto at = message.find(" was given a disallowed flag override");
               at != std::string::npos) {
      // This one names the flag without its dashes.
      problem.kind = Problem::Kind::TakesNoValue;
      problem.word = "--" + message.substr(0, at);
    }
    return problem;
  } catch (const BadValueThrown& e) {
    return Problem{Problem::Kind::BadValue, e.option, e.value, e.message};
  } catch (const CLI::CallForHelp&) {
    return std::nullopt;  // add_help(..., true): the flag the tool checks first is set
  } catch (const CLI::ParseError& e) {
    return Problem{Problem::Kind::Other, "", "", e.what()};
  }
  const std::vector<std::string> extras = app.remaining(true);
  if (!extras.empty()) {
    const std::string& word = extras.front();
    const bool looks_like_option = word.size() > 1 && word[0] == '-';
    return Problem{looks_like_option ? Problem::Kind::UnknownOption : Problem::Kind::Unexpected,
                   detail::option_word(word), "", "unexpected argument '" + word + "'"};
  }
  if (repeats != Repeats::LastWins) {
    std::vector<CLI::App*> apps;
    detail::collect_apps(app, apps);
    for (CLI::App* in : apps) {
      std::map<const CLI::Option*, int> seen;
      for (const CLI::Option* option : in->parse_order()) {
        if (repeats == Repeats::RefuseValues && option->get_items_expected_max() == 0) continue;
        if (++seen[option] == 2) {
          return Problem{Problem::Kind::Repeated, option->get_name(), "",
                         option->get_name() + " given twice"};
        }
      }
    }
  }
  return std::nullopt;
}

}  // namespace meshdeform::command_line
