// Integration tests of meshdeform::client against the real meshdeform-server binary on a
// loopback port (tests/support/server_process.h). One server per test suite (every test gets a
// fresh process under ctest anyway), started with --refine-budget 0 so that revisions come only
// from our moves. Every call has a deadline (a safety bound, never an assertion), every loop is
// bounded in count and time; the one timing assumption, shared with the transport tests, is
// that a 1000-iteration solve of the 4,802-vertex cylinder outlasts a 300 ms deadline.
#include "client_cpp/client.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <future>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "core/methods/deformer.h"
#include "core/io/mesh_io.h"
#include "core/samples/samples.h"
#include "tests/support/mesh_factories.h"
#include "tests/support/server_process.h"

namespace meshdeform::client {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

template <typename T>
std::string message_of(const Result<T>& r) {
  return r.ok() ? std::string("ok") : r.status().to_string();
}

void expect_code(const Status& status, ErrorCode code, const std::string& fragment = "") {
  EXPECT_EQ(status.code(), code) << status.to_string();
  if (!fragment.empty()) {
    EXPECT_NE(status.message().find(fragment), std::string::npos)
        << "'" << status.message() << "' lacks '" << fragment << "'";
  }
}

/// The sample "cylinder_small" as the server builds it (core's small benchmark suite).
core::DeformationBenchmark small_cylinder() {
  for (core::DeformationBenchmark& b : core::make_suite(core::SuiteScale::Small)) {
    if (b.name == "cylinder") return std::move(b);
  }
  ADD_FAILURE() << "no cylinder in the small suite";
  return {};
}

/// Group 1 (the sample's handle group) rotated about y by `angle_deg` and lifted.
MoveSpec bend(double angle_deg, int iterations = 0) {
  MoveSpec spec;
  GroupMove move;
  move.group = 1;
  move.rotation =
      Eigen::Quaterniond(Eigen::AngleAxisd(angle_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()));
  move.translation = Eigen::Vector3d(0.1, 0.0, 0.05);
  spec.moves.push_back(move);
  spec.max_iterations = iterations;
  return spec;
}

std::vector<int> constrained_of(const std::vector<HandleGroup>& groups) {
  std::vector<int> c;
  for (const HandleGroup& g : groups) c.insert(c.end(), g.vertices.begin(), g.vertices.end());
  std::sort(c.begin(), c.end());
  return c;
}

/// The targets bend() gives on a session whose handles were set at rest: fixed vertices at rest,
/// group 1 rotated about the centroid of its anchors, then translated (as the server does).
Positions bend_targets(const Positions& V, const std::vector<HandleGroup>& groups,
                       const std::vector<int>& constrained, double angle_deg) {
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(angle_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
  Eigen::Vector3d pivot = Eigen::Vector3d::Zero();
  for (int v : groups[1].vertices) pivot += V.row(v).transpose();
  pivot /= static_cast<double>(groups[1].vertices.size());
  const std::set<int> handle(groups[1].vertices.begin(), groups[1].vertices.end());
  Positions targets(static_cast<Eigen::Index>(constrained.size()), 3);
  for (std::size_t j = 0; j < constrained.size(); ++j) {
    const Eigen::Vector3d x = V.row(constrained[j]).transpose();
    const Eigen::Vector3d t =
        handle.count(constrained[j])
            ? Eigen::Vector3d(pivot + R * (x - pivot) + Eigen::Vector3d(0.1, 0.0, 0.05))
            : x;
    targets.row(static_cast<Eigen::Index>(j)) = t.transpose();
  }
  return targets;
}

bool is_lower_hex(const std::string& s, std::size_t length) {
  return s.size() == length && std::all_of(s.begin(), s.end(), [](char c) {
           return (c >= '0' && c <= '9') || (c >= 'a' && c <= 'f');
         });
}

class ClientTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    std::string error;
    server_ = test::ServerProcess::start(MESHDEFORM_SERVER_PATH,
                                         {"--refine-budget", "0", "--workers", "2"}, error)
                  .release();
    if (!server_) {
      start_error_ = new std::string(error);
      return;
    }
    ClientOptions options;
    options.target = server_->address();
    options.default_timeout = seconds(60);  // a safety bound for every call
    options.watch_timeout = seconds(120);
    Result<Client> client = Client::connect(options);
    if (client.ok()) client_ = new Client(std::move(client).value());
  }

  static void TearDownTestSuite() {
    delete client_;
    client_ = nullptr;
    delete server_;  // SIGTERM, bounded
    server_ = nullptr;
    delete start_error_;
    start_error_ = nullptr;
  }

  void SetUp() override {
    ASSERT_NE(server_, nullptr) << (start_error_ ? *start_error_ : std::string());
    ASSERT_NE(client_, nullptr);
  }

  const Client& client() const { return *client_; }

  /// A sample session with its suggested groups set as handles.
  Session create_with_handles(const std::string& sample) {
    Result<Session> session = client().create_session_from_sample(sample);
    EXPECT_TRUE(session.ok()) << message_of(session);
    if (!session.ok()) return {};
    EXPECT_EQ(session->suggested_groups.size(), 2u);
    Result<SessionInfo> info = client().set_handles(session->edit(), session->suggested_groups);
    EXPECT_TRUE(info.ok()) << message_of(info);
    return *session;
  }

  static test::ServerProcess* server_;
  static Client* client_;
  static std::string* start_error_;
};

test::ServerProcess* ClientTest::server_ = nullptr;
Client* ClientTest::client_ = nullptr;
std::string* ClientTest::start_error_ = nullptr;

// --- create -------------------------------------------------------------------------------------

TEST_F(ClientTest, CreatesFromObjAndOffBytesAndFiles) {
  const MeshData mesh = test::make_icosphere(2);  // 162 vertices, 320 faces
  for (const io::MeshFormat format : {io::MeshFormat::Obj, io::MeshFormat::Off}) {
    SCOPED_TRACE(io::format_name(format));
    Result<std::string> bytes = io::write_mesh_to_memory(mesh, format);
    ASSERT_TRUE(bytes.ok()) << message_of(bytes);
    Result<Session> session = client().create_session_from_bytes(*bytes, format);
    ASSERT_TRUE(session.ok()) << message_of(session);
    EXPECT_TRUE(is_lower_hex(session->id, 32)) << session->id;
    EXPECT_TRUE(is_lower_hex(session->edit_token, 64));
    EXPECT_TRUE(is_lower_hex(session->view_token, 64));
    EXPECT_NE(session->edit_token, session->view_token);
    EXPECT_EQ(session->info.session_id, session->id);
    EXPECT_EQ(session->info.vertices, 162);
    EXPECT_EQ(session->info.faces, 320);
    EXPECT_EQ(session->info.components, 1);
    EXPECT_EQ(session->info.boundary_loops, 0);
    EXPECT_EQ(session->info.revision, 0u);
    EXPECT_FALSE(session->info.last_method.has_value());
    EXPECT_TRUE(session->info.bbox_min.isApprox(mesh.V.colwise().minCoeff().transpose()));
    EXPECT_TRUE(session->info.bbox_max.isApprox(mesh.V.colwise().maxCoeff().transpose()));
    EXPECT_TRUE(session->suggested_groups.empty());
    EXPECT_TRUE(client().close_session(session->edit()).ok());
  }
  // From a file: the format comes from the extension.
  const std::filesystem::path dir = std::filesystem::temp_directory_path() /
                                    ("meshdeform_client_test_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::filesystem::path path = dir / "sphere.OFF";
  ASSERT_TRUE(io::write_mesh(dir / "sphere.off", mesh).ok());
  std::filesystem::rename(dir / "sphere.off", path);
  Result<Session> from_file = client().create_session_from_file(path);
  ASSERT_TRUE(from_file.ok()) << message_of(from_file);
  EXPECT_EQ(from_file->info.vertices, 162);
  EXPECT_TRUE(client().close_session(from_file->edit()).ok());
  expect_code(client().create_session_from_file(dir / "missing.obj").status(), ErrorCode::NotFound,
              "missing.obj");
  expect_code(client().create_session_from_file(dir / "sphere.xyz").status(),
              ErrorCode::InvalidArgument);
  std::filesystem::remove_all(dir);
}

TEST_F(ClientTest, CreatesFromSampleWithSuggestedGroups) {
  Result<Session> session = client().create_session_from_sample("cylinder_small");
  ASSERT_TRUE(session.ok()) << message_of(session);
  EXPECT_EQ(session->info.vertices, 420);
  ASSERT_EQ(session->suggested_groups.size(), 2u);
  EXPECT_EQ(session->suggested_groups[0].role, HandleRole::Fixed);
  EXPECT_EQ(session->suggested_groups[1].role, HandleRole::Handle);
  const core::DeformationBenchmark bench = small_cylinder();
  for (const HandleGroup& g : session->suggested_groups) {
    ASSERT_FALSE(g.vertices.empty());
    for (int v : g.vertices) {
      EXPECT_EQ(bench.selection(v), g.role == HandleRole::Fixed ? 0 : 2) << "vertex " << v;
    }
  }
  // Set them as handles: the info echoes the groups and one factorization is cached.
  Result<SessionInfo> info = client().set_handles(session->edit(), session->suggested_groups);
  ASSERT_TRUE(info.ok()) << message_of(info);
  EXPECT_EQ(info->groups, session->suggested_groups);
  EXPECT_EQ(info->cached_deformers, 1);
  EXPECT_EQ(info->revision, 0u);
}

TEST_F(ClientTest, OnProgressHearsThePhasesOfCreateAndSetHandles) {
  std::vector<std::string> create_phases, set_phases;
  auto collect = [](std::vector<std::string>& into) {
    return [&into](const Progress& p) {
      EXPECT_GE(p.fraction, 0.0);
      EXPECT_LE(p.fraction, 1.0);
      EXPECT_GE(p.elapsed_seconds, 0.0);
      if (into.empty() || into.back() != p.phase) into.push_back(p.phase);
    };
  };
  CallOptions create_call;
  create_call.on_progress = collect(create_phases);
  Result<Session> session = client().create_session_from_sample("cylinder_small", {}, create_call);
  ASSERT_TRUE(session.ok()) << message_of(session);
  EXPECT_EQ(session->info.vertices, 420);
  EXPECT_EQ(create_phases, (std::vector<std::string>{"queued", "parse", "session"}));

  CallOptions set_call;
  set_call.on_progress = collect(set_phases);
  Result<SessionInfo> info =
      client().set_handles(session->edit(), session->suggested_groups, core::Method::Arap, set_call);
  ASSERT_TRUE(info.ok()) << message_of(info);
  EXPECT_EQ(info->groups, session->suggested_groups);
  EXPECT_EQ(set_phases, (std::vector<std::string>{"queued", "factorize"}));

  // Errors are the plain call's.
  std::vector<std::string> refused_phases;
  CallOptions refused_call;
  refused_call.on_progress = collect(refused_phases);
  expect_code(client()
                  .set_handles(session->view(), session->suggested_groups, core::Method::Arap,
                               refused_call)
                  .status(),
              ErrorCode::PermissionDenied);
  EXPECT_TRUE(refused_phases.empty());
}

// --- move ---------------------------------------------------------------------------------------

TEST_F(ClientTest, MoveMatchesTheCoreSolveAndReportsExactDeltas) {
  const Session s = create_with_handles("cylinder_small");
  const core::DeformationBenchmark bench = small_cylinder();
  const Positions& V0 = bench.mesh.V;
  const std::vector<int> constrained = constrained_of(s.suggested_groups);
  // The service's settings: default DeformerSettings (lambda 100, one solver thread), and per
  // move max_iterations 2 and tolerance 1e-4, warm-started by the same deformer.
  const Eigen::VectorXi idx = Eigen::Map<const Eigen::VectorXi>(
      constrained.data(), static_cast<Eigen::Index>(constrained.size()));
  auto deformer = core::make_deformer(core::Method::ScaleAware, V0, bench.mesh.F, idx);
  ASSERT_TRUE(deformer.ok()) << message_of(deformer);
  core::SolveOptions options;
  options.max_iterations = 2;
  options.tolerance = 1e-4;
  const double diag = test::bbox_diagonal(bench.mesh);

  Positions previous = V0;
  for (int step = 1; step <= 2; ++step) {
    SCOPED_TRACE(step);
    const double angle = 20.0 * step;
    auto expected =
        (*deformer)->solve(bend_targets(V0, s.suggested_groups, constrained, angle), options);
    ASSERT_TRUE(expected.ok()) << message_of(expected);
    MoveSpec spec = bend(angle);
    spec.full_positions = true;
    spec.editor = "test";
    Result<DeformResult> result = client().move(s.edit(), spec);
    ASSERT_TRUE(result.ok()) << message_of(result);
    EXPECT_EQ(result->revision, static_cast<std::uint64_t>(step));
    EXPECT_EQ(result->method, core::Method::ScaleAware);
    EXPECT_EQ(result->iterations, expected->iterations);
    EXPECT_EQ(result->converged, expected->converged);
    EXPECT_EQ(result->editor, "test");
    EXPECT_FALSE(result->refinement);
    EXPECT_EQ(result->built_deformer, false);  // set_handles built it
    ASSERT_TRUE(result->positions.has_value());
    const Positions& V = *result->positions;
    ASSERT_EQ(V.rows(), V0.rows());
    EXPECT_LE((V - expected->V).cwiseAbs().maxCoeff(), test::kExactTol * diag);
    // The delta: exactly the vertices that differ from the previous revision, ascending.
    std::vector<int> changed;
    for (int v = 0; v < V.rows(); ++v) {
      if (V.row(v) != previous.row(v)) changed.push_back(v);
    }
    EXPECT_FALSE(changed.empty());
    EXPECT_EQ(result->changed_indices, changed);
    ASSERT_EQ(result->changed_positions.rows(), static_cast<Eigen::Index>(changed.size()));
    for (std::size_t j = 0; j < changed.size(); ++j) {
      EXPECT_EQ(result->changed_positions.row(static_cast<Eigen::Index>(j)), V.row(changed[j]));
    }
    EXPECT_GT(result->e_theta, 0.0);
    EXPECT_TRUE(std::isfinite(result->e_phi));
    EXPECT_TRUE(std::isfinite(result->area_log_rms));
    EXPECT_GE(result->solve_seconds, 0.0);
    // Carried from the server (0 would mean the field was lost on the way): a move waits at
    // least its hand-off from the transport to a worker.
    EXPECT_GT(result->queue_seconds, 0.0);
    previous = V;
  }
  // Without full_positions only the delta travels; a mirror fed the deltas stays exact.
  SessionMirror mirror;
  DeformResult rest;
  rest.revision = 2;
  rest.positions = previous;
  ASSERT_TRUE(mirror.apply(rest).ok());
  Result<DeformResult> third = client().move(s.edit(), bend(35.0));
  ASSERT_TRUE(third.ok()) << message_of(third);
  EXPECT_FALSE(third->positions.has_value());
  ASSERT_TRUE(mirror.apply(*third).ok());
  auto expected =
      (*deformer)->solve(bend_targets(V0, s.suggested_groups, constrained, 35.0), options);
  ASSERT_TRUE(expected.ok());
  EXPECT_LE((mirror.positions() - expected->V).cwiseAbs().maxCoeff(), test::kExactTol * diag);
  // A delta that does not follow the mirrored revision is refused.
  expect_code(mirror.apply(*third), ErrorCode::FailedPrecondition, "does not follow");

  Result<SessionInfo> info = client().session_info(s.view());
  ASSERT_TRUE(info.ok()) << message_of(info);
  EXPECT_EQ(info->revision, 3u);
  EXPECT_EQ(info->last_method, core::Method::ScaleAware);
}

TEST_F(ClientTest, ExplicitTargetsWithArapLandExactly) {
  const Session s = create_with_handles("cylinder_small");
  MoveSpec spec;
  spec.method = core::Method::Arap;
  spec.max_iterations = 5;
  const int v = s.suggested_groups[1].vertices[0];
  spec.targets.push_back({v, Eigen::Vector3d(0.3, 0.1, 2.2)});
  spec.full_positions = true;
  Result<DeformResult> result = client().move(s.edit(), spec);
  ASSERT_TRUE(result.ok()) << message_of(result);
  EXPECT_EQ(result->method, core::Method::Arap);
  EXPECT_TRUE(result->built_deformer);  // the ARAP system is new
  ASSERT_TRUE(result->positions.has_value());
  // ARAP pins handles exactly.
  EXPECT_EQ(result->positions->row(v), Eigen::RowVector3d(0.3, 0.1, 2.2));
}

// Issue 17: undo and redo through the C++ client; the info reports the history.
TEST_F(ClientTest, UndoAndRedoApplyTheSessionsHistory) {
  const Session s = create_with_handles("cylinder_small");
  MoveSpec spec = bend(20.0);
  spec.method = core::Method::Laplacian;
  spec.max_iterations = 1;
  spec.full_positions = true;
  Result<DeformResult> first = client().move(s.edit(), spec);
  ASSERT_TRUE(first.ok()) << message_of(first);
  MoveSpec second = bend(40.0);
  second.method = core::Method::Laplacian;
  second.max_iterations = 1;
  ASSERT_TRUE(client().move(s.edit(), second).ok());
  Result<SessionInfo> info = client().session_info(s.view());
  ASSERT_TRUE(info.ok()) << message_of(info);
  EXPECT_EQ(info->history_steps, 3);
  EXPECT_EQ(info->history_position, 2);
  EXPECT_EQ(info->settings_method, core::Method::Laplacian);

  MoveSpec undo;
  undo.history = HistoryAction::Undo;
  undo.method = core::Method::Laplacian;
  undo.max_iterations = 1;
  undo.full_positions = true;
  Result<DeformResult> undone = client().move(s.edit(), undo);
  ASSERT_TRUE(undone.ok()) << message_of(undone);
  EXPECT_EQ(*undone->positions, *first->positions);  // one direct solve: the same bits
  EXPECT_EQ(client().session_info(s.view())->history_position, 1);
  undo.moves.push_back(bend(5.0).moves[0]);
  EXPECT_EQ(client().move(s.edit(), undo).status().code(), ErrorCode::InvalidArgument);
  MoveSpec redo = undo;
  redo.moves.clear();
  redo.history = HistoryAction::Redo;
  ASSERT_TRUE(client().move(s.edit(), redo).ok());
  EXPECT_EQ(client().move(s.edit(), redo).status().code(), ErrorCode::FailedPrecondition);
}

TEST_F(ClientTest, GetMeshParsesBackAsGlbAndObj) {
  const Session s = create_with_handles("cylinder_small");
  MoveSpec spec = bend(30.0);
  spec.full_positions = true;
  Result<DeformResult> moved = client().move(s.edit(), spec);
  ASSERT_TRUE(moved.ok()) << message_of(moved);
  const Positions& V = *moved->positions;
  const core::DeformationBenchmark bench = small_cylinder();
  const double diag = test::bbox_diagonal(bench.mesh);

  // GLB (the default) stores float32 positions: equal to float round-off.
  Result<std::string> glb = client().get_mesh(s.view());
  ASSERT_TRUE(glb.ok()) << message_of(glb);
  Result<MeshData> parsed = io::read_mesh_from_memory(*glb, io::MeshFormat::Glb);
  ASSERT_TRUE(parsed.ok()) << message_of(parsed);
  ASSERT_EQ(parsed->V.rows(), V.rows());
  EXPECT_EQ(parsed->F, bench.mesh.F);
  const double float_tol = 4.0 * std::numeric_limits<float>::epsilon() * V.cwiseAbs().maxCoeff();
  EXPECT_LE((parsed->V - V).cwiseAbs().maxCoeff(), float_tol);

  // OBJ keeps full double precision: bit-identical.
  Result<std::string> obj = client().get_mesh(s.view(), io::MeshFormat::Obj);
  ASSERT_TRUE(obj.ok()) << message_of(obj);
  Result<MeshData> exact = io::read_mesh_from_memory(*obj, io::MeshFormat::Obj);
  ASSERT_TRUE(exact.ok()) << message_of(exact);
  EXPECT_EQ(exact->V, V);
  EXPECT_EQ(exact->F, bench.mesh.F);

  // An older kept revision: the rest mesh.
  Result<std::string> rest = client().get_mesh(s.view(), io::MeshFormat::Obj, 0);
  ASSERT_TRUE(rest.ok()) << message_of(rest);
  Result<MeshData> rest_mesh = io::read_mesh_from_memory(*rest, io::MeshFormat::Obj);
  ASSERT_TRUE(rest_mesh.ok());
  EXPECT_LE((rest_mesh->V - bench.mesh.V).cwiseAbs().maxCoeff(), test::kExactTol * diag);
  // A revision that never existed.
  expect_code(client().get_mesh(s.view(), io::MeshFormat::Obj, 99).status(), ErrorCode::NotFound,
              "revision 99");
}

// --- watch --------------------------------------------------------------------------------------

TEST_F(ClientTest, TwoWatchersSeeTheSameRevisions) {
  const Session s = create_with_handles("cylinder_small");
  WatchStream w1 = client().open_watch(s.view());
  WatchStream w2 = client().open_watch(s.edit());  // the edit token may watch too
  SessionMirror m1, m2;
  for (auto [stream, mirror] : {std::pair{&w1, &m1}, std::pair{&w2, &m2}}) {
    Result<std::optional<WatchUpdate>> snapshot = stream->next();
    ASSERT_TRUE(snapshot.ok()) << message_of(snapshot);
    ASSERT_TRUE(snapshot->has_value());
    const WatchUpdate& u = **snapshot;
    EXPECT_TRUE(u.is_snapshot);
    EXPECT_EQ(u.result.revision, 0u);
    ASSERT_TRUE(u.result.positions.has_value());
    EXPECT_EQ(u.result.positions->rows(), 420);
    EXPECT_TRUE(u.result.changed_indices.empty());
    ASSERT_TRUE(mirror->apply(u).ok());
  }
  Positions last;
  for (int step = 1; step <= 3; ++step) {
    MoveSpec spec = bend(10.0 * step);
    spec.editor = "editor-" + std::to_string(step);
    spec.full_positions = true;
    Result<DeformResult> moved = client().move(s.edit(), spec);
    ASSERT_TRUE(moved.ok()) << message_of(moved);
    last = *moved->positions;
    for (auto [stream, mirror] : {std::pair{&w1, &m1}, std::pair{&w2, &m2}}) {
      Result<std::optional<WatchUpdate>> next = stream->next();
      ASSERT_TRUE(next.ok()) << message_of(next);
      ASSERT_TRUE(next->has_value());
      const WatchUpdate& u = **next;
      EXPECT_FALSE(u.is_snapshot);
      EXPECT_EQ(u.skipped_revisions, 0u);
      EXPECT_EQ(u.result.revision, moved->revision);
      EXPECT_EQ(u.result.editor, spec.editor);
      EXPECT_EQ(u.result.changed_indices, moved->changed_indices);
      EXPECT_EQ(u.result.changed_positions, moved->changed_positions);
      EXPECT_EQ(u.result.iterations, moved->iterations);
      ASSERT_TRUE(mirror->apply(u).ok());
      EXPECT_EQ(mirror->revision(), moved->revision);
      EXPECT_EQ(mirror->positions(), last);
    }
  }
  Result<SessionInfo> during = client().session_info(s.view());
  ASSERT_TRUE(during.ok());
  EXPECT_EQ(during->watchers, 2);
  // Closing the session ends both streams OK.
  ASSERT_TRUE(client().close_session(s.edit()).ok());
  for (WatchStream* stream : {&w1, &w2}) {
    Result<std::optional<WatchUpdate>> end = stream->next();
    ASSERT_TRUE(end.ok()) << message_of(end);
    EXPECT_FALSE(end->has_value());
  }
}

TEST_F(ClientTest, SlowWatcherDoesNotHoldUpTheEditor) {
  const Session s = create_with_handles("cylinder_small");
  // 16 deltas of ~10 KB each: more than the watcher's fixed 64 KiB receive window can buffer
  // (with the adaptive window, gRPC would buffer them all on the client and nothing would skip).
  constexpr int kMoves = 16;
  ClientOptions viewer_options = client().options();
  viewer_options.adaptive_receive_window = false;
  Result<Client> viewer = Client::connect(viewer_options);
  ASSERT_TRUE(viewer.ok()) << message_of(viewer);
  std::mutex mutex;
  std::condition_variable changed;
  bool has_snapshot = false, is_editor_done = false;
  struct Seen {
    std::uint64_t revision;
    bool is_snapshot;
    std::uint64_t skipped;
  };
  std::vector<Seen> seen;
  SessionMirror mirror;
  Status mirror_status;

  // The watcher blocks in its callback on the join snapshot until the editor is done: every
  // revision is committed while it reads nothing, so it must skip (the server keeps a one-slot
  // mailbox per watcher) rather than hold the editor up.
  std::future<Result<WatchEnd>> watcher = std::async(std::launch::async, [&] {
    return viewer->watch(s.view(), [&](const WatchUpdate& update) {
      std::unique_lock lock(mutex);
      seen.push_back({update.result.revision, update.is_snapshot, update.skipped_revisions});
      if (const Status applied = mirror.apply(update); !applied.ok()) mirror_status = applied;
      if (!has_snapshot) {
        has_snapshot = true;
        changed.notify_all();
        changed.wait_for(lock, seconds(60), [&] { return is_editor_done; });
      } else {
        lock.unlock();
        std::this_thread::sleep_for(milliseconds(20));  // and stays slow afterwards
      }
      return true;
    });
  });
  // However this test ends, release the watcher and end its stream (bounded teardown).
  struct Release {
    std::mutex& mutex;
    std::condition_variable& changed;
    bool& is_editor_done;
    const Client& client;
    SessionRef edit;
    ~Release() {
      {
        const std::lock_guard lock(mutex);
        is_editor_done = true;
        changed.notify_all();
      }
      (void)client.close_session(edit);
    }
  } release{mutex, changed, is_editor_done, client(), s.edit()};
  {
    std::unique_lock lock(mutex);
    ASSERT_TRUE(changed.wait_for(lock, seconds(60), [&] { return has_snapshot; }));
  }
  Positions final_positions;
  for (int step = 1; step <= kMoves; ++step) {
    MoveSpec spec = bend(3.0 * step);
    spec.full_positions = step == kMoves;
    Result<DeformResult> moved = client().move(s.edit(), spec);
    ASSERT_TRUE(moved.ok()) << "move " << step << ": " << message_of(moved);
    EXPECT_EQ(moved->revision, static_cast<std::uint64_t>(step));
    if (moved->positions) final_positions = *moved->positions;
  }
  {
    const std::lock_guard lock(mutex);
    is_editor_done = true;
    changed.notify_all();
  }
  // The newest revision still reaches the watcher before the close ends its stream.
  ASSERT_TRUE(client().close_session(s.edit()).ok());
  ASSERT_EQ(watcher.wait_for(seconds(60)), std::future_status::ready);
  Result<WatchEnd> end = watcher.get();
  ASSERT_TRUE(end.ok()) << message_of(end);
  EXPECT_EQ(*end, WatchEnd::StreamEnded);

  const std::lock_guard lock(mutex);
  ASSERT_TRUE(mirror_status.ok()) << mirror_status.to_string();
  ASSERT_FALSE(seen.empty());
  EXPECT_TRUE(seen.front().is_snapshot);
  EXPECT_EQ(seen.front().revision, 0u);
  std::uint64_t skipped = 0;
  for (std::size_t i = 1; i < seen.size(); ++i) {
    SCOPED_TRACE(i);
    ASSERT_GT(seen[i].revision, seen[i - 1].revision);
    // Each gap is announced: a snapshot counting exactly the revisions never sent.
    EXPECT_EQ(seen[i].skipped, seen[i].revision - seen[i - 1].revision - 1);
    EXPECT_EQ(seen[i].is_snapshot, seen[i].skipped > 0);
    skipped += seen[i].skipped;
  }
  EXPECT_EQ(seen.back().revision, static_cast<std::uint64_t>(kMoves));
  EXPECT_GT(skipped, 0u) << "the watcher read " << seen.size() << " updates";
  EXPECT_LT(seen.size(), static_cast<std::size_t>(kMoves + 1));
  EXPECT_EQ(mirror.revision(), static_cast<std::uint64_t>(kMoves));
  EXPECT_EQ(mirror.positions(), final_positions);
}

TEST_F(ClientTest, WatchStopsByCallbackAndByStopToken) {
  const Session s = create_with_handles("cylinder_small");
  int calls = 0;
  Result<WatchEnd> by_callback = client().watch(s.view(), [&](const WatchUpdate& update) {
    ++calls;
    EXPECT_TRUE(update.is_snapshot);
    return false;
  });
  ASSERT_TRUE(by_callback.ok()) << message_of(by_callback);
  EXPECT_EQ(*by_callback, WatchEnd::StoppedByCallback);
  EXPECT_EQ(calls, 1);

  std::stop_source stop;
  CallOptions call;
  call.stop = stop.get_token();
  calls = 0;
  Result<WatchEnd> by_token = client().watch(
      s.view(),
      [&](const WatchUpdate&) {
        ++calls;
        stop.request_stop();  // the blocked read that follows is cancelled
        return true;
      },
      call);
  ASSERT_TRUE(by_token.ok()) << message_of(by_token);
  EXPECT_EQ(*by_token, WatchEnd::StoppedByToken);
  EXPECT_EQ(calls, 1);

  // The server unsubscribes both (shortly after the client sees the end).
  Result<SessionInfo> info = client().session_info(s.view());
  for (int i = 0; i < 200 && info.ok() && info->watchers != 0; ++i) {
    std::this_thread::sleep_for(milliseconds(50));
    info = client().session_info(s.view());
  }
  ASSERT_TRUE(info.ok()) << message_of(info);
  EXPECT_EQ(info->watchers, 0);
}

// --- tokens and bad input -----------------------------------------------------------------------

TEST_F(ClientTest, TokensAreEnforced) {
  const Session s = create_with_handles("cylinder_small");
  // The view token reads but cannot edit.
  EXPECT_TRUE(client().session_info(s.view()).ok());
  EXPECT_TRUE(client().get_mesh(s.view(), io::MeshFormat::Obj).ok());
  expect_code(client().move(s.view(), bend(10)).status(), ErrorCode::PermissionDenied);
  expect_code(client().set_handles(s.view(), s.suggested_groups).status(),
              ErrorCode::PermissionDenied);
  expect_code(client().close_session(s.view()), ErrorCode::PermissionDenied);
  // A wrong token is refused everywhere, and never echoed.
  const SessionRef wrong{s.id, std::string(64, 'a')};
  for (const Status& status :
       {client().session_info(wrong).status(), client().move(wrong, bend(10)).status(),
        client().get_mesh(wrong).status(), client().close_session(wrong)}) {
    expect_code(status, ErrorCode::PermissionDenied);
    EXPECT_EQ(status.message().find(wrong.token), std::string::npos);
    EXPECT_EQ(status.message().find(s.edit_token), std::string::npos);
  }
  WatchStream stream = client().open_watch(wrong);
  expect_code(stream.next().status(), ErrorCode::PermissionDenied);
  // Nothing was changed by the refused calls.
  Result<SessionInfo> info = client().session_info(s.edit());
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->revision, 0u);
}

TEST_F(ClientTest, BadInputsPinTheirCodes) {
  const Session s = create_with_handles("cylinder_small");
  const int nv = s.info.vertices;
  const int handle = s.suggested_groups[1].vertices[0];
  const double nan = std::numeric_limits<double>::quiet_NaN();

  MoveSpec nan_target;
  nan_target.targets.push_back({handle, Eigen::Vector3d(0, nan, 0)});
  expect_code(client().move(s.edit(), nan_target).status(), ErrorCode::InvalidArgument);
  MoveSpec nan_move = bend(10);
  nan_move.moves[0].translation.x() = nan;
  expect_code(client().move(s.edit(), nan_move).status(), ErrorCode::InvalidArgument);
  MoveSpec unknown_group = bend(10);
  unknown_group.moves[0].group = 7;
  expect_code(client().move(s.edit(), unknown_group).status(), ErrorCode::InvalidArgument,
              "group 7");
  MoveSpec fixed_group = bend(10);
  fixed_group.moves[0].group = 0;
  expect_code(client().move(s.edit(), fixed_group).status(), ErrorCode::InvalidArgument, "fixed");
  MoveSpec out_of_range;
  out_of_range.targets.push_back({nv + 5, Eigen::Vector3d::Zero()});
  expect_code(client().move(s.edit(), out_of_range).status(), ErrorCode::InvalidArgument,
              std::to_string(nv + 5));
  MoveSpec zero_scale = bend(10);
  zero_scale.moves[0].scale = 0.0;
  expect_code(client().move(s.edit(), zero_scale).status(), ErrorCode::InvalidArgument);
  MoveSpec too_many = bend(10);
  too_many.max_iterations = 1001;
  expect_code(client().move(s.edit(), too_many).status(), ErrorCode::InvalidArgument);
  MoveSpec ora_arap = bend(10);
  ora_arap.method = core::Method::Arap;
  ora_arap.ora = true;
  expect_code(client().move(s.edit(), ora_arap).status(), ErrorCode::InvalidArgument);
  // Handles: index out of range, a vertex in two groups, no groups.
  std::vector<HandleGroup> bad = s.suggested_groups;
  bad[1].vertices.push_back(nv);
  expect_code(client().set_handles(s.edit(), bad).status(), ErrorCode::InvalidArgument,
              std::to_string(nv));
  bad = s.suggested_groups;
  bad[1].vertices.push_back(bad[0].vertices[0]);
  expect_code(client().set_handles(s.edit(), bad).status(), ErrorCode::InvalidArgument);
  expect_code(client().set_handles(s.edit(), {}).status(), ErrorCode::InvalidArgument);
  // Negative indices cannot travel (uint32 on the wire): refused here, naming the value.
  MoveSpec negative;
  negative.targets.push_back({-3, Eigen::Vector3d::Zero()});
  expect_code(client().move(s.edit(), negative).status(), ErrorCode::InvalidArgument, "-3");
  bad = s.suggested_groups;
  bad[0].vertices[0] = -1;
  expect_code(client().set_handles(s.edit(), bad).status(), ErrorCode::InvalidArgument, "-1");
  // Nothing was committed.
  Result<SessionInfo> info = client().session_info(s.view());
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->revision, 0u);
  EXPECT_EQ(info->groups, s.suggested_groups);

  // Bad meshes and sources.
  expect_code(
      client().create_session_from_bytes("v 0 0 0\nf 1 2 9\n", io::MeshFormat::Obj).status(),
      ErrorCode::InvalidArgument);
  expect_code(client().create_session_from_bytes("garbage", io::MeshFormat::Glb).status(),
              ErrorCode::InvalidArgument);
  expect_code(client().create_session_from_bytes("", io::MeshFormat::Off).status(),
              ErrorCode::InvalidArgument);
  expect_code(client().create_session_from_sample("no_such_sample").status(),
              ErrorCode::InvalidArgument, "cylinder_small");
  CreateOptions bad_lambda;
  bad_lambda.lambda = -1.0;
  expect_code(client().create_session_from_sample("bar_small", bad_lambda).status(),
              ErrorCode::InvalidArgument);

  // Move before handles.
  Result<Session> bare = client().create_session_from_sample("bar_small");
  ASSERT_TRUE(bare.ok()) << message_of(bare);
  expect_code(client().move(bare->edit(), bend(10)).status(), ErrorCode::FailedPrecondition);
}

TEST_F(ClientTest, UnknownSessionIsNotFoundEverywhere) {
  const SessionRef unknown{std::string(32, '0'), std::string(64, '0')};
  expect_code(client().session_info(unknown).status(), ErrorCode::NotFound);
  expect_code(client().set_handles(unknown, {{HandleRole::Fixed, {0, 1}}}).status(),
              ErrorCode::NotFound);
  expect_code(client().move(unknown, bend(10)).status(), ErrorCode::NotFound);
  expect_code(client().get_mesh(unknown).status(), ErrorCode::NotFound);
  expect_code(client().close_session(unknown), ErrorCode::NotFound);
  WatchStream stream = client().open_watch(unknown);
  expect_code(stream.next().status(), ErrorCode::NotFound);
  // A closed session is unknown too.
  Result<Session> s = client().create_session_from_sample("bar_small");
  ASSERT_TRUE(s.ok()) << message_of(s);
  ASSERT_TRUE(client().close_session(s->edit()).ok());
  expect_code(client().session_info(s->view()).status(), ErrorCode::NotFound);
  expect_code(client().close_session(s->edit()), ErrorCode::NotFound);
}

// --- deadline and cancellation ------------------------------------------------------------------

TEST_F(ClientTest, DeadlineStopsALongSolveAndTheSessionStillServes) {
  const Session s = create_with_handles("cylinder");  // 4,802 vertices
  MoveSpec long_move = bend(30.0, 1000);
  long_move.tolerance = 0.0;
  CallOptions call;
  call.timeout = milliseconds(300);
  expect_code(client().move(s.edit(), long_move, call).status(), ErrorCode::DeadlineExceeded);
  Result<SessionInfo> after = client().session_info(s.view());
  ASSERT_TRUE(after.ok()) << message_of(after);
  EXPECT_EQ(after->revision, 0u);  // nothing committed
  Result<DeformResult> ok = client().move(s.edit(), bend(10.0));
  ASSERT_TRUE(ok.ok()) << message_of(ok);
  EXPECT_EQ(ok->revision, 1u);
}

TEST_F(ClientTest, StopTokenCancelsALongSolveAndTheSessionStillServes) {
  const Session s = create_with_handles("cylinder");
  MoveSpec long_move = bend(30.0, 1000);
  long_move.tolerance = 0.0;
  std::stop_source stop;
  CallOptions call;
  call.stop = stop.get_token();
  std::future<Result<DeformResult>> running =
      std::async(std::launch::async, [&] { return client().move(s.edit(), long_move, call); });
  // Cancel once the solve is likely running (a cancel before the server sees it is fine too).
  std::this_thread::sleep_for(milliseconds(200));
  stop.request_stop();
  ASSERT_EQ(running.wait_for(seconds(60)), std::future_status::ready);
  expect_code(running.get().status(), ErrorCode::Cancelled);
  // A token already stopped cancels before sending.
  expect_code(client().move(s.edit(), bend(10.0), call).status(), ErrorCode::Cancelled);
  Result<SessionInfo> after = client().session_info(s.view());
  ASSERT_TRUE(after.ok()) << message_of(after);
  EXPECT_EQ(after->revision, 0u);
  Result<DeformResult> ok = client().move(s.edit(), bend(10.0));
  ASSERT_TRUE(ok.ok()) << message_of(ok);
  EXPECT_EQ(ok->revision, 1u);
}

// --- stats --------------------------------------------------------------------------------------

TEST_F(ClientTest, ServerStatsCountSessionsAndMoves) {
  const Session s = create_with_handles("cylinder_small");
  ASSERT_TRUE(client().move(s.edit(), bend(10.0)).ok());
  Result<ServerStats> stats = client().server_stats();
  ASSERT_TRUE(stats.ok()) << message_of(stats);
  EXPECT_GE(stats->sessions, 1u);
  EXPECT_GE(stats->moves_committed, 1u);
  EXPECT_GE(stats->deformer_constructions, 1u);
  EXPECT_GT(stats->estimated_bytes, 0u);
  EXPECT_EQ(stats->workers, 2u);
  EXPECT_GE(stats->uptime_seconds, 0.0);
  EXPECT_EQ(stats->refinements_committed, 0u);  // --refine-budget 0
}

}  // namespace
}  // namespace meshdeform::client
