// Hostile uploads against the real meshdeform-server on loopback (issue 11): crafted headers that
// used to cost the server seconds to minutes of CPU (a PLY element of 2e9 property-less rows),
// and large uploads whose callers give up (short deadlines), all in flight from one client while a
// normal client creates a session, sets handles and moves. The normal client must succeed (with
// generous bounds); the hostile calls are refused or time out, and their work stops: the server's
// own counters (GetServerStats) show no heavy work admitted or running afterwards and count the
// cancelled parses. Clients are told apart by x-forwarded-for (the server trusts it here).

#include <gtest/gtest.h>
#include <grpcpp/grpcpp.h>

#include <atomic>
#include <chrono>
#include <cstdint>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "meshdeform/v1/deformation.grpc.pb.h"
#include "tests/support/mesh_factories.h"
#include "tests/support/server_process.h"

namespace meshdeform {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;
namespace v1 = meshdeform::v1;

std::string ply_ascii_junk_element() {
  return "ply\nformat ascii 1.0\nelement vx 2\nelement junk 272222222\nend_header\n";
}

std::string ply_binary_zero_width_rows() {
  return "ply\nformat binary_little_endian 1.0\nelement vertex 0\nproperty float x\n"
         "property float y\nproperty float z\nelement padding 2000000000\nend_header\n";
}

class HostileUploadTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string error;
    server_ = test::ServerProcess::start(
        MESHDEFORM_SERVER_PATH,
        {"--workers", "2", "--trust-forwarded-for", "--create-rate", "0", "--heavy-per-client",
         "2", "--heavy-total", "8", "--refine-budget", "0", "--max-vertices", "1100000",
         "--max-message-mib", "128"},
        error);
    ASSERT_NE(server_, nullptr) << error;
    grpc::ChannelArguments args;
    args.SetMaxSendMessageSize(128 << 20);
    channel_ = grpc::CreateCustomChannel(server_->address(), grpc::InsecureChannelCredentials(),
                                         args);
    stub_ = v1::DeformationService::NewStub(channel_);
  }

  /// A context for `client` (named by x-forwarded-for) with a deadline.
  static void prepare(grpc::ClientContext& context, const std::string& client,
                      milliseconds deadline) {
    context.set_deadline(std::chrono::system_clock::now() + deadline);
    context.AddMetadata("x-forwarded-for", client);
  }

  v1::GetServerStatsResponse stats() {
    grpc::ClientContext context;
    prepare(context, "observer", seconds(30));
    v1::GetServerStatsResponse response;
    const grpc::Status status = stub_->GetServerStats(&context, {}, &response);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return response;
  }

  std::unique_ptr<test::ServerProcess> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::DeformationService::Stub> stub_;
};

TEST_F(HostileUploadTest, HostileUploadsStopAndANormalClientIsServed) {
  const std::string slow_upload = test::make_grid_obj_text(480);  // 230k vertices, ~9 MB of OBJ
  std::atomic<int> unexpected{0};
  std::set<int> seen_codes;
  std::mutex seen_mutex;
  auto hostile_call = [&](const std::string& bytes, v1::MeshFormat format, milliseconds deadline) {
    grpc::ClientContext context;
    prepare(context, "hostile-script", deadline);
    v1::CreateSessionRequest request;
    request.set_mesh_bytes(bytes);
    request.set_format(format);
    v1::CreateSessionResponse response;
    const grpc::Status status = stub_->CreateSession(&context, request, &response);
    const int code = status.error_code();
    {
      std::lock_guard lock(seen_mutex);
      seen_codes.insert(code);
    }
    // Refused (bad header, over the heavy limit) or timed out; never accepted.
    if (code != grpc::INVALID_ARGUMENT && code != grpc::DEADLINE_EXCEEDED &&
        code != grpc::RESOURCE_EXHAUSTED) {
      unexpected.fetch_add(1);
      ADD_FAILURE() << "hostile upload got " << code << ": " << status.error_message();
    }
  };
  std::vector<std::jthread> hostile;  // joined on every path, an early ASSERT included
  for (int i = 0; i < 3; ++i) {
    hostile.emplace_back([&] {
      hostile_call(ply_binary_zero_width_rows(), v1::MESH_FORMAT_PLY, seconds(2));
      hostile_call(ply_ascii_junk_element(), v1::MESH_FORMAT_PLY, seconds(2));
      // A caller that gives up after 300 ms (before or during its parse).
      hostile_call(slow_upload, v1::MESH_FORMAT_OBJ, milliseconds(300));
    });
  }

  // The normal client, meanwhile: create, set handles, move. Generous bounds: a busy machine is
  // slow, but nothing here may wait on the hostile work.
  {
    grpc::ClientContext context;
    prepare(context, "normal-client", seconds(120));
    v1::CreateSessionRequest request;
    request.set_sample("cylinder_small");
    v1::CreateSessionResponse created;
    const grpc::Status status = stub_->CreateSession(&context, request, &created);
    ASSERT_TRUE(status.ok()) << status.error_code() << ": " << status.error_message();
    ASSERT_EQ(created.suggested_groups_size(), 2);

    grpc::ClientContext handles_context;
    prepare(handles_context, "normal-client", seconds(120));
    v1::SetHandlesRequest handles;
    handles.set_session_id(created.session_id());
    handles.set_token(created.edit_token());
    *handles.mutable_groups() = created.suggested_groups();
    v1::SetHandlesResponse handles_response;
    const grpc::Status set = stub_->SetHandles(&handles_context, handles, &handles_response);
    ASSERT_TRUE(set.ok()) << set.error_code() << ": " << set.error_message();

    grpc::ClientContext move_context;
    prepare(move_context, "normal-client", seconds(120));
    v1::MoveHandlesRequest move;
    move.set_session_id(created.session_id());
    move.set_token(created.edit_token());
    v1::GroupMove* group = move.add_moves();
    group->set_group(1);
    group->mutable_translation()->set_x(0.05);
    v1::MoveHandlesResponse moved;
    const grpc::Status moved_status = stub_->MoveHandles(&move_context, move, &moved);
    ASSERT_TRUE(moved_status.ok()) << moved_status.error_code() << ": "
                                   << moved_status.error_message();
    EXPECT_EQ(moved.result().revision(), 1u);
  }
  for (std::jthread& t : hostile) t.join();
  EXPECT_EQ(unexpected.load(), 0);
  EXPECT_TRUE(seen_codes.count(grpc::INVALID_ARGUMENT)) << "the crafted headers were refused";

  // A caller that abandons a large upload while the server parses it: once the server reports
  // it running, the client cancels; the parse must stop (a 1M-vertex OBJ takes seconds to read).
  {
    const std::string huge = test::make_grid_obj_text(1000);  // ~1M vertices, ~55 MB
    grpc::ClientContext context;
    prepare(context, "abandoning-client", seconds(600));
    v1::CreateSessionRequest request;
    request.set_mesh_bytes(huge);
    request.set_format(v1::MESH_FORMAT_OBJ);
    v1::CreateSessionResponse response;
    grpc::Status status;
    std::jthread upload([&] { status = stub_->CreateSession(&context, request, &response); });
    const auto give_up = std::chrono::steady_clock::now() + seconds(60);
    while (stats().heavy_work_running() == 0 && std::chrono::steady_clock::now() < give_up) {
      std::this_thread::sleep_for(milliseconds(5));
    }
    context.TryCancel();
    upload.join();
    EXPECT_EQ(status.error_code(), grpc::CANCELLED) << status.error_message();
  }

  // The hostile work stops: wait (bounded) until the server has no heavy work admitted or
  // running. A parse that ran on after its caller left would hold its slot for seconds.
  v1::GetServerStatsResponse after;
  const auto give_up = std::chrono::steady_clock::now() + seconds(60);
  do {
    after = stats();
    if (after.heavy_work_admitted() == 0 && after.heavy_work_running() == 0) break;
    std::this_thread::sleep_for(milliseconds(50));
  } while (std::chrono::steady_clock::now() < give_up);
  EXPECT_EQ(after.heavy_work_admitted(), 0u);
  EXPECT_EQ(after.heavy_work_running(), 0u);
  // The abandoned parse was stopped (and any 300 ms upload the server had started).
  EXPECT_GE(after.uploads_cancelled(), 1u);
  RecordProperty("uploads_cancelled", static_cast<int>(after.uploads_cancelled()));
  RecordProperty("heavy_work_rejected", static_cast<int>(after.heavy_work_rejected()));
  // No hostile upload made a session: only the normal client's exists.
  EXPECT_EQ(after.sessions(), 1u);

  // And the server still serves the normal client.
  grpc::ClientContext context;
  prepare(context, "normal-client", seconds(60));
  v1::CreateSessionRequest request;
  request.set_sample("bar_small");
  v1::CreateSessionResponse created;
  EXPECT_TRUE(stub_->CreateSession(&context, request, &created).ok());
}

}  // namespace
}  // namespace meshdeform
