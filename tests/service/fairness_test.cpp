// Issue 40 in the service: what one client can do to the others, what a full disk does to an
// edit, what a close does to the solve it interrupts, and numbers that cannot give a finite
// result. Conditions and counters only (no wall-clock thresholds).
#include <gtest/gtest.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <future>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include "core/samples/samples.h"
#include "server/service/deformation_service.h"
#include "server/service/persistence.h"

namespace meshdeform::service {
namespace {

namespace fs = std::filesystem;
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

CreateSessionRequest sample_request(const std::string& name, const std::string& client = "") {
  CreateSessionRequest request;
  request.sample = name;
  request.client = client;
  return request;
}

struct Fixture {
  CreatedSession created;
  std::vector<HandleGroup> groups;
};

Fixture create_with_handles(DeformationService& service, const std::string& sample,
                            const std::string& client = "") {
  Result<CreatedSession> created = service.create_session(sample_request(sample, client));
  EXPECT_TRUE(created.ok()) << message_of(created);
  if (!created.ok()) return {};
  Fixture f{*created, created->suggested_groups};
  SetHandlesRequest handles{f.groups, core::Method::ScaleAware};
  handles.client = client;
  Result<SessionInfo> info = service.set_handles(f.created.id, f.created.edit_token, handles);
  EXPECT_TRUE(info.ok()) << message_of(info);
  return f;
}

/// Group 1 (the sample's handles) turned about y by `angle_deg` and lifted.
MoveRequest twist(double angle_deg, int iterations, double tolerance = 1e-4) {
  MoveRequest move;
  GroupMove g;
  g.group = 1;
  g.rotation =
      Eigen::Quaterniond(Eigen::AngleAxisd(angle_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()));
  g.translation = Eigen::Vector3d(0.1, 0.0, 0.05);
  move.moves.push_back(g);
  move.max_iterations = iterations;
  move.tolerance = tolerance;
  return move;
}

fs::path fresh_dir(const std::string& what) {
  std::random_device random;
  return fs::temp_directory_path() /
         ("meshdeform-" + what + "-" + std::to_string(random()) + std::to_string(random()));
}

// --- solver time shared between sessions -------------------------------------------------------

// Two sessions run 1000-iteration solves on both workers; a third session's one-iteration move
// is answered while both still run (they yield between iterations), not after one of them ends.
// The long solves are warm (a first small move), so they iterate from the start, and they are
// cancelled once the short move is answered: the test never waits for them to finish.
TEST(FairnessTest, LongSolvesLetAnotherSessionsShortMoveThrough) {
  ServiceOptions options;
  options.workers = 2;
  DeformationService service(options);
  Fixture a = create_with_handles(service, "cylinder");
  Fixture b = create_with_handles(service, "cylinder");
  Fixture c = create_with_handles(service, "cylinder_small");
  ASSERT_TRUE(service.move_handles(a.created.id, a.created.edit_token, twist(10, 1)).ok());
  ASSERT_TRUE(service.move_handles(b.created.id, b.created.edit_token, twist(-10, 1)).ok());

  std::promise<Result<DeformResult>> long_a, long_b, short_c;
  auto done_a = long_a.get_future(), done_b = long_b.get_future(), done_c = short_c.get_future();
  std::stop_source stop_a, stop_b;
  service.move_handles_async(a.created.id, a.created.edit_token, twist(170, 1000, 0),
                             stop_a.get_token(),
                             [&](Result<DeformResult> r) { long_a.set_value(std::move(r)); });
  service.move_handles_async(b.created.id, b.created.edit_token, twist(-170, 1000, 0),
                             stop_b.get_token(),
                             [&](Result<DeformResult> r) { long_b.set_value(std::move(r)); });
  // Both long solves hold a worker.
  for (int i = 0; i < 60000 && service.stats().solves_running < 2; ++i) {
    std::this_thread::sleep_for(milliseconds(5));
  }
  ASSERT_EQ(service.stats().solves_running, 2u);
  ASSERT_EQ(service.stats().queued_normal, 0u);
  service.move_handles_async(c.created.id, c.created.edit_token, twist(20, 1), {},
                             [&](Result<DeformResult> r) { short_c.set_value(std::move(r)); });
  ASSERT_EQ(done_c.wait_for(seconds(600)), std::future_status::ready);
  const bool a_running = done_a.wait_for(seconds(0)) != std::future_status::ready;
  const bool b_running = done_b.wait_for(seconds(0)) != std::future_status::ready;
  stop_a.request_stop();
  stop_b.request_stop();
  EXPECT_TRUE(a_running && b_running)
      << "the short move waited for a long solve to end (a running: " << a_running
      << ", b running: " << b_running << ")";
  const Result<DeformResult> c_result = done_c.get();
  ASSERT_TRUE(c_result.ok()) << message_of(c_result);
  EXPECT_EQ(c_result->revision, 1u);
  EXPECT_GE(service.stats().yielded_tasks, 1u);
  // The long solves stop when asked and commit nothing.
  ASSERT_EQ(done_a.wait_for(seconds(600)), std::future_status::ready);
  ASSERT_EQ(done_b.wait_for(seconds(600)), std::future_status::ready);
  expect_code(done_a.get().status(), ErrorCode::Cancelled);
  expect_code(done_b.get().status(), ErrorCode::Cancelled);
}

// Short moves of four sessions queued on one worker: each waits its turn. A move's solve runs the
// moves queued after it at its yield points only once it has run ServiceOptions::yield_after
// (a long solve), never sooner; with yield_after 0 it runs them at its first yield point. Every
// move is answered either way. (Counted by yielded_tasks: no timing is measured.)
TEST(FairnessTest, ShortMovesYieldOnlyOnceTheyHaveRunLong) {
  for (const bool yields : {false, true}) {
    SCOPED_TRACE(yields ? "yield_after 0" : "yield_after 1 h");
    ServiceOptions options;
    options.workers = 1;
    options.yield_after = yields ? milliseconds(0) : milliseconds(3'600'000);
    DeformationService service(options);
    std::vector<Fixture> sessions;
    for (int i = 0; i < 4; ++i) {
      sessions.push_back(create_with_handles(service, "cylinder_small"));
      // Warm: the moves below iterate from the previous result, no cold start.
      ASSERT_TRUE(
          service.move_handles(sessions.back().created.id, sessions.back().created.edit_token,
                               twist(5, 1)).ok());
    }
    constexpr int kRounds = 5;
    std::vector<std::promise<Result<DeformResult>>> promises(4 * kRounds);
    std::vector<std::future<Result<DeformResult>>> futures;
    for (auto& p : promises) futures.push_back(p.get_future());
    // All queued at once: each session's strand posts its next move when the last one ends, so
    // up to four moves (one per session) wait on the worker while another runs.
    for (int round = 0; round < kRounds; ++round) {
      for (int i = 0; i < 4; ++i) {
        auto* promise = &promises[static_cast<std::size_t>(4 * round + i)];
        service.move_handles_async(
            sessions[static_cast<std::size_t>(i)].created.id,
            sessions[static_cast<std::size_t>(i)].created.edit_token, twist(10 + round, 2), {},
            [promise](Result<DeformResult> r) { promise->set_value(std::move(r)); });
      }
    }
    for (auto& f : futures) {
      ASSERT_EQ(f.wait_for(seconds(600)), std::future_status::ready);
      const Result<DeformResult> r = f.get();
      EXPECT_TRUE(r.ok()) << message_of(r);
    }
    if (yields) {
      EXPECT_GE(service.stats().yielded_tasks, 1u);
    } else {
      EXPECT_EQ(service.stats().yielded_tasks, 0u);
    }
  }
}

// A move's queue_seconds is its wait from arrival to the start of its solve: on one worker, a
// move that arrives while another session's long solve runs waits at least until that solve
// ends (no yielding here), and says so; the metric counts every move.
TEST(FairnessTest, AMoveReportsItsWaitForAFreeWorker) {
  ServiceOptions options;
  options.workers = 1;
  options.yield_after = milliseconds(3'600'000);
  DeformationService service(options);
  Fixture a = create_with_handles(service, "cylinder");
  Fixture b = create_with_handles(service, "cylinder_small");
  ASSERT_TRUE(service.move_handles(a.created.id, a.created.edit_token, twist(10, 1)).ok());
  const Result<DeformResult> alone =
      service.move_handles(b.created.id, b.created.edit_token, twist(5, 1));
  ASSERT_TRUE(alone.ok()) << message_of(alone);
  EXPECT_GE(alone->queue_seconds, 0.0);

  using Clock = std::chrono::steady_clock;
  std::promise<Clock::time_point> long_done;
  std::promise<Result<DeformResult>> short_done;
  auto long_future = long_done.get_future();
  auto short_future = short_done.get_future();
  std::stop_source stop_long;
  service.move_handles_async(a.created.id, a.created.edit_token, twist(170, 1000, 0),
                             stop_long.get_token(),
                             [&](Result<DeformResult>) { long_done.set_value(Clock::now()); });
  for (int i = 0; i < 60000 && service.stats().solves_running < 1; ++i) {
    std::this_thread::sleep_for(milliseconds(5));
  }
  ASSERT_EQ(service.stats().solves_running, 1u);
  service.move_handles_async(b.created.id, b.created.edit_token, twist(20, 1), {},
                             [&](Result<DeformResult> r) { short_done.set_value(std::move(r)); });
  const Clock::time_point posted = Clock::now();  // the short move arrived before this
  stop_long.request_stop();
  ASSERT_EQ(long_future.wait_for(seconds(600)), std::future_status::ready);
  const Clock::time_point long_ended = long_future.get();
  ASSERT_EQ(short_future.wait_for(seconds(600)), std::future_status::ready);
  const Result<DeformResult> waited = short_future.get();
  ASSERT_TRUE(waited.ok()) << message_of(waited);
  EXPECT_GE(waited->queue_seconds,
            std::chrono::duration<double>(long_ended - posted).count());
  EXPECT_NE(service.render_metrics().find("meshdeform_move_queue_seconds_count 3"),
            std::string::npos)
      << "three moves answered OK (the cancelled one is not counted)";
}

// A yielding solve computes exactly what it computes alone.
TEST(FairnessTest, YieldingDoesNotChangeTheResult) {
  ServiceOptions options;
  options.workers = 2;
  DeformationService alone(options), shared(options);
  Fixture a = create_with_handles(alone, "cylinder_small");
  Fixture b = create_with_handles(shared, "cylinder_small");
  Fixture other = create_with_handles(shared, "cylinder_small");
  const Result<DeformResult> expected =
      alone.move_handles(a.created.id, a.created.edit_token, twist(90, 30, 0));
  ASSERT_TRUE(expected.ok()) << message_of(expected);
  std::promise<Result<DeformResult>> promise;
  auto future = promise.get_future();
  shared.move_handles_async(b.created.id, b.created.edit_token, twist(90, 30, 0), {},
                            [&](Result<DeformResult> r) { promise.set_value(std::move(r)); });
  for (int i = 0; i < 10; ++i) {
    ASSERT_TRUE(shared.move_handles(other.created.id, other.created.edit_token, twist(i, 1)).ok());
  }
  const Result<DeformResult> got = future.get();
  ASSERT_TRUE(got.ok()) << message_of(got);
  EXPECT_EQ(*got->positions, *expected->positions);
}

// --- quotas per client -------------------------------------------------------------------------

TEST(QuotaTest, OneClientCannotTakeEverySessionSlot) {
  ServiceOptions options;
  options.workers = 2;
  options.max_sessions = 8;
  options.max_sessions_per_client = 3;
  DeformationService service(options);
  int opened = 0;
  Status refused;
  for (int i = 0; i < 8; ++i) {
    Result<CreatedSession> created = service.create_session(sample_request("bar_small", "ipv4:10.0.0.1"));
    if (!created.ok()) {
      refused = created.status();
      break;
    }
    ++opened;
  }
  EXPECT_EQ(opened, 3);
  expect_code(refused, ErrorCode::ResourceExhausted, "per client");
  // Another client still gets sessions.
  EXPECT_TRUE(service.create_session(sample_request("bar_small", "ipv4:10.0.0.2")).ok());
}

// In memory, an evicted session is lost: creating sessions never evicts another client's idle
// session that is within its quota; the newcomer is refused instead.
TEST(QuotaTest, MemoryBudgetNeverEvictsAnotherClientsSessionInMemory) {
  ServiceOptions options;
  options.workers = 2;
  int nv = 0, nf = 0;
  for (const auto& b : core::make_suite(core::SuiteScale::Small)) {
    if (b.name == "cactus") {
      nv = static_cast<int>(b.mesh.V.rows());
      nf = static_cast<int>(b.mesh.F.rows());
    }
  }
  const std::size_t one = estimate_session_bytes(nv, nf, 0, options.kept_revisions);
  options.memory_budget_bytes = 3 * one + one / 2;
  DeformationService service(options);
  // Three clients hold one idle session each (each within its quota of three quarters).
  std::vector<CreatedSession> held;
  for (const char* client : {"ipv4:10.0.0.2", "ipv4:10.0.0.3", "ipv4:10.0.0.4"}) {
    auto created = service.create_session(sample_request("cactus_small", client));
    ASSERT_TRUE(created.ok()) << message_of(created);
    held.push_back(*created);
  }
  // A fourth client does not fit: it is refused, and nobody's session is evicted for it.
  expect_code(service.create_session(sample_request("cactus_small", "ipv4:10.0.0.1")).status(),
              ErrorCode::ResourceExhausted, "memory");
  for (const CreatedSession& session : held) {
    EXPECT_TRUE(service.session_info(session.id, session.view_token).ok())
        << "another client's idle session was evicted";
  }
  EXPECT_EQ(service.stats().evicted_lru, 0u);
  // A client that holds a session makes room from its own (its choice to make).
  auto second = service.create_session(sample_request("cactus_small", "ipv4:10.0.0.2"));
  ASSERT_TRUE(second.ok()) << message_of(second);
  expect_code(service.session_info(held[0].id, held[0].view_token).status(), ErrorCode::NotFound);
  EXPECT_TRUE(service.session_info(held[1].id, held[1].view_token).ok());
  EXPECT_TRUE(service.session_info(held[2].id, held[2].view_token).ok());
}

// A client over budget makes room from its own idle sessions first.
TEST(QuotaTest, EvictionPrefersTheRequestersOwnSessions) {
  ServiceOptions options;
  options.workers = 2;
  options.state_dir = fresh_dir("quota").string();  // eviction is lossless here
  int nv = 0, nf = 0;
  for (const auto& b : core::make_suite(core::SuiteScale::Small)) {
    if (b.name == "cactus") {
      nv = static_cast<int>(b.mesh.V.rows());
      nf = static_cast<int>(b.mesh.F.rows());
    }
  }
  const std::size_t one = estimate_session_bytes(nv, nf, 0, options.kept_revisions);
  options.memory_budget_bytes = 2 * one + one / 2;
  {
    DeformationService service(options);
    auto theirs = service.create_session(sample_request("cactus_small", "ipv4:10.0.0.2"));
    auto mine = service.create_session(sample_request("cactus_small", "ipv4:10.0.0.1"));
    ASSERT_TRUE(theirs.ok() && mine.ok());
    // theirs is the least recently used; still, the requester's own session goes first.
    auto again = service.create_session(sample_request("cactus_small", "ipv4:10.0.0.1"));
    ASSERT_TRUE(again.ok()) << message_of(again);
    EXPECT_EQ(service.stats().evicted_lru, 1u);
    EXPECT_EQ(service.stats().sessions, 2u);
    EXPECT_TRUE(service.session_info(theirs->id, theirs->view_token).ok());
  }
  std::error_code ignored;
  fs::remove_all(options.state_dir, ignored);
}

// --- acknowledged means durable ----------------------------------------------------------------

// A state directory whose disk fills up: the edit is refused (ResourceExhausted), the revision
// does not advance, the failure is counted, and once there is room again editing goes on. A new
// service on the directory (a restart) holds exactly the last acknowledged revision.
TEST(DurableEditTest, AFullDiskRefusesTheEditAndLosesNothing) {
  const fs::path dir = fresh_dir("full");
  auto full = std::make_shared<std::atomic<bool>>(false);
  ServiceOptions options;
  options.workers = 2;
  options.state_dir = dir.string();
  options.state_write_fault = [full](std::string_view) { return full->load() ? ENOSPC : 0; };
  SessionId id;
  Token view;
  Positions acknowledged;
  std::uint64_t revision = 0;
  {
    DeformationService service(options);
    Fixture f = create_with_handles(service, "cylinder_small");
    id = f.created.id;
    view = f.created.view_token;
    ASSERT_TRUE(service.move_handles(id, f.created.edit_token, twist(10, 2)).ok());
    full->store(true);
    const Result<DeformResult> refused =
        service.move_handles(id, f.created.edit_token, twist(20, 2));
    expect_code(refused.status(), ErrorCode::ResourceExhausted, "state");
    EXPECT_EQ(service.session_info(id, view)->revision, 1u);
    EXPECT_GE(service.stats().persist_failures, 1u);
    // SetHandles and CreateSession are refused the same way, and change nothing.
    expect_code(service.set_handles(id, f.created.edit_token, {f.groups}).status(),
                ErrorCode::ResourceExhausted);
    expect_code(service.create_session(sample_request("bar_small")).status(),
                ErrorCode::ResourceExhausted);
    EXPECT_EQ(service.stats().sessions, 1u);
    full->store(false);
    const Result<DeformResult> next = service.move_handles(id, f.created.edit_token, twist(30, 2));
    ASSERT_TRUE(next.ok()) << message_of(next);
    EXPECT_EQ(next->revision, 2u);
    revision = next->revision;
    acknowledged = *next->positions;
  }
  DeformationService restarted(options);
  Result<SessionInfo> info = restarted.session_info(id, view);
  ASSERT_TRUE(info.ok()) << message_of(info);
  EXPECT_EQ(info->revision, revision);
  std::error_code ignored;
  fs::remove_all(dir, ignored);
}

// --- close is final ----------------------------------------------------------------------------

TEST(CloseTest, CloseStopsTheRunningSolveAndNothingIsPublishedAfter) {
  ServiceOptions options;
  options.workers = 2;
  DeformationService service(options);
  Fixture f = create_with_handles(service, "cylinder");
  Result<Subscription> watch = service.watch(f.created.id, f.created.view_token);
  ASSERT_TRUE(watch.ok());
  (void)(*watch)->try_take();  // the join snapshot
  std::promise<Result<DeformResult>> promise;
  auto future = promise.get_future();
  service.move_handles_async(f.created.id, f.created.edit_token, twist(120, 1000, 0), {},
                             [&](Result<DeformResult> r) { promise.set_value(std::move(r)); });
  for (int i = 0; i < 6000 && service.stats().solves_running == 0; ++i) {
    std::this_thread::sleep_for(milliseconds(5));
  }
  ASSERT_EQ(service.stats().solves_running, 1u);
  ASSERT_TRUE(service.close_session(f.created.id, f.created.edit_token).ok());
  // The running solve stops (it would take seconds more) and commits nothing.
  ASSERT_EQ(future.wait_for(seconds(120)), std::future_status::ready);
  expect_code(future.get().status(), ErrorCode::NotFound, "closed");
  // Stopped by the close, not run to its end and then dropped.
  EXPECT_EQ(service.stats().moves_cancelled, 1u);
  EXPECT_FALSE((*watch)->try_take().has_value());
  EXPECT_TRUE((*watch)->closed());
  EXPECT_EQ(service.stats().moves_committed, 0u);
}

// --- numbers that cannot give a finite result --------------------------------------------------

TEST(BadNumbersTest, AreInvalidArgumentNamingTheField) {
  ServiceOptions options;
  options.workers = 2;
  DeformationService service(options);
  Fixture f = create_with_handles(service, "cylinder_small");
  auto move_with = [&](auto edit) {
    MoveRequest move = twist(10, 2);
    edit(move);
    return service.move_handles(f.created.id, f.created.edit_token, move).status();
  };
  expect_code(move_with([](MoveRequest& m) { m.moves[0].translation.x() = 1e150; }),
              ErrorCode::InvalidArgument, "moves[0].translation");
  expect_code(move_with([](MoveRequest& m) { m.moves[0].scale = 1e200; }),
              ErrorCode::InvalidArgument, "moves[0].scale");
  expect_code(move_with([](MoveRequest& m) { m.moves[0].scale = 1e-200; }),
              ErrorCode::InvalidArgument, "moves[0].scale");
  expect_code(move_with([](MoveRequest& m) { m.moves[0].pivot = Eigen::Vector3d(1e300, 0, 0); }),
              ErrorCode::InvalidArgument, "moves[0]");
  expect_code(move_with([](MoveRequest& m) {
                m.moves[0].translation.x() = 1e300;
                m.method = core::Method::Arap;
              }),
              ErrorCode::InvalidArgument, "moves[0].translation");
  expect_code(move_with([](MoveRequest& m) {
                m.moves.clear();
                m.targets.push_back(VertexTarget{0, Eigen::Vector3d(0, 0, 1e200)});
              }),
              ErrorCode::InvalidArgument, "targets");
  expect_code(move_with([&](MoveRequest& m) {
                core::MagnifyRegion region;
                region.vertices = Eigen::VectorXi::LinSpaced(40, 100, 139);
                region.scale = 1e300;
                m.magnify.push_back(region);
              }),
              ErrorCode::InvalidArgument, "magnify[0].scale");
  EXPECT_EQ(service.session_info(f.created.id, f.created.view_token)->revision, 0u);

  CreateSessionRequest huge_lambda = sample_request("bar_small");
  huge_lambda.settings.lambda = 1e308;
  expect_code(service.create_session(huge_lambda).status(), ErrorCode::InvalidArgument, "lambda");
  CreateSessionRequest tiny_lambda = sample_request("bar_small");
  tiny_lambda.settings.lambda = 1e-300;
  expect_code(service.create_session(tiny_lambda).status(), ErrorCode::InvalidArgument, "lambda");

  // Far but representable moves still solve, to finite numbers.
  const Result<DeformResult> far =
      service.move_handles(f.created.id, f.created.edit_token, [] {
        MoveRequest m = twist(10, 2);
        m.moves[0].translation.x() = 50;
        return m;
      }());
  ASSERT_TRUE(far.ok()) << message_of(far);
  EXPECT_TRUE(far->positions->allFinite());
  EXPECT_TRUE(std::isfinite(far->e_theta) && std::isfinite(far->e_phi));
}

TEST(BadNumbersTest, GroupMessagesNameTheGroupsRole) {
  ServiceOptions options;
  options.workers = 2;
  DeformationService service(options);
  Result<CreatedSession> created = service.create_session(sample_request("cylinder_small"));
  ASSERT_TRUE(created.ok());
  std::vector<HandleGroup> groups = created->suggested_groups;
  ASSERT_EQ(groups[0].role, HandleRole::Fixed);
  groups[1].vertices.push_back(groups[0].vertices[0]);
  expect_code(service.set_handles(created->id, created->edit_token, {groups}).status(),
              ErrorCode::InvalidArgument, "fixed group 0");
  groups = created->suggested_groups;
  groups[1].vertices.push_back(-1);
  expect_code(service.set_handles(created->id, created->edit_token, {groups}).status(),
              ErrorCode::InvalidArgument, "handle group 1");
}

}  // namespace
}  // namespace meshdeform::service
