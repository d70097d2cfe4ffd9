// Sessions on Redis behind the real nginx with round robin (issue 16: "nginx round-robin (no
// hash) must also be correct"): three meshdeform-server replicas on one redis-server, nginx
// running the shipped docker/nginx.conf.template with its two `hash` lines taken out, so that
// consecutive calls of one session land on different replicas. Every move must build on the one
// before (consecutive revisions, no ABORTED), a Watch through nginx sees every revision, and every
// replica really served the session. Skipped (GTEST_SKIP) when redis-server or nginx is missing.
// Loopback only; every call has a deadline; every loop is bounded; every child dies with the test.
#include <gtest/gtest.h>
#include <grpcpp/grpcpp.h>
#include <stdlib.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

#include "core/io/mesh_io.h"
#include "meshdeform/v1/deformation.grpc.pb.h"
#include "tests/support/grpc_calls.h"
#include "tests/support/nginx_process.h"
#include "tests/support/redis_process.h"
#include "tests/support/server_process.h"

namespace meshdeform {
namespace {

namespace fs = std::filesystem;
using std::chrono::seconds;
using test::bound;

using test::read_text;

TEST(RedisNginxTest, RoundRobinThroughNginxKeepsEverySessionCorrect) {
  if (test::RedisProcess::binary().empty()) {
    GTEST_SKIP() << "redis-server is not installed (scripts/install-deps.sh installs it)";
  }
  const std::string nginx_binary = test::find_nginx();
  if (nginx_binary.empty()) {
    GTEST_SKIP() << "no nginx binary (/usr/sbin/nginx, or set MESHDEFORM_NGINX)";
  }
  std::string error;
  auto redis = test::RedisProcess::start({}, error);
  ASSERT_NE(redis, nullptr) << error;

  char pattern[] = "/tmp/meshdeform-redis-nginx-XXXXXX";
  ASSERT_NE(::mkdtemp(pattern), nullptr);
  const fs::path dir = pattern;
  struct Cleanup {
    fs::path dir;
    ~Cleanup() {
      std::error_code ignored;
      fs::remove_all(dir, ignored);
    }
  } cleanup{dir};
  // nginx's workers run as an unprivileged user when the test runs as root: let them in.
  fs::permissions(dir, fs::perms::owner_all | fs::perms::group_read | fs::perms::group_exec |
                           fs::perms::others_read | fs::perms::others_exec);
  fs::create_directories(dir / "nginx-temp");

  constexpr int kReplicas = 3;
  std::vector<std::unique_ptr<test::ServerProcess>> replicas;
  std::string upstream_grpc, upstream_http;
  for (int i = 0; i < kReplicas; ++i) {
    auto replica = test::ServerProcess::start(
        MESHDEFORM_SERVER_PATH,
        {"--redis", redis->url(), "--refine-budget", "0", "--workers", "1", "--http-listen",
         "127.0.0.1:0", "--log-level", "debug"},
        error);
    ASSERT_NE(replica, nullptr) << error;
    const int http_port = replica->http_port();
    ASSERT_GT(http_port, 0) << replica->log();
    upstream_grpc += "server 127.0.0.1:" + std::to_string(replica->port()) + "; ";
    upstream_http += "server 127.0.0.1:" + std::to_string(http_port) + "; ";
    replicas.push_back(std::move(replica));
  }
  std::string conf_template = read_text(fs::path(MESHDEFORM_DOCKER_DIR) / "nginx.conf.template");
  ASSERT_FALSE(conf_template.empty());
  // Round robin: drop the session affinity of both upstream blocks.
  const std::string hash_line = "    hash $meshdeform_affinity;\n";
  int removed = 0;
  for (std::size_t at = conf_template.find(hash_line); at != std::string::npos;
       at = conf_template.find(hash_line)) {
    conf_template.erase(at, hash_line.size());
    ++removed;
  }
  ASSERT_EQ(removed, 2) << "the template's upstream blocks changed: update this test";

  std::unique_ptr<test::NginxProcess> nginx;
  int grpc_port = 0;
  std::string last_error;
  for (int attempt = 0; attempt < 3 && !nginx; ++attempt) {  // a stolen free port: retry
    grpc_port = test::free_loopback_port();
    const int http_port = test::free_loopback_port();
    const std::optional<std::string> rendered = test::render_template(
        conf_template,
        {{"MESHDEFORM_GRPC_SERVERS", upstream_grpc},
         {"MESHDEFORM_HTTP_SERVERS", upstream_http},
         {"NGINX_GRPC_LISTEN", "127.0.0.1:" + std::to_string(grpc_port)},
         {"NGINX_HTTP_LISTEN", "127.0.0.1:" + std::to_string(http_port)},
         {"NGINX_TEMP_DIR", (dir / "nginx-temp").string()},
         {"NGINX_ACCESS_LOG", (dir / "access.log").string()},
         {"NGINX_ERROR_LOG", (dir / "error.log").string()}},
        error);
    ASSERT_TRUE(rendered.has_value()) << error;
    std::ofstream(dir / "nginx.conf") << *rendered;
    nginx = test::NginxProcess::start(nginx_binary, dir, dir / "nginx.conf",
                                      {grpc_port, http_port}, last_error);
  }
  ASSERT_NE(nginx, nullptr) << last_error;

  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  auto stub = v1::DeformationService::NewStub(grpc::CreateCustomChannel(
      "127.0.0.1:" + std::to_string(grpc_port), grpc::InsecureChannelCredentials(), args));
  v1::CreateSessionRequest create;
  create.set_sample("cylinder_small");
  v1::CreateSessionResponse created;
  {
    grpc::ClientContext context;
    bound(context);
    const grpc::Status status = stub->CreateSession(&context, create, &created);
    ASSERT_TRUE(status.ok()) << status.error_message();
  }
  {
    v1::SetHandlesRequest handles;
    handles.set_session_id(created.session_id());
    handles.set_token(created.edit_token());
    *handles.mutable_groups() = created.suggested_groups();
    v1::SetHandlesResponse response;
    grpc::ClientContext context;
    bound(context, seconds(60));
    const grpc::Status status = stub->SetHandles(&context, handles, &response);
    ASSERT_TRUE(status.ok()) << status.error_message();
  }
  grpc::ClientContext watch_context;
  bound(watch_context, seconds(300));
  v1::WatchRequest watch_request;
  watch_request.set_session_id(created.session_id());
  watch_request.set_token(created.view_token());
  std::unique_ptr<grpc::ClientReader<v1::DeformUpdate>> watch =
      stub->Watch(&watch_context, watch_request);

  constexpr int kMoves = 45;
  std::vector<double> last_positions;
  for (int i = 1; i <= kMoves; ++i) {
    const v1::MoveHandlesRequest move =
        test::lift_move(created.session_id(), created.edit_token(), i);
    v1::MoveHandlesResponse response;
    grpc::ClientContext context;
    bound(context, seconds(60));
    const grpc::Status status = stub->MoveHandles(&context, move, &response);
    ASSERT_TRUE(status.ok()) << "move " << i << ": " << status.error_message();
    EXPECT_EQ(response.result().revision(), static_cast<std::uint64_t>(i));
    last_positions.assign(response.result().positions().begin(),
                          response.result().positions().end());
  }
  // Every replica served the session (round robin), loading it from Redis on its first call.
  for (int i = 0; i < kReplicas; ++i) {
    EXPECT_NE(replicas[i]->log().find(created.session_id()), std::string::npos)
        << "replica " << i << " never served the session";
  }
  // The watch (on whichever replica nginx picked) saw every revision, in order.
  std::uint64_t newest = 0, accounted = 0;
  v1::DeformUpdate update;
  bool joined = false;
  for (int reads = 0; reads < 1000 && newest < kMoves && watch->Read(&update); ++reads) {
    const std::uint64_t revision = update.result().revision();
    if (!joined) {  // the join snapshot: whatever revision was current then
      joined = true;
      accounted = revision;
      newest = revision;
      continue;
    }
    EXPECT_EQ(revision, newest + 1 + update.skipped_revisions()) << "revisions out of order";
    accounted += 1 + update.skipped_revisions();
    newest = revision;
  }
  EXPECT_EQ(newest, static_cast<std::uint64_t>(kMoves));
  EXPECT_EQ(accounted, static_cast<std::uint64_t>(kMoves));
  watch_context.TryCancel();
  // The mesh read through nginx (any replica) is the last acknowledged one.
  v1::GetSessionInfoRequest info_request;
  info_request.set_session_id(created.session_id());
  info_request.set_token(created.view_token());
  for (int i = 0; i < kReplicas; ++i) {  // round robin: each replica answers one of these
    v1::GetSessionInfoResponse info;
    grpc::ClientContext context;
    bound(context);
    ASSERT_TRUE(stub->GetSessionInfo(&context, info_request, &info).ok());
    EXPECT_EQ(info.info().revision(), static_cast<std::uint64_t>(kMoves));
  }
  v1::GetMeshRequest mesh_request;
  mesh_request.set_session_id(created.session_id());
  mesh_request.set_token(created.view_token());
  mesh_request.set_format(v1::MESH_FORMAT_OBJ);
  v1::GetMeshResponse mesh;
  {
    grpc::ClientContext context;
    bound(context);
    ASSERT_TRUE(stub->GetMesh(&context, mesh_request, &mesh).ok());
  }
  Result<io::LoadedMesh> loaded = io::load_mesh_from_memory(mesh.mesh_bytes(), io::MeshFormat::Obj);
  ASSERT_TRUE(loaded.ok()) << loaded.status().to_string();
  ASSERT_EQ(static_cast<std::size_t>(loaded->mesh.V.size()), last_positions.size());
  for (Eigen::Index v = 0; v < loaded->mesh.V.rows(); ++v)
    for (int c = 0; c < 3; ++c)
      EXPECT_EQ(loaded->mesh.V(v, c), last_positions[static_cast<std::size_t>(3 * v + c)]);
}

}  // namespace
}  // namespace meshdeform
