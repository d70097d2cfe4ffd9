// common/command_line.h, the CLI11 layer every command-line tool parses with: what it accepts and
// how it names what it refuses. In process; the tools' own wording is tested through their
// binaries (cli_test.cpp, tests/client, tests/loadtest).
#include "common/command_line.h"

#include <gtest/gtest.h>

#include <optional>
#include <string>
#include <vector>

namespace meshdeform::command_line {
namespace {

using Kind = Problem::Kind;

/// A small tool: --mesh VALUE, --count N (checked: 1..9), --verbose, -h/--help.
struct Tool {
  explicit Tool(bool help_stops = false) {
    configure(app);
    add_text(app, "--mesh", mesh);
    add_checked(app, "--count", [this](const std::string& value) -> std::optional<std::string> {
      if (value.size() != 1 || value[0] < '1' || value[0] > '9') return "not in 1..9";
      count = value[0] - '0';
      return std::nullopt;
    });
    add_flag(app, "--verbose", verbose);
    add_help(app, help, help_stops);
  }
  std::optional<Problem> parse(const std::vector<std::string>& args,
                               Repeats repeats = Repeats::Refuse) {
    return command_line::parse(app, args, repeats);
  }
  CLI::App app;
  std::optional<std::string> mesh;
  int count = 0;
  bool verbose = false;
  bool help = false;
};

TEST(CommandLineTest, BothValueSyntaxesAndFlags) {
  Tool tool;
  EXPECT_FALSE(tool.parse({"--mesh", "a.obj", "--count=3", "--verbose"}));
  EXPECT_EQ(tool.mesh, "a.obj");
  EXPECT_EQ(tool.count, 3);
  EXPECT_TRUE(tool.verbose);
  Tool other;
  EXPECT_FALSE(other.parse({"--mesh=b=c.obj"}));
  EXPECT_EQ(other.mesh, "b=c.obj");
  EXPECT_FALSE(other.verbose);
}

TEST(CommandLineTest, ValuesMayLookLikeOptionsOrNegativeNumbers) {
  Tool tool;
  EXPECT_FALSE(tool.parse({"--mesh", "--verbose"}));
  EXPECT_EQ(tool.mesh, "--verbose");
  EXPECT_FALSE(tool.verbose);
  Tool negative;
  EXPECT_FALSE(negative.parse({"--mesh", "-5"}));
  EXPECT_EQ(negative.mesh, "-5");
}

TEST(CommandLineTest, AnEmptyInlineValueIsAValue) {
  Tool tool;
  EXPECT_FALSE(tool.parse({"--mesh=", "--verbose"}));
  EXPECT_EQ(tool.mesh, "");  // not "--verbose", which CLI11 alone would take
  EXPECT_TRUE(tool.verbose);
}

TEST(CommandLineTest, UnknownOptionsAndStrayWordsAreNamed) {
  std::optional<Problem> problem = Tool().parse({"--mesh", "a", "--frobnicate=2"});
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->kind, Kind::UnknownOption);
  EXPECT_EQ(problem->word, "--frobnicate");
  problem = Tool().parse({"-x"});
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->kind, Kind::UnknownOption);
  EXPECT_EQ(problem->word, "-x");
  problem = Tool().parse({"--mesh", "a", "stray"});
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->kind, Kind::Unexpected);
  EXPECT_EQ(problem->word, "stray");
}

TEST(CommandLineTest, MissingValueNamesTheOption) {
  const std::optional<Problem> problem = Tool().parse({"--verbose", "--mesh"});
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->kind, Kind::MissingValue);
  EXPECT_EQ(problem->word, "--mesh");
}

TEST(CommandLineTest, AFlagTakesNoValue) {
  const std::optional<Problem> problem = Tool().parse({"--verbose=0"});
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->kind, Kind::TakesNoValue);
  EXPECT_EQ(problem->word, "--verbose");
}

TEST(CommandLineTest, RepeatsAreRefusedOrTheLastWins) {
  std::optional<Problem> problem = Tool().parse({"--mesh", "a", "--mesh", "b"});
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->kind, Kind::Repeated);
  EXPECT_EQ(problem->word, "--mesh");
  problem = Tool().parse({"--verbose", "--verbose"});
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->word, "--verbose");
  Tool values_only;
  EXPECT_FALSE(values_only.parse({"--verbose", "--verbose"}, Repeats::RefuseValues));
  Tool last_wins;
  EXPECT_FALSE(last_wins.parse({"--mesh", "a", "--mesh", "b"}, Repeats::LastWins));
  EXPECT_EQ(last_wins.mesh, "b");
}

TEST(CommandLineTest, TheFirstBadValueOnTheLineIsReported) {
  const std::optional<Problem> problem =
      Tool().parse({"--count", "0", "--count", "x"}, Repeats::LastWins);
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->kind, Kind::BadValue);
  EXPECT_EQ(problem->word, "--count");
  EXPECT_EQ(problem->value, "0");
  EXPECT_EQ(problem->message, "not in 1..9");
}

TEST(CommandLineTest, HelpEitherStopsTheParseOrNeedsAGoodLine) {
  Tool stops(true);
  EXPECT_FALSE(stops.parse({"-h", "--frobnicate", "--count", "0"}));
  EXPECT_TRUE(stops.help);
  Tool after(true);  // a bad value before --help is still reported
  const std::optional<Problem> bad = after.parse({"--count", "0", "--help"});
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->kind, Kind::BadValue);
  EXPECT_FALSE(after.help);
  Tool checked;
  const std::optional<Problem> problem = checked.parse({"--help", "--frobnicate"});
  ASSERT_TRUE(problem);
  EXPECT_EQ(problem->word, "--frobnicate");
  Tool plain;
  EXPECT_FALSE(plain.parse({"--mesh", "a", "--help"}));
  EXPECT_TRUE(plain.help);
}

}  // namespace
}  // namespace meshdeform::command_line
