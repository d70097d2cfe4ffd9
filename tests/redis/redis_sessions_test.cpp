// Sessions on Redis (issue 16), against a real redis-server started on a loopback port by each
// test (tests/support/redis_process.h) and stopped at its end. In process: two DeformationService
// instances, each with its own RedisStateStore (its own lease owner), stand for two replicas.
// Through the binary: meshdeform-server replicas on the same Redis, one killed with SIGKILL, and
// the startup errors. Skipped (GTEST_SKIP) only when redis-server is not installed. Every loop is
// bounded in count and time; no timing thresholds.
#include <gtest/gtest.h>
#include <grpcpp/grpcpp.h>
#include <signal.h>
#include <sys/wait.h>

#include <atomic>
#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <random>
#include <set>
#include <sstream>
#include <thread>

#include "core/io/mesh_io.h"
#include "meshdeform/v1/deformation.grpc.pb.h"
#include "server/service/deformation_service.h"
#include "server/redis/redis_store.h"
#include "tests/support/grpc_calls.h"
#include "tests/redis/failed_start.h"
#include "tests/support/child_process.h"
#include "tests/support/redis_process.h"
#include "tests/support/server_process.h"

namespace meshdeform {
namespace {

namespace fs = std::filesystem;
using service::DeformationService;
using redis::RedisStateStore;
using std::chrono::milliseconds;
using std::chrono::seconds;
using test::bound;

#define MD_REQUIRE_REDIS()                                                                   \
  do {                                                                                       \
    if (test::RedisProcess::binary().empty()) {                                              \
      GTEST_SKIP() << "redis-server is not installed (scripts/install-deps.sh installs it)"; \
    }                                                                                        \
  } while (false)

std::unique_ptr<test::RedisProcess> start_redis(const test::RedisOptions& options = {}) {
  std::string error;
  auto redis = test::RedisProcess::start(options, error);
  EXPECT_NE(redis, nullptr) << error;
  return redis;
}

std::shared_ptr<RedisStateStore> connect_store(const test::RedisProcess& redis,
                                               int log_length = 32) {
  Result<redis::RedisConfig> config = redis::parse_redis_url(redis.url());
  EXPECT_TRUE(config.ok()) << config.status().to_string();
  if (!config.ok()) return nullptr;
  config->log_length = log_length;
  Result<std::unique_ptr<RedisStateStore>> store = RedisStateStore::connect(*config);
  EXPECT_TRUE(store.ok()) << store.status().to_string();
  if (!store.ok()) return nullptr;
  return std::shared_ptr<RedisStateStore>(std::move(store).value());
}

service::ServiceOptions replica_options() {
  service::ServiceOptions options;
  options.workers = 2;
  options.refine_budget = 0;  // only the moves commit revisions
  return options;
}

/// A replica: a service on its own connection pool and lease owner id.
struct Replica {
  explicit Replica(const test::RedisProcess& redis, int log_length = 32)
      : store(connect_store(redis, log_length)), service(replica_options(), store) {}
  std::shared_ptr<RedisStateStore> store;
  DeformationService service;
};

service::MoveRequest lift(double z) {
  service::MoveRequest move;
  service::GroupMove g;
  g.group = 1;
  g.translation = Eigen::Vector3d(0.0, 0.0, z);
  move.moves.push_back(g);
  move.max_iterations = 1;
  return move;
}

service::CreatedSession create_with_handles(DeformationService& service) {
  service::CreateSessionRequest request;
  request.sample = "cylinder_small";
  Result<service::CreatedSession> created = service.create_session(request);
  EXPECT_TRUE(created.ok()) << created.status().to_string();
  if (!created.ok()) return {};
  service::SetHandlesRequest handles;
  handles.groups = created->suggested_groups;
  const Result<service::SessionInfo> set =
      service.set_handles(created->id, created->edit_token, handles);
  EXPECT_TRUE(set.ok()) << set.status().to_string();
  return *created;
}

// --- The store itself --------------------------------------------------------------------------

TEST(RedisStoreTest, UrlParsingTakesTlsAndRefusesPasswords) {
  Result<redis::RedisConfig> plain = redis::parse_redis_url("redis://db.internal:6380/3");
  ASSERT_TRUE(plain.ok()) << plain.status().to_string();
  EXPECT_EQ(plain->host, "db.internal");
  EXPECT_EQ(plain->port, 6380);
  EXPECT_EQ(plain->database, 3);
  Result<redis::RedisConfig> user = redis::parse_redis_url("redis://editor@10.0.0.5");
  ASSERT_TRUE(user.ok());
  EXPECT_EQ(user->username, "editor");
  EXPECT_EQ(user->port, 6379);
  EXPECT_FALSE(plain->tls);
  // rediss://: TLS (redis_tls_test.cpp connects through it).
  const Result<redis::RedisConfig> tls = redis::parse_redis_url("rediss://editor@db:6380/2");
  ASSERT_TRUE(tls.ok()) << tls.status().to_string();
  EXPECT_TRUE(tls->tls);
  EXPECT_EQ(tls->host, "db");
  EXPECT_EQ(tls->port, 6380);
  EXPECT_EQ(tls->database, 2);
  EXPECT_EQ(tls->username, "editor");
  EXPECT_FALSE(redis::parse_redis_url("rediss://u:secret@db").ok());
  const Result<redis::RedisConfig> secret = redis::parse_redis_url("redis://u:secret@db");
  ASSERT_FALSE(secret.ok());
  EXPECT_EQ(secret.status().message().find("secret"), std::string::npos);
  EXPECT_FALSE(redis::parse_redis_url("http://db").ok());
  EXPECT_FALSE(redis::parse_redis_url("redis://db:99999").ok());
}

TEST(RedisStoreTest, CommitIsACompareAndSetOnTheVersionFromTheLeaseHolder) {
  MD_REQUIRE_REDIS();
  auto redis = start_redis();
  ASSERT_NE(redis, nullptr);
  auto a = connect_store(*redis), b = connect_store(*redis);
  ASSERT_TRUE(a && b);
  Replica creator(*redis);
  const service::CreatedSession created = create_with_handles(creator.service);
  ASSERT_FALSE(created.id.value.empty());

  Result<service::SharedState> loaded = a->load(created.id);
  ASSERT_TRUE(loaded.ok()) << loaded.status().to_string();
  const std::uint64_t version = loaded->version;
  EXPECT_EQ(version, 1u);  // the handle change
  service::PersistedSession next = loaded->state;
  next.revision = 1;
  service::SharedLogEntry entry;
  auto result = std::make_shared<service::DeformResult>();
  result->positions = std::make_shared<const Positions>(next.positions);
  entry.result = result;
  entry.targets = next.targets;

  // Without the lease: refused, nothing written.
  Status refused = a->commit(next, version, entry);
  EXPECT_EQ(refused.code(), ErrorCode::Aborted) << refused.to_string();
  EXPECT_NE(refused.message().find("revision 0 is current"), std::string::npos)
      << refused.message();
  // b holds the lease: a waits a bounded time and is told when it ends.
  ASSERT_TRUE(b->acquire_lease(created.id, milliseconds(0)).ok());
  const Status busy = a->acquire_lease(created.id, milliseconds(50));
  EXPECT_EQ(busy.code(), ErrorCode::Aborted) << busy.to_string();
  EXPECT_NE(busy.message().find("another replica (revision 0 is current"), std::string::npos)
      << busy.message();
  // The holder commits version + 1; the same base version again loses and names revision 1.
  ASSERT_TRUE(b->commit(next, version, entry).ok());
  const Status stale = b->commit(next, version, entry);
  EXPECT_EQ(stale.code(), ErrorCode::Aborted);
  EXPECT_NE(stale.message().find("revision 1 is current"), std::string::npos) << stale.message();
  Result<std::optional<std::uint64_t>> now = a->version(created.id);
  ASSERT_TRUE(now.ok());
  EXPECT_EQ(now->value_or(0), version + 1);
  // The log holds the write, in version order.
  Result<std::vector<service::SharedLogEntry>> log = a->read_log(created.id, version, 10);
  ASSERT_TRUE(log.ok()) << log.status().to_string();
  ASSERT_EQ(log->size(), 1u);
  EXPECT_EQ((*log)[0].version, version + 1);
  EXPECT_EQ((*log)[0].revision, 1u);
  ASSERT_TRUE((*log)[0].result);
  EXPECT_EQ(*(*log)[0].result->positions, next.positions);
  // Released, the lease is free for a.
  b->release_lease(created.id);
  EXPECT_TRUE(a->acquire_lease(created.id, milliseconds(0)).ok());
  a->release_lease(created.id);
}

TEST(RedisStoreTest, TheLeaseOfADeadReplicaRunsOutAndALiveOneIsRenewed) {
  MD_REQUIRE_REDIS();
  auto redis = start_redis();
  ASSERT_NE(redis, nullptr);
  Result<redis::RedisConfig> config = redis::parse_redis_url(redis->url());
  ASSERT_TRUE(config.ok());
  config->lease = milliseconds(1000);
  const service::SessionId id{std::string(32, 'b')};
  Result<std::unique_ptr<RedisStateStore>> alive = RedisStateStore::connect(*config);
  Result<std::unique_ptr<RedisStateStore>> other = RedisStateStore::connect(*config);
  ASSERT_TRUE(alive.ok() && other.ok());
  // A live holder renews its lease (every lease/3) for as long as it holds it: several lease
  // durations later another replica still cannot take it.
  ASSERT_TRUE((*alive)->acquire_lease(id, milliseconds(0)).ok());
  std::this_thread::sleep_for(milliseconds(2500));
  EXPECT_EQ((*other)->acquire_lease(id, milliseconds(0)).code(), ErrorCode::Aborted);
  // The holder dies without giving it back (its renewer stops): the lease runs out and the
  // other replica, waiting, takes it.
  alive->reset();
  const Status taken = (*other)->acquire_lease(id, milliseconds(10'000));
  EXPECT_TRUE(taken.ok()) << taken.to_string();
  (*other)->release_lease(id);
}

TEST(RedisStoreTest, PooledConnectionsSurviveARedisRestart) {
  MD_REQUIRE_REDIS();
  auto redis = start_redis();
  ASSERT_NE(redis, nullptr);
  auto store = connect_store(*redis);
  ASSERT_TRUE(store);
  const service::SessionId unknown{std::string(32, 'a')};
  Result<std::optional<std::uint64_t>> before = store->version(unknown);
  ASSERT_TRUE(before.ok()) << before.status().to_string();
  EXPECT_FALSE(before->has_value());
  // The pooled connection now points at a dead server; a new one listens on the same port.
  ASSERT_TRUE(redis->stop(SIGKILL));
  test::RedisOptions same;
  same.dir = redis->dir();
  same.port = redis->port();
  auto restarted = start_redis(same);
  ASSERT_NE(restarted, nullptr);
  Result<std::optional<std::uint64_t>> after = store->version(unknown);
  EXPECT_TRUE(after.ok()) << after.status().to_string();
  EXPECT_TRUE(store->acquire_lease(unknown, milliseconds(0)).ok());
  store->release_lease(unknown);
}

// --- Two replicas -------------------------------------------------------------------------------

TEST(RedisReplicasTest, RacingReplicasGiveOneWinnerPerRevisionAndLoseNothing) {
  MD_REQUIRE_REDIS();
  auto redis = start_redis();
  ASSERT_NE(redis, nullptr);
  Replica a(*redis), b(*redis);
  const service::CreatedSession created = create_with_handles(a.service);
  ASSERT_FALSE(created.id.value.empty());

  constexpr int kMovesEach = 100;  // 200 commits raced for in all
  struct Acked {
    std::uint64_t revision;
    Positions positions;
  };
  std::mutex mutex;
  std::vector<Acked> acked;
  std::atomic<int> aborted{0}, other_errors{0}, won_by_a{0}, won_by_b{0};
  std::string first_error;
  auto editor = [&](DeformationService& service, double sign, std::atomic<int>& won) {
    for (int i = 1; i <= kMovesEach; ++i) {
      Result<service::DeformResult> moved =
          service.move_handles(created.id, created.edit_token, lift(sign * 0.001 * i));
      const std::lock_guard lock(mutex);
      if (moved.ok()) {
        acked.push_back({moved->revision, *moved->positions});
        won.fetch_add(1);
      } else if (moved.status().code() == ErrorCode::Aborted) {
        aborted.fetch_add(1);
      } else {
        other_errors.fetch_add(1);
        if (first_error.empty()) first_error = moved.status().to_string();
      }
    }
  };
  {
    std::jthread ta([&] { editor(a.service, 1.0, won_by_a); });
    std::jthread tb([&] { editor(b.service, -1.0, won_by_b); });
  }
  EXPECT_EQ(other_errors.load(), 0) << first_error;
  // Both replicas really edited the one session (each catching up with the other's revisions
  // before its own commit), not one replica always refused.
  EXPECT_GT(won_by_a.load(), 0);
  EXPECT_GT(won_by_b.load(), 0);
  RecordProperty("won_by_a", won_by_a.load());
  RecordProperty("won_by_b", won_by_b.load());
  RecordProperty("aborted", aborted.load());
  ASSERT_FALSE(acked.empty());
  // Exactly one acknowledged commit per revision, and the revisions are 1..R without a hole.
  std::map<std::uint64_t, const Acked*> by_revision;
  for (const Acked& a_commit : acked) {
    EXPECT_TRUE(by_revision.emplace(a_commit.revision, &a_commit).second)
        << "revision " << a_commit.revision << " acknowledged twice";
  }
  const std::uint64_t last = by_revision.rbegin()->first;
  EXPECT_EQ(by_revision.size(), last);
  EXPECT_EQ(acked.size() + static_cast<std::size_t>(aborted.load()), 2u * kMovesEach);
  // A third replica loads the newest acknowledged revision exactly.
  Replica c(*redis);
  Result<service::SessionInfo> info = c.service.session_info(created.id, created.view_token);
  ASSERT_TRUE(info.ok()) << info.status().to_string();
  EXPECT_EQ(info->revision, last);
  Result<std::string> mesh = c.service.get_mesh(created.id, created.view_token, io::MeshFormat::Obj);
  ASSERT_TRUE(mesh.ok());
  Result<io::LoadedMesh> parsed = io::load_mesh_from_memory(*mesh, io::MeshFormat::Obj);
  ASSERT_TRUE(parsed.ok());
  EXPECT_TRUE(parsed->mesh.V.isApprox(by_revision[last]->positions, 1e-12));
  // Both replicas agree on it too (each catches up on its next call).
  for (DeformationService* service : {&a.service, &b.service}) {
    Result<service::SessionInfo> seen = service->session_info(created.id, created.view_token);
    ASSERT_TRUE(seen.ok());
    EXPECT_EQ(seen->revision, last);
  }
}

TEST(RedisReplicasTest, RoundRobinOverThreeReplicasIsCorrect) {
  // What nginx round robin does to one client's calls: each goes to the next replica. Every call
  // must see the previous one's effect (revisions consecutive, handles set elsewhere honoured).
  MD_REQUIRE_REDIS();
  auto redis = start_redis();
  ASSERT_NE(redis, nullptr);
  Replica r0(*redis), r1(*redis), r2(*redis);
  DeformationService* replicas[] = {&r0.service, &r1.service, &r2.service};
  const service::CreatedSession created = create_with_handles(r0.service);
  ASSERT_FALSE(created.id.value.empty());
  std::uint64_t expected = 0;
  Positions last;
  for (int i = 0; i < 60; ++i) {
    DeformationService& service = *replicas[i % 3];
    if (i == 30) {
      // New handles through one replica (a handle change: the others reload the whole state):
      // the handle group alone, anchored where the drag left it.
      service::SetHandlesRequest handles;
      handles.groups = created.suggested_groups;
      Result<service::SessionInfo> set =
          service.set_handles(created.id, created.edit_token, handles);
      ASSERT_TRUE(set.ok()) << set.status().to_string();
      EXPECT_EQ(set->revision, expected);
      continue;
    }
    Result<service::DeformResult> moved =
        service.move_handles(created.id, created.edit_token, lift(0.002 * (i % 30 + 1)));
    ASSERT_TRUE(moved.ok()) << "call " << i << ": " << moved.status().to_string();
    EXPECT_EQ(moved->revision, ++expected) << "call " << i;
    last = *moved->positions;
  }
  for (DeformationService* service : replicas) {
    Result<service::SessionInfo> info = service->session_info(created.id, created.view_token);
    ASSERT_TRUE(info.ok());
    EXPECT_EQ(info->revision, expected);
    Result<std::string> mesh = service->get_mesh(created.id, created.view_token, io::MeshFormat::Obj);
    ASSERT_TRUE(mesh.ok());
    Result<io::LoadedMesh> parsed = io::load_mesh_from_memory(*mesh, io::MeshFormat::Obj);
    ASSERT_TRUE(parsed.ok());
    EXPECT_TRUE(parsed->mesh.V.isApprox(last, 1e-12));
  }
}

TEST(RedisReplicasTest, AReplicaBehindTheTrimmedLogLoadsTheWholeState) {
  MD_REQUIRE_REDIS();
  auto redis = start_redis();
  ASSERT_NE(redis, nullptr);
  constexpr int kLog = 4;  // the log keeps the newest 4 revisions only
  Replica a(*redis, kLog), b(*redis, kLog);
  const service::CreatedSession created = create_with_handles(a.service);
  ASSERT_FALSE(created.id.value.empty());
  Result<service::SessionInfo> loaded = b.service.session_info(created.id, created.view_token);
  ASSERT_TRUE(loaded.ok()) << loaded.status().to_string();
  EXPECT_EQ(loaded->revision, 0u);
  Result<service::DeformResult> moved = Error(ErrorCode::Internal, "no move yet");
  for (int i = 1; i <= 3 * kLog; ++i) {
    moved = a.service.move_handles(created.id, created.edit_token, lift(0.002 * i));
    ASSERT_TRUE(moved.ok()) << moved.status().to_string();
  }
  Result<service::SessionInfo> caught_up = b.service.session_info(created.id, created.view_token);
  ASSERT_TRUE(caught_up.ok()) << caught_up.status().to_string();
  EXPECT_EQ(caught_up->revision, moved->revision);
  Result<std::string> mesh = b.service.get_mesh(created.id, created.view_token, io::MeshFormat::Obj);
  ASSERT_TRUE(mesh.ok());
  Result<io::LoadedMesh> parsed = io::load_mesh_from_memory(*mesh, io::MeshFormat::Obj);
  ASSERT_TRUE(parsed.ok());
  EXPECT_TRUE(parsed->mesh.V.isApprox(*moved->positions, 1e-12));
  // And B edits on from there.
  Result<service::DeformResult> next =
      b.service.move_handles(created.id, created.edit_token, lift(0.05));
  ASSERT_TRUE(next.ok()) << next.status().to_string();
  EXPECT_EQ(next->revision, moved->revision + 1);
  // The log really is trimmed to kLog entries.
  Result<std::vector<service::SharedLogEntry>> log = a.store->read_log(created.id, 0, 100);
  ASSERT_TRUE(log.ok()) << log.status().to_string();
  EXPECT_EQ(log->size(), static_cast<std::size_t>(kLog));
}

// Issue 17: the settings and the undo history travel with the session between replicas, both
// through the log (B replays A's commits) and through the whole state (a trimmed log).
TEST(RedisReplicasTest, SettingsAndUndoHistoryAreSharedByTheReplicas) {
  MD_REQUIRE_REDIS();
  auto redis = start_redis();
  ASSERT_NE(redis, nullptr);
  Replica a(*redis), b(*redis);
  const service::CreatedSession created = create_with_handles(a.service);
  ASSERT_FALSE(created.id.value.empty());
  const auto& id = created.id;
  const auto& token = created.edit_token;
  service::MoveRequest first = lift(0.1);
  first.max_iterations = 3;
  first.rigidity = 10;
  ASSERT_TRUE(a.service.move_handles(id, token, first).ok());
  ASSERT_TRUE(a.service.move_handles(id, token, lift(0.2)).ok());
  service::MoveRequest undo;
  undo.history = service::HistoryAction::Undo;
  undo.max_iterations = 3;
  undo.rigidity = 10;
  ASSERT_TRUE(a.service.move_handles(id, token, undo).ok());

  Result<service::SessionInfo> on_b = b.service.session_info(id, created.view_token);
  ASSERT_TRUE(on_b.ok()) << on_b.status().to_string();
  ASSERT_EQ(on_b->edit.steps.size(), 3u);
  EXPECT_EQ(on_b->edit.position, 1);
  ASSERT_TRUE(on_b->edit.settings.has_value());
  EXPECT_EQ(on_b->edit.settings->max_iterations, 3);
  EXPECT_EQ(on_b->edit.settings->rigidity, 10);
  // B continues A's history; A sees it through the log.
  service::MoveRequest redo = undo;
  redo.history = service::HistoryAction::Redo;
  ASSERT_TRUE(b.service.move_handles(id, token, redo).ok());
  Result<service::SessionInfo> on_a = a.service.session_info(id, created.view_token);
  ASSERT_TRUE(on_a.ok());
  EXPECT_EQ(on_a->edit.position, 2);
  EXPECT_EQ(on_a->edit.steps[2].moves[0].translation.z(), 0.2);
  // A replica that loads the whole state (no log to replay) gets the same.
  Replica c(*redis);
  Result<service::SessionInfo> on_c = c.service.session_info(id, created.view_token);
  ASSERT_TRUE(on_c.ok()) << on_c.status().to_string();
  EXPECT_EQ(on_c->edit.position, 2);
  EXPECT_EQ(on_c->edit.steps.size(), 3u);
  EXPECT_EQ(on_c->edit.settings->rigidity, 10);
}

TEST(RedisReplicasTest, WatcherOnReplicaBSeesEveryRevisionCommittedThroughA) {
  MD_REQUIRE_REDIS();
  auto redis = start_redis();
  ASSERT_NE(redis, nullptr);
  Replica a(*redis), b(*redis);
  const service::CreatedSession created = create_with_handles(a.service);
  ASSERT_FALSE(created.id.value.empty());
  Result<service::Subscription> watch = b.service.watch(created.id, created.view_token);
  ASSERT_TRUE(watch.ok()) << watch.status().to_string();
  std::optional<service::DeformUpdate> joined = (*watch)->wait_take(milliseconds(10'000));
  ASSERT_TRUE(joined.has_value());
  EXPECT_TRUE(joined->is_snapshot);
  EXPECT_EQ(joined->result->revision, 0u);

  // Step by step: each revision arrives on B, in order, as an update (not a snapshot), with A's
  // positions and a changed list that takes B from the previous revision to this one.
  Positions seen = *joined->result->positions;
  constexpr int kSteps = 40;
  for (int i = 1; i <= kSteps; ++i) {
    Result<service::DeformResult> moved =
        a.service.move_handles(created.id, created.edit_token, lift(0.002 * i));
    ASSERT_TRUE(moved.ok()) << moved.status().to_string();
    std::optional<service::DeformUpdate> update;
    for (int tries = 0; tries < 100 && !update; ++tries) {  // at most ~100 s
      update = (*watch)->wait_take(milliseconds(1000));
    }
    ASSERT_TRUE(update.has_value()) << "revision " << moved->revision << " never reached B";
    EXPECT_EQ(update->result->revision, moved->revision);
    EXPECT_EQ(update->result->revision, static_cast<std::uint64_t>(i));
    EXPECT_FALSE(update->is_snapshot);
    EXPECT_EQ(update->skipped_revisions, 0u);
    for (std::size_t j = 0; j < update->result->changed.size(); ++j) {
      seen.row(update->result->changed[j]) =
          update->result->changed_positions.row(static_cast<Eigen::Index>(j));
    }
    EXPECT_EQ(seen, *moved->positions) << "at revision " << i;
  }
  // A burst: every revision is delivered or counted as skipped, in increasing order.
  constexpr int kBurst = 30;
  std::uint64_t final_revision = 0;
  for (int i = 1; i <= kBurst; ++i) {
    Result<service::DeformResult> moved =
        a.service.move_handles(created.id, created.edit_token, lift(-0.002 * i));
    ASSERT_TRUE(moved.ok()) << moved.status().to_string();
    final_revision = moved->revision;
  }
  std::uint64_t newest = kSteps, accounted = 0;
  for (int tries = 0; tries < 200 && newest < final_revision; ++tries) {
    std::optional<service::DeformUpdate> update = (*watch)->wait_take(milliseconds(500));
    if (!update) continue;
    EXPECT_GT(update->result->revision, newest);
    EXPECT_EQ(update->result->revision, newest + 1 + update->skipped_revisions);
    accounted += 1 + update->skipped_revisions;
    newest = update->result->revision;
  }
  EXPECT_EQ(newest, final_revision);
  EXPECT_EQ(accounted, static_cast<std::uint64_t>(kBurst));
  // Closing through A ends the watch on B.
  ASSERT_TRUE(a.service.close_session(created.id, created.edit_token).ok());
  for (int tries = 0; tries < 100 && !(*watch)->closed(); ++tries) {
    (void)(*watch)->wait_take(milliseconds(100));
  }
  EXPECT_TRUE((*watch)->closed());
  EXPECT_EQ(b.service.session_info(created.id, created.view_token).status().code(),
            ErrorCode::NotFound);
}

TEST(RedisReplicasTest, NothingIsAcknowledgedThatRedisDidNotTakeAndAppendonlyKeepsIt) {
  MD_REQUIRE_REDIS();
  auto redis = start_redis();  // appendonly yes, appendfsync always
  ASSERT_NE(redis, nullptr);
  const int port = redis->port();
  const std::string dir = redis->dir();
  std::uint64_t acked_revision = 0;
  Positions acked_positions;
  Replica a(*redis);
  const service::CreatedSession created = create_with_handles(a.service);
  ASSERT_FALSE(created.id.value.empty());
  for (int i = 1; i <= 20; ++i) {
    Result<service::DeformResult> moved =
        a.service.move_handles(created.id, created.edit_token, lift(0.003 * i));
    ASSERT_TRUE(moved.ok()) << moved.status().to_string();
    acked_revision = moved->revision;
    acked_positions = *moved->positions;
  }
  // Redis crashes: the next edit fails and the replica's copy does not move on.
  ASSERT_TRUE(redis->stop(SIGKILL));
  Result<service::DeformResult> refused =
      a.service.move_handles(created.id, created.edit_token, lift(0.5));
  ASSERT_FALSE(refused.ok());
  // Not the caller's fault and maybe not for long: UNAVAILABLE, which clients may retry.
  EXPECT_EQ(refused.status().code(), ErrorCode::Unavailable) << refused.status().to_string();
  EXPECT_NE(refused.status().message().find("redis"), std::string::npos)
      << refused.status().to_string();

  // Restarted on its append-only file: every acknowledged revision is there, for a new replica.
  test::RedisOptions same;
  same.dir = dir;
  same.port = port;
  auto restarted = start_redis(same);
  ASSERT_NE(restarted, nullptr);
  Replica b(*restarted);
  Result<service::SessionInfo> info = b.service.session_info(created.id, created.view_token);
  ASSERT_TRUE(info.ok()) << info.status().to_string();
  EXPECT_EQ(info->revision, acked_revision);
  Result<std::string> mesh = b.service.get_mesh(created.id, created.view_token, io::MeshFormat::Obj);
  ASSERT_TRUE(mesh.ok());
  Result<io::LoadedMesh> parsed = io::load_mesh_from_memory(*mesh, io::MeshFormat::Obj);
  ASSERT_TRUE(parsed.ok());
  EXPECT_TRUE(parsed->mesh.V.isApprox(acked_positions, 1e-12));
  // The replica that lived through the outage edits again at once: its pooled connections to
  // the dead server are dropped, not failed on, and its copy was not ahead of Redis.
  Result<service::DeformResult> next =
      a.service.move_handles(created.id, created.edit_token, lift(0.1));
  ASSERT_TRUE(next.ok()) << next.status().to_string();
  EXPECT_EQ(next->revision, acked_revision + 1);
  Result<service::SessionInfo> after = b.service.session_info(created.id, created.view_token);
  ASSERT_TRUE(after.ok()) << after.status().to_string();
  EXPECT_EQ(after->revision, acked_revision + 1);
}

// --- Through the binary -------------------------------------------------------------------------

std::unique_ptr<v1::DeformationService::Stub> connect(const test::ServerProcess& server) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  return v1::DeformationService::NewStub(
      grpc::CreateCustomChannel(server.address(), grpc::InsecureChannelCredentials(), args));
}

using test::failed_start;

void expect_startup_error(const std::pair<std::optional<int>, std::string>& run,
                          const std::string& fragment) {
  ASSERT_TRUE(run.first.has_value()) << "the server did not stop at startup:\n" << run.second;
  ASSERT_TRUE(WIFEXITED(*run.first));
  EXPECT_EQ(WEXITSTATUS(*run.first), 2) << run.second;
  EXPECT_NE(run.second.find("redis_unusable"), std::string::npos) << run.second;
  EXPECT_NE(run.second.find(fragment), std::string::npos) << run.second;
  EXPECT_EQ(run.second.find("\"listening\""), std::string::npos) << run.second;
}

TEST(RedisServerTest, StartupErrorsAreClear) {
  MD_REQUIRE_REDIS();
  test::RedisOptions protected_redis;
  protected_redis.password = "correct horse";
  auto redis = start_redis(protected_redis);
  ASSERT_NE(redis, nullptr);
  std::random_device random;
  const std::string password_file =
      (fs::temp_directory_path() / ("meshdeform-redis-pw-" + std::to_string(random()))).string();
  {
    std::ofstream(password_file) << "wrong battery\n";
  }
  // Unreachable: nothing listens on a port that was just free.
  const int closed = test::free_loopback_port();
  expect_startup_error(
      failed_start({"--redis", "redis://127.0.0.1:" + std::to_string(closed)}), "unreachable");
  // Wrong password, from the file and from the environment.
  expect_startup_error(failed_start({"--redis", redis->url(), "--redis-password-file",
                                     password_file}),
                       "refused the password");
  expect_startup_error(
      failed_start({"--redis", redis->url()}, {"MESHDEFORM_REDIS_PASSWORD=not it"}),
      "refused the password");
  // No password for a server that wants one.
  expect_startup_error(failed_start({"--redis", redis->url()}), "NOAUTH");
  // TLS to a closed port is unreachable (redis_tls_test.cpp covers a bad certificate); a
  // password in the URL is refused before connecting.
  expect_startup_error(
      failed_start({"--redis", "rediss://127.0.0.1:" + std::to_string(closed)}), "unreachable");
  expect_startup_error(failed_start({"--redis", "redis://u:pw@127.0.0.1:6380"}),
                       "redis-password-file");
  // The right password starts it.
  {
    std::ofstream(password_file) << "correct horse\n";
  }
  std::string error;
  auto server = test::ServerProcess::start(
      MESHDEFORM_SERVER_PATH, {"--redis", redis->url(), "--redis-password-file", password_file},
      error);
  EXPECT_NE(server, nullptr) << error;
  std::error_code ignored;
  fs::remove(password_file, ignored);
}

TEST(RedisServerTest, Kill9OfTheOwningReplicaMovesTheSessionWithEveryAcknowledgedRevision) {
  MD_REQUIRE_REDIS();
  auto redis = start_redis();
  ASSERT_NE(redis, nullptr);
  const std::vector<std::string> flags = {"--redis", redis->url(), "--redis-lease-ms", "1000",
                                          "--refine-budget", "0"};
  std::string error;
  auto owner = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
  ASSERT_NE(owner, nullptr) << error;
  auto other = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
  ASSERT_NE(other, nullptr) << error;
  auto stub = connect(*owner);

  v1::CreateSessionResponse created;
  ASSERT_TRUE(test::create_sample_with_handles(*stub, "cylinder_small", &created).ok());
  // A watcher on the other replica, from the start.
  auto other_stub = connect(*other);
  grpc::ClientContext watch_context;
  bound(watch_context, seconds(120));
  v1::WatchRequest watch_request;
  watch_request.set_session_id(created.session_id());
  watch_request.set_token(created.view_token());
  std::unique_ptr<grpc::ClientReader<v1::DeformUpdate>> watch =
      other_stub->Watch(&watch_context, watch_request);

  // The drag: moves through the owner until it dies (at most 400).
  std::atomic<std::uint64_t> acked_revision{0};
  std::mutex mutex;
  std::vector<double> acked_positions;
  std::atomic<int> acked_moves{0};
  std::jthread editor([&] {
    for (int i = 1; i <= 400; ++i) {
      const v1::MoveHandlesRequest move =
          test::lift_move(created.session_id(), created.edit_token(), i);
      v1::MoveHandlesResponse response;
      grpc::ClientContext context;
      bound(context, seconds(10));
      if (!stub->MoveHandles(&context, move, &response).ok()) return;  // the owner is gone
      {
        const std::lock_guard lock(mutex);
        acked_positions.assign(response.result().positions().begin(),
                               response.result().positions().end());
        acked_revision.store(response.result().revision());
      }
      acked_moves.fetch_add(1);
    }
  });
  for (int i = 0; i < 3000 && acked_moves.load() < 10; ++i) {
    std::this_thread::sleep_for(milliseconds(10));
  }
  const std::optional<int> killed = owner->stop(SIGKILL, seconds(20));
  editor.join();
  ASSERT_TRUE(killed.has_value());
  EXPECT_TRUE(WIFSIGNALED(*killed));
  ASSERT_GE(acked_moves.load(), 10);

  // The other replica serves it: nothing acknowledged is missing (a move in flight at the kill
  // may have been stored without its answer arriving).
  v1::GetSessionInfoRequest info_request;
  info_request.set_session_id(created.session_id());
  info_request.set_token(created.view_token());
  v1::GetSessionInfoResponse info;
  {
    grpc::ClientContext context;
    bound(context);
    const grpc::Status status = other_stub->GetSessionInfo(&context, info_request, &info);
    ASSERT_TRUE(status.ok()) << status.error_message() << "\n" << other->log();
  }
  const std::uint64_t acked = acked_revision.load();
  EXPECT_GE(info.info().revision(), acked);
  EXPECT_LE(info.info().revision(), acked + 1);
  if (info.info().revision() == acked) {
    v1::GetMeshRequest mesh_request;
    mesh_request.set_session_id(created.session_id());
    mesh_request.set_token(created.view_token());
    mesh_request.set_format(v1::MESH_FORMAT_OBJ);
    v1::GetMeshResponse mesh;
    grpc::ClientContext context;
    bound(context);
    ASSERT_TRUE(other_stub->GetMesh(&context, mesh_request, &mesh).ok());
    Result<io::LoadedMesh> loaded =
        io::load_mesh_from_memory(mesh.mesh_bytes(), io::MeshFormat::Obj);
    ASSERT_TRUE(loaded.ok());
    const std::lock_guard lock(mutex);
    ASSERT_EQ(static_cast<std::size_t>(loaded->mesh.V.size()), acked_positions.size());
    for (Eigen::Index v = 0; v < loaded->mesh.V.rows(); ++v)
      for (int c = 0; c < 3; ++c)
        EXPECT_EQ(loaded->mesh.V(v, c), acked_positions[static_cast<std::size_t>(3 * v + c)]);
  }
  // Editing goes on there once the dead owner's lease ran out (the call waits for it).
  std::uint64_t continued = 0;
  {
    v1::MoveHandlesRequest move;
    move.set_session_id(created.session_id());
    move.set_token(created.edit_token());
    move.add_moves()->set_group(1);
    v1::MoveHandlesResponse response;
    grpc::ClientContext context;
    bound(context, seconds(60));
    const grpc::Status status = other_stub->MoveHandles(&context, move, &response);
    ASSERT_TRUE(status.ok()) << status.error_message() << "\n" << other->log();
    continued = response.result().revision();
    EXPECT_EQ(continued, info.info().revision() + 1);
  }
  // The watcher on the surviving replica saw the owner's revisions in order, up to the new one.
  std::uint64_t newest = 0;
  v1::DeformUpdate update;
  for (int i = 0; i < 2000 && newest < continued && watch->Read(&update); ++i) {
    if (!update.has_result()) continue;
    const std::uint64_t revision = update.result().revision();
    EXPECT_GE(revision, newest) << "revisions went back";
    newest = revision;
  }
  EXPECT_EQ(newest, continued);
  watch_context.TryCancel();
}

}  // namespace
}  // namespace meshdeform
