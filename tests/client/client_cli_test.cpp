// meshdeform-client (the CLI binary) against the real meshdeform-server on loopback: the round
// trip create -> handles -> move -> get (checked against the core library's own solve), watch,
// info, close, stats, the token from the environment, and the exit codes (0 ok, 1 server error
// naming its code, 2 usage). The CLI runs as a test::ChildProcess with its output in files; every
// run is bounded.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <memory>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "core/methods/deformer.h"
#include "core/io/deform_spec.h"
#include "core/io/mesh_io.h"
#include "core/samples/samples.h"
#include "tests/support/mesh_factories.h"
#include "tests/support/child_process.h"
#include "tests/support/server_process.h"

extern char** environ;

namespace meshdeform::client {
namespace {

using nlohmann::json;
namespace fs = std::filesystem;

struct CliRun {
  int exit_code = -1;  // -1: did not exit in time (killed)
  std::string out, err;
};

std::string slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

class ClientCliTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    std::string error;
    server_ = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, {"--refine-budget", "0"}, error)
                  .release();
    if (!server_) start_error_ = new std::string(error);
  }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
    delete start_error_;
    start_error_ = nullptr;
  }

  void SetUp() override {
    ASSERT_NE(server_, nullptr) << (start_error_ ? *start_error_ : std::string());
    dir_ = fs::temp_directory_path() /
           ("meshdeform_cli_test_" + std::to_string(::getpid()) + "_" +
            ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::create_directories(dir_);
  }
  void TearDown() override {
    std::error_code ec;
    fs::remove_all(dir_, ec);
  }

  /// Runs meshdeform-client with `--server <ours>` prepended (unless `with_server` is false)
  /// and `extra_env` added to the environment; waits at most 60 s.
  CliRun run(std::vector<std::string> args, bool with_server = true,
             const std::vector<std::string>& extra_env = {}) {
    if (with_server) args.insert(args.begin(), {"--server", server_->address()});
    args.insert(args.begin(), MESHDEFORM_CLIENT_CLI_PATH);
    const fs::path out = dir_ / "stdout.txt", err = dir_ / "stderr.txt";
    test::ChildStreams streams;
    streams.stdout_path = out.string();
    streams.stderr_path = err.string();
    streams.env = extra_env;
    streams.unset_env = {"MESHDEFORM_TOKEN"};
    CliRun result;
    std::string error;
    std::optional<test::ChildProcess> child = test::ChildProcess::spawn(args, streams, error);
    if (!child) {
      result.err = "spawn failed: " + error;
      return result;
    }
    const std::optional<int> status = child->wait(std::chrono::seconds(60));  // else killed
    if (status && WIFEXITED(*status)) result.exit_code = WEXITSTATUS(*status);
    result.out = slurp(out);
    result.err = slurp(err);
    return result;
  }

  /// Parses the one-line JSON a successful command prints.
  static json parse(const CliRun& run) {
    try {
      return json::parse(run.out);
    } catch (const json::exception& e) {
      ADD_FAILURE() << "not JSON: '" << run.out << "' (" << e.what() << "); stderr: " << run.err;
      return json::object();
    }
  }

  fs::path write_file(const std::string& name, const std::string& text) {
    const fs::path path = dir_ / name;
    std::ofstream(path, std::ios::binary) << text;
    return path;
  }

  static test::ServerProcess* server_;
  static std::string* start_error_;
  fs::path dir_;
};

test::ServerProcess* ClientCliTest::server_ = nullptr;
std::string* ClientCliTest::start_error_ = nullptr;

std::string describe(const CliRun& r) {
  return "exit " + std::to_string(r.exit_code) + "\nstdout: " + r.out + "\nstderr: " + r.err;
}

TEST_F(ClientCliTest, RoundTripCreateHandlesMoveGet) {
  // create
  const CliRun created = run({"create", "--sample", "cylinder_small"});
  ASSERT_EQ(created.exit_code, 0) << describe(created);
  const json session = parse(created);
  const std::string id = session.value("session_id", "");
  const std::string edit = session.value("edit_token", "");
  const std::string view = session.value("view_token", "");
  ASSERT_EQ(id.size(), 32u);
  ASSERT_EQ(edit.size(), 64u);
  ASSERT_EQ(view.size(), 64u);
  EXPECT_EQ(session["vertices"], 420);
  ASSERT_EQ(session["suggested_groups"].size(), 2u);

  // handles: create's output carries the suggested groups.
  const fs::path groups = write_file("created.json", created.out);
  const CliRun handles =
      run({"handles", "--session", id, "--token", edit, "--groups", groups.string()});
  ASSERT_EQ(handles.exit_code, 0) << describe(handles);
  EXPECT_EQ(parse(handles)["revision"], 0);

  // move: a .def similarity (rotation by 30 degrees about y, a lift) on the handle group.
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() =
      Eigen::AngleAxisd(30.0 * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
  T.topRightCorner<3, 1>() = Eigen::Vector3d(0.4, 0.0, 0.1);
  Result<std::string> def_text = io::format_def(T);
  ASSERT_TRUE(def_text.ok());
  const fs::path def = write_file("bend.def", *def_text);
  const CliRun moved = run({"move", "--session", id, "--token", edit, "--def", def.string(),
                            "--iterations", "3", "--editor", "cli"});
  ASSERT_EQ(moved.exit_code, 0) << describe(moved);
  const json result = parse(moved);
  EXPECT_EQ(result["revision"], 1);
  EXPECT_EQ(result["method"], "scale_aware");
  EXPECT_EQ(result["editor"], "cli");
  EXPECT_EQ(result["changed"], 420);

  // get (OBJ: full double precision) and compare with the core library's own solve.
  const fs::path obj = dir_ / "deformed.obj";
  const CliRun got = run({"get", "--session", id, "--token", view, "--out", obj.string()});
  ASSERT_EQ(got.exit_code, 0) << describe(got);
  Result<MeshData> mesh = io::read_mesh(obj);
  ASSERT_TRUE(mesh.ok()) << mesh.status().to_string();

  core::DeformationBenchmark bench;
  for (core::DeformationBenchmark& b : core::make_suite(core::SuiteScale::Small)) {
    if (b.name == "cylinder") bench = std::move(b);
  }
  std::vector<int> constrained;
  std::set<int> handle_set;
  for (const json& g : session["suggested_groups"]) {
    for (const json& v : g["vertices"]) {
      constrained.push_back(v.get<int>());
      if (g["role"] == "handle") handle_set.insert(v.get<int>());
    }
  }
  std::sort(constrained.begin(), constrained.end());
  Positions targets(static_cast<Eigen::Index>(constrained.size()), 3);
  for (std::size_t j = 0; j < constrained.size(); ++j) {
    const Eigen::Vector3d rest = bench.mesh.V.row(constrained[j]).transpose();
    const Eigen::Vector3d t = handle_set.count(constrained[j])
                                  ? Eigen::Vector3d((T * rest.homogeneous()).head<3>())
                                  : rest;
    targets.row(static_cast<Eigen::Index>(j)) = t.transpose();
  }
  const Eigen::VectorXi idx = Eigen::Map<const Eigen::VectorXi>(
      constrained.data(), static_cast<Eigen::Index>(constrained.size()));
  auto deformer = core::make_deformer(core::Method::ScaleAware, bench.mesh.V, bench.mesh.F, idx);
  ASSERT_TRUE(deformer.ok());
  core::SolveOptions options;
  options.max_iterations = 3;
  auto expected = (*deformer)->solve(targets, options);
  ASSERT_TRUE(expected.ok());
  EXPECT_EQ(result["iterations"], expected->iterations);
  ASSERT_EQ(mesh->V.rows(), expected->V.rows());
  EXPECT_EQ(mesh->F, bench.mesh.F);
  EXPECT_LE((mesh->V - expected->V).cwiseAbs().maxCoeff(),
            test::kExactTol * test::bbox_diagonal(bench.mesh));

  // info and watch with the view token, from the environment (kept out of argv).
  const CliRun info = run({"info", "--session", id}, true, {"MESHDEFORM_TOKEN=" + view});
  ASSERT_EQ(info.exit_code, 0) << describe(info);
  EXPECT_EQ(parse(info)["revision"], 1);
  EXPECT_EQ(parse(info)["last_method"], "scale_aware");
  const CliRun watched =
      run({"watch", "--session", id, "--token", view, "--max-updates", "1", "--seconds", "30",
           "--coarse-preview"});
  ASSERT_EQ(watched.exit_code, 0) << describe(watched);
  const json line = parse(watched);  // exactly one line: the join snapshot
  EXPECT_EQ(line["is_snapshot"], true);
  EXPECT_FALSE(line.contains("coarse")) << "a single-level session's snapshot has no coarse level";
  EXPECT_EQ(line["revision"], 1);
  EXPECT_EQ(line["vertices"], 420);

  // close: the view token is refused (exit 1 naming the code), the edit token closes.
  const CliRun refused = run({"close", "--session", id, "--token", view});
  EXPECT_EQ(refused.exit_code, 1) << describe(refused);
  EXPECT_NE(refused.err.find("PermissionDenied"), std::string::npos) << refused.err;
  EXPECT_EQ(refused.err.find(view), std::string::npos) << "the token leaked: " << refused.err;
  const CliRun closed = run({"close", "--session", id, "--token", edit});
  EXPECT_EQ(closed.exit_code, 0) << describe(closed);
  const CliRun gone = run({"info", "--session", id, "--token", edit});
  EXPECT_EQ(gone.exit_code, 1) << describe(gone);
  EXPECT_NE(gone.err.find("NotFound"), std::string::npos) << gone.err;
}

TEST_F(ClientCliTest, MoveWithAJsonEditSpecSetsItsOwnGroups) {
  const CliRun created = run({"create", "--sample", "bar_small"});
  ASSERT_EQ(created.exit_code, 0) << describe(created);
  const json session = parse(created);
  const std::string id = session.value("session_id", "");
  const std::string edit = session.value("edit_token", "");
  const json fixed = session["suggested_groups"][0]["vertices"];
  const json handle = session["suggested_groups"][1]["vertices"];
  const json spec = {
      {"fixed", fixed},
      {"handles", json::array({{{"vertices", handle},
                                {"translation", {0.0, 0.2, 0.0}},
                                {"rotation", {{"axis", {0, 0, 1}}, {"angle_deg", 45}}}}})},
      {"options", {{"iterations", 2}, {"method", "scale_aware"}}}};
  const fs::path path = write_file("edit.json", spec.dump());
  const CliRun moved = run({"move", "--session", id, "--token", edit, "--edit", path.string()});
  ASSERT_EQ(moved.exit_code, 0) << describe(moved);
  EXPECT_EQ(parse(moved)["revision"], 1);
  EXPECT_EQ(parse(moved)["built_deformer"], false);  // set by the spec's groups just before
  const CliRun info = run({"info", "--session", id, "--token", edit});
  ASSERT_EQ(info.exit_code, 0) << describe(info);
  const json groups = parse(info)["groups"];
  ASSERT_EQ(groups.size(), 2u);
  EXPECT_EQ(groups[0]["role"], "fixed");
  EXPECT_EQ(groups[0]["vertices"], fixed);
  EXPECT_EQ(groups[1]["role"], "handle");
  EXPECT_EQ(groups[1]["vertices"], handle);
  // The same groups again: no new SetHandles, the next move warm-starts (revision 2).
  const CliRun again =
      run({"move", "--session", id, "--token", edit, "--edit", path.string(), "--method", "arap"});
  ASSERT_EQ(again.exit_code, 0) << describe(again);
  EXPECT_EQ(parse(again)["revision"], 2);
  EXPECT_EQ(parse(again)["method"], "arap");
  // stats sees at least this session.
  const CliRun stats = run({"stats"});
  ASSERT_EQ(stats.exit_code, 0) << describe(stats);
  EXPECT_GE(parse(stats)["sessions"].get<int>(), 1);
}

TEST_F(ClientCliTest, ProgressPrintsThePhasesOnStderrAndKeepsStdoutJson) {
  const CliRun created = run({"create", "--sample", "cylinder_small", "--progress"});
  ASSERT_EQ(created.exit_code, 0) << describe(created);
  const json session = parse(created);  // stdout stays the one JSON object
  EXPECT_EQ(session["vertices"], 420);
  auto phases_of = [](const std::string& err) {
    std::vector<std::string> phases;
    std::istringstream lines(err);
    for (std::string line; std::getline(lines, line);) {
      if (line.empty() || line[0] != '{') continue;  // server log lines are not ours
      const json j = json::parse(line, nullptr, false);
      if (!j.is_object() || !j.contains("phase")) continue;
      EXPECT_GE(j["fraction"].get<double>(), 0.0);
      EXPECT_LE(j["fraction"].get<double>(), 1.0);
      const std::string phase = j["phase"];
      if (phases.empty() || phases.back() != phase) phases.push_back(phase);
    }
    return phases;
  };
  EXPECT_EQ(phases_of(created.err), (std::vector<std::string>{"queued", "parse", "session"}));

  const fs::path groups = write_file("progress_groups.json", created.out);
  const std::string id = session.value("session_id", ""), edit = session.value("edit_token", "");
  const CliRun handles = run({"handles", "--session", id, "--token", edit, "--groups",
                              groups.string(), "--prepare", "arap", "--progress"});
  ASSERT_EQ(handles.exit_code, 0) << describe(handles);
  EXPECT_EQ(parse(handles)["revision"], 0);
  EXPECT_EQ(phases_of(handles.err), (std::vector<std::string>{"queued", "factorize"}));
}

TEST_F(ClientCliTest, CreateFromAMeshFile) {
  Result<std::string> off = io::write_mesh_to_memory(test::make_icosphere(1), io::MeshFormat::Off);
  ASSERT_TRUE(off.ok());
  const fs::path path = write_file("sphere.off", *off);
  const CliRun created = run({"create", "--mesh", path.string()});
  ASSERT_EQ(created.exit_code, 0) << describe(created);
  EXPECT_EQ(parse(created)["vertices"], 42);
  const fs::path bad = write_file("bad.obj", "v 0 0 0\nf 1 2 3\n");
  const CliRun refused = run({"create", "--mesh", bad.string()});
  EXPECT_EQ(refused.exit_code, 1) << describe(refused);
  EXPECT_NE(refused.err.find("InvalidArgument"), std::string::npos) << refused.err;
}

TEST_F(ClientCliTest, UsageErrorsExitTwoAndHelpExitsZero) {
  const CliRun help = run({"--help"}, false);
  EXPECT_EQ(help.exit_code, 0) << describe(help);
  EXPECT_NE(help.out.find("usage: meshdeform-client"), std::string::npos);
  for (const std::vector<std::string>& args : std::vector<std::vector<std::string>>{
           {},
           {"frobnicate"},
           {"info", "--token", "t"},                          // no --session
           {"create", "--sample", "bar", "--mesh", "x.obj"},  // both sources
           {"create", "--bogus", "1"},                        // unknown option
           {"move", "--session", "s", "--token", "t"},        // no --def / --edit
           {"move", "--session", "s", "--token", "t", "--edit", "{", "--iterations", "0"},
           {"handles", "--session", "s", "--token", "t", "--groups", "[1, 2]"},
           {"get", "--session", "s", "--token", "t", "--out", "mesh.xyz"},
           {"create", "--mesh", "/nonexistent/file.obj"},
       }) {
    const CliRun r = run(args);
    EXPECT_EQ(r.exit_code, 2) << testing::PrintToString(args) << "\n" << describe(r);
    EXPECT_FALSE(r.err.empty());
  }
  // An unreachable server is a server error (1) naming the gRPC code.
  const CliRun unreachable = run({"--server", "127.0.0.1:1", "--timeout", "20", "stats"}, false);
  EXPECT_EQ(unreachable.exit_code, 1) << describe(unreachable);
  EXPECT_NE(unreachable.err.find("UNAVAILABLE"), std::string::npos) << unreachable.err;
}

TEST_F(ClientCliTest, UsageErrorsNameTheOptionOrWord) {
  const std::vector<std::pair<std::vector<std::string>, std::string>> cases = {
      {{"create", "--bogus", "1"}, "unknown option --bogus for 'create'"},
      {{"--bogus", "create"}, "unknown option --bogus (options follow the command)"},
      {{"--session", "s", "info"}, "unknown option --session (options follow the command)"},
      {{"create", "--mesh"}, "--mesh needs a value"},
      {{"create", "--mesh", "a.obj", "--mesh=b.obj"}, "--mesh given twice"},
      {{"--timeout", "5", "stats", "--timeout", "6"}, "--timeout given twice"},
      {{"create", "--weld=1"}, "--weld takes no value"},
      {{"frobnicate"}, "unknown command 'frobnicate'"},
      {{"create", "info"}, "unexpected argument 'info'"},
      {{"--timeout", "abc", "stats"}, "--timeout 'abc' is not a finite number"},
  };
  for (const auto& [args, expected] : cases) {
    const CliRun r = run(args, false);
    SCOPED_TRACE(expected);
    EXPECT_EQ(r.exit_code, 2) << describe(r);
    EXPECT_NE(r.err.find("meshdeform-client: " + expected + "\n"), std::string::npos) << r.err;
    EXPECT_NE(r.err.find("run 'meshdeform-client --help' for usage"), std::string::npos) << r.err;
  }
  // --help anywhere, the command's options included, as long as the line parses.
  const CliRun help = run({"move", "--session", "s", "--help"}, false);
  EXPECT_EQ(help.exit_code, 0) << describe(help);
  EXPECT_NE(help.out.find("usage: meshdeform-client"), std::string::npos);
}

TEST_F(ClientCliTest, GlobalOptionsAlsoComeAfterTheCommand) {
  const CliRun info = run({"info", "--session", "nope", "--token", "t", "--server",
                           server_->address(), "--timeout=20"},
                          false);
  EXPECT_EQ(info.exit_code, 1) << describe(info);  // the server's answer, not a usage error
  EXPECT_NE(info.err.find("meshdeform-client: info: "), std::string::npos) << info.err;
}

}  // namespace
}  // namespace meshdeform::client
