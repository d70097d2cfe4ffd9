// End-to-end tests of `meshdeform-cli curve` (MESHDEFORM_CLI_PATH): the Fig. 9 Koch edit writes
// an SVG with the original and three results, a JSON report, and usage errors exit 2.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "tests/support/child_process.h"

namespace meshdeform::cli {
namespace {

namespace fs = std::filesystem;

using CurveRun = test::CapturedRun;
using test::read_text;

size_t count(const std::string& text, const std::string& word) {
  size_t n = 0;
  for (size_t pos = text.find(word); pos != std::string::npos; pos = text.find(word, pos + 1)) ++n;
  return n;
}

class CurveCliTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = test::make_test_dir("meshdeform_curve_cli_test"); }
  void TearDown() override { test::remove_test_dir(dir_, HasFailure()); }

  /// Runs `meshdeform-cli curve ARGS...` in the test directory, capturing stdout and stderr (a
  /// CLI still running after 10 minutes is killed).
  CurveRun run(const std::vector<std::string>& args) const {
    std::vector<std::string> words = {MESHDEFORM_CLI_PATH, "curve"};
    words.insert(words.end(), args.begin(), args.end());
    CurveRun result = test::run_captured(words, dir_, std::chrono::minutes(10));
    EXPECT_EQ(result.spawn_error, "");
    EXPECT_FALSE(result.is_timed_out);
    return result;
  }

  fs::path dir_;
};

TEST_F(CurveCliTest, KochLevelThreeWritesTheFigure) {
  const CurveRun r = run({"--koch", "3", "--svg", "fig9.svg"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string svg = read_text(dir_ / "fig9.svg");
  ASSERT_FALSE(svg.empty());
  EXPECT_NE(svg.find("<svg"), std::string::npos);
  EXPECT_NE(svg.find("</svg>"), std::string::npos);
  EXPECT_EQ(count(svg, "<polyline"), 4u);  // the original, then Laplacian, ARAP, scale-aware
  EXPECT_EQ(count(svg, " rad</text>"), 3u);
  for (const char* name : {"Laplacian", "ARAP", "scale-aware"}) {
    EXPECT_NE(svg.find(name), std::string::npos) << name;
    EXPECT_NE(r.out.find(name), std::string::npos) << name << " in " << r.out;
  }
  EXPECT_NE(r.out.find("wrote fig9.svg"), std::string::npos) << r.out;
}

TEST_F(CurveCliTest, ReportHasEveryMethodAndScaleAwareWins) {
  const CurveRun r =
      run({"--koch", "4", "--pull", "0.3", "--svg", "fig.svg", "--report", "report.json"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const auto report = nlohmann::json::parse(read_text(dir_ / "report.json"));
  EXPECT_EQ(report["edit"]["level"], 4);
  EXPECT_EQ(report["edit"]["points"], 257);
  EXPECT_EQ(report["edit"]["handle"], 128);
  EXPECT_EQ(report["edit"]["constrained"], nlohmann::json({0, 128, 256}));
  const auto& methods = report["methods"];
  ASSERT_EQ(methods.size(), 3u);
  EXPECT_EQ(methods[0]["method"], "laplacian");
  EXPECT_EQ(methods[1]["method"], "arap");
  EXPECT_EQ(methods[2]["method"], "scale_aware");
  for (const auto& m : methods) {
    for (const char* key : {"e_theta", "scale_log_rms", "seconds", "iterations", "converged",
                            "energy", "max_constraint_error"}) {
      EXPECT_TRUE(m.contains(key)) << m["method"] << " lacks " << key;
    }
    EXPECT_LT(static_cast<double>(m["max_constraint_error"]), 0.01) << m["method"];
  }
  const double scale_aware = methods[2]["e_theta"];
  EXPECT_LT(scale_aware, static_cast<double>(methods[0]["e_theta"]));
  EXPECT_LT(scale_aware, static_cast<double>(methods[1]["e_theta"]));
}

TEST_F(CurveCliTest, UsageErrorsExitTwo) {
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{}, "missing --koch"},
      {{"--koch", "3"}, "missing --svg"},
      {{"--svg", "x.svg"}, "missing --koch"},
      {{"--koch", "0", "--svg", "x.svg"}, "--koch must be an integer in [1, 7], got '0'"},
      {{"--koch", "8", "--svg", "x.svg"}, "got '8'"},
      {{"--koch", "three", "--svg", "x.svg"}, "got 'three'"},
      {{"--koch", "3", "--svg", "x.svg", "--pull", "nan"}, "--pull must be a finite number"},
      {{"--koch", "3", "--svg", "x.svg", "--lambda", "-1"}, "--lambda must be a number > 0"},
      {{"--koch", "3", "--svg", "x.svg", "--iterations", "-2"}, "--iterations must be"},
      {{"--koch", "3", "--svg", "x.svg", "--bogus"}, "bogus"},
      {{"--koch", "3", "--koch", "4", "--svg", "x.svg"}, "koch"},
  };
  for (const auto& [args, message] : cases) {
    SCOPED_TRACE(testing::Message() << "case expecting '" << message << "'");
    const CurveRun r = run(args);
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_NE(r.err.find(message), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "x.svg"));
  }
}

TEST_F(CurveCliTest, MissingOutputDirectoryIsARuntimeError) {
  const CurveRun r = run({"--koch", "2", "--svg", "no/such/dir/fig.svg"});
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("does not exist"), std::string::npos) << r.err;
}

TEST_F(CurveCliTest, HelpExitsZero) {
  const CurveRun r = run({"--help"});
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_NE(r.out.find("--koch LEVEL"), std::string::npos);
}

}  // namespace
}  // namespace meshdeform::cli
