// The method switch, ORA and magnification through the real meshdeform-cli binary.
#include <gtest/gtest.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "core/methods/deform_types.h"
#include "core/io/mesh_io.h"
#include "core/samples/samples.h"
#include "tests/support/child_process.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform {
namespace {

namespace fs = std::filesystem;

using CliRun = test::CapturedRun;

class MethodCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = test::make_test_dir("meshdeform_method_cli");
    // A 13 x 13 bumpy grid: left column fixed, right column lifted.
    const MeshData grid = test::make_grid(12, 0.05);
    ASSERT_TRUE(io::write_mesh(dir_ / "grid.obj", grid).ok());
  }
  void TearDown() override { test::remove_test_dir(dir_, HasFailure()); }

  /// Runs the CLI in the test directory with `arguments` split at spaces (no quoting needed
  /// here); a CLI still running after 10 minutes is killed.
  CliRun run(const std::string& arguments) const {
    std::vector<std::string> words = {MESHDEFORM_CLI_PATH};
    std::istringstream in(arguments);
    for (std::string word; in >> word;) words.push_back(word);
    CliRun r = test::run_captured(words, dir_, std::chrono::minutes(10));
    EXPECT_EQ(r.spawn_error, "");
    EXPECT_FALSE(r.is_timed_out);
    return r;
  }

  void write(const std::string& name, const std::string& text) const {
    std::ofstream(dir_ / name) << text;
  }

  nlohmann::json report() const {
    std::ifstream in(dir_ / "report.json");
    return nlohmann::json::parse(in);
  }

  static std::string column(int i) {
    std::string out;
    for (int j = 0; j <= 12; ++j) out += (j ? ", " : "") + std::to_string(j * 13 + i);
    return out;
  }

  fs::path dir_;
};

TEST_F(MethodCliTest, EveryMethodRunsAndIsReported) {
  write("edit.json", R"({"fixed": [)" + column(0) + R"(], "handles": [{"vertices": [)" +
                         column(12) + R"(], "translation": [0, 0, 0.3]}]})");
  for (const char* method : {"scale_aware", "arap", "laplacian"}) {
    SCOPED_TRACE(method);
    const CliRun r = run(std::string("deform --mesh grid.obj --edit edit.json --out out.obj "
                                  "--report report.json --method ") + method);
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const auto j = report();
    EXPECT_EQ(j["method"], method);
    EXPECT_FALSE(j.contains("stitch"));
    auto out = io::load_mesh(dir_ / "out.obj");
    ASSERT_TRUE(out.ok());
    EXPECT_NEAR(out->mesh.V(12, 2), 0.3, 0.01);  // a handle reached its target
  }
}

TEST_F(MethodCliTest, OraAndMagnifyComeFromFlagsOrTheSpec) {
  write("edit.json", R"({"fixed": [)" + column(0) + R"(], "handles": [{"vertices": [)" +
                         column(12) + R"(], "translation": [0.4, 0, 0]}]})");
  CliRun r = run("deform --mesh grid.obj --edit edit.json --out out.obj --report report.json --ora");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto j = report();
  ASSERT_TRUE(j.contains("stitch"));
  EXPECT_LT(static_cast<double>(j["stitch"]["after"]["area_log_rms"]),
            static_cast<double>(j["stitch"]["before"]["area_log_rms"]));

  // Magnify the right half by 1.5 from the spec, with the method and ORA set there too.
  std::string right;
  for (int j2 = 0; j2 <= 12; ++j2) {
    for (int i = 6; i <= 12; ++i) right += (right.empty() ? "" : ", ") + std::to_string(j2 * 13 + i);
  }
  write("magnify.json", R"({"fixed": [)" + column(0) + R"(], "magnify": [{"vertices": [)" + right +
                            R"(], "scale": 1.5}], "options": {"method": "scale_aware"}})");
  r = run("deform --mesh grid.obj --edit magnify.json --out big.obj --report report.json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  j = report();
  ASSERT_TRUE(j.contains("magnify"));
  EXPECT_EQ(j["magnify"][0]["scale"], 1.5);
  ASSERT_TRUE(j.contains("stitch"));
  auto big = io::load_mesh(dir_ / "big.obj");
  ASSERT_TRUE(big.ok());
  // The magnified half is wider than it was (0.5 at rest).
  EXPECT_GT(big->mesh.V.col(0).maxCoeff() - big->mesh.V(6 * 13 + 6, 0), 0.6);
}

TEST_F(MethodCliTest, BadMethodAndOraWithABaselineAreErrors) {
  write("edit.json", R"({"fixed": [0, 1], "handles": [{"vertices": [168], "translation": [0, 0, 1]}]})");
  CliRun r = run("deform --mesh grid.obj --edit edit.json --out out.obj --method rigid");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_NE(r.err.find("rigid"), std::string::npos) << r.err;
  r = run("deform --mesh grid.obj --edit edit.json --out out.obj --method arap --ora");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("ORA and magnification belong to the scale-aware method"), std::string::npos)
      << r.err;
  write("bad.json", R"({"fixed": [0, 1], "options": {"method": "fem"}})");
  r = run("deform --mesh grid.obj --edit bad.json --out out.obj");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("fem"), std::string::npos) << r.err;
}


TEST_F(MethodCliTest, RigidityComesFromTheFlagOrTheSpecAndIsReported) {
  write("edit.json", R"({"fixed": [)" + column(0) + R"(], "handles": [{"vertices": [)" +
                         column(12) + R"(], "translation": [0.4, 0, 0.2]}]})");
  // Default: the library's default rigidity and start (Auto: the rigid start at rigidity > 0;
  // this edit folds nothing, so nothing else runs).
  CliRun r = run("deform --mesh grid.obj --edit edit.json --out out.obj --report report.json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto j = report();
  EXPECT_EQ(j["options"]["rigidity"], core::kDefaultRigidity);
  EXPECT_EQ(j["options"]["start"], "auto");
  EXPECT_EQ(j["start_used"], "rigid");
  EXPECT_EQ(j["start_candidates"], 1);
  EXPECT_EQ(j["folded_edges"], 0);
  const double default_area = j["final"]["area_log_rms"];

  // 0 is the paper's method, from the Laplacian guess.
  r = run("deform --mesh grid.obj --edit edit.json --out out.obj --report report.json --rigidity 0");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  j = report();
  EXPECT_EQ(j["options"]["rigidity"], 0.0);
  EXPECT_EQ(j["options"]["start"], "auto");
  EXPECT_EQ(j["start_used"], "laplacian");
  EXPECT_TRUE(j["folded_edges"].is_null());  // only checked with scale control
  const double paper_area = j["final"]["area_log_rms"];
  EXPECT_LT(default_area, paper_area);
  for (const auto& it : j["history"]) EXPECT_TRUE(it.contains("energy_before"));

  // From the spec; the flag wins over the spec.
  write("rigid.json", R"({"fixed": [)" + column(0) + R"(], "handles": [{"vertices": [)" +
                          column(12) + R"(], "translation": [0.4, 0, 0.2]}], "options": {"rigidity": 7.5}})");
  r = run("deform --mesh grid.obj --edit rigid.json --out out.obj --report report.json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(report()["options"]["rigidity"], 7.5);
  r = run("deform --mesh grid.obj --edit rigid.json --out out.obj --report report.json "
          "--rigidity 0.5 --start rigid");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  j = report();
  EXPECT_EQ(j["options"]["rigidity"], 0.5);
  EXPECT_EQ(j["options"]["start"], "rigid");
  EXPECT_EQ(j["start_used"], "rigid");
  r = run("deform --mesh grid.obj --edit rigid.json --out out.obj --report report.json "
          "--start auto");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(report()["options"]["start"], "auto");
  r = run("deform --mesh grid.obj --edit rigid.json --out out.obj --report report.json "
          "--start propagated");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(report()["options"]["start"], "propagated");
  EXPECT_EQ(report()["paper_start_iterations"], 0);
  r = run("deform --mesh grid.obj --edit rigid.json --out out.obj --report report.json "
          "--start paper");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  j = report();
  EXPECT_EQ(j["options"]["start"], "paper");
  EXPECT_EQ(j["start_used"], "paper");
  EXPECT_GE(j["paper_start_iterations"], 1);

  // Bad values are usage errors (flag) or runtime errors (spec), naming the option.
  for (const char* bad : {"-1", "nan", "abc", "inf"}) {
    SCOPED_TRACE(bad);
    r = run(std::string("deform --mesh grid.obj --edit edit.json --out out.obj --rigidity ") + bad);
    EXPECT_EQ(r.exit_code, 2);
    EXPECT_NE(r.err.find("--rigidity"), std::string::npos) << r.err;
  }
  write("bad.json", R"({"fixed": [0, 1], "options": {"rigidity": -2}})");
  r = run("deform --mesh grid.obj --edit bad.json --out out.obj");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.err.find("options.rigidity"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace meshdeform
