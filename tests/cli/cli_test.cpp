// End-to-end tests of the meshdeform-cli binary (MESHDEFORM_CLI_PATH): each test runs the real
// executable in its own temporary directory and checks exit codes, messages and written files.
#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "core/io/mesh_io.h"
#include "tests/support/child_process.h"

namespace meshdeform::cli {
namespace {

namespace fs = std::filesystem;

using RunResult = test::CapturedRun;
using test::read_text;

void write_text(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << text;
}

class CliTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = test::make_test_dir("meshdeform_cli_test"); }
  void TearDown() override { test::remove_test_dir(dir_, HasFailure()); }

  /// Runs the CLI with `args` in the test directory (stdin closed, stdout/stderr captured; a
  /// CLI still running after 10 minutes is killed).
  RunResult run(const std::vector<std::string>& args) const {
    std::vector<std::string> words = {MESHDEFORM_CLI_PATH};
    words.insert(words.end(), args.begin(), args.end());
    RunResult result = test::run_captured(words, dir_, std::chrono::minutes(10));
    EXPECT_EQ(result.spawn_error, "");
    EXPECT_FALSE(result.is_timed_out);
    return result;
  }

  /// `generate --small` of one model (or all) into dir/gen.
  void generate_small(const std::string& model) const {
    const RunResult r = run({"generate", "--model", model, "--small", "--out-dir", "gen"});
    ASSERT_EQ(r.exit_code, 0) << r.err;
  }

  fs::path dir_;
};

TEST_F(CliTest, GenerateSmallWritesEveryModel) {
  generate_small("all");
  const std::vector<std::pair<std::string, int>> expected = {
      {"bumpy_plane", 441}, {"cylinder", 420}, {"bar", 554}, {"cactus", 336}};
  for (const auto& [name, vertices] : expected) {
    SCOPED_TRACE(name);
    const fs::path base = dir_ / "gen" / name;
    ASSERT_TRUE(fs::exists(base.string() + ".sel"));
    ASSERT_TRUE(fs::exists(base.string() + ".def"));
    auto mesh = io::load_mesh(base.string() + ".off");
    ASSERT_TRUE(mesh.ok()) << mesh.status().to_string();
    EXPECT_EQ(mesh->mesh.V.rows(), vertices);
  }
}

TEST_F(CliTest, DeformWithSelAndDefReducesAngleError) {
  generate_small("cylinder");
  const RunResult r = run({"deform", "--mesh", "gen/cylinder.off", "--sel", "gen/cylinder.sel",
                           "--def", "gen/cylinder.def", "--out", "result.obj", "--report",
                           "report.json", "--iterations", "8"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("result.obj"), std::string::npos) << r.out;  // the one-line summary

  auto result = io::load_mesh(dir_ / "result.obj");
  ASSERT_TRUE(result.ok()) << result.status().to_string();
  EXPECT_EQ(result->mesh.V.rows(), 420);

  const auto report = nlohmann::json::parse(read_text(dir_ / "report.json"));
  EXPECT_EQ(report["input"]["vertices"], 420);
  EXPECT_EQ(report["options"]["max_iterations"], 8);
  const auto& history = report["history"];
  ASSERT_GE(history.size(), 2u);
  EXPECT_EQ(history[0]["iteration"], 0);
  for (const char* key : {"energy", "e_theta", "e_phi", "elapsed_seconds", "pcg_iterations",
                          "normal_sweeps", "refactored"}) {
    EXPECT_TRUE(history.back().contains(key)) << key;
  }
  const double start = history[0]["e_theta"];
  const double final_e_theta = report["final"]["e_theta"];
  EXPECT_LT(final_e_theta, start);
  EXPECT_LT(static_cast<double>(history.back()["e_theta"]), start);
  for (const char* key : {"factorizations", "pcg_iterations", "precompute_seconds", "solve_seconds",
                          "iterations", "converged"}) {
    EXPECT_TRUE(report.contains(key)) << key;
  }
  EXPECT_TRUE(report["final"].contains("area_log_rms"));
}

TEST_F(CliTest, DeformWritesEveryMeshFormat) {
  generate_small("bar");
  for (const std::string ext : {"off", "ply", "stl", "glb"}) {
    SCOPED_TRACE(ext);
    const RunResult r = run({"deform", "--mesh", "gen/bar.off", "--sel", "gen/bar.sel", "--def",
                             "gen/bar.def", "--iterations", "2", "--out", "bar_out." + ext});
    ASSERT_EQ(r.exit_code, 0) << r.err;
    auto mesh = io::load_mesh(dir_ / ("bar_out." + ext));
    ASSERT_TRUE(mesh.ok()) << mesh.status().to_string();
    EXPECT_EQ(mesh->mesh.V.rows(), 554);
  }
}

TEST_F(CliTest, DeformWithJsonEditSpec) {
  generate_small("bar");
  auto mesh = io::load_mesh(dir_ / "gen" / "bar.off");
  ASSERT_TRUE(mesh.ok()) << mesh.status().to_string();
  // Fix the z = 0 end, turn the z = 2 end by 90 degrees about the bar's axis.
  nlohmann::json fixed = nlohmann::json::array(), handle = nlohmann::json::array();
  for (Eigen::Index v = 0; v < mesh->mesh.V.rows(); ++v) {
    if (mesh->mesh.V(v, 2) < 0.05) fixed.push_back(v);
    if (mesh->mesh.V(v, 2) > 1.95) handle.push_back(v);
  }
  const nlohmann::json spec = {{"fixed", fixed},
                               {"handles",
                                {{{"vertices", handle},
                                  {"rotation", {{"axis", {0, 0, 1}}, {"angle_deg", 90}}},
                                  {"pivot", {0, 0, 2}}}}},
                               {"options", {{"iterations", 4}}}};
  write_text(dir_ / "edit.json", spec.dump(2));

  const RunResult r = run({"deform", "--mesh", "gen/bar.off", "--edit", "edit.json", "--out",
                           "twisted.ply", "--report", "twisted.json"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto result = io::load_mesh(dir_ / "twisted.ply");
  ASSERT_TRUE(result.ok()) << result.status().to_string();
  EXPECT_EQ(result->mesh.V.rows(), mesh->mesh.V.rows());
  const auto report = nlohmann::json::parse(read_text(dir_ / "twisted.json"));
  EXPECT_EQ(report["options"]["max_iterations"], 4);  // taken from the spec
  EXPECT_EQ(report["input"]["constrained"], fixed.size() + handle.size());
  EXPECT_LT(static_cast<double>(report["final"]["e_theta"]),
            static_cast<double>(report["history"][0]["e_theta"]));

  // A flag overrides the spec's option.
  const RunResult r2 = run({"deform", "--mesh", "gen/bar.off", "--edit", "edit.json", "--out",
                            "twisted.obj", "--report", "twisted2.json", "--iterations", "2"});
  ASSERT_EQ(r2.exit_code, 0) << r2.err;
  EXPECT_EQ(nlohmann::json::parse(read_text(dir_ / "twisted2.json"))["options"]["max_iterations"],
            2);
}

TEST_F(CliTest, UsageErrorsExitWithTwoAndNameTheProblem) {
  generate_small("cylinder");
  const std::vector<std::string> base = {"deform",           "--mesh", "gen/cylinder.off", "--sel",
                                         "gen/cylinder.sel", "--def",  "gen/cylinder.def", "--out",
                                         "out.obj"};
  struct Case {
    std::vector<std::string> extra;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {{"--frobnicate"}, "--frobnicate"},
      {{"--iterations", "abc"}, "--iterations"},
      {{"--iterations", "-3"}, "--iterations"},
      {{"--tolerance", "nan"}, "--tolerance"},
      {{"--inner-iterations", "0"}, "--inner-iterations"},
      {{"--start", "sideways"}, "sideways"},
      {{"--stopping", "whenever"}, "--stopping"},
      {{"--multilevel", "maybe"}, "--multilevel"},
      {{"--edit", "edit.json"}, "--edit"},
      {{"stray"}, "stray"},
  };
  for (const auto& c : cases) {
    std::vector<std::string> args = base;
    args.insert(args.end(), c.extra.begin(), c.extra.end());
    const RunResult r = run(args);
    SCOPED_TRACE(c.expected);
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_NE(r.err.find(c.expected), std::string::npos) << r.err;
  }
  const std::vector<std::pair<std::vector<std::string>, std::string>> others = {
      {{"deform", "--mesh", "gen/cylinder.off", "--out", "out.obj"}, "--sel"},
      {{"deform", "--mesh", "gen/cylinder.off", "--sel", "gen/cylinder.sel", "--out", "o.obj"},
       "--def"},
      {{"deform", "--sel", "gen/cylinder.sel", "--def", "gen/cylinder.def", "--out", "o.obj"},
       "--mesh"},
      {{"deform", "--mesh", "gen/cylinder.off", "--sel", "gen/cylinder.sel", "--def",
        "gen/cylinder.def", "--out", "out.xyz"},
       "out.xyz"},
      {{"generate", "--model", "teapot", "--out-dir", "x"}, "teapot"},
      {{"generate", "--model", "bar"}, "--out-dir"},
      {{"demo", "--bogus"}, "--bogus"},
      {{"transmogrify"}, "transmogrify"},
      {{}, "Usage"},
  };
  for (const auto& [args, expected] : others) {
    const RunResult r = run(args);
    SCOPED_TRACE(expected);
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_NE(r.err.find(expected), std::string::npos) << r.err;
  }
}

// Issue 41: the stopping rule and the multilevel switch are options; the report says which rule
// "converged" is and where the time went, besides every key it had.
TEST_F(CliTest, ReportStatesTheStoppingRuleAndThePhases) {
  generate_small("cylinder");
  const std::vector<std::string> base = {"deform",           "--mesh", "gen/cylinder.off", "--sel",
                                         "gen/cylinder.sel", "--def",  "gen/cylinder.def", "--out",
                                         "out.obj",          "--report"};
  std::vector<std::string> defaults = base;
  defaults.push_back("default.json");
  ASSERT_EQ(run(defaults).exit_code, 0);
  const auto report = nlohmann::json::parse(read_text(dir_ / "default.json"));
  EXPECT_EQ(report["options"]["stopping_rule"], "remaining");
  EXPECT_EQ(report["options"]["tolerance"], 1e-3);
  EXPECT_EQ(report["stopping"]["rule"], "remaining");
  EXPECT_NE(report["stopping"]["description"].get<std::string>().find("remaining"),
            std::string::npos);
  for (const char* key : {"setup_seconds", "start_seconds", "levels_seconds", "fine_seconds"}) {
    ASSERT_TRUE(report["phases"].contains(key)) << key;
    EXPECT_GE(report["phases"][key].get<double>(), 0.0) << key;
  }
  // 420 vertices: below the multilevel threshold, one level.
  EXPECT_EQ(report["multilevel"]["used"], false);
  EXPECT_EQ(report["phases"]["levels_seconds"], 0.0);
  for (const char* key : {"iterations", "converged", "solve_seconds", "precompute_seconds",
                          "history", "final", "start_used"}) {
    EXPECT_TRUE(report.contains(key)) << key;
  }

  // The rule before issue 41, and the multilevel path off: recorded as asked.
  std::vector<std::string> old_rule = base;
  old_rule.insert(old_rule.end(), {"old.json", "--stopping", "change", "--tolerance", "1e-4",
                                   "--multilevel", "off"});
  ASSERT_EQ(run(old_rule).exit_code, 0);
  const auto old_report = nlohmann::json::parse(read_text(dir_ / "old.json"));
  EXPECT_EQ(old_report["options"]["stopping_rule"], "change");
  EXPECT_EQ(old_report["options"]["multilevel"], false);
  EXPECT_EQ(old_report["stopping"]["rule"], "change");
  // The change rule stops when the last change is below the tolerance, and says how far it was.
  if (old_report["converged"].get<bool>()) {
    EXPECT_LT(old_report["stopping"]["estimated_remaining"].get<double>(), 1e-4);
  }
}

TEST_F(CliTest, RuntimeErrorsExitWithOneAndNameTheProblem) {
  generate_small("all");
  write_text(dir_ / "garbage.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n");  // truncated
  write_text(dir_ / "bad.json", "{ \"fixed\": [0, 1], \"handles\": [ ");
  write_text(dir_ / "out_of_range.json",
             R"({"fixed": [0, 1], "handles": [{"vertices": [99999], "translation": [0, 0, 1]}]})");
  write_text(dir_ / "bad.sel", "0\n1\n7\n");
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      // Missing mesh file.
      {{"deform", "--mesh", "missing.off", "--sel", "gen/bar.sel", "--def", "gen/bar.def", "--out",
        "o.obj"},
       "missing.off"},
      // Missing selection file.
      {{"deform", "--mesh", "gen/bar.off", "--sel", "nowhere.sel", "--def", "gen/bar.def", "--out",
        "o.obj"},
       "nowhere.sel"},
      // Selection of another model: wrong length (554 vs 420 vertices).
      {{"deform", "--mesh", "gen/cylinder.off", "--sel", "gen/bar.sel", "--def", "gen/cylinder.def",
        "--out", "o.obj"},
       "420"},
      // A malformed mesh.
      {{"deform", "--mesh", "garbage.off", "--sel", "gen/bar.sel", "--def", "gen/bar.def", "--out",
        "o.obj"},
       "garbage.off"},
      // Malformed JSON edit spec.
      {{"deform", "--mesh", "gen/bar.off", "--edit", "bad.json", "--out", "o.obj"}, "bad.json"},
      // A handle index out of range.
      {{"deform", "--mesh", "gen/bar.off", "--edit", "out_of_range.json", "--out", "o.obj"},
       "99999"},
      // Output directory that does not exist.
      {{"deform", "--mesh", "gen/bar.off", "--sel", "gen/bar.sel", "--def", "gen/bar.def", "--out",
        "no/such/dir/o.obj"},
       "no/such/dir"},
      // Mesh with a .def as selection (not a role list).
      {{"deform", "--mesh", "gen/bar.off", "--sel", "gen/bar.def", "--def", "gen/bar.def", "--out",
        "o.obj"},
       "bar.def"},
  };
  for (const auto& [args, expected] : cases) {
    const RunResult r = run(args);
    SCOPED_TRACE(expected);
    EXPECT_EQ(r.exit_code, 1) << r.err;
    EXPECT_NE(r.err.find(expected), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("error"), std::string::npos) << r.err;
    EXPECT_FALSE(fs::exists(dir_ / "o.obj"));
  }
}

TEST_F(CliTest, HelpForEveryCommand) {
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
           {"--help"}, {"deform", "--help"}, {"generate", "--help"}, {"demo", "-h"}}) {
    const RunResult r = run(args);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    EXPECT_NE(r.out.find("Usage"), std::string::npos) << r.out;
  }
}

TEST_F(CliTest, OptionSyntaxErrorsExitTwoNamingTheOption) {
  // The option syntax every command shares (parsed by CLI11 under cli/args.cpp).
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"generate", "--model", "bar", "--out-dir"}, "option '--out-dir' needs a value"},
      {{"generate", "--model", "bar", "--model", "cylinder", "--out-dir", "g"},
       "option '--model' given twice"},
      {{"demo", "--verbose", "--verbose"}, "option '--verbose' given twice"},
      {{"demo", "--verbose=1"}, "option '--verbose' takes no value"},
      {{"demo", "--bogus=1"}, "unknown option '--bogus'"},
      {{"demo", "-x"}, "unexpected argument '-x' (options start with --)"},
      {{"curve", "--koch", "3", "--svg", "x.svg", "stray"}, "unexpected argument 'stray'"},
  };
  for (const auto& [args, expected] : cases) {
    const RunResult r = run(args);
    SCOPED_TRACE(expected);
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_NE(r.err.find(expected), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("Try 'meshdeform-cli " + args.front() + " --help'"), std::string::npos)
        << r.err;
    EXPECT_TRUE(r.out.empty()) << r.out;
  }
}

TEST_F(CliTest, BothValueSyntaxesAndHelpAfterOtherOptions) {
  RunResult r = run({"generate", "--model=bar", "--small", "--out-dir=inline"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(fs::exists(dir_ / "inline" / "bar.off"));
  // --help wins over missing required options, but not over a malformed line.
  r = run({"deform", "--iterations", "abc", "-h"});
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("Usage: meshdeform-cli deform"), std::string::npos) << r.out;
  r = run({"deform", "--help", "--bogus"});
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_NE(r.err.find("--bogus"), std::string::npos) << r.err;
}

TEST_F(CliTest, DemoWritesItsThreeFiles) {
  const RunResult r = run({"demo", "--out-dir", "demo_out"});
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_NE(r.out.find("E_theta"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("4802"), std::string::npos) << r.out;
  for (const char* name : {"demo_result.glb", "demo_result.obj", "demo_report.json"}) {
    ASSERT_TRUE(fs::exists(dir_ / "demo_out" / name)) << name;
    EXPECT_GT(fs::file_size(dir_ / "demo_out" / name), 0u) << name;
  }
  for (const char* name : {"demo_result.glb", "demo_result.obj"}) {
    auto mesh = io::load_mesh(dir_ / "demo_out" / name);
    ASSERT_TRUE(mesh.ok()) << mesh.status().to_string();
    EXPECT_EQ(mesh->mesh.V.rows(), 4802) << name;
  }
  const auto report = nlohmann::json::parse(read_text(dir_ / "demo_out" / "demo_report.json"));
  EXPECT_LT(static_cast<double>(report["final"]["e_theta"]),
            static_cast<double>(report["history"][0]["e_theta"]));
}

}  // namespace
}  // namespace meshdeform::cli
