// Crash recovery through the real binary: meshdeform-server with --state-dir is killed with
// SIGKILL while a client keeps moving handles; a new server on the same directory resumes the
// session at (at least) the last revision the client saw acknowledged, with exactly its positions.
// Loopback only; every call has a deadline; loops are bounded.
#include <gtest/gtest.h>
#include <grpcpp/grpcpp.h>
#include <signal.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <random>
#include <thread>

#include "core/io/mesh_io.h"
#include "meshdeform/v1/deformation.grpc.pb.h"
#include "tests/support/grpc_calls.h"
#include "tests/support/server_process.h"

namespace meshdeform {
namespace {

namespace fs = std::filesystem;
using std::chrono::seconds;
using test::bound;

std::unique_ptr<v1::DeformationService::Stub> connect(const test::ServerProcess& server) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  return v1::DeformationService::NewStub(
      grpc::CreateCustomChannel(server.address(), grpc::InsecureChannelCredentials(), args));
}

TEST(Kill9RecoveryTest, NoAcknowledgedRevisionIsLost) {
  std::random_device random;
  const fs::path dir = fs::temp_directory_path() /
                       ("meshdeform-kill9-" + std::to_string(random()) + std::to_string(random()));
  const std::vector<std::string> flags = {"--state-dir", dir.string(), "--refine-budget", "0"};
  std::string error;
  auto server = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
  ASSERT_NE(server, nullptr) << error;
  auto stub = connect(*server);

  v1::CreateSessionResponse created;
  ASSERT_TRUE(test::create_sample_with_handles(*stub, "cylinder_small", &created).ok());

  // The editor: moves until the server dies (bounded: at most 400 moves).
  std::atomic<std::uint64_t> acked_revision{0};
  std::mutex mutex;
  std::vector<double> acked_positions;
  std::atomic<int> acked_moves{0};
  std::jthread editor([&] {  // bounded loop; joined on every path
    for (int i = 1; i <= 400; ++i) {
      const v1::MoveHandlesRequest move =
          test::lift_move(created.session_id(), created.edit_token(), i);
      v1::MoveHandlesResponse response;
      grpc::ClientContext context;
      bound(context, seconds(10));
      if (!stub->MoveHandles(&context, move, &response).ok()) return;  // the server is gone
      {
        const std::lock_guard lock(mutex);
        acked_positions.assign(response.result().positions().begin(),
                               response.result().positions().end());
        acked_revision.store(response.result().revision());
      }
      acked_moves.fetch_add(1);
    }
  });
  // Kill in the middle of the stream of moves.
  for (int i = 0; i < 2000 && acked_moves.load() < 8; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  const std::optional<int> killed = server->stop(SIGKILL, std::chrono::seconds(20));
  editor.join();
  ASSERT_TRUE(killed.has_value());
  EXPECT_TRUE(WIFSIGNALED(*killed));
  ASSERT_GE(acked_moves.load(), 8);

  auto restarted = test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
  ASSERT_NE(restarted, nullptr) << error;
  auto stub2 = connect(*restarted);
  v1::GetSessionInfoRequest info_request;
  info_request.set_session_id(created.session_id());
  info_request.set_token(created.view_token());
  v1::GetSessionInfoResponse info;
  {
    grpc::ClientContext context;
    bound(context);
    const grpc::Status status = stub2->GetSessionInfo(&context, info_request, &info);
    ASSERT_TRUE(status.ok()) << status.error_message() << "\n" << restarted->log();
  }
  // A move in flight at the kill may have been committed (and persisted) without its answer
  // arriving; nothing acknowledged may be missing.
  const std::uint64_t acked = acked_revision.load();
  EXPECT_GE(info.info().revision(), acked);
  EXPECT_LE(info.info().revision(), acked + 1);
  {
    v1::GetMeshRequest mesh_request;
    mesh_request.set_session_id(created.session_id());
    mesh_request.set_token(created.view_token());
    mesh_request.set_format(v1::MESH_FORMAT_OBJ);
    v1::GetMeshResponse mesh;
    grpc::ClientContext context;
    bound(context);
    ASSERT_TRUE(stub2->GetMesh(&context, mesh_request, &mesh).ok());
    Result<io::LoadedMesh> loaded = io::load_mesh_from_memory(mesh.mesh_bytes(), io::MeshFormat::Obj);
    ASSERT_TRUE(loaded.ok());
    if (info.info().revision() == acked) {
      const std::lock_guard lock(mutex);
      ASSERT_EQ(static_cast<std::size_t>(loaded->mesh.V.size()), acked_positions.size());
      for (Eigen::Index v = 0; v < loaded->mesh.V.rows(); ++v)
        for (int c = 0; c < 3; ++c)
          EXPECT_EQ(loaded->mesh.V(v, c), acked_positions[static_cast<std::size_t>(3 * v + c)]);
    }
  }
  // The wrong token is still refused, and editing continues.
  {
    v1::GetSessionInfoRequest wrong = info_request;
    wrong.set_token("not-the-token");
    v1::GetSessionInfoResponse ignored;
    grpc::ClientContext context;
    bound(context);
    EXPECT_EQ(stub2->GetSessionInfo(&context, wrong, &ignored).error_code(),
              grpc::StatusCode::PERMISSION_DENIED);
  }
  {
    v1::MoveHandlesRequest move;
    move.set_session_id(created.session_id());
    move.set_token(created.edit_token());
    move.add_moves()->set_group(1);
    v1::MoveHandlesResponse response;
    grpc::ClientContext context;
    bound(context, seconds(60));
    const grpc::Status status = stub2->MoveHandles(&context, move, &response);
    ASSERT_TRUE(status.ok()) << status.error_message();
    EXPECT_EQ(response.result().revision(), info.info().revision() + 1);
  }
  restarted.reset();
  std::error_code ignored;
  fs::remove_all(dir, ignored);
}

}  // namespace
}  // namespace meshdeform
