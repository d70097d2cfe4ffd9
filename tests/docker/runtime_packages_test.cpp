// The container image's runtime package list (issue 42): docker/Dockerfile's runtime stage
// installs docker/runtime-packages.txt, and that list must name the Debian package of every shared
// library the Release meshdeform-server loads (as ldd resolves them, transitively), so that the
// image starts the server from its package list alone. scripts/runtime-packages.sh derives the
// packages from the binary built for this test (MESHDEFORM_SERVER_PATH); these tests check the
// committed list against it, check that the check itself fails when a linked library's package is
// missing or a package is stale, and check that the Dockerfile really installs that list.
// No network, no container engine: ldd and dpkg-query on this machine only. Each script run is a
// child process with a generous bounded wait.
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <vector>

#include "tests/support/child_process.h"

namespace meshdeform {
namespace {

namespace fs = std::filesystem;

const fs::path kSourceDir = MESHDEFORM_SOURCE_DIR;
const fs::path kScript = kSourceDir / "scripts" / "runtime-packages.sh";
const fs::path kList = kSourceDir / "docker" / "runtime-packages.txt";
const fs::path kDockerfile = kSourceDir / "docker" / "Dockerfile";
constexpr const char* kServer = MESHDEFORM_SERVER_PATH;

using ScriptRun = test::CapturedRun;
using test::read_text;

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> lines;
  std::istringstream in(text);
  for (std::string line; std::getline(in, line);) lines.push_back(line);
  return lines;
}

// The package names in a list file: comments and blank lines dropped, as the Dockerfile reads it.
std::vector<std::string> packages_in(const std::string& text) {
  std::vector<std::string> packages;
  for (std::string line : lines_of(text)) {
    line = line.substr(0, line.find('#'));
    line.erase(std::remove_if(line.begin(), line.end(), ::isspace), line.end());
    if (!line.empty()) packages.push_back(line);
  }
  return packages;
}

class RuntimePackagesTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = test::make_test_dir("meshdeform_runtime_packages");
    ASSERT_TRUE(fs::exists(kScript)) << kScript;
    ASSERT_TRUE(fs::exists(kList)) << kList;
    ASSERT_TRUE(fs::exists(kServer)) << kServer;
  }
  void TearDown() override { test::remove_test_dir(dir_, HasFailure()); }

  // Runs scripts/runtime-packages.sh with `args` under bash; waits at most two minutes (it takes
  // seconds: one ldd and one dpkg-query).
  ScriptRun run_script(const std::vector<std::string>& args) const {
    std::vector<std::string> words = {"/bin/bash", kScript.string()};
    words.insert(words.end(), args.begin(), args.end());
    ScriptRun run = test::run_captured(words, dir_, std::chrono::minutes(2));
    EXPECT_EQ(run.spawn_error, "") << "cannot run " << kScript;
    EXPECT_FALSE(run.is_timed_out) << kScript << " still running after 2 minutes";
    return run;
  }

  // The committed list with `package` left out, written to the test directory.
  fs::path list_without(const std::string& package) const {
    const fs::path path = dir_ / ("without-" + package + ".txt");
    std::ofstream out(path);
    for (const std::string& line : lines_of(read_text(kList))) {
      if (line != package) out << line << "\n";
    }
    return path;
  }

  fs::path dir_;
};

// The committed list is exactly what the server loads: nothing missing, nothing stale.
TEST_F(RuntimePackagesTest, CommittedListCoversEveryLibraryTheServerLoads) {
  const ScriptRun run = run_script({"--check", kList.string(), kServer});
  EXPECT_EQ(run.exit_code, 0) << run.err;
  EXPECT_NE(run.err.find("covers the"), std::string::npos) << run.err;
}

// What the script derives from the binary: the packages of its direct NEEDED libraries (the ones
// the issue found missing among them) and of what those load in turn, the C and C++ runtimes too.
TEST_F(RuntimePackagesTest, DerivesDirectAndTransitivePackagesFromTheBinary) {
  const ScriptRun run = run_script({kServer});
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const std::vector<std::string> derived = packages_in(run.out);
  const auto has = [&](const std::string& p) {
    return std::find(derived.begin(), derived.end(), p) != derived.end();
  };
  // NEEDED by the server itself: OpenMesh (the package the issue found missing), zstd (the
  // link-sized updates of issue 45), gRPC, CHOLMOD, hiredis, the C++ runtime.
  EXPECT_TRUE(has("libopenmesh1"));
  EXPECT_TRUE(has("libzstd1"));
  EXPECT_TRUE(has("libgrpc++1.51"));
  EXPECT_TRUE(has("libcholmod3"));
  EXPECT_TRUE(has("libhiredis0.14"));
  EXPECT_TRUE(has("libstdc++6"));
  EXPECT_TRUE(has("libc6"));
  // Only loaded through another library: re2 and c-ares by gRPC, METIS by CHOLMOD, and the BLAS
  // that the libblas.so.3 alternative resolves to (a symlink dpkg does not own).
  EXPECT_TRUE(has("libre2-9"));
  EXPECT_TRUE(has("libc-ares2"));
  EXPECT_TRUE(has("libmetis5"));
  EXPECT_TRUE(std::any_of(derived.begin(), derived.end(),
                          [](const std::string& p) { return p.rfind("libopenblas0", 0) == 0; }))
      << run.out;
  // Sorted and without duplicates, so the written list is stable.
  EXPECT_TRUE(std::is_sorted(derived.begin(), derived.end()));
  EXPECT_EQ(std::adjacent_find(derived.begin(), derived.end()), derived.end());
  // And the committed list is the same set.
  EXPECT_EQ(packages_in(read_text(kList)), derived);
}

// The check fails when the package of a library the server links directly is missing (the
// failure of issue 42: libopenmesh1), and says which libraries need it.
TEST_F(RuntimePackagesTest, CheckFailsWhenALinkedLibrarysPackageIsMissing) {
  const fs::path list = list_without("libopenmesh1");
  ASSERT_EQ(packages_in(read_text(list)).size() + 1, packages_in(read_text(kList)).size());
  const ScriptRun run = run_script({"--check", list.string(), kServer});
  EXPECT_EQ(run.exit_code, 1) << run.err;
  EXPECT_NE(run.err.find("lacks libopenmesh1"), std::string::npos) << run.err;
  EXPECT_NE(run.err.find("libOpenMeshCore.so.9.0 (NEEDED)"), std::string::npos) << run.err;
}

// ... and when the missing package is one that only another library loads.
TEST_F(RuntimePackagesTest, CheckFailsWhenATransitiveLibrarysPackageIsMissing) {
  const ScriptRun run = run_script({"--check", list_without("libre2-9").string(), kServer});
  EXPECT_EQ(run.exit_code, 1) << run.err;
  EXPECT_NE(run.err.find("lacks libre2-9, which provides: libre2.so.9"), std::string::npos)
      << run.err;
}

// A package the server does not load is stale (the list is generated, never kept by hand).
TEST_F(RuntimePackagesTest, CheckFailsOnAPackageTheServerDoesNotLoad) {
  const fs::path list = dir_ / "with-extra.txt";
  fs::copy_file(kList, list);
  std::ofstream(list, std::ios::app) << "libboost-dev\n";
  const ScriptRun run = run_script({"--check", list.string(), kServer});
  EXPECT_EQ(run.exit_code, 1) << run.err;
  EXPECT_NE(run.err.find("names libboost-dev"), std::string::npos) << run.err;
}

// Input the script cannot map is a usage error (2), never a pass.
TEST_F(RuntimePackagesTest, RefusesWhatItCannotMap) {
  EXPECT_EQ(run_script({(dir_ / "no-such-binary").string()}).exit_code, 2);
  const ScriptRun not_elf = run_script({kList.string()});
  EXPECT_EQ(not_elf.exit_code, 2) << not_elf.err;
  EXPECT_EQ(run_script({"--check", (dir_ / "no-such-list").string(), kServer}).exit_code, 2);
}

// The list checked above is the list the image installs: the runtime stage copies
// docker/runtime-packages.txt and hands its lines to apt-get install, and the builder stage
// checks it against the binary it built.
TEST_F(RuntimePackagesTest, DockerfileRuntimeStageInstallsTheList) {
  const std::string dockerfile = read_text(kDockerfile);
  ASSERT_FALSE(dockerfile.empty()) << kDockerfile;
  // The stages, by their "FROM ... AS name" lines.
  std::map<std::string, std::string> stages;
  const std::regex from_line(R"(^FROM\s+\S+\s+AS\s+(\S+)\s*$)", std::regex::icase);
  std::string current;
  for (const std::string& line : lines_of(dockerfile)) {
    std::smatch match;
    if (std::regex_match(line, match, from_line)) {
      current = match[1];
      continue;
    }
    if (!current.empty()) stages[current] += line + "\n";
  }
  ASSERT_TRUE(stages.count("runtime")) << "no 'FROM ... AS runtime' stage";
  ASSERT_TRUE(stages.count("builder")) << "no 'FROM ... AS builder' stage";
  const std::string& runtime = stages["runtime"];

  std::smatch copy;
  ASSERT_TRUE(std::regex_search(runtime, copy,
                                std::regex(R"(COPY\s+docker/runtime-packages\.txt\s+(\S+))")))
      << "the runtime stage does not copy docker/runtime-packages.txt:\n" << runtime;
  const std::string installed_from = copy[1];
  // apt-get install ... $(sed ... <the copied list>) in the same stage, after the COPY.
  const std::size_t install = runtime.find("apt-get install", copy.position(0));
  ASSERT_NE(install, std::string::npos) << runtime;
  const std::size_t reads = runtime.find("$(sed -e 's/#.*//' " + installed_from + ")", install);
  EXPECT_NE(reads, std::string::npos)
      << "the runtime stage's apt-get install does not read " << installed_from << ":\n"
      << runtime;
  // The builder refuses to produce a binary the list does not cover.
  EXPECT_NE(stages["builder"].find("scripts/runtime-packages.sh --check docker/runtime-packages.txt"),
            std::string::npos)
      << stages["builder"];
}

}  // namespace
}  // namespace meshdeform
