// meshdeform-server's command line through the real binary: --help, and the flag errors that stop
// it before it listens (exit code 2, a message naming the flag; the usage text for an unknown or
// incomplete flag). Every run exits on its own; a child still running after 60 s is killed, and
// every child dies with the test (tests/support/child_process.h).
#include <gtest/gtest.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include "tests/support/child_process.h"

namespace meshdeform {
namespace {

namespace fs = std::filesystem;

struct ServerRun {
  int exit_code = -1;  ///< -1: did not exit within 60 s (then killed) or could not start
  std::string out, err;
};

using test::read_text;

class ServerFlagsTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = test::make_test_dir("meshdeform_server_flags_test"); }
  void TearDown() override { test::remove_test_dir(dir_, HasFailure()); }

  /// meshdeform-server with exactly `args` (no --listen added: every case here exits first).
  ServerRun run(const std::vector<std::string>& args) const {
    std::vector<std::string> words = {MESHDEFORM_SERVER_PATH};
    words.insert(words.end(), args.begin(), args.end());
    // A server still running after 60 s is killed (exit_code stays -1).
    test::CapturedRun run = test::run_captured(words, dir_, std::chrono::seconds(60));
    ServerRun result;
    result.exit_code = run.exit_code;
    result.out = std::move(run.out);
    result.err = run.spawn_error.empty() ? std::move(run.err) : "spawn failed: " + run.spawn_error;
    return result;
  }

  fs::path dir_;
};

TEST_F(ServerFlagsTest, HelpPrintsTheUsageAndExitsZero) {
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
           {"--help"}, {"-h"}, {"--max-sessions", "5", "--help", "--bogus"}}) {
    const ServerRun r = run(args);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    EXPECT_EQ(r.out.rfind("usage: meshdeform-server [flags]\n", 0), 0u) << r.out;
    EXPECT_NE(r.out.find("  --trust-forwarded-for "), std::string::npos) << r.out;
    EXPECT_TRUE(r.err.empty()) << r.err;
  }
}

TEST_F(ServerFlagsTest, FlagErrorsExitTwoNamingTheFlag) {
  struct Case {
    std::vector<std::string> args;
    std::string message;  ///< the first line of stderr
    bool with_usage;
  };
  const std::vector<Case> cases = {
      {{"--bogus", "1"}, "meshdeform-server: unknown flag --bogus", true},
      {{"--frobnicate=2"}, "meshdeform-server: unknown flag --frobnicate", true},
      {{"--listen"}, "meshdeform-server: --listen needs a value", true},
      {{"--test-hooks=1"}, "meshdeform-server: --test-hooks takes no value", true},
      {{"--max-sessions", "0"}, "meshdeform-server: bad value '0' for --max-sessions", false},
      {{"--max-sessions=abc"}, "meshdeform-server: bad value 'abc' for --max-sessions", false},
      {{"--workers", "2", "--workers", "2000"},
       "meshdeform-server: bad value '2000' for --workers", false},
      {{"--log-level", "loud"}, "meshdeform-server: bad value 'loud' for --log-level", false},
      {{"--cors-origin="}, "meshdeform-server: bad value '' for --cors-origin", false},
      {{"--create-rate", "-1", "--move-rate", "x"},
       "meshdeform-server: bad value '-1' for --create-rate", false},  // the first bad one
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.message);
    const ServerRun r = run(c.args);
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_EQ(r.err.substr(0, r.err.find('\n')), c.message) << r.err;
    EXPECT_EQ(r.err.find("usage: meshdeform-server") != std::string::npos, c.with_usage) << r.err;
    EXPECT_TRUE(r.out.empty()) << r.out;
  }
}

}  // namespace
}  // namespace meshdeform
