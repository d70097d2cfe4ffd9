// Sessions on Redis over TLS (rediss://, issue 16): a real redis-server serving only TLS on a
// loopback port, with a self-signed certificate made by the openssl CLI at test time. Debian 12's
// hiredis 0.14 has no TLS, so these check the store's own OpenSSL bridge: two replicas on
// rediss:// share a session, a certificate that does not chain to the CA or does not name the
// host is refused at connect with UNAVAILABLE, and the server binary stops at startup on it.
// Skipped (GTEST_SKIP) when redis-server or the openssl CLI is not installed. Every wait is
// bounded.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <thread>

#include "core/io/mesh_io.h"
#include "server/service/deformation_service.h"
#include "server/redis/redis_store.h"
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

/// A self-signed certificate (also its own CA) `<name>_cert.pem` / `<name>_key.pem` in `dir`,
/// naming `san` (an openssl subjectAltName value), as tests/client/tls_test.cpp makes them.
bool make_certificate(const fs::path& dir, const std::string& name, const std::string& san) {
  const fs::path key = dir / (name + "_key.pem");
  const fs::path cert = dir / (name + "_cert.pem");
  const std::string command = "openssl req -x509 -newkey rsa:2048 -nodes -days 2 -subj /CN=" +
                              name + " -addext subjectAltName=" + san + " -keyout '" +
                              key.string() + "' -out '" + cert.string() + "' >/dev/null 2>&1";
  std::error_code ec;
  return std::system(command.c_str()) == 0 && fs::file_size(cert, ec) > 0 &&
         fs::file_size(key, ec) > 0;
}

bool have_openssl_cli() { return std::system("openssl version >/dev/null 2>&1") == 0; }

/// A temporary directory with the certificates: `server` (names localhost and 127.0.0.1),
/// `other` (an unrelated self-signed certificate, the wrong CA) and `misnamed` (names only
/// redis.invalid).
class TlsRedisTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (test::RedisProcess::binary().empty()) {
      GTEST_SKIP() << "redis-server is not installed (scripts/install-deps.sh installs it)";
    }
    if (!have_openssl_cli()) GTEST_SKIP() << "the openssl CLI is not installed (Debian: openssl)";
    std::random_device random;
    dir_ = fs::temp_directory_path() /
           ("meshdeform-redis-tls-" + std::to_string(random()) + std::to_string(random()));
    fs::create_directories(dir_);
    ASSERT_TRUE(make_certificate(dir_, "server", "DNS:localhost,IP:127.0.0.1"));
    ASSERT_TRUE(make_certificate(dir_, "other", "DNS:localhost,IP:127.0.0.1"));
    ASSERT_TRUE(make_certificate(dir_, "misnamed", "DNS:redis.invalid"));
  }
  void TearDown() override {
    std::error_code ignored;
    if (!dir_.empty()) fs::remove_all(dir_, ignored);
  }

  std::string cert(const std::string& name) const { return (dir_ / (name + "_cert.pem")).string(); }

  /// redis-server serving TLS only, with certificate `name`.
  std::unique_ptr<test::RedisProcess> start_tls_redis(const std::string& name) {
    test::RedisOptions options;
    options.tls_cert_file = cert(name);
    options.tls_key_file = (dir_ / (name + "_key.pem")).string();
    std::string error;
    auto redis = test::RedisProcess::start(options, error);
    EXPECT_NE(redis, nullptr) << error;
    return redis;
  }

  /// Connects a store to `url` trusting `ca`.
  static Result<std::unique_ptr<RedisStateStore>> connect(const std::string& url,
                                                          const std::string& ca) {
    Result<redis::RedisConfig> config = redis::parse_redis_url(url);
    if (!config.ok()) return config.status();
    config->tls_ca_file = ca;
    return RedisStateStore::connect(*config);
  }

  fs::path dir_;
};

service::ServiceOptions replica_options() {
  service::ServiceOptions options;
  options.workers = 2;
  options.refine_budget = 0;  // only the moves commit revisions
  return options;
}

TEST_F(TlsRedisTest, TwoReplicasOnRedissShareASession) {
  auto redis = start_tls_redis("server");
  ASSERT_NE(redis, nullptr);
  ASSERT_TRUE(redis->url().starts_with("rediss://"));
  Result<std::unique_ptr<RedisStateStore>> store_a = connect(redis->url(), cert("server"));
  ASSERT_TRUE(store_a.ok()) << store_a.status().to_string();
  Result<std::unique_ptr<RedisStateStore>> store_b = connect(redis->url(), cert("server"));
  ASSERT_TRUE(store_b.ok()) << store_b.status().to_string();
  DeformationService a(replica_options(), std::shared_ptr<RedisStateStore>(std::move(*store_a)));
  DeformationService b(replica_options(), std::shared_ptr<RedisStateStore>(std::move(*store_b)));

  service::CreateSessionRequest request;
  request.sample = "cylinder_small";
  Result<service::CreatedSession> created = a.create_session(request);
  ASSERT_TRUE(created.ok()) << created.status().to_string();
  service::SetHandlesRequest handles;
  handles.groups = created->suggested_groups;
  Result<service::SessionInfo> set = a.set_handles(created->id, created->edit_token, handles);
  ASSERT_TRUE(set.ok()) << set.status().to_string();
  std::uint64_t last = 0;
  for (int i = 1; i <= 3; ++i) {
    service::MoveRequest move;
    service::GroupMove g;
    g.group = 1;
    g.translation = Eigen::Vector3d(0.0, 0.0, 0.01 * i);
    move.moves.push_back(g);
    move.max_iterations = 1;
    Result<service::DeformResult> moved = a.move_handles(created->id, created->edit_token, move);
    ASSERT_TRUE(moved.ok()) << moved.status().to_string();
    last = moved->revision;
  }
  ASSERT_GE(last, 3u);
  // The other replica loads it from Redis (over its own TLS connections) at that revision.
  Result<service::SessionInfo> seen = b.session_info(created->id, created->view_token);
  ASSERT_TRUE(seen.ok()) << seen.status().to_string();
  EXPECT_EQ(seen->revision, last);
  Result<std::string> mesh_a = a.get_mesh(created->id, created->view_token, io::MeshFormat::Obj);
  Result<std::string> mesh_b = b.get_mesh(created->id, created->view_token, io::MeshFormat::Obj);
  ASSERT_TRUE(mesh_a.ok() && mesh_b.ok());
  EXPECT_EQ(*mesh_a, *mesh_b);

  // A bigger session (the full-size sample: its stored state is far larger than a socket
  // buffer) goes through the relays intact both ways.
  service::CreateSessionRequest big;
  big.sample = "cylinder";
  Result<service::CreatedSession> large = a.create_session(big);
  ASSERT_TRUE(large.ok()) << large.status().to_string();
  Result<std::string> large_a = a.get_mesh(large->id, large->view_token, io::MeshFormat::Obj);
  Result<std::string> large_b = b.get_mesh(large->id, large->view_token, io::MeshFormat::Obj);
  ASSERT_TRUE(large_a.ok()) << large_a.status().to_string();
  ASSERT_TRUE(large_b.ok()) << large_b.status().to_string();
  RecordProperty("large_mesh_obj_bytes", static_cast<int>(large_a->size()));
  EXPECT_GT(large_a->size(), 256u * 1024u);
  EXPECT_EQ(*large_a, *large_b);
}

/// Threads of this process now (Linux: /proc/self/task).
std::size_t thread_count() {
  std::size_t n = 0;
  std::error_code ec;
  for (auto it = fs::directory_iterator("/proc/self/task", ec); !ec && it != fs::directory_iterator();
       it.increment(ec)) {
    ++n;
  }
  return n;
}

/// Waits (at most 5 s) until this process has `expected` threads; returns the last count.
std::size_t wait_for_threads(std::size_t expected) {
  std::size_t n = thread_count();
  for (int i = 0; i < 250 && n != expected; ++i) {
    std::this_thread::sleep_for(milliseconds(20));
    n = thread_count();
  }
  return n;
}

TEST_F(TlsRedisTest, RelayThreadsEndWithTheirConnectionAndTheStore) {
  auto redis = start_tls_redis("server");
  ASSERT_NE(redis, nullptr);
  const std::size_t before = thread_count();
  {
    Result<std::unique_ptr<RedisStateStore>> store = connect(redis->url(), cert("server"));
    ASSERT_TRUE(store.ok()) << store.status().to_string();
    // One pooled connection (its relay) and the lease renewer.
    EXPECT_EQ(wait_for_threads(before + 2), before + 2);
    const service::SessionId unknown{std::string(32, 'b')};
    Result<std::optional<std::uint64_t>> version = (*store)->version(unknown);
    ASSERT_TRUE(version.ok()) << version.status().to_string();
    EXPECT_FALSE(version->has_value());
    // Redis dies: the relay ends on its own (EOF from the server); the store reconnects to a
    // TLS Redis restarted on the same port, dropping the dead pooled connection.
    ASSERT_TRUE(redis->stop(SIGKILL));
    test::RedisOptions same;
    same.dir = redis->dir();
    same.port = redis->port();
    same.tls_cert_file = cert("server");
    same.tls_key_file = (dir_ / "server_key.pem").string();
    std::string error;
    auto restarted = test::RedisProcess::start(same, error);
    ASSERT_NE(restarted, nullptr) << error;
    Result<std::optional<std::uint64_t>> again = (*store)->version(unknown);
    EXPECT_TRUE(again.ok()) << again.status().to_string();
    EXPECT_TRUE((*store)->acquire_lease(unknown, milliseconds(0)).ok());
    (*store)->release_lease(unknown);
    // The dead connection's relay ended when Redis went away: still one relay.
    EXPECT_EQ(wait_for_threads(before + 2), before + 2);
  }
  // The store is gone: so are its relays and its renewer (joined in the destructor).
  EXPECT_EQ(wait_for_threads(before), before);
}

TEST_F(TlsRedisTest, AWrongCaOrHostFailsAtConnectWithUnavailable) {
  auto redis = start_tls_redis("server");
  ASSERT_NE(redis, nullptr);
  // A certificate that does not chain to the given CA.
  Result<std::unique_ptr<RedisStateStore>> wrong_ca = connect(redis->url(), cert("other"));
  ASSERT_FALSE(wrong_ca.ok());
  EXPECT_EQ(wrong_ca.status().code(), ErrorCode::Unavailable);
  const std::string message = wrong_ca.status().message();
  EXPECT_NE(message.find("certificate verify failed"), std::string::npos) << message;
  EXPECT_NE(message.find("127.0.0.1:" + std::to_string(redis->port())), std::string::npos)
      << message;
  // The system's CAs (no --redis-ca-file) do not know a self-signed certificate either.
  Result<std::unique_ptr<RedisStateStore>> system_ca = connect(redis->url(), "");
  ASSERT_FALSE(system_ca.ok());
  EXPECT_EQ(system_ca.status().code(), ErrorCode::Unavailable);
  EXPECT_NE(system_ca.status().message().find("certificate verify failed"), std::string::npos)
      << system_ca.status().message();
  // The right CA, but "localhost" is a name the certificate carries: it connects.
  Result<std::unique_ptr<RedisStateStore>> by_name =
      connect("rediss://localhost:" + std::to_string(redis->port()), cert("server"));
  EXPECT_TRUE(by_name.ok()) << by_name.status().to_string();

  // A certificate from the trusted CA that names another host.
  auto misnamed = start_tls_redis("misnamed");
  ASSERT_NE(misnamed, nullptr);
  Result<std::unique_ptr<RedisStateStore>> wrong_host =
      connect(misnamed->url(), cert("misnamed"));
  ASSERT_FALSE(wrong_host.ok());
  EXPECT_EQ(wrong_host.status().code(), ErrorCode::Unavailable);
  EXPECT_NE(wrong_host.status().message().find("certificate verify failed"), std::string::npos)
      << wrong_host.status().message();
  EXPECT_NE(wrong_host.status().message().find("mismatch"), std::string::npos)
      << wrong_host.status().message();
  Result<std::unique_ptr<RedisStateStore>> wrong_name =
      connect("rediss://localhost:" + std::to_string(misnamed->port()), cert("misnamed"));
  ASSERT_FALSE(wrong_name.ok());
  EXPECT_EQ(wrong_name.status().code(), ErrorCode::Unavailable);
  EXPECT_NE(wrong_name.status().message().find("mismatch"), std::string::npos)
      << wrong_name.status().message();

  // A plain client on the TLS port, and TLS to a closed port: clear errors, no hang.
  Result<std::unique_ptr<RedisStateStore>> plain =
      connect("redis://127.0.0.1:" + std::to_string(redis->port()), "");
  EXPECT_FALSE(plain.ok());
  const int closed = test::free_loopback_port();
  Result<std::unique_ptr<RedisStateStore>> refused =
      connect("rediss://127.0.0.1:" + std::to_string(closed), cert("server"));
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), ErrorCode::Unavailable);
  EXPECT_NE(refused.status().message().find("unreachable"), std::string::npos)
      << refused.status().message();
  // An unreadable CA file is a configuration error.
  Result<std::unique_ptr<RedisStateStore>> no_file =
      connect(redis->url(), (dir_ / "missing.pem").string());
  ASSERT_FALSE(no_file.ok());
  EXPECT_EQ(no_file.status().code(), ErrorCode::InvalidArgument);
}

using test::failed_start;

TEST_F(TlsRedisTest, TheServerStopsAtStartupOnABadCaAndStartsWithTheRightOne) {
  auto redis = start_tls_redis("server");
  ASSERT_NE(redis, nullptr);
  const auto run = failed_start({"--redis", redis->url(), "--redis-ca-file", cert("other")});
  ASSERT_TRUE(run.first.has_value()) << "the server did not stop at startup:\n" << run.second;
  ASSERT_TRUE(WIFEXITED(*run.first));
  EXPECT_EQ(WEXITSTATUS(*run.first), 2) << run.second;
  EXPECT_NE(run.second.find("redis_unusable"), std::string::npos) << run.second;
  EXPECT_NE(run.second.find("certificate verify failed"), std::string::npos) << run.second;
  EXPECT_EQ(run.second.find("\"listening\""), std::string::npos) << run.second;
  // --redis-ca-file with a plain URL is a mistake, said so.
  const auto plain = failed_start(
      {"--redis", "redis://127.0.0.1:" + std::to_string(redis->port()), "--redis-ca-file",
       cert("server")});
  ASSERT_TRUE(plain.first.has_value()) << plain.second;
  EXPECT_EQ(WEXITSTATUS(*plain.first), 2) << plain.second;
  EXPECT_NE(plain.second.find("rediss://"), std::string::npos) << plain.second;
  // The right CA: the server starts on the TLS Redis.
  std::string error;
  auto server = test::ServerProcess::start(
      MESHDEFORM_SERVER_PATH, {"--redis", redis->url(), "--redis-ca-file", cert("server")}, error);
  EXPECT_NE(server, nullptr) << error;
}

}  // namespace
}  // namespace meshdeform
