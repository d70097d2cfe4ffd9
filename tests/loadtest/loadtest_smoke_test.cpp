// Smoke tests of the meshdeform-loadtest binary (MESHDEFORM_LOADTEST_PATH) against the real
// meshdeform-server (MESHDEFORM_SERVER_PATH) on a loopback port. Each run is a child process with
// a bounded wait; assertions are on counts and consistency, never on timings.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "tests/support/child_process.h"
#include "tests/support/server_process.h"

extern char** environ;

namespace meshdeform::loadtest {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

constexpr int kExitOk = 0;
constexpr int kExitRunFailed = 1;
constexpr int kExitUsage = 2;

using ChildResult = test::CapturedRun;
using test::read_text;

class LoadtestTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = test::make_test_dir("meshdeform_loadtest_test"); }
  void TearDown() override { test::remove_test_dir(dir_, HasFailure()); }

  // Runs the load tester with `args` in the test directory (stdin /dev/null, stdout/stderr
  // captured) and waits at most `timeout`; a child still running then is killed.
  ChildResult run_loadtest(const std::vector<std::string>& args,
                           std::chrono::seconds timeout = std::chrono::seconds(120)) const {
    std::vector<std::string> words = {MESHDEFORM_LOADTEST_PATH};
    words.insert(words.end(), args.begin(), args.end());
    ChildResult result = test::run_captured(words, dir_, timeout);
    EXPECT_EQ(result.spawn_error, "") << "cannot spawn " << MESHDEFORM_LOADTEST_PATH;
    return result;
  }

  static std::unique_ptr<test::ServerProcess> start_server(
      std::vector<std::string> flags = {"--refine-budget", "0"}) {
    std::string error;
    auto server = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
    EXPECT_NE(server, nullptr) << error;
    return server;
  }

  fs::path dir_;
};

// A latency summary is non-empty, positive and ordered.
void expect_ordered_positive(const json& summary, const std::string& what) {
  ASSERT_TRUE(summary.is_object()) << what;
  ASSERT_TRUE(summary["p50"].is_number()) << what << ": " << summary.dump();
  const double min = summary["min"].get<double>();
  const double p50 = summary["p50"].get<double>();
  const double p95 = summary["p95"].get<double>();
  const double p99 = summary["p99"].get<double>();
  const double max = summary["max"].get<double>();
  EXPECT_GT(min, 0.0) << what;
  EXPECT_LE(min, p50) << what;
  EXPECT_LE(p50, p95) << what;
  EXPECT_LE(p95, p99) << what;
  EXPECT_LE(p99, max) << what;
}

TEST_F(LoadtestTest, SmokeRunCompletesEveryMoveWithWatchers) {
  const auto server = start_server();
  ASSERT_NE(server, nullptr);
  const fs::path json_path = dir_ / "report.json";
  const fs::path markdown_path = dir_ / "report.md";
  const ChildResult run =
      run_loadtest({"--server", server->address(), "--sessions", "2", "--moves", "5", "--rate", "0",
                    "--watchers", "1", "--sample", "cylinder_small", "--duration", "30", "--json",
                    json_path.string(), "--markdown", markdown_path.string()});
  ASSERT_FALSE(run.is_timed_out) << run.out << run.err;
  ASSERT_EQ(run.exit_code, kExitOk) << run.out << run.err;
  EXPECT_NE(run.out.find("meshdeform-loadtest:"), std::string::npos) << run.out;

  const json report = json::parse(read_text(json_path));
  EXPECT_TRUE(report["completed"].get<bool>());
  EXPECT_EQ(report["config"]["sessions"], 2);
  EXPECT_EQ(report["setup"]["sessions_ok"], 2);
  expect_ordered_positive(report["setup"]["setup_ms"], "setup");

  const json& moves = report["moves"];
  EXPECT_EQ(moves["sent"], 10);
  EXPECT_EQ(moves["ok"], 10);
  EXPECT_EQ(moves["failed"], 0);
  EXPECT_TRUE(moves["errors_by_code"].empty()) << moves["errors_by_code"].dump();
  EXPECT_EQ(moves["skipped_ticks"], 0);  // rate 0: no ticks
  EXPECT_EQ(moves["latency_ms"]["count"], 10);
  expect_ordered_positive(moves["latency_ms"], "move latency");
  EXPECT_GT(moves["per_second_total"].get<double>(), 0.0);

  ASSERT_EQ(report["sessions"].size(), 2u);
  for (const json& session : report["sessions"]) {
    EXPECT_TRUE(session["set_up"].get<bool>()) << session.dump();
    EXPECT_EQ(session["moves_ok"], 5);
    EXPECT_EQ(session["close_status"], "OK");
    ASSERT_EQ(session["watchers"].size(), 1u);
    const json& watcher = session["watchers"][0];
    EXPECT_TRUE(watcher["join_snapshot"].get<bool>()) << watcher.dump();
    EXPECT_GE(watcher["updates"].get<int>(), 1) << watcher.dump();
    EXPECT_GE(watcher["snapshots"].get<int>(), 1) << watcher.dump();
    EXPECT_EQ(watcher["end_status"], "OK") << watcher.dump();  // the close ends the stream OK
  }
  EXPECT_EQ(report["watchers"]["streams"], 2);
  EXPECT_EQ(report["watchers"]["with_join_snapshot"], 2);

  // The stats block is always there; its memory may be null while GetServerStats is not wired.
  const json& server_stats = report["server"];
  ASSERT_TRUE(server_stats.is_object());
  EXPECT_TRUE(server_stats.contains("stats_available"));
  EXPECT_TRUE(server_stats.contains("resident_bytes_before"));
  EXPECT_TRUE(server_stats.contains("resident_bytes_loaded"));
  EXPECT_TRUE(server_stats["loaded"].contains("status"));
  if (server_stats["stats_available"].get<bool>()) {
    EXPECT_GE(server_stats["loaded"]["moves_committed"].get<int>(), 10);
    EXPECT_EQ(server_stats["loaded"]["sessions"], 2);
  } else {
    EXPECT_TRUE(server_stats["resident_bytes_loaded"].is_null());
  }

  const std::string markdown = read_text(markdown_path);
  EXPECT_NE(markdown.find("# Load test"), std::string::npos) << markdown;
  EXPECT_NE(markdown.find("| moves OK | 10 |"), std::string::npos) << markdown;
}

TEST_F(LoadtestTest, CompactEncodingsShrinkResponsesAndUpdates) {
  // The same scripted drag with each PositionEncoding: every move lands, and the compact ones
  // carry fewer bytes per move response and per watcher delta than doubles.
  const auto server = start_server();
  ASSERT_NE(server, nullptr);
  std::map<std::string, json> reports;
  for (const std::string encoding : {"doubles", "float32", "meshopt"}) {
    SCOPED_TRACE(encoding);
    const fs::path json_path = dir_ / ("report_" + encoding + ".json");
    const ChildResult run = run_loadtest(
        {"--server", server->address(), "--sessions", "1", "--moves", "4", "--rate", "0",
         "--watchers", "1", "--sample", "cylinder_small", "--duration", "30", "--encoding",
         encoding, "--json", json_path.string()});
    ASSERT_FALSE(run.is_timed_out) << run.out << run.err;
    ASSERT_EQ(run.exit_code, kExitOk) << run.out << run.err;
    const json report = json::parse(read_text(json_path));
    EXPECT_EQ(report["config"]["encoding"], encoding);
    EXPECT_EQ(report["moves"]["ok"], 4);
    EXPECT_GT(report["moves"]["mean_response_bytes"].get<double>(), 0.0);
    reports[encoding] = report;
  }
  const double doubles = reports["doubles"]["moves"]["mean_response_bytes"].get<double>();
  EXPECT_LT(reports["float32"]["moves"]["mean_response_bytes"].get<double>(), 0.7 * doubles);
  EXPECT_LT(reports["meshopt"]["moves"]["mean_response_bytes"].get<double>(), 0.7 * doubles);
  const double delta = reports["doubles"]["watchers"]["mean_delta_bytes"].get<double>();
  if (delta > 0) {  // the watcher saw a delta (not only its join snapshot)
    EXPECT_LT(reports["float32"]["watchers"]["mean_delta_bytes"].get<double>(), 0.7 * delta);
  }
}

TEST_F(LoadtestTest, ThroughAnEmulatedLinkWithLinkSizedUpdates) {
  // --via-link and --updates: every move lands, the watchers apply every update, the reports
  // name the link and what it carried, and the updates are far smaller than doubles.
  const auto server = start_server();
  ASSERT_NE(server, nullptr);
  const fs::path json_path = dir_ / "link.json";
  const fs::path markdown_path = dir_ / "link.md";
  const ChildResult run = run_loadtest(
      {"--server", server->address(), "--sessions", "2", "--moves", "4", "--rate", "0",
       "--watchers", "1", "--sample", "cylinder_small", "--duration", "60", "--via-link",
       "50mbit,20ms", "--fixed-receive-window", "--updates", "quantized", "--max-update-bytes",
       "2048", "--json", json_path.string(), "--markdown", markdown_path.string()});
  ASSERT_FALSE(run.is_timed_out) << run.out << run.err;
  ASSERT_EQ(run.exit_code, kExitOk) << run.out << run.err;
  const json report = json::parse(read_text(json_path));
  EXPECT_EQ(report["moves"]["ok"], 8);
  EXPECT_EQ(report["config"]["updates"], "quantized");
  EXPECT_EQ(report["config"]["via_link"], "50mbit,20ms");
  const json& link = report["link"];
  EXPECT_DOUBLE_EQ(link["down_mbit"].get<double>(), 50.0);
  EXPECT_DOUBLE_EQ(link["rtt_ms"].get<double>(), 20.0);
  EXPECT_EQ(link["connections"], 2);  // one line per session's channel
  EXPECT_GT(link["bytes_down"].get<double>(), 0.0);
  EXPECT_GT(link["bytes_up"].get<double>(), 0.0);
  const json& sized = report["watchers"]["link_sized"];
  EXPECT_EQ(sized["decode_failures"], 0);
  EXPECT_GE(sized["revision_updates"].get<int>(), 1);
  EXPECT_LE(sized["update_bytes"]["max"].get<double>(), 2048.0 + 200.0);  // payload + header
  // Moves ask for no positions: the responses carry the figures only.
  EXPECT_LT(report["moves"]["mean_response_bytes"].get<double>(), 300.0);
  // Every own move was followed by an update at or past it, applied at the watcher.
  EXPECT_EQ(sized["applied_after_send_ms"]["count"], 8);
  for (const json& session : report["sessions"]) {
    EXPECT_EQ(session["watchers"][0]["end_status"], "OK") << session.dump();
  }
  const std::string markdown = read_text(markdown_path);
  EXPECT_NE(markdown.find("link (--via-link 50mbit,20ms)"), std::string::npos) << markdown;
  EXPECT_NE(markdown.find("link-sized: bytes per update"), std::string::npos) << markdown;
}

TEST_F(LoadtestTest, CoarsePreviewIsCountedForMultiresolutionSessions) {
  // Multiresolution sessions at the sample's size: with --coarse-preview every watcher asks for
  // the coarse level, and the updates of the moves carry it, well formed and smaller than the
  // full positions; without the flag none does.
  const auto server = start_server({"--refine-budget", "0", "--multires-above", "1000",
                                     "--multires-coarse-vertices", "1000"});
  ASSERT_NE(server, nullptr);
  std::map<bool, json> reports;
  for (const bool preview : {true, false}) {
    SCOPED_TRACE(preview ? "--coarse-preview" : "without");
    const fs::path json_path = dir_ / (preview ? "preview.json" : "plain.json");
    const fs::path markdown_path = dir_ / (preview ? "preview.md" : "plain.md");
    std::vector<std::string> args = {
        "--server", server->address(), "--sessions", "1", "--moves", "4", "--rate", "0",
        "--watchers", "2", "--sample", "cylinder", "--duration", "60", "--encoding", "float32",
        "--json", json_path.string(), "--markdown", markdown_path.string()};
    if (preview) args.push_back("--coarse-preview");
    const ChildResult run = run_loadtest(args);
    ASSERT_FALSE(run.is_timed_out) << run.out << run.err;
    ASSERT_EQ(run.exit_code, kExitOk) << run.out << run.err;
    const json report = json::parse(read_text(json_path));
    EXPECT_EQ(report["moves"]["ok"], 4);
    EXPECT_EQ(report["config"]["coarse_preview"], preview);
    const std::string markdown = read_text(markdown_path);
    EXPECT_EQ(markdown.find("coarse preview: updates") != std::string::npos, preview) << markdown;
    reports[preview] = report;
  }
  const json& with = reports[true]["watchers"];
  const json& coarse = with["coarse_preview"];
  // Each watcher gets at least the newest move (latest wins may skip the ones between), and
  // every update after the join is a move solved on the coarse level.
  EXPECT_GE(coarse["updates"].get<int>(), 2);
  EXPECT_EQ(coarse["updates"].get<int>(), with["deltas"].get<int>());
  EXPECT_EQ(coarse["malformed"], 0);
  EXPECT_GT(coarse["coarse_bytes"]["min"].get<double>(), 0.0);
  EXPECT_LT(coarse["coarse_bytes"]["p50"].get<double>(), with["mean_delta_bytes"].get<double>());
  EXPECT_EQ(reports[false]["watchers"]["coarse_preview"]["updates"], 0);
}

TEST_F(LoadtestTest, SettleWaitsForTheRefinementsConvergedRevision) {
  // --settle-seconds: after the drag each session waits for its watcher to receive a converged
  // revision at or past its last move (here the server's background refinement, which the
  // three one-iteration moves leave to do) and reports the time from the last move's response.
  // The bound is generous: the test waits only as long as the refinement takes.
  const auto server = start_server({"--refine-budget", "300"});
  ASSERT_NE(server, nullptr);
  const fs::path json_path = dir_ / "settle.json";
  const fs::path markdown_path = dir_ / "settle.md";
  const ChildResult run = run_loadtest(
      {"--server", server->address(), "--sessions", "2", "--moves", "3", "--rate", "0",
       "--iterations", "1", "--watchers", "1", "--sample", "cylinder_small", "--duration", "60",
       "--settle-seconds", "300", "--json", json_path.string(), "--markdown",
       markdown_path.string()},
      std::chrono::seconds(420));
  ASSERT_FALSE(run.is_timed_out) << run.out << run.err;
  ASSERT_EQ(run.exit_code, kExitOk) << run.out << run.err;
  const json report = json::parse(read_text(json_path));
  EXPECT_EQ(report["moves"]["ok"], 6);
  EXPECT_EQ(report["config"]["settle_seconds"], 300.0);
  EXPECT_EQ(report["settle"]["sessions_settled"], 2);
  EXPECT_EQ(report["settle"]["ms_after_last_response"]["count"], 2);
  EXPECT_GE(report["watchers"]["refinements"].get<int>(), 2);  // the moves did not converge
  for (const json& session : report["sessions"]) {
    ASSERT_TRUE(session["settle_ms"].is_number()) << session.dump();
    // A refinement revision comes after the move's response (and the server's rest delay).
    EXPECT_GT(session["settle_ms"].get<double>(), 0.0) << session.dump();
  }
  const std::string markdown = read_text(markdown_path);
  EXPECT_NE(markdown.find("converged revision seen after the last move's response"),
            std::string::npos)
      << markdown;
}

TEST_F(LoadtestTest, LosslessSettledTimesTheSettledRevisionAndCountsItLossless) {
  // --lossless-settled: quantized watchers get the settled revision (here refinement's last,
  // its budget of 4 iterations spent) lossless; --settle-seconds waits for it and reports it.
  const auto server = start_server({"--refine-budget", "4"});
  ASSERT_NE(server, nullptr);
  const fs::path json_path = dir_ / "settled.json";
  const ChildResult run = run_loadtest(
      {"--server", server->address(), "--sessions", "2", "--moves", "3", "--rate", "0",
       "--iterations", "1", "--watchers", "1", "--sample", "cylinder_small", "--duration", "60",
       "--updates", "quantized", "--lossless-settled", "--settle-seconds", "120", "--json",
       json_path.string()},
      std::chrono::seconds(300));
  ASSERT_FALSE(run.is_timed_out) << run.out << run.err;
  ASSERT_EQ(run.exit_code, kExitOk) << run.out << run.err;
  const json report = json::parse(read_text(json_path));
  EXPECT_EQ(report["moves"]["ok"], 6);
  EXPECT_EQ(report["settle"]["sessions_with_settled_revision"], 2) << report["settle"].dump();
  EXPECT_EQ(report["settle"]["settled_lossless"], 2);
  EXPECT_GE(report["watchers"]["lossless_updates"].get<int>(), 2);
  EXPECT_EQ(report["watchers"]["link_sized"]["decode_failures"], 0);
  for (const json& session : report["sessions"]) {
    EXPECT_TRUE(session["settled_lossless"].get<bool>()) << session.dump();
    EXPECT_GT(session["settled_ms"].get<double>(), 0.0) << session.dump();
  }
}

TEST_F(LoadtestTest, BadLinkOrUpdateFlagsAreUsageErrors) {
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
           {"--server", "127.0.0.1:1", "--via-link", "20furlongs"},
           {"--server", "127.0.0.1:1", "--updates", "lossy"},
           {"--server", "127.0.0.1:1", "--updates", "quantized", "--max-update-bytes", "10"},
           {"--server", "127.0.0.1:1", "--max-update-bytes", "4096"},
           {"--server", "127.0.0.1:1", "--updates", "lossless", "--lossless-settled"}}) {
    const ChildResult run = run_loadtest(args, std::chrono::seconds(30));
    ASSERT_FALSE(run.is_timed_out);
    EXPECT_EQ(run.exit_code, kExitUsage) << args[2] << "\n" << run.err;
    EXPECT_TRUE(run.out.empty()) << run.out;
  }
}

TEST_F(LoadtestTest, RemoteTargetIsRefusedWithoutAllowRemote) {
  // Nothing listens there; a refusal must come before any connection attempt.
  const ChildResult run = run_loadtest(
      {"--server", "10.255.255.1:1", "--sessions", "1", "--moves", "1", "--duration", "5"},
      std::chrono::seconds(30));
  ASSERT_FALSE(run.is_timed_out);
  EXPECT_EQ(run.exit_code, kExitUsage) << run.out << run.err;
  EXPECT_NE(run.err.find("--allow-remote"), std::string::npos) << run.err;
  EXPECT_TRUE(run.out.empty()) << run.out;  // no run, no summary
}

TEST_F(LoadtestTest, BadFlagsAreUsageErrors) {
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
           {"--server", "127.0.0.1:1", "--bogus", "1"},
           {"--server", "127.0.0.1:1", "--sessions", "0"},
           {"--server", "127.0.0.1:1", "--method", "nope"},
           {"--server", "127.0.0.1:1", "--encoding", "float16"},
           {"--server", "127.0.0.1:1", "--rate", "-1"},
           {"--server", "127.0.0.1:1", "--sample", "bar", "--mesh", "x.obj"},
           {"--server", "127.0.0.1:1", "--settle-seconds", "5"},  // no watcher to see it
           {"--server", "127.0.0.1:1", "--watchers", "1", "--settle-seconds", "-1"},
           {"--sessions", "1"}}) {
    const ChildResult run = run_loadtest(args, std::chrono::seconds(30));
    ASSERT_FALSE(run.is_timed_out);
    std::string joined;
    for (const std::string& arg : args) joined += arg + " ";
    EXPECT_EQ(run.exit_code, kExitUsage) << joined << "\n" << run.out << run.err;
    EXPECT_TRUE(run.out.empty()) << run.out;
  }
  const ChildResult help = run_loadtest({"--help"}, std::chrono::seconds(30));
  EXPECT_EQ(help.exit_code, kExitOk);
  EXPECT_NE(help.out.find("--allow-remote"), std::string::npos);
}

TEST_F(LoadtestTest, FlagErrorsNameTheFlag) {
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"--server", "127.0.0.1:1", "--bogus", "1"}, "unknown flag --bogus"},
      {{"--server", "127.0.0.1:1", "--sessions=0"}, "bad value '0' for --sessions"},
      {{"--server", "127.0.0.1:1", "--duration"}, "--duration needs a value"},
      {{"--server", "127.0.0.1:1", "--allow-remote=1"}, "--allow-remote takes no value"},
      {{"--server", "127.0.0.1:1", "stray"}, "unexpected argument 'stray'"},
  };
  for (const auto& [args, message] : cases) {
    SCOPED_TRACE(message);
    const ChildResult run = run_loadtest(args, std::chrono::seconds(30));
    ASSERT_FALSE(run.is_timed_out);
    EXPECT_EQ(run.exit_code, kExitUsage) << run.err;
    EXPECT_EQ(run.err.rfind("meshdeform-loadtest: " + message + "\nusage: meshdeform-loadtest", 0),
              0u)
        << run.err;
  }
  // --help stops the parse: what follows it is not checked.
  const ChildResult help = run_loadtest({"--sessions", "2", "-h", "--bogus"}, std::chrono::seconds(30));
  EXPECT_EQ(help.exit_code, kExitOk) << help.err;
  EXPECT_EQ(help.out.rfind("usage: meshdeform-loadtest --server HOST:PORT [flags]\n", 0), 0u)
      << help.out;
}

TEST_F(LoadtestTest, UnreachableServerFailsSetupAndStillReports) {
  // Port 1 on loopback: nobody listens (binding it needs root), so every call is UNAVAILABLE.
  const fs::path json_path = dir_ / "report.json";
  const ChildResult run = run_loadtest({"--server", "127.0.0.1:1", "--sessions", "2", "--moves",
                                        "1", "--duration", "10", "--json", json_path.string()},
                                       std::chrono::seconds(60));
  ASSERT_FALSE(run.is_timed_out);
  EXPECT_EQ(run.exit_code, kExitRunFailed) << run.out << run.err;
  const json report = json::parse(read_text(json_path));
  EXPECT_EQ(report["setup"]["sessions_ok"], 0);
  EXPECT_EQ(report["moves"]["sent"], 0);
  EXPECT_FALSE(report["server"]["stats_available"].get<bool>());
}

TEST_F(LoadtestTest, FailOnErrorsTurnsMoveErrorsIntoExitOne) {
  const auto server = start_server();
  ASSERT_NE(server, nullptr);
  const fs::path json_path = dir_ / "report.json";
  // A 1 ms deadline makes failures likely, not certain: the exit code must match the report.
  const ChildResult run =
      run_loadtest({"--server", server->address(), "--sessions", "1", "--moves", "3", "--rate", "0",
                    "--sample", "cylinder", "--move-deadline-ms", "1", "--duration", "30",
                    "--fail-on-errors", "--json", json_path.string()});
  ASSERT_FALSE(run.is_timed_out);
  const json report = json::parse(read_text(json_path));
  EXPECT_TRUE(report["completed"].get<bool>());
  EXPECT_EQ(report["moves"]["sent"], 3);
  const int failed = report["moves"]["failed"].get<int>();
  EXPECT_EQ(report["moves"]["ok"].get<int>() + failed, 3);
  EXPECT_EQ(run.exit_code, failed > 0 ? kExitRunFailed : kExitOk) << run.out << run.err;
  for (const auto& [code, count] : report["moves"]["errors_by_code"].items()) {
    EXPECT_TRUE(code == "DEADLINE_EXCEEDED" || code == "CANCELLED") << code;
  }
}

}  // namespace
}  // namespace meshdeform::loadtest
