// Drives a real DeformationService through DeformServiceImpl in an in-process grpc::Server with the
// generated stub. Positions travel as doubles (see deformation.proto), so results are compared with
// the service's own to 1e-9 of the bounding-box diagonal; GLB stores float32 and is compared to
// float round-off. Every wait is bounded by a call deadline; no test depends on timing thresholds
// except that a 1000-iteration solve of a 4,802-vertex mesh outlasts a 300 ms deadline.
#include <gtest/gtest.h>

#include <grpcpp/create_channel.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/security/credentials.h>
#include <grpcpp/security/server_credentials.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <future>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include <meshoptimizer.h>

#include "core/io/mesh_io.h"
#include "meshdeform/v1/deformation.grpc.pb.h"
#include "server/service/deformation_service.h"
#include "server/transport/deform_service_impl.h"
#include "server/transport/proto_convert.h"
#include "server/transport/server_setup.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::transport {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

constexpr int kMaxMessageMib = 64;

/// Every call gets a deadline, so that no test can hang.
void bound(grpc::ClientContext& context, seconds timeout = seconds(60)) {
  context.set_deadline(std::chrono::system_clock::now() + timeout);
}

std::string describe(const grpc::Status& status) {
  return std::to_string(static_cast<int>(status.error_code())) + ": " + status.error_message();
}

v1::CreateSessionRequest sample_request(const std::string& name) {
  v1::CreateSessionRequest request;
  request.set_sample(name);
  return request;
}

/// Group 1 (the sample's handle group) rotated about y by `angle_deg` and lifted, as in the
/// service tests.
v1::GroupMove bend(double angle_deg) {
  v1::GroupMove move;
  move.set_group(1);
  const Eigen::Quaterniond q(
      Eigen::AngleAxisd(angle_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()));
  move.mutable_rotation()->set_w(q.w());
  move.mutable_rotation()->set_x(q.x());
  move.mutable_rotation()->set_y(q.y());
  move.mutable_rotation()->set_z(q.z());
  move.mutable_translation()->set_x(0.1);
  move.mutable_translation()->set_z(0.05);
  return move;
}

service::MoveRequest bend_domain(double angle_deg) {
  service::MoveRequest move;
  service::GroupMove g;
  g.group = 1;
  g.rotation =
      Eigen::Quaterniond(Eigen::AngleAxisd(angle_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()));
  g.translation = Eigen::Vector3d(0.1, 0.0, 0.05);
  move.moves.push_back(g);
  return move;
}

Positions positions_of(const google::protobuf::RepeatedField<double>& flat) {
  Positions P(flat.size() / 3, 3);
  for (int r = 0; r < P.rows(); ++r)
    for (int c = 0; c < 3; ++c) P(r, c) = flat[3 * r + c];
  return P;
}

/// `impl` on a real TCP port of 127.0.0.1 (not in-process: the peer is a network address).
/// @return the server (nullptr if it did not start); *port the port it bound.
std::unique_ptr<grpc::Server> serve_on_loopback(DeformServiceImpl& impl, int* port) {
  grpc::ServerBuilder builder;
  builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), port);
  configure_builder(builder, impl, kMaxMessageMib);
  return builder.BuildAndStart();
}

service::ServiceOptions one_worker() {
  service::ServiceOptions options;
  options.workers = 1;
  return options;
}

/// Reads a *WithProgress stream to its end: the phases in first-seen order, whether the last
/// event held the response (and how many events followed it), and the final status.
template <typename Event>
struct StreamRead {
  std::vector<std::string> phases;
  int progress_events = 0;
  int responses = 0;
  bool response_last = false;
  Event last;
  grpc::Status status;
};

template <typename Event>
StreamRead<Event> read_all(grpc::ClientReader<Event>& reader) {
  StreamRead<Event> out;
  Event event;
  for (int i = 0; i < 100000 && reader.Read(&event); ++i) {
    if (event.has_progress()) {
      ++out.progress_events;
      out.response_last = false;
      const std::string& phase = event.progress().phase();
      if (std::find(out.phases.begin(), out.phases.end(), phase) == out.phases.end())
        out.phases.push_back(phase);
      EXPECT_GE(event.progress().fraction(), 0.0);
      EXPECT_LE(event.progress().fraction(), 1.0);
    } else if (event.has_response()) {
      ++out.responses;
      out.response_last = true;
      out.last = event;
    }
  }
  out.status = reader.Finish();
  return out;
}

class DeformServiceTest : public ::testing::Test {
 protected:
  void SetUp() override { start(service::ServiceOptions{}); }
  void TearDown() override { stop(); }

  void start(service::ServiceOptions options) {
    options.workers = 2;
    service_ = std::make_unique<service::DeformationService>(options);
    impl_ = std::make_unique<DeformServiceImpl>(*service_);
    enable_health_and_reflection();
    grpc::ServerBuilder builder;
    configure_builder(builder, *impl_, kMaxMessageMib);
    server_ = builder.BuildAndStart();
    ASSERT_NE(server_, nullptr);
    grpc::ChannelArguments args;
    args.SetMaxReceiveMessageSize(kMaxMessageMib << 20);
    args.SetMaxSendMessageSize(kMaxMessageMib << 20);
    channel_ = server_->InProcessChannel(args);
    stub_ = v1::DeformationService::NewStub(channel_);
  }

  void stop() {
    if (server_) server_->Shutdown(std::chrono::system_clock::now() + seconds(10));
    stub_.reset();
    channel_.reset();
    server_.reset();
    impl_.reset();
    service_.reset();
  }

  grpc::Status create(const v1::CreateSessionRequest& request, v1::CreateSessionResponse* out) {
    grpc::ClientContext context;
    bound(context);
    return stub_->CreateSession(&context, request, out);
  }

  /// SetHandles of a session's suggested groups, with its edit token.
  static v1::SetHandlesRequest suggested_handles(const v1::CreateSessionResponse& created) {
    v1::SetHandlesRequest handles;
    handles.set_session_id(created.session_id());
    handles.set_token(created.edit_token());
    *handles.mutable_groups() = created.suggested_groups();
    return handles;
  }

  /// A sample session with its suggested groups set as handles.
  v1::CreateSessionResponse create_with_handles(const std::string& sample) {
    v1::CreateSessionResponse created;
    const grpc::Status status = create(sample_request(sample), &created);
    EXPECT_TRUE(status.ok()) << describe(status);
    EXPECT_EQ(created.suggested_groups_size(), 2);
    v1::SetHandlesResponse response;
    const grpc::Status set = set_handles(suggested_handles(created), &response);
    EXPECT_TRUE(set.ok()) << describe(set);
    return created;
  }

  grpc::Status set_handles(const v1::SetHandlesRequest& request, v1::SetHandlesResponse* out) {
    grpc::ClientContext context;
    bound(context);
    return stub_->SetHandles(&context, request, out);
  }

  /// The *WithProgress streams, read to their end (bounded by the call's deadline).
  StreamRead<v1::CreateSessionEvent> create_with_progress(const v1::CreateSessionRequest& request) {
    grpc::ClientContext context;
    bound(context);
    return read_all(*stub_->CreateSessionWithProgress(&context, request));
  }
  StreamRead<v1::SetHandlesEvent> set_handles_with_progress(const v1::SetHandlesRequest& request) {
    grpc::ClientContext context;
    bound(context);
    return read_all(*stub_->SetHandlesWithProgress(&context, request));
  }

  grpc::Status move(const v1::MoveHandlesRequest& request, v1::MoveHandlesResponse* out,
                    seconds timeout = seconds(60)) {
    grpc::ClientContext context;
    bound(context, timeout);
    return stub_->MoveHandles(&context, request, out);
  }

  v1::MoveHandlesRequest bend_request(const v1::CreateSessionResponse& created, double angle) {
    v1::MoveHandlesRequest request;
    request.set_session_id(created.session_id());
    request.set_token(created.edit_token());
    *request.add_moves() = bend(angle);
    return request;
  }

  grpc::Status info(const std::string& id, const std::string& token, v1::SessionInfo* out) {
    grpc::ClientContext context;
    bound(context);
    v1::GetSessionInfoRequest request;
    request.set_session_id(id);
    request.set_token(token);
    v1::GetSessionInfoResponse response;
    grpc::Status status = stub_->GetSessionInfo(&context, request, &response);
    *out = response.info();
    return status;
  }

  /// Waits (bounded) until the service counted `count` cancelled moves.
  bool wait_for_cancelled_moves(std::uint64_t count) {
    for (int i = 0; i < 600; ++i) {
      if (service_->stats().moves_cancelled >= count) return true;
      std::this_thread::sleep_for(milliseconds(50));
    }
    return false;
  }

  std::unique_ptr<service::DeformationService> service_;
  std::unique_ptr<DeformServiceImpl> impl_;
  std::unique_ptr<grpc::Server> server_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::DeformationService::Stub> stub_;
};

// --- create ------------------------------------------------------------------------------------

TEST_F(DeformServiceTest, CreateFromObjBytes) {
  const MeshData grid = test::make_grid(6, 0.05);
  Result<std::string> obj = io::write_mesh_to_memory(grid, io::MeshFormat::Obj);
  ASSERT_TRUE(obj.ok());
  v1::CreateSessionRequest request;
  request.set_mesh_bytes(*obj);
  request.set_format(v1::MESH_FORMAT_OBJ);
  v1::CreateSessionResponse created;
  const grpc::Status status = create(request, &created);
  ASSERT_TRUE(status.ok()) << describe(status);
  EXPECT_EQ(created.session_id().size(), 32u);
  EXPECT_EQ(created.edit_token().size(), 64u);
  EXPECT_EQ(created.view_token().size(), 64u);
  EXPECT_EQ(created.info().vertices(), 49u);
  EXPECT_EQ(created.info().faces(), 72u);
  EXPECT_EQ(created.info().boundary_loops(), 1u);
  EXPECT_EQ(created.info().revision(), 0u);
  EXPECT_NEAR(created.info().bbox_max().y(), 1.0, 1e-12);
  EXPECT_EQ(created.suggested_groups_size(), 0);
}

TEST_F(DeformServiceTest, CreateFromSampleSuggestsGroups) {
  v1::CreateSessionResponse created;
  const grpc::Status status = create(sample_request("cylinder_small"), &created);
  ASSERT_TRUE(status.ok()) << describe(status);
  EXPECT_EQ(created.info().vertices(), 420u);
  EXPECT_EQ(created.info().boundary_loops(), 2u);
  ASSERT_EQ(created.suggested_groups_size(), 2);
  EXPECT_EQ(created.suggested_groups(0).role(), v1::HANDLE_ROLE_FIXED);
  EXPECT_EQ(created.suggested_groups(1).role(), v1::HANDLE_ROLE_HANDLE);
}

// --- move: the wire result equals the service's own -------------------------------------------

TEST_F(DeformServiceTest, MoveMatchesTheServiceAndGetMeshParsesBack) {
  const v1::CreateSessionResponse created = create_with_handles("cylinder_small");

  // The same edits on a separate service, called directly.
  service::DeformationService reference(one_worker());
  service::CreateSessionRequest ref_request;
  ref_request.sample = "cylinder_small";
  Result<service::CreatedSession> ref = reference.create_session(ref_request);
  ASSERT_TRUE(ref.ok());
  ASSERT_TRUE(reference.set_handles(ref->id, ref->edit_token, {ref->suggested_groups}).ok());

  const double diag = (Eigen::Vector3d(created.info().bbox_max().x(), created.info().bbox_max().y(),
                                       created.info().bbox_max().z()) -
                       Eigen::Vector3d(created.info().bbox_min().x(), created.info().bbox_min().y(),
                                       created.info().bbox_min().z()))
                          .norm();
  Positions previous;
  for (int step = 1; step <= 2; ++step) {
    const double angle = 20.0 * step;
    v1::MoveHandlesRequest request = bend_request(created, angle);
    request.set_full_positions(true);
    request.set_editor("test");
    v1::MoveHandlesResponse response;
    const grpc::Status status = move(request, &response);
    ASSERT_TRUE(status.ok()) << describe(status);
    Result<service::DeformResult> expected =
        reference.move_handles(ref->id, ref->edit_token, bend_domain(angle));
    ASSERT_TRUE(expected.ok());

    const v1::DeformResult& r = response.result();
    EXPECT_EQ(r.revision(), static_cast<std::uint64_t>(step));
    EXPECT_EQ(r.method(), v1::METHOD_SCALE_AWARE);
    EXPECT_EQ(r.iterations(), static_cast<std::uint32_t>(expected->iterations));
    EXPECT_EQ(r.editor(), "test");
    EXPECT_EQ(r.built_deformer(), false);  // SetHandles built it
    EXPECT_NEAR(r.e_theta(), expected->e_theta, 1e-9);
    EXPECT_NEAR(r.e_phi(), expected->e_phi, 1e-9);
    ASSERT_EQ(r.positions_size(), 3 * 420);
    const Positions V = positions_of(r.positions());
    EXPECT_LE((V - *expected->positions).cwiseAbs().maxCoeff(), test::kExactTol * diag);
    // The delta lists agree with the full positions.
    ASSERT_EQ(r.changed_positions_size(), 3 * r.changed_indices_size());
    EXPECT_EQ(static_cast<std::size_t>(r.changed_indices_size()), expected->changed.size());
    const Positions changed = positions_of(r.changed_positions());
    for (int j = 0; j < r.changed_indices_size(); ++j) {
      EXPECT_EQ(static_cast<int>(r.changed_indices(j)), expected->changed[j]);
      EXPECT_EQ(changed.row(j), V.row(r.changed_indices(j)));
    }
    previous = V;
  }

  // GetMesh (default format GLB, float32) parses back to the current positions.
  grpc::ClientContext context;
  bound(context);
  v1::GetMeshRequest get;
  get.set_session_id(created.session_id());
  get.set_token(created.view_token());
  v1::GetMeshResponse mesh;
  const grpc::Status status = stub_->GetMesh(&context, get, &mesh);
  ASSERT_TRUE(status.ok()) << describe(status);
  EXPECT_EQ(mesh.format(), v1::MESH_FORMAT_GLB);
  Result<MeshData> parsed = io::read_mesh_from_memory(mesh.mesh_bytes(), io::MeshFormat::Glb);
  ASSERT_TRUE(parsed.ok()) << parsed.status().to_string();
  ASSERT_EQ(parsed->V.rows(), 420);
  EXPECT_EQ(parsed->F.rows(), static_cast<Eigen::Index>(created.info().faces()));
  EXPECT_LE((parsed->V - previous).cwiseAbs().maxCoeff(), 1e-6 * diag);  // float32

  v1::SessionInfo after;
  ASSERT_TRUE(info(created.session_id(), created.view_token(), &after).ok());
  EXPECT_EQ(after.revision(), 2u);
  EXPECT_EQ(after.last_method(), v1::METHOD_SCALE_AWARE);
  EXPECT_EQ(after.groups_size(), 2);
}

TEST_F(DeformServiceTest, ExplicitTargetsWithArap) {
  const v1::CreateSessionResponse created = create_with_handles("cylinder_small");
  v1::MoveHandlesRequest request;
  request.set_session_id(created.session_id());
  request.set_token(created.edit_token());
  request.set_method(v1::METHOD_ARAP);
  const std::uint32_t v = created.suggested_groups(1).vertices(0);
  request.mutable_targets()->add_vertices(v);
  for (double x : {0.5, 0.25, 2.0}) request.mutable_targets()->add_positions(x);
  request.set_full_positions(true);
  v1::MoveHandlesResponse response;
  const grpc::Status status = move(request, &response);
  ASSERT_TRUE(status.ok()) << describe(status);
  EXPECT_EQ(response.result().method(), v1::METHOD_ARAP);
  EXPECT_TRUE(response.result().built_deformer());
  const Positions V = positions_of(response.result().positions());
  // ARAP pins handles exactly.
  EXPECT_NEAR((V.row(v) - Eigen::RowVector3d(0.5, 0.25, 2.0)).norm(), 0.0, 1e-9);
}

// --- error paths -------------------------------------------------------------------------------

TEST_F(DeformServiceTest, BadInputIsInvalidArgument) {
  v1::CreateSessionResponse created;
  v1::CreateSessionRequest garbage;
  garbage.set_mesh_bytes("this is not a mesh\nf 1 2 9\n");
  garbage.set_format(v1::MESH_FORMAT_OBJ);
  EXPECT_EQ(create(garbage, &created).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  v1::CreateSessionRequest no_format;
  no_format.set_mesh_bytes("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  EXPECT_EQ(create(no_format, &created).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(create(v1::CreateSessionRequest{}, &created).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  const grpc::Status unknown_sample = create(sample_request("spot"), &created);
  EXPECT_EQ(unknown_sample.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(unknown_sample.error_message().find("cylinder_small"), std::string::npos);
  v1::CreateSessionRequest bad_lambda = sample_request("cylinder_small");
  bad_lambda.set_lambda(std::nan(""));
  EXPECT_EQ(create(bad_lambda, &created).error_code(), grpc::StatusCode::INVALID_ARGUMENT);

  const v1::CreateSessionResponse s = create_with_handles("cylinder_small");
  // Bad index in SetHandles.
  v1::SetHandlesRequest bad_index;
  bad_index.set_session_id(s.session_id());
  bad_index.set_token(s.edit_token());
  v1::HandleGroup* g = bad_index.add_groups();
  g->set_role(v1::HANDLE_ROLE_HANDLE);
  g->add_vertices(3);
  g->add_vertices(420);
  v1::SetHandlesResponse set_response;
  const grpc::Status bad = set_handles(bad_index, &set_response);
  EXPECT_EQ(bad.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(bad.error_message().find("420"), std::string::npos) << bad.error_message();
  g->set_role(v1::HANDLE_ROLE_UNSPECIFIED);
  EXPECT_EQ(set_handles(bad_index, &set_response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);

  v1::MoveHandlesResponse response;
  // NaN target.
  v1::MoveHandlesRequest nan_target;
  nan_target.set_session_id(s.session_id());
  nan_target.set_token(s.edit_token());
  nan_target.mutable_targets()->add_vertices(s.suggested_groups(1).vertices(0));
  for (double x : {0.0, std::nan(""), 0.0}) nan_target.mutable_targets()->add_positions(x);
  EXPECT_EQ(move(nan_target, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  // Positions not 3 per vertex.
  v1::MoveHandlesRequest short_targets = nan_target;
  short_targets.mutable_targets()->mutable_positions()->RemoveLast();
  EXPECT_EQ(move(short_targets, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  // Target for a vertex that is not constrained (index range checked by the service).
  v1::MoveHandlesRequest free_target = nan_target;
  free_target.mutable_targets()->set_vertices(0, 100000);
  free_target.mutable_targets()->set_positions(1, 0.0);
  EXPECT_EQ(move(free_target, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  // Non-finite translation, zero quaternion, bad group, too many iterations.
  v1::MoveHandlesRequest bad_move = bend_request(s, 10);
  bad_move.mutable_moves(0)->mutable_translation()->set_y(INFINITY);
  EXPECT_EQ(move(bad_move, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  bad_move = bend_request(s, 10);
  *bad_move.mutable_moves(0)->mutable_rotation() = v1::Quaternion();
  EXPECT_EQ(move(bad_move, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  bad_move = bend_request(s, 10);
  bad_move.mutable_moves(0)->set_group(7);
  EXPECT_EQ(move(bad_move, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  bad_move = bend_request(s, 10);
  bad_move.set_max_iterations(100000);
  EXPECT_EQ(move(bad_move, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  v1::SessionInfo after;
  ASSERT_TRUE(info(s.session_id(), s.view_token(), &after).ok());
  EXPECT_EQ(after.revision(), 0u);  // nothing committed
}

TEST_F(DeformServiceTest, UnknownSessionIsNotFoundEverywhere) {
  const std::string id(32, 'a'), token(64, 'b');
  v1::SetHandlesResponse set_response;
  v1::SetHandlesRequest set;
  set.set_session_id(id);
  set.set_token(token);
  v1::HandleGroup* g = set.add_groups();
  g->set_role(v1::HANDLE_ROLE_FIXED);
  g->add_vertices(0);
  EXPECT_EQ(set_handles(set, &set_response).error_code(), grpc::StatusCode::NOT_FOUND);
  v1::MoveHandlesRequest move_request;
  move_request.set_session_id(id);
  move_request.set_token(token);
  v1::MoveHandlesResponse move_response;
  EXPECT_EQ(move(move_request, &move_response).error_code(), grpc::StatusCode::NOT_FOUND);
  v1::SessionInfo unused;
  EXPECT_EQ(info(id, token, &unused).error_code(), grpc::StatusCode::NOT_FOUND);
  {
    grpc::ClientContext context;
    bound(context);
    v1::GetMeshRequest request;
    request.set_session_id(id);
    request.set_token(token);
    v1::GetMeshResponse response;
    EXPECT_EQ(stub_->GetMesh(&context, request, &response).error_code(),
              grpc::StatusCode::NOT_FOUND);
  }
  {
    grpc::ClientContext context;
    bound(context);
    v1::CloseSessionRequest request;
    request.set_session_id(id);
    request.set_token(token);
    v1::CloseSessionResponse response;
    EXPECT_EQ(stub_->CloseSession(&context, request, &response).error_code(),
              grpc::StatusCode::NOT_FOUND);
  }
  {
    grpc::ClientContext context;
    bound(context);
    v1::WatchRequest request;
    request.set_session_id(id);
    request.set_token(token);
    auto reader = stub_->Watch(&context, request);
    v1::DeformUpdate update;
    EXPECT_FALSE(reader->Read(&update));
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::NOT_FOUND);
  }
}

TEST_F(DeformServiceTest, TokensArePermissionDenied) {
  const v1::CreateSessionResponse s = create_with_handles("cylinder_small");
  const std::string wrong(64, 'f');
  // The view token cannot edit.
  v1::SetHandlesRequest set;
  set.set_session_id(s.session_id());
  set.set_token(s.view_token());
  *set.mutable_groups() = s.suggested_groups();
  v1::SetHandlesResponse set_response;
  EXPECT_EQ(set_handles(set, &set_response).error_code(), grpc::StatusCode::PERMISSION_DENIED);
  v1::MoveHandlesRequest move_request = bend_request(s, 10);
  move_request.set_token(s.view_token());
  v1::MoveHandlesResponse move_response;
  EXPECT_EQ(move(move_request, &move_response).error_code(), grpc::StatusCode::PERMISSION_DENIED);
  move_request.set_token(wrong);
  EXPECT_EQ(move(move_request, &move_response).error_code(), grpc::StatusCode::PERMISSION_DENIED);
  {
    grpc::ClientContext context;
    bound(context);
    v1::CloseSessionRequest request;
    request.set_session_id(s.session_id());
    request.set_token(s.view_token());
    v1::CloseSessionResponse response;
    EXPECT_EQ(stub_->CloseSession(&context, request, &response).error_code(),
              grpc::StatusCode::PERMISSION_DENIED);
  }
  // A wrong token cannot read either; the view token can.
  v1::SessionInfo unused;
  EXPECT_EQ(info(s.session_id(), wrong, &unused).error_code(), grpc::StatusCode::PERMISSION_DENIED);
  EXPECT_TRUE(info(s.session_id(), s.view_token(), &unused).ok());
  {
    grpc::ClientContext context;
    bound(context);
    v1::WatchRequest request;
    request.set_session_id(s.session_id());
    request.set_token(wrong);
    auto reader = stub_->Watch(&context, request);
    v1::DeformUpdate update;
    EXPECT_FALSE(reader->Read(&update));
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::PERMISSION_DENIED);
  }
}

TEST_F(DeformServiceTest, MoveBeforeHandlesIsFailedPrecondition) {
  v1::CreateSessionResponse created;
  ASSERT_TRUE(create(sample_request("cylinder_small"), &created).ok());
  v1::MoveHandlesResponse response;
  const grpc::Status status = move(bend_request(created, 10), &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << describe(status);
}

TEST_F(DeformServiceTest, LimitsAreResourceExhausted) {
  stop();
  service::ServiceOptions options;
  options.max_sessions = 1;
  options.max_vertices = 500;
  start(options);
  v1::CreateSessionResponse created;
  // Over max_vertices: the 4,802-vertex cylinder.
  EXPECT_EQ(create(sample_request("cylinder"), &created).error_code(),
            grpc::StatusCode::RESOURCE_EXHAUSTED);
  ASSERT_TRUE(create(sample_request("cylinder_small"), &created).ok());
  const grpc::Status second = create(sample_request("cylinder_small"), &created);
  EXPECT_EQ(second.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << describe(second);
}

// --- deadline and cancellation -----------------------------------------------------------------

TEST_F(DeformServiceTest, DeadlineExpiringMidSolveIsDeadlineExceeded) {
  const v1::CreateSessionResponse s = create_with_handles("cylinder");  // 4,802 vertices
  v1::MoveHandlesRequest long_move = bend_request(s, 30);
  long_move.set_max_iterations(1000);
  long_move.set_tolerance(0.0);
  v1::MoveHandlesResponse response;
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + milliseconds(300));
  const grpc::Status status = stub_->MoveHandles(&context, long_move, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED) << describe(status);
  // The server stopped the solve (its deadline or the call's cancellation), committing nothing.
  EXPECT_TRUE(wait_for_cancelled_moves(1));
  v1::SessionInfo after;
  ASSERT_TRUE(info(s.session_id(), s.view_token(), &after).ok());
  EXPECT_EQ(after.revision(), 0u);
  // The session still works.
  v1::MoveHandlesResponse ok_response;
  const grpc::Status ok = move(bend_request(s, 10), &ok_response);
  ASSERT_TRUE(ok.ok()) << describe(ok);
  EXPECT_EQ(ok_response.result().revision(), 1u);
}

TEST_F(DeformServiceTest, ClientCancellationStopsTheSolve) {
  const v1::CreateSessionResponse s = create_with_handles("cylinder");
  v1::MoveHandlesRequest long_move = bend_request(s, 30);
  long_move.set_max_iterations(1000);
  long_move.set_tolerance(0.0);
  v1::MoveHandlesResponse response;
  grpc::ClientContext context;
  bound(context);
  std::promise<grpc::Status> done;
  std::future<grpc::Status> future = done.get_future();
  stub_->async()->MoveHandles(&context, &long_move, &response,
                              [&done](grpc::Status status) { done.set_value(std::move(status)); });
  // Cancel once the solve has started (a cancel before the server sees the call is fine too).
  std::this_thread::sleep_for(milliseconds(100));
  context.TryCancel();
  ASSERT_EQ(future.wait_for(seconds(60)), std::future_status::ready);
  EXPECT_EQ(future.get().error_code(), grpc::StatusCode::CANCELLED);
  EXPECT_TRUE(wait_for_cancelled_moves(1));
  v1::SessionInfo after;
  ASSERT_TRUE(info(s.session_id(), s.view_token(), &after).ok());
  EXPECT_EQ(after.revision(), 0u);
}

// --- watch -------------------------------------------------------------------------------------

TEST_F(DeformServiceTest, TwoWatchStreamsSeeTheSameRevisions) {
  const v1::CreateSessionResponse s = create_with_handles("cylinder_small");
  grpc::ClientContext c1, c2;
  bound(c1);
  bound(c2);
  v1::WatchRequest w1, w2;
  w1.set_session_id(s.session_id());
  w1.set_token(s.view_token());
  w2.set_session_id(s.session_id());
  w2.set_token(s.edit_token());  // the edit token may watch too
  auto r1 = stub_->Watch(&c1, w1);
  auto r2 = stub_->Watch(&c2, w2);
  for (auto* reader : {r1.get(), r2.get()}) {
    v1::DeformUpdate snapshot;
    ASSERT_TRUE(reader->Read(&snapshot));
    EXPECT_TRUE(snapshot.is_snapshot());
    EXPECT_EQ(snapshot.result().revision(), 0u);
    EXPECT_EQ(snapshot.result().positions_size(), 3 * 420);
    EXPECT_EQ(snapshot.result().changed_indices_size(), 0);
  }
  for (int step = 1; step <= 3; ++step) {
    v1::MoveHandlesRequest request = bend_request(s, 10.0 * step);
    request.set_editor("editor-" + std::to_string(step));
    v1::MoveHandlesResponse response;
    const grpc::Status status = move(request, &response);
    ASSERT_TRUE(status.ok()) << describe(status);
    for (auto* reader : {r1.get(), r2.get()}) {
      v1::DeformUpdate update;
      ASSERT_TRUE(reader->Read(&update));
      EXPECT_FALSE(update.is_snapshot());
      EXPECT_EQ(update.skipped_revisions(), 0u);
      EXPECT_EQ(update.result().revision(), response.result().revision());
      EXPECT_EQ(update.result().editor(), "editor-" + std::to_string(step));
      ASSERT_EQ(update.result().changed_indices_size(),
                response.result().changed_indices_size());
      for (int j = 0; j < update.result().changed_indices_size(); ++j) {
        EXPECT_EQ(update.result().changed_indices(j), response.result().changed_indices(j));
      }
      ASSERT_EQ(update.result().changed_positions_size(),
                response.result().changed_positions_size());
      for (int j = 0; j < update.result().changed_positions_size(); ++j) {
        EXPECT_EQ(update.result().changed_positions(j), response.result().changed_positions(j));
      }
    }
  }
  v1::SessionInfo during;
  ASSERT_TRUE(info(s.session_id(), s.view_token(), &during).ok());
  EXPECT_EQ(during.watchers(), 2u);
  // Closing the session ends both streams with OK.
  {
    grpc::ClientContext context;
    bound(context);
    v1::CloseSessionRequest request;
    request.set_session_id(s.session_id());
    request.set_token(s.edit_token());
    v1::CloseSessionResponse response;
    ASSERT_TRUE(stub_->CloseSession(&context, request, &response).ok());
  }
  for (auto* reader : {r1.get(), r2.get()}) {
    v1::DeformUpdate update;
    EXPECT_FALSE(reader->Read(&update));
    const grpc::Status finished = reader->Finish();
    EXPECT_TRUE(finished.ok()) << describe(finished);
  }
}

TEST_F(DeformServiceTest, CancelledWatchUnsubscribes) {
  const v1::CreateSessionResponse s = create_with_handles("cylinder_small");
  {
    grpc::ClientContext context;
    bound(context);
    v1::WatchRequest request;
    request.set_session_id(s.session_id());
    request.set_token(s.view_token());
    auto reader = stub_->Watch(&context, request);
    v1::DeformUpdate snapshot;
    ASSERT_TRUE(reader->Read(&snapshot));
    context.TryCancel();
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::CANCELLED);
  }
  // The server side unsubscribes in OnDone, shortly after the client sees CANCELLED.
  v1::SessionInfo after;
  for (int i = 0; i < 600; ++i) {
    ASSERT_TRUE(info(s.session_id(), s.view_token(), &after).ok());
    if (after.watchers() == 0) break;
    std::this_thread::sleep_for(milliseconds(50));
  }
  EXPECT_EQ(after.watchers(), 0u);
  v1::MoveHandlesResponse response;
  EXPECT_TRUE(move(bend_request(s, 10), &response).ok());
}

// --- health ------------------------------------------------------------------------------------

/// grpc.health.v1.Health/Check with an empty service name over a generic stub (Debian ships no
/// generated health stub). The response is {status = 1 (SERVING)}: bytes 0x08 0x01.
grpc::Status health_check(const std::shared_ptr<grpc::Channel>& channel, std::string* body) {
  grpc::GenericStub stub(channel);
  grpc::ClientContext context;
  bound(context, seconds(30));
  const grpc::Slice empty(std::string{});
  const grpc::ByteBuffer request(&empty, 1);  // an empty HealthCheckRequest (service "")
  grpc::ByteBuffer response;
  std::promise<grpc::Status> done;
  stub.UnaryCall(&context, "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                 [&done](grpc::Status status) { done.set_value(std::move(status)); });
  std::future<grpc::Status> future = done.get_future();
  if (future.wait_for(seconds(60)) != std::future_status::ready) {
    return grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, "no answer");
  }
  grpc::Status status = future.get();
  std::vector<grpc::Slice> slices;
  if (status.ok() && response.Dump(&slices).ok()) {
    for (const grpc::Slice& slice : slices) {
      body->append(reinterpret_cast<const char*>(slice.begin()), slice.size());
    }
  }
  return status;
}

TEST_F(DeformServiceTest, HealthIsServingInProcessAndOnLoopback) {
  std::string body;
  const grpc::Status status = health_check(channel_, &body);
  ASSERT_TRUE(status.ok()) << describe(status);
  EXPECT_EQ(body, std::string("\x08\x01", 2));

  // A second server on a loopback port picked by the kernel: the real network path.
  service::DeformationService service(one_worker());
  DeformServiceImpl impl(service);
  int port = 0;
  std::unique_ptr<grpc::Server> server = serve_on_loopback(impl, &port);
  ASSERT_NE(server, nullptr);
  ASSERT_GT(port, 0);
  auto channel = grpc::CreateChannel("127.0.0.1:" + std::to_string(port),
                                     grpc::InsecureChannelCredentials());
  std::string tcp_body;
  const grpc::Status tcp = health_check(channel, &tcp_body);
  ASSERT_TRUE(tcp.ok()) << describe(tcp);
  EXPECT_EQ(tcp_body, std::string("\x08\x01", 2));
  // And a real call over TCP.
  auto stub = v1::DeformationService::NewStub(channel);
  grpc::ClientContext context;
  bound(context);
  v1::CreateSessionResponse created;
  const grpc::Status made = stub->CreateSession(&context, sample_request("bar_small"), &created);
  ASSERT_TRUE(made.ok()) << describe(made);
  EXPECT_EQ(created.info().vertices(), 554u);
  server->Shutdown(std::chrono::system_clock::now() + seconds(10));
}

// --- compact position encodings (issue 5: bytes per browser update) ----------------------------

/// Decodes packed positions of `count` vertices in `encoding` back to float32 xyz.
std::vector<float> unpack(const std::string& bytes, v1::PositionEncoding encoding,
                          std::size_t count) {
  std::vector<float> out(3 * count);
  if (count == 0) {
    EXPECT_TRUE(bytes.empty());  // no vertex, no bytes (meshopt too: no header to decode)
    return out;
  }
  if (encoding == v1::POSITION_ENCODING_FLOAT32) {
    EXPECT_EQ(bytes.size(), out.size() * sizeof(float));
    if (bytes.size() == out.size() * sizeof(float)) std::memcpy(out.data(), bytes.data(), bytes.size());
  } else {
    EXPECT_EQ(meshopt_decodeVertexBuffer(out.data(), count, 3 * sizeof(float),
                                         reinterpret_cast<const unsigned char*>(bytes.data()),
                                         bytes.size()),
              0);
  }
  return out;
}

TEST_F(DeformServiceTest, CompactEncodingsCarryTheSamePositions) {
  // The same deterministic edit on three sessions, one per encoding: the packed forms must decode
  // to exactly the float32 rounding of the doubles (MESHOPT is lossless over FLOAT32), with the
  // same changed indices; MESHOPT must be the smallest.
  std::vector<v1::MoveHandlesResponse> responses;
  for (v1::PositionEncoding encoding :
       {v1::POSITION_ENCODING_UNSPECIFIED, v1::POSITION_ENCODING_FLOAT32,
        v1::POSITION_ENCODING_MESHOPT}) {
    const v1::CreateSessionResponse s = create_with_handles("cylinder_small");
    v1::MoveHandlesRequest request = bend_request(s, 30);
    request.set_full_positions(true);
    request.set_encoding(encoding);
    v1::MoveHandlesResponse response;
    const grpc::Status status = move(request, &response);
    ASSERT_TRUE(status.ok()) << describe(status);
    EXPECT_EQ(response.result().encoding(), encoding);
    responses.push_back(response);
  }
  const v1::DeformResult& exact = responses[0].result();
  ASSERT_EQ(exact.positions_size(), 3 * 420);
  ASSERT_GT(exact.changed_indices_size(), 100);
  EXPECT_TRUE(exact.packed_positions().empty());
  // The bend moves every vertex (the fixed ring too, by the soft constraint), so the compact
  // forms send the delta dense: all positions, no indices.
  ASSERT_EQ(exact.changed_indices_size(), 420);
  EXPECT_FALSE(exact.dense());  // doubles keep the exact changed lists
  for (int e = 1; e <= 2; ++e) {
    const v1::DeformResult& packed = responses[static_cast<std::size_t>(e)].result();
    EXPECT_EQ(packed.positions_size(), 0);
    EXPECT_EQ(packed.changed_positions_size(), 0);
    EXPECT_TRUE(packed.dense());
    EXPECT_EQ(packed.changed_indices_size(), 0);
    EXPECT_TRUE(packed.packed_changed_positions().empty());
    const std::vector<float> all = unpack(packed.packed_positions(), packed.encoding(), 420);
    for (int j = 0; j < exact.positions_size(); ++j) {
      ASSERT_EQ(all[static_cast<std::size_t>(j)], static_cast<float>(exact.positions(j))) << j;
    }
  }
  const std::size_t doubles = responses[0].ByteSizeLong();
  const std::size_t floats = responses[1].ByteSizeLong();
  const std::size_t meshopt = responses[2].ByteSizeLong();
  EXPECT_LT(floats, doubles * 6 / 10) << doubles << " vs " << floats;
  EXPECT_LT(meshopt, floats) << floats << " vs " << meshopt;
}

TEST(ProtoConvertTest, ARevisionIsEncodedOnceForItsResponseAndEveryWatcher) {
  // A dense result (every vertex changed): the response, a watcher's delta and a joining
  // watcher's snapshot all send the same packed positions, made once into the result's memo.
  service::DeformResult result;
  Positions V(50, 3);
  for (int i = 0; i < 50; ++i) V.row(i) << 0.1 * i, std::sin(0.3 * i), 1.0 - 0.02 * i;
  result.positions = std::make_shared<const Positions>(V);
  for (int i = 0; i < 50; ++i) result.changed.push_back(i);
  result.changed_positions = V;
  v1::DeformResult response;
  transport::result_to_proto(result, false, v1::POSITION_ENCODING_MESHOPT, &response);
  ASSERT_TRUE(response.dense());
  const std::size_t encoded = result.encoded->bytes();
  EXPECT_EQ(encoded, response.packed_positions().size());
  service::DeformUpdate delta{std::make_shared<const service::DeformResult>(result), false, 0};
  service::DeformUpdate snapshot{delta.result, true, 0};
  v1::DeformUpdate delta_proto, snapshot_proto;
  transport::update_to_proto(delta, v1::POSITION_ENCODING_MESHOPT, &delta_proto);
  transport::update_to_proto(snapshot, v1::POSITION_ENCODING_MESHOPT, &snapshot_proto);
  EXPECT_EQ(delta_proto.result().packed_positions(), response.packed_positions());
  EXPECT_EQ(snapshot_proto.result().packed_positions(), response.packed_positions());
  EXPECT_EQ(result.encoded->bytes(), encoded) << "the same revision was encoded again";
  const std::vector<float> decoded = unpack(response.packed_positions(),
                                            v1::POSITION_ENCODING_MESHOPT, 50);
  for (int i = 0; i < 50; ++i) {
    for (int c = 0; c < 3; ++c) {
      ASSERT_EQ(decoded[static_cast<std::size_t>(3 * i + c)], static_cast<float>(V(i, c)));
    }
  }
  // Another encoding is another entry; a copy with other positions takes a new memo (the
  // memo's contract), and then sends its own positions.
  v1::DeformResult floats;
  transport::result_to_proto(result, false, v1::POSITION_ENCODING_FLOAT32, &floats);
  EXPECT_EQ(result.encoded->bytes(), encoded + 50 * 12);
  service::DeformResult moved = result;
  moved.positions = std::make_shared<const Positions>(2.0 * V);
  moved.encoded = std::make_shared<service::BytesMemo>();
  v1::DeformResult moved_response;
  transport::result_to_proto(moved, false, v1::POSITION_ENCODING_MESHOPT, &moved_response);
  EXPECT_EQ(unpack(moved_response.packed_positions(), v1::POSITION_ENCODING_MESHOPT, 50)[3],
            static_cast<float>(2.0 * V(1, 0)));
  // A coarse level's positions are one more entry, shared by every stream that asks for them:
  // two streams (each sent its own mesh) carry the same bytes, made once.
  auto mesh = std::make_shared<core::CoarseLevelMesh>();
  mesh->F = Triangles(1, 3);
  mesh->F << 0, 1, 2;
  mesh->to_fine.resize(3);
  mesh->to_fine << 0, 10, 20;
  mesh->key = core::coarse_level_key(mesh->F, mesh->to_fine);
  Positions coarse_rows(3, 3);
  for (int i = 0; i < 3; ++i) coarse_rows.row(i) = V.row(mesh->to_fine(i));
  result.coarse = std::make_shared<const core::CoarseLevelPositions>(
      core::CoarseLevelPositions{mesh, coarse_rows});
  const std::size_t before_coarse = result.encoded->bytes();
  std::optional<std::uint64_t> sent_a, sent_b;
  v1::DeformUpdate coarse_a, coarse_b;
  transport::coarse_to_proto(result, &sent_a, &coarse_a);
  transport::coarse_to_proto(result, &sent_b, &coarse_b);
  EXPECT_EQ(coarse_a.coarse().positions(), coarse_b.coarse().positions());
  EXPECT_EQ(coarse_b.coarse().triangles_size(), 3);
  EXPECT_EQ(result.encoded->bytes(), before_coarse + 3 * 12) << "coarse positions encoded twice";
  EXPECT_EQ(unpack(coarse_a.coarse().positions(), v1::POSITION_ENCODING_FLOAT32, 3)[3],
            static_cast<float>(V(10, 0)));
}

TEST_F(DeformServiceTest, WatchSnapshotsAndDeltasInMeshopt) {
  const v1::CreateSessionResponse s = create_with_handles("cylinder_small");
  grpc::ClientContext context;
  bound(context);
  v1::WatchRequest watch;
  watch.set_session_id(s.session_id());
  watch.set_token(s.view_token());
  watch.set_encoding(v1::POSITION_ENCODING_MESHOPT);
  auto reader = stub_->Watch(&context, watch);
  v1::DeformUpdate snapshot;
  ASSERT_TRUE(reader->Read(&snapshot));
  ASSERT_TRUE(snapshot.is_snapshot());
  EXPECT_EQ(snapshot.result().encoding(), v1::POSITION_ENCODING_MESHOPT);
  std::vector<float> mirror = unpack(snapshot.result().packed_positions(),
                                     v1::POSITION_ENCODING_MESHOPT, 420);
  // Move 1 (from rest) moves every vertex: a dense delta. Moves 2 and 3 solve the same targets
  // with Laplacian editing (direct, deterministic): 2 changes vertices, 3 changes none (a sparse,
  // empty delta).
  for (int step = 1; step <= 3; ++step) {
    v1::MoveHandlesRequest request = bend_request(s, 25);
    if (step >= 2) request.set_method(v1::METHOD_LAPLACIAN);
    request.set_full_positions(true);  // doubles: the reference
    v1::MoveHandlesResponse response;
    ASSERT_TRUE(move(request, &response).ok());
    v1::DeformUpdate update;
    ASSERT_TRUE(reader->Read(&update));
    ASSERT_FALSE(update.is_snapshot());
    const v1::DeformResult& r = update.result();
    if (step == 1) {
      EXPECT_TRUE(r.dense());
    }
    if (step == 3) {
      EXPECT_FALSE(r.dense());
      EXPECT_EQ(r.changed_indices_size(), 0);
      EXPECT_TRUE(r.packed_changed_positions().empty());
    }
    if (r.dense()) {
      mirror = unpack(r.packed_positions(), v1::POSITION_ENCODING_MESHOPT, 420);
    } else {
      const std::vector<float> changed =
          unpack(r.packed_changed_positions(), v1::POSITION_ENCODING_MESHOPT,
                 static_cast<std::size_t>(r.changed_indices_size()));
      for (int j = 0; j < r.changed_indices_size(); ++j) {
        const std::size_t v = r.changed_indices(j);
        for (int c = 0; c < 3; ++c) mirror[3 * v + c] = changed[static_cast<std::size_t>(3 * j + c)];
      }
    }
    // Snapshot + deltas reproduce each revision (to float32 rounding of the doubles).
    for (int j = 0; j < response.result().positions_size(); ++j) {
      ASSERT_EQ(mirror[static_cast<std::size_t>(j)],
                static_cast<float>(response.result().positions(j)))
          << "step " << step << " value " << j;
    }
  }
  context.TryCancel();
}

TEST_F(DeformServiceTest, UnknownEncodingIsInvalidArgument) {
  const v1::CreateSessionResponse s = create_with_handles("cylinder_small");
  v1::MoveHandlesRequest request = bend_request(s, 10);
  request.set_encoding(static_cast<v1::PositionEncoding>(42));
  v1::MoveHandlesResponse response;
  const grpc::Status moved = move(request, &response);
  EXPECT_EQ(moved.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(moved.error_message().find("42"), std::string::npos) << moved.error_message();
  grpc::ClientContext context;
  bound(context);
  v1::WatchRequest watch;
  watch.set_session_id(s.session_id());
  watch.set_token(s.view_token());
  watch.set_encoding(static_cast<v1::PositionEncoding>(-1));
  auto reader = stub_->Watch(&context, watch);
  v1::DeformUpdate update;
  EXPECT_FALSE(reader->Read(&update));
  EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::INVALID_ARGUMENT);
}

// --- magnify regions (paper Section 5.3) --------------------------------------------------------

/// Total area of the faces whose three vertices are all in `region`.
double region_area(const MeshData& mesh, const google::protobuf::RepeatedField<double>& flat,
                   const std::vector<bool>& region) {
  double area = 0;
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    if (!region[mesh.F(f, 0)] || !region[mesh.F(f, 1)] || !region[mesh.F(f, 2)]) continue;
    Eigen::Vector3d p[3];
    for (int k = 0; k < 3; ++k) {
      const int v = mesh.F(f, k);
      p[k] = Eigen::Vector3d(flat[3 * v], flat[3 * v + 1], flat[3 * v + 2]);
    }
    area += 0.5 * (p[1] - p[0]).cross(p[2] - p[0]).norm();
  }
  return area;
}

TEST_F(DeformServiceTest, MagnifyGrowsTheRegionWithScaleAwareOnly) {
  const v1::CreateSessionResponse s = create_with_handles("cylinder_small");
  // The mesh itself, to find the region: the upper half of the tube, handles excluded.
  v1::GetMeshResponse mesh_bytes;
  {
    grpc::ClientContext context;
    bound(context);
    v1::GetMeshRequest request;
    request.set_session_id(s.session_id());
    request.set_token(s.view_token());
    request.set_format(v1::MESH_FORMAT_OBJ);
    ASSERT_TRUE(stub_->GetMesh(&context, request, &mesh_bytes).ok());
  }
  Result<MeshData> mesh = io::read_mesh_from_memory(mesh_bytes.mesh_bytes(), io::MeshFormat::Obj);
  ASSERT_TRUE(mesh.ok());
  std::vector<bool> constrained(static_cast<std::size_t>(mesh->V.rows()), false);
  for (const v1::HandleGroup& g : s.suggested_groups()) {
    for (std::uint32_t v : g.vertices()) constrained[v] = true;
  }
  // Height axis: the longest side of the bounding box.
  const Eigen::Vector3d extent = mesh->V.colwise().maxCoeff() - mesh->V.colwise().minCoeff();
  Eigen::Index axis = 0;
  extent.maxCoeff(&axis);
  const double lo = mesh->V.col(axis).minCoeff();
  std::vector<bool> region(static_cast<std::size_t>(mesh->V.rows()), false);
  v1::MagnifyRegion magnify;
  magnify.set_scale(1.5);
  for (Eigen::Index v = 0; v < mesh->V.rows(); ++v) {
    const double t = (mesh->V(v, axis) - lo) / extent(axis);
    if (t > 0.55 && !constrained[static_cast<std::size_t>(v)]) {
      region[static_cast<std::size_t>(v)] = true;
      magnify.add_vertices(static_cast<std::uint32_t>(v));
    }
  }
  ASSERT_GT(magnify.vertices_size(), 50);

  auto still = [&](bool with_magnify, v1::Method method) {
    v1::MoveHandlesRequest request;
    request.set_session_id(s.session_id());
    request.set_token(s.edit_token());
    request.set_method(method);
    request.set_max_iterations(10);
    request.set_full_positions(true);
    if (with_magnify) *request.add_magnify() = magnify;
    return request;
  };
  v1::MoveHandlesResponse plain, grown;
  ASSERT_TRUE(move(still(false, v1::METHOD_SCALE_AWARE), &plain).ok());
  const grpc::Status status = move(still(true, v1::METHOD_SCALE_AWARE), &grown);
  ASSERT_TRUE(status.ok()) << describe(status);
  Positions rest_flat = mesh->V;
  google::protobuf::RepeatedField<double> rest;
  for (Eigen::Index v = 0; v < rest_flat.rows(); ++v)
    for (int c = 0; c < 3; ++c) rest.Add(rest_flat(v, c));
  const double a0 = region_area(*mesh, rest, region);
  const double a_plain = region_area(*mesh, plain.result().positions(), region);
  const double a_grown = region_area(*mesh, grown.result().positions(), region);
  EXPECT_NEAR(a_plain / a0, 1.0, 1e-3);  // handles at rest: the rest pose, nothing grows
  // k = 1.5 asks for 2.25x the area; the constrained rims hold the tube, so it gets part of it.
  EXPECT_GT(a_grown / a0, 1.3) << a_grown / a0;

  // Wrong method, bad scale, bad index: InvalidArgument, nothing committed.
  v1::SessionInfo before;
  ASSERT_TRUE(info(s.session_id(), s.view_token(), &before).ok());
  v1::MoveHandlesResponse response;
  EXPECT_EQ(move(still(true, v1::METHOD_ARAP), &response).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
  v1::MoveHandlesRequest bad = still(true, v1::METHOD_SCALE_AWARE);
  bad.mutable_magnify(0)->set_scale(0);
  EXPECT_EQ(move(bad, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  bad.mutable_magnify(0)->set_scale(std::nan(""));
  EXPECT_EQ(move(bad, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  bad = still(true, v1::METHOD_SCALE_AWARE);
  bad.mutable_magnify(0)->add_vertices(100000);
  const grpc::Status out_of_range = move(bad, &response);
  EXPECT_EQ(out_of_range.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(out_of_range.error_message().find("100000"), std::string::npos)
      << out_of_range.error_message();
  v1::SessionInfo after;
  ASSERT_TRUE(info(s.session_id(), s.view_token(), &after).ok());
  EXPECT_EQ(after.revision(), before.revision());
}

// --- per-client rate limits ------------------------------------------------------------------

TEST_F(DeformServiceTest, RateLimitsAreResourceExhaustedWithARetryHintPerClient) {
  stop();
  service::ServiceOptions options;
  options.create_rate = {0.001, 2.0};  // two sessions, then one every ~17 minutes
  options.move_rate = {0.001, 3.0};
  start(options);
  auto create_as = [&](const std::string& browser, grpc::Status* status) {
    grpc::ClientContext context;
    bound(context);
    // In-process calls come from the gRPC-Web gateway, which names the browser this way.
    if (!browser.empty()) context.AddMetadata("x-meshdeform-peer", browser);
    v1::CreateSessionResponse created;
    *status = stub_->CreateSession(&context, sample_request("cylinder_small"), &created);
    const auto& trailers = context.GetServerTrailingMetadata();
    const auto it = trailers.find("retry-after-ms");
    return it == trailers.end() ? std::string() : std::string(it->second.data(), it->second.size());
  };
  grpc::Status status;
  EXPECT_EQ(create_as("ipv4:10.0.0.1", &status), "");
  EXPECT_TRUE(status.ok()) << describe(status);
  EXPECT_EQ(create_as("ipv4:10.0.0.1", &status), "");
  EXPECT_TRUE(status.ok()) << describe(status);
  const std::string retry = create_as("ipv4:10.0.0.1", &status);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_NE(status.error_message().find("retry in"), std::string::npos) << status.error_message();
  ASSERT_FALSE(retry.empty());
  EXPECT_GT(std::stoll(retry), 60'000);  // 1 / 0.001 s, about 1000 s
  // Another browser is not held back by the first one.
  EXPECT_EQ(create_as("ipv4:10.0.0.2", &status), "");
  EXPECT_TRUE(status.ok()) << describe(status);

  // Moves: three, then refused with nothing committed; reads are never limited.
  const v1::CreateSessionResponse s = create_with_handles("cylinder_small");  // anonymous client
  for (int i = 1; i <= 3; ++i) {
    v1::MoveHandlesResponse response;
    const grpc::Status moved = move(bend_request(s, 5.0 * i), &response);
    ASSERT_TRUE(moved.ok()) << i << " " << describe(moved);
  }
  v1::MoveHandlesResponse response;
  EXPECT_EQ(move(bend_request(s, 20), &response).error_code(),
            grpc::StatusCode::RESOURCE_EXHAUSTED);
  v1::SessionInfo after;
  ASSERT_TRUE(info(s.session_id(), s.view_token(), &after).ok());
  EXPECT_EQ(after.revision(), 3u);
  const service::ServiceStats stats = service_->stats();
  EXPECT_EQ(stats.rate_limited_creates, 1u);
  EXPECT_EQ(stats.rate_limited_moves, 1u);
  EXPECT_NE(service_->render_metrics().find(
                "meshdeform_rate_limited_total{call=\"MoveHandles\"} 1"),
            std::string::npos);
}

TEST(ClientIdentityTest, BehindATrustedProxyClientsAreNamedByForwardedFor) {
  service::ServiceOptions options;
  options.create_rate = {0.001, 1.0};
  service::DeformationService service(options);
  ClientIdentityOptions identity;
  identity.trust_forwarded_for = true;
  DeformServiceImpl impl(service, identity);
  int port = 0;
  std::unique_ptr<grpc::Server> server = serve_on_loopback(impl, &port);
  ASSERT_NE(server, nullptr);
  auto stub = v1::DeformationService::NewStub(grpc::CreateChannel(
      "127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials()));
  std::vector<grpc::StatusCode> codes;
  // One proxy address, three clients behind it (the proxy sets the header; nginx: $remote_addr).
  for (const char* client : {"203.0.113.1", "203.0.113.2", "203.0.113.1"}) {
    grpc::ClientContext context;
    bound(context);
    context.AddMetadata("x-forwarded-for", client);
    v1::CreateSessionResponse created;
    codes.push_back(stub->CreateSession(&context, sample_request("bar_small"), &created).error_code());
  }
  EXPECT_EQ(codes[0], grpc::StatusCode::OK);
  EXPECT_EQ(codes[1], grpc::StatusCode::OK);  // another client behind the same proxy
  EXPECT_EQ(codes[2], grpc::StatusCode::RESOURCE_EXHAUSTED);
  server->Shutdown(std::chrono::system_clock::now() + seconds(10));
}

TEST(ClientIdentityTest, NetworkPeersCannotNameThemselves) {
  // Over TCP the peer address names the client, whatever metadata it sends.
  service::ServiceOptions options;
  options.create_rate = {0.001, 1.0};
  service::DeformationService service(options);
  DeformServiceImpl impl(service);
  int port = 0;
  std::unique_ptr<grpc::Server> server = serve_on_loopback(impl, &port);
  ASSERT_NE(server, nullptr);
  auto stub = v1::DeformationService::NewStub(grpc::CreateChannel(
      "127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials()));
  std::vector<grpc::StatusCode> codes;
  for (const char* name : {"ipv4:10.9.9.1", "ipv4:10.9.9.2"}) {
    grpc::ClientContext context;
    bound(context);
    context.AddMetadata("x-meshdeform-peer", name);
    context.AddMetadata("x-forwarded-for", name);
    v1::CreateSessionResponse created;
    codes.push_back(stub->CreateSession(&context, sample_request("bar_small"), &created).error_code());
  }
  EXPECT_EQ(codes[0], grpc::StatusCode::OK);
  EXPECT_EQ(codes[1], grpc::StatusCode::RESOURCE_EXHAUSTED);
  server->Shutdown(std::chrono::system_clock::now() + seconds(10));
}

TEST_F(DeformServiceTest, SessionInfoTellsWhatTheTokenAllows) {
  const v1::CreateSessionResponse s = create_with_handles("cylinder_small");
  for (const bool edit : {true, false}) {
    grpc::ClientContext context;
    bound(context);
    v1::GetSessionInfoRequest request;
    request.set_session_id(s.session_id());
    request.set_token(edit ? s.edit_token() : s.view_token());
    v1::GetSessionInfoResponse response;
    ASSERT_TRUE(stub_->GetSessionInfo(&context, request, &response).ok());
    EXPECT_EQ(response.can_edit(), edit);
    EXPECT_EQ(response.view_token(), edit ? s.view_token() : "");  // never the edit token
  }
}

namespace meshdeform::transport {
namespace {

// Issue 17: the settings and undo history travel in SessionInfo.edit, undo and redo are moves.
TEST_F(DeformServiceTest, UndoRedoAndTheEditStateOverTheWire) {
  const v1::CreateSessionResponse created = create_with_handles("cylinder_small");
  v1::MoveHandlesRequest first = bend_request(created, 20);
  first.set_method(v1::METHOD_LAPLACIAN);
  first.set_max_iterations(1);
  first.set_full_positions(true);
  v1::MoveHandlesResponse bent, second, undone, response;
  ASSERT_TRUE(move(first, &bent).ok());
  v1::MoveHandlesRequest next = bend_request(created, 40);
  next.set_method(v1::METHOD_LAPLACIAN);
  next.set_max_iterations(1);
  next.set_gesture(12);
  ASSERT_TRUE(move(next, &second).ok());

  v1::SessionInfo info_now;
  ASSERT_TRUE(info(created.session_id(), created.view_token(), &info_now).ok());
  ASSERT_EQ(info_now.edit().steps_size(), 3);
  EXPECT_EQ(info_now.edit().position(), 2u);
  EXPECT_EQ(info_now.edit().steps(2).gesture(), 12u);
  ASSERT_EQ(info_now.edit().steps(2).moves_size(), 1);
  EXPECT_EQ(info_now.edit().steps(2).moves(0).group(), 1u);
  EXPECT_EQ(info_now.edit().settings().method(), v1::METHOD_LAPLACIAN);
  EXPECT_EQ(info_now.edit().settings().max_iterations(), 1u);
  int constrained = 0;
  for (const v1::HandleGroup& g : info_now.groups()) constrained += g.vertices_size();
  EXPECT_EQ(info_now.group_anchors_size(), 3 * constrained);

  v1::MoveHandlesRequest undo;
  undo.set_session_id(created.session_id());
  undo.set_token(created.edit_token());
  undo.set_method(v1::METHOD_LAPLACIAN);
  undo.set_max_iterations(1);
  undo.set_history(v1::HISTORY_ACTION_UNDO);
  undo.set_full_positions(true);
  ASSERT_TRUE(move(undo, &undone).ok());
  ASSERT_EQ(undone.result().positions_size(), bent.result().positions_size());
  for (int i = 0; i < bent.result().positions_size(); ++i) {
    ASSERT_EQ(undone.result().positions(i), bent.result().positions(i)) << "coordinate " << i;
  }
  ASSERT_TRUE(info(created.session_id(), created.view_token(), &info_now).ok());
  EXPECT_EQ(info_now.edit().position(), 1u);

  // Undo with moves, and an unknown action, are INVALID_ARGUMENT; past the start, FAILED_PRECONDITION.
  v1::MoveHandlesRequest with_moves = undo;
  *with_moves.add_moves() = bend(5);
  EXPECT_EQ(move(with_moves, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  v1::MoveHandlesRequest unknown = undo;
  unknown.set_history(static_cast<v1::HistoryAction>(9));
  EXPECT_EQ(move(unknown, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  ASSERT_TRUE(move(undo, &response).ok());
  const grpc::Status nothing = move(undo, &response);
  EXPECT_EQ(nothing.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << describe(nothing);
  EXPECT_NE(nothing.error_message().find("nothing to undo"), std::string::npos);
  v1::MoveHandlesRequest redo = undo;
  redo.set_history(v1::HISTORY_ACTION_REDO);
  ASSERT_TRUE(move(redo, &response).ok());
  ASSERT_TRUE(info(created.session_id(), created.view_token(), &info_now).ok());
  EXPECT_EQ(info_now.edit().position(), 1u);
}

// --- progress streams (issue 15) ---------------------------------------------------------------

TEST_F(DeformServiceTest, CreateAndSetHandlesWithProgressStreamPhasesThenTheResponse) {
  const auto created = create_with_progress(sample_request("cylinder_small"));
  ASSERT_TRUE(created.status.ok()) << describe(created.status);
  EXPECT_EQ(created.responses, 1);
  EXPECT_TRUE(created.response_last);
  EXPECT_EQ(created.phases, (std::vector<std::string>{"queued", "parse", "session"}));
  const v1::CreateSessionResponse& session = created.last.response();
  EXPECT_EQ(session.info().vertices(), 420u);
  ASSERT_EQ(session.suggested_groups_size(), 2);

  const auto set = set_handles_with_progress(suggested_handles(session));
  ASSERT_TRUE(set.status.ok()) << describe(set.status);
  EXPECT_EQ(set.responses, 1);
  EXPECT_TRUE(set.response_last);
  EXPECT_EQ(set.phases,
            (std::vector<std::string>{"queued", "validate", "rigid_start", "step_two"}));
  EXPECT_EQ(set.last.response().info().groups_size(), 2);

  // The session works as if set with the unary call.
  v1::MoveHandlesResponse moved;
  const grpc::Status move_status = move(bend_request(session, 20), &moved);
  ASSERT_TRUE(move_status.ok()) << describe(move_status);
  EXPECT_EQ(moved.result().revision(), 1u);
}

TEST_F(DeformServiceTest, ProgressStreamsEndWithTheUnaryCallsErrors) {
  {  // A bad mesh: INVALID_ARGUMENT after the parse began, and no response.
    v1::CreateSessionRequest bad;
    bad.set_mesh_bytes("v 0 0 0\nf 1 2 3\n");
    bad.set_format(v1::MESH_FORMAT_OBJ);
    const auto read = create_with_progress(bad);
    EXPECT_EQ(read.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << describe(read.status);
    EXPECT_EQ(read.responses, 0);
  }
  const v1::CreateSessionResponse s = create_with_handles("cylinder_small");
  v1::SetHandlesRequest handles = suggested_handles(s);
  {  // The view token cannot set handles: PERMISSION_DENIED before any work.
    handles.set_token(s.view_token());
    const auto read = set_handles_with_progress(handles);
    EXPECT_EQ(read.status.error_code(), grpc::StatusCode::PERMISSION_DENIED);
    EXPECT_EQ(read.progress_events, 0);
    EXPECT_EQ(read.responses, 0);
  }
  {  // An unknown session: NOT_FOUND.
    handles.set_session_id("0123456789abcdef0123456789abcdef");
    handles.set_token(s.edit_token());
    EXPECT_EQ(set_handles_with_progress(handles).status.error_code(), grpc::StatusCode::NOT_FOUND);
  }
  {  // A vertex out of range: INVALID_ARGUMENT.
    handles.set_session_id(s.session_id());
    handles.mutable_groups(1)->add_vertices(1'000'000);
    EXPECT_EQ(set_handles_with_progress(handles).status.error_code(),
              grpc::StatusCode::INVALID_ARGUMENT);
  }
}

TEST_F(DeformServiceTest, ACancelledProgressStreamEndsAndTheSessionStillServes) {
  v1::CreateSessionResponse created;
  ASSERT_TRUE(create(sample_request("cylinder"), &created).ok());
  const v1::SetHandlesRequest handles = suggested_handles(created);
  {
    grpc::ClientContext context;
    bound(context);
    auto reader = stub_->SetHandlesWithProgress(&context, handles);
    v1::SetHandlesEvent first;
    ASSERT_TRUE(reader->Read(&first));  // "queued", sent when the call was admitted
    ASSERT_TRUE(first.has_progress());
    EXPECT_EQ(first.progress().phase(), "queued");
    context.TryCancel();
    const auto rest = read_all(*reader);
    // Cancelled, unless the precompute finished before the cancel reached it.
    EXPECT_TRUE(rest.status.error_code() == grpc::StatusCode::CANCELLED || rest.status.ok())
        << describe(rest.status);
  }
  const auto read = set_handles_with_progress(handles);
  ASSERT_TRUE(read.status.ok()) << describe(read.status);
  EXPECT_EQ(read.responses, 1);
  v1::MoveHandlesResponse moved;
  const grpc::Status status = move(bend_request(created, 20), &moved);
  EXPECT_TRUE(status.ok()) << describe(status);
}

}  // namespace
}  // namespace meshdeform::transport

namespace meshdeform::transport {
namespace {

// Issue 44: exact undo over the wire. Steps carry their settings and (while kept) the revision
// that showed them, moves answer with the history position, undo commits the kept positions
// bit for bit, and restore_revision brings back an earlier shape after a SetHandles.
TEST_F(DeformServiceTest, ExactUndoFieldsOverTheWire) {
  const v1::CreateSessionResponse created = create_with_handles("cylinder_small");
  v1::MoveHandlesRequest first = bend_request(created, 20);
  first.set_max_iterations(2);  // scale-aware, far from converged: a re-solve would land elsewhere
  first.set_full_positions(true);
  v1::MoveHandlesResponse bent, second, undone, response;
  ASSERT_TRUE(move(first, &bent).ok());
  EXPECT_EQ(bent.result().history_position(), 1u);
  v1::MoveHandlesRequest stiffer = first;
  stiffer.set_rigidity(300);  // the same moves, other settings: a step of its own
  ASSERT_TRUE(move(stiffer, &second).ok());
  EXPECT_TRUE(second.result().has_history_position());
  EXPECT_EQ(second.result().history_position(), 2u);

  v1::SessionInfo now;
  ASSERT_TRUE(info(created.session_id(), created.view_token(), &now).ok());
  ASSERT_EQ(now.edit().steps_size(), 3);
  EXPECT_FALSE(now.edit().steps(0).has_settings());  // the handles as set, before any move
  ASSERT_TRUE(now.edit().steps(2).has_settings());
  EXPECT_EQ(now.edit().steps(2).settings().rigidity(), 300);
  EXPECT_NE(now.edit().steps(1).settings().rigidity(), 300);
  ASSERT_TRUE(now.edit().steps(1).has_revision());
  EXPECT_EQ(now.edit().steps(1).revision(), bent.result().revision());
  ASSERT_TRUE(now.edit().steps(2).has_revision());  // the current step: the current revision
  EXPECT_EQ(now.edit().steps(2).revision(), now.revision());

  v1::MoveHandlesRequest undo;
  undo.set_session_id(created.session_id());
  undo.set_token(created.edit_token());
  undo.set_history(v1::HISTORY_ACTION_UNDO);
  undo.set_full_positions(true);
  ASSERT_TRUE(move(undo, &undone).ok());
  EXPECT_EQ(undone.result().iterations(), 0u);  // restored, not solved
  EXPECT_EQ(undone.result().history_position(), 1u);
  ASSERT_EQ(undone.result().positions_size(), bent.result().positions_size());
  for (int i = 0; i < bent.result().positions_size(); ++i) {
    ASSERT_EQ(undone.result().positions(i), bent.result().positions(i)) << "coordinate " << i;
  }
  // Watch updates never carry a history position.
  EXPECT_FALSE(v1::DeformResult().has_history_position());

  // New handles (the same groups again), then the first bend's shape by its revision.
  {
    grpc::ClientContext context;
    bound(context);
    v1::SetHandlesRequest again;
    again.set_session_id(created.session_id());
    again.set_token(created.edit_token());
    *again.mutable_groups() = created.suggested_groups();
    v1::SetHandlesResponse set;
    ASSERT_TRUE(stub_->SetHandles(&context, again, &set).ok());
  }
  v1::MoveHandlesRequest restore = bend_request(created, 0);
  restore.clear_moves();
  restore.set_restore_revision(bent.result().revision());
  restore.set_full_positions(true);
  ASSERT_TRUE(move(restore, &response).ok());
  EXPECT_EQ(response.result().iterations(), 0u);
  for (int i = 0; i < bent.result().positions_size(); ++i) {
    ASSERT_EQ(response.result().positions(i), bent.result().positions(i)) << "coordinate " << i;
  }
  restore.set_restore_revision(response.result().revision() + 10);
  const grpc::Status unknown = move(restore, &response);
  EXPECT_EQ(unknown.error_code(), grpc::StatusCode::FAILED_PRECONDITION) << describe(unknown);
  EXPECT_NE(unknown.error_message().find("not kept"), std::string::npos);
  v1::MoveHandlesRequest both = undo;
  both.set_restore_revision(0);
  EXPECT_EQ(move(both, &response).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
}

}  // namespace
}  // namespace meshdeform::transport

// Issue 44: a watcher asking for coarse_preview gets, with each move a multiresolution session
// solved on its coarse level, that level's positions (its mesh once per stream), which are the
// prolonged full result's at the coarse vertices; full-resolution solves carry none, and a
// watcher that did not ask gets none. The same in plain and in link-sized (delta) streams.
TEST_F(DeformServiceTest, CoarsePreviewCarriesTheCoarseLevelOfMultiresolutionMoves) {
  stop();
  service::ServiceOptions options;
  options.multires_above = 1000;
  options.multires_coarse_vertices = 1000;
  options.refine_delay = milliseconds(600'000);  // no refinement revision during the test
  start(options);
  const v1::CreateSessionResponse s = create_with_handles("cylinder");
  const std::uint32_t vertex_count = s.info().vertices();
  ASSERT_GT(vertex_count, 2000u) << "the sample must be above the multiresolution threshold";

  struct Stream {
    grpc::ClientContext context;
    std::unique_ptr<grpc::ClientReader<v1::DeformUpdate>> reader;
    bool coarse_preview = false;
    bool link_sized = false;
  };
  std::vector<std::unique_ptr<Stream>> streams;
  for (const auto& [preview, link_sized] :
       {std::pair{true, false}, std::pair{true, true}, std::pair{false, false}}) {
    auto stream = std::make_unique<Stream>();
    stream->coarse_preview = preview;
    stream->link_sized = link_sized;
    bound(stream->context);
    v1::WatchRequest request;
    request.set_session_id(s.session_id());
    request.set_token(s.view_token());
    request.set_coarse_preview(preview);
    if (link_sized) request.mutable_updates()->set_mode(v1::DELTA_MODE_QUANTIZED);
    stream->reader = stub_->Watch(&stream->context, request);
    v1::DeformUpdate join;
    ASSERT_TRUE(stream->reader->Read(&join));
    EXPECT_EQ(join.result().revision(), 0u);
    EXPECT_FALSE(join.has_coarse()) << "the rest mesh was not solved on a coarse level";
    streams.push_back(std::move(stream));
  }

  std::uint64_t key = 0;
  std::vector<std::uint32_t> to_fine;
  for (int step = 1; step <= 3; ++step) {
    // Steps 1 and 2 move on the coarse level; step 3 asks for ORA, solved at full resolution.
    v1::MoveHandlesRequest request = bend_request(s, 15.0 * step);
    request.set_full_positions(true);
    request.set_ora(step == 3);
    v1::MoveHandlesResponse response;
    const grpc::Status status = move(request, &response);
    ASSERT_TRUE(status.ok()) << describe(status);
    const Positions full = positions_of(response.result().positions());
    for (const auto& stream : streams) {
      SCOPED_TRACE("step " + std::to_string(step) + (stream->coarse_preview ? " preview" : "") +
                   (stream->link_sized ? " link-sized" : ""));
      v1::DeformUpdate update;
      ASSERT_TRUE(stream->reader->Read(&update));
      ASSERT_EQ(update.result().revision(), response.result().revision());
      if (!stream->coarse_preview || step == 3) {
        EXPECT_FALSE(update.has_coarse());
        continue;
      }
      ASSERT_TRUE(update.has_coarse());
      const v1::CoarseLevel& coarse = update.coarse();
      const std::uint32_t nc = coarse.vertex_count();
      EXPECT_GE(nc, 3u);
      EXPECT_LT(nc, vertex_count / 2);
      ASSERT_EQ(coarse.positions().size(), 12u * nc);
      if (step == 1) {
        // The stream's first update of the level brings its mesh.
        ASSERT_EQ(static_cast<std::uint32_t>(coarse.to_fine_size()), nc);
        ASSERT_GT(coarse.triangles_size(), 0);
        EXPECT_EQ(coarse.triangles_size() % 3, 0);
        for (const std::uint32_t t : coarse.triangles()) EXPECT_LT(t, nc);
        for (int i = 0; i < coarse.to_fine_size(); ++i) {
          EXPECT_LT(coarse.to_fine(i), vertex_count);
          if (i > 0) {
            EXPECT_LT(coarse.to_fine(i - 1), coarse.to_fine(i)) << "ascending, distinct";
          }
        }
        if (key == 0) {
          key = coarse.key();
          to_fine.assign(coarse.to_fine().begin(), coarse.to_fine().end());
        }
        EXPECT_EQ(coarse.key(), key) << "one level, one key on every stream";
        EXPECT_TRUE(std::equal(to_fine.begin(), to_fine.end(), coarse.to_fine().begin()));
      } else {
        // Known to the stream: positions only.
        EXPECT_EQ(coarse.key(), key);
        EXPECT_EQ(coarse.to_fine_size(), 0);
        EXPECT_EQ(coarse.triangles_size(), 0);
      }
      ASSERT_EQ(to_fine.size(), nc);
      std::vector<float> xyz(3u * nc);
      std::memcpy(xyz.data(), coarse.positions().data(), coarse.positions().size());
      // The prolongation keeps coarse vertices where the coarse solve put them.
      int mismatches = 0;
      for (std::uint32_t i = 0; i < nc; ++i) {
        for (int c = 0; c < 3; ++c) {
          if (xyz[3 * i + c] != static_cast<float>(full(to_fine[i], c))) ++mismatches;
        }
      }
      EXPECT_EQ(mismatches, 0);
    }
  }
  for (const auto& stream : streams) stream->context.TryCancel();
}

}  // namespace
}  // namespace meshdeform::transport
