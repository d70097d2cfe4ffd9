// The client's own transport behaviour, against a scripted stand-in server on a loopback port (a
// grpc::CallbackGenericService that answers every method with a chosen status, or never): the
// x-session-id header on every per-session call, the mapping of every gRPC code back to an
// ErrorCode, deadlines on every call, cancellation, local validation, and an unreachable server.
// No meshdeform server is involved, so every outcome is exact.
#include <grpcpp/generic/async_generic_service.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/security/server_credentials.h>
#include <grpcpp/server_builder.h>
#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "client_cpp/client.h"

namespace meshdeform::client {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

constexpr const char* kService = "/meshdeform.v1.DeformationService/";

template <typename T>
std::string message_of(const Result<T>& r) {
  return r.ok() ? std::string("ok") : r.status().to_string();
}

/// Records each call's method and x-session-id header, then finishes it with `code` (or, when
/// `is_hanging`, only when the call is cancelled, e.g. by its deadline).
class ScriptedService final : public grpc::CallbackGenericService {
 public:
  struct Call {
    std::string method;
    std::optional<std::string> session_header;
  };

  grpc::ServerGenericBidiReactor* CreateReactor(
      grpc::GenericCallbackServerContext* context) override {
    Call call{context->method(), std::nullopt};
    const auto& metadata = context->client_metadata();
    if (auto it = metadata.find("x-session-id"); it != metadata.end()) {
      call.session_header = std::string(it->second.data(), it->second.size());
    }
    {
      const std::lock_guard lock(mutex_);
      calls_.push_back(std::move(call));
    }
    if (is_hanging.load()) return new HangingReactor();
    return new FinishingReactor(grpc::Status(code.load(), "scripted failure"));
  }

  std::vector<Call> take_calls() {
    const std::lock_guard lock(mutex_);
    return std::exchange(calls_, {});
  }

  std::atomic<grpc::StatusCode> code{grpc::StatusCode::NOT_FOUND};
  std::atomic<bool> is_hanging{false};

 private:
  class FinishingReactor final : public grpc::ServerGenericBidiReactor {
   public:
    explicit FinishingReactor(const grpc::Status& status) { Finish(status); }
    void OnDone() override { delete this; }
  };
  class HangingReactor final : public grpc::ServerGenericBidiReactor {
   public:
    void OnCancel() override { Finish(grpc::Status::CANCELLED); }
    void OnDone() override { delete this; }
  };

  std::mutex mutex_;
  std::vector<Call> calls_;
};

class ClientTransportTest : public ::testing::Test {
 protected:
  void SetUp() override {
    grpc::ServerBuilder builder;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port_);
    builder.RegisterCallbackGenericService(&service_);
    server_ = builder.BuildAndStart();
    ASSERT_NE(server_, nullptr);
    ASSERT_GT(port_, 0);
    ClientOptions options;
    options.target = "127.0.0.1:" + std::to_string(port_);
    options.default_timeout = seconds(30);  // a safety bound
    options.watch_timeout = seconds(30);
    Result<Client> client = Client::connect(options);
    ASSERT_TRUE(client.ok()) << message_of(client);
    client_.emplace(std::move(client).value());
  }

  void TearDown() override {
    if (server_) server_->Shutdown(std::chrono::system_clock::now() + seconds(5));
  }

  /// Every RPC of the client once, with session `ref`; the statuses in call order.
  std::vector<Status> call_everything(const SessionRef& ref, const CallOptions& call = {}) {
    std::vector<Status> out;
    out.push_back(client_->create_session_from_sample("bar_small", {}, call).status());
    out.push_back(
        client_->set_handles(ref, {{HandleRole::Fixed, {0, 1}}}, core::Method::ScaleAware, call)
            .status());
    MoveSpec spec;
    spec.moves.push_back(GroupMove{});
    out.push_back(client_->move(ref, spec, call).status());
    WatchStream stream = client_->open_watch(ref, call);
    out.push_back(stream.next().status());
    out.push_back(client_->get_mesh(ref, io::MeshFormat::Glb, std::nullopt, call).status());
    out.push_back(client_->session_info(ref, call).status());
    out.push_back(client_->close_session(ref, call));
    out.push_back(client_->server_stats(call).status());
    return out;
  }

  ScriptedService service_;
  std::unique_ptr<grpc::Server> server_;
  int port_ = 0;
  std::optional<Client> client_;
};

TEST_F(ClientTransportTest, EveryPerSessionCallSendsTheSessionIdHeader) {
  const SessionRef ref{"0123456789abcdef0123456789abcdef", "secret-token-must-not-leak"};
  const std::vector<Status> statuses = call_everything(ref);
  for (const Status& status : statuses) {
    EXPECT_EQ(status.code(), ErrorCode::NotFound) << status.to_string();
    EXPECT_NE(status.message().find("NOT_FOUND: scripted failure"), std::string::npos)
        << status.message();
    EXPECT_EQ(status.message().find(ref.token), std::string::npos);
  }
  const std::vector<ScriptedService::Call> calls = service_.take_calls();
  const std::vector<std::pair<std::string, bool>> expected = {
      {"CreateSession", false}, {"SetHandles", true},     {"MoveHandles", true},
      {"Watch", true},          {"GetMesh", true},        {"GetSessionInfo", true},
      {"CloseSession", true},   {"GetServerStats", false}};
  ASSERT_EQ(calls.size(), expected.size());
  for (std::size_t i = 0; i < calls.size(); ++i) {
    SCOPED_TRACE(expected[i].first);
    EXPECT_EQ(calls[i].method, kService + expected[i].first);
    if (expected[i].second) {
      ASSERT_TRUE(calls[i].session_header.has_value());
      EXPECT_EQ(*calls[i].session_header, ref.id);
    } else {
      EXPECT_FALSE(calls[i].session_header.has_value());
    }
  }
}

TEST_F(ClientTransportTest, EveryGrpcCodeMapsToAnErrorCodeAndKeepsItsName) {
  const std::map<grpc::StatusCode, ErrorCode> expected = {
      {grpc::StatusCode::CANCELLED, ErrorCode::Cancelled},
      {grpc::StatusCode::UNKNOWN, ErrorCode::Internal},
      {grpc::StatusCode::INVALID_ARGUMENT, ErrorCode::InvalidArgument},
      {grpc::StatusCode::DEADLINE_EXCEEDED, ErrorCode::DeadlineExceeded},
      {grpc::StatusCode::NOT_FOUND, ErrorCode::NotFound},
      {grpc::StatusCode::ALREADY_EXISTS, ErrorCode::FailedPrecondition},
      {grpc::StatusCode::PERMISSION_DENIED, ErrorCode::PermissionDenied},
      {grpc::StatusCode::RESOURCE_EXHAUSTED, ErrorCode::ResourceExhausted},
      {grpc::StatusCode::FAILED_PRECONDITION, ErrorCode::FailedPrecondition},
      {grpc::StatusCode::ABORTED, ErrorCode::Aborted},
      {grpc::StatusCode::OUT_OF_RANGE, ErrorCode::InvalidArgument},
      {grpc::StatusCode::UNIMPLEMENTED, ErrorCode::FailedPrecondition},
      {grpc::StatusCode::INTERNAL, ErrorCode::Internal},
      {grpc::StatusCode::UNAVAILABLE, ErrorCode::Unavailable},
      {grpc::StatusCode::DATA_LOSS, ErrorCode::Internal},
      {grpc::StatusCode::UNAUTHENTICATED, ErrorCode::PermissionDenied},
  };
  const SessionRef ref{"s1", "t"};
  for (const auto& [code, error] : expected) {
    const std::string name = grpc_code_name(static_cast<int>(code));
    SCOPED_TRACE(name);
    EXPECT_EQ(to_error_code(static_cast<int>(code)), error);
    service_.code = code;
    const Status status = client_->session_info(ref).status();
    EXPECT_EQ(status.code(), error) << status.to_string();
    EXPECT_EQ(status.message(), "GetSessionInfo: " + name + ": scripted failure");
  }
  EXPECT_EQ(to_error_code(0), ErrorCode::Ok);
  EXPECT_EQ(grpc_code_name(4), "DEADLINE_EXCEEDED");
  EXPECT_EQ(grpc_code_name(99), "CODE_99");
  EXPECT_EQ(to_error_code(99), ErrorCode::Internal);
}

TEST_F(ClientTransportTest, EveryCallHasADeadline) {
  service_.is_hanging = true;  // the server never answers
  ClientOptions options = client_->options();
  options.default_timeout = milliseconds(200);
  options.watch_timeout = milliseconds(200);
  Result<Client> impatient = Client::connect(options);
  ASSERT_TRUE(impatient.ok());
  client_.emplace(std::move(impatient).value());
  for (const Status& status : call_everything({"s1", "t"})) {
    EXPECT_EQ(status.code(), ErrorCode::DeadlineExceeded) << status.to_string();
  }
  // A per-call timeout overrides the default (here: the other way round, on a patient client).
  options.default_timeout = seconds(60);
  Result<Client> patient = Client::connect(options);
  ASSERT_TRUE(patient.ok());
  CallOptions call;
  call.timeout = milliseconds(100);
  EXPECT_EQ(patient->session_info({"s1", "t"}, call).status().code(), ErrorCode::DeadlineExceeded);
}

TEST_F(ClientTransportTest, StopTokenCancelsAHangingCall) {
  service_.is_hanging = true;
  std::stop_source stop;
  CallOptions call;
  call.stop = stop.get_token();
  std::future<Status> pending = std::async(std::launch::async, [&] {
    MoveSpec spec;
    return client_->move({"s1", "t"}, spec, call).status();
  });
  // Wait (bounded) until the server holds the call, then cancel.
  for (int i = 0; i < 600 && service_.take_calls().empty(); ++i) {
    std::this_thread::sleep_for(milliseconds(10));
  }
  stop.request_stop();
  ASSERT_EQ(pending.wait_for(seconds(30)), std::future_status::ready);
  const Status status = pending.get();
  EXPECT_EQ(status.code(), ErrorCode::Cancelled) << status.to_string();

  // A watch blocked on a silent server ends cleanly when its token is stopped.
  std::stop_source watch_stop;
  CallOptions watch_call;
  watch_call.stop = watch_stop.get_token();
  std::future<Result<WatchEnd>> watching = std::async(std::launch::async, [&] {
    return client_->watch(
        {"s1", "t"}, [](const WatchUpdate&) { return true; }, watch_call);
  });
  for (int i = 0; i < 600 && service_.take_calls().empty(); ++i) {
    std::this_thread::sleep_for(milliseconds(10));
  }
  watch_stop.request_stop();
  ASSERT_EQ(watching.wait_for(seconds(30)), std::future_status::ready);
  Result<WatchEnd> end = watching.get();
  ASSERT_TRUE(end.ok()) << message_of(end);
  EXPECT_EQ(*end, WatchEnd::StoppedByToken);
}

TEST_F(ClientTransportTest, BadInputIsRefusedBeforeSending) {
  const SessionRef bad_id{"line\nbreak", "t"};
  EXPECT_EQ(client_->session_info(bad_id).status().code(), ErrorCode::InvalidArgument);
  WatchStream stream = client_->open_watch(bad_id);
  EXPECT_EQ(stream.next().status().code(), ErrorCode::InvalidArgument);
  const SessionRef ok_id{"s1", "t"};
  MoveSpec negative_group;
  negative_group.moves.emplace_back();
  negative_group.moves.back().group = -1;
  EXPECT_EQ(client_->move(ok_id, negative_group).status().code(), ErrorCode::InvalidArgument);
  MoveSpec negative_iterations;
  negative_iterations.max_iterations = -2;
  EXPECT_EQ(client_->move(ok_id, negative_iterations).status().code(), ErrorCode::InvalidArgument);
  CallOptions zero_timeout;
  zero_timeout.timeout = milliseconds(0);
  EXPECT_EQ(client_->session_info(ok_id, zero_timeout).status().code(), ErrorCode::InvalidArgument);
  EXPECT_TRUE(service_.take_calls().empty());  // nothing reached the server
}

TEST_F(ClientTransportTest, ConnectValidatesOptions) {
  ClientOptions options;
  options.target = "";
  EXPECT_EQ(Client::connect(options).status().code(), ErrorCode::InvalidArgument);
  options = ClientOptions{};
  options.default_timeout = milliseconds(0);
  EXPECT_EQ(Client::connect(options).status().code(), ErrorCode::InvalidArgument);
  options = ClientOptions{};
  options.max_message_mib = 0;
  EXPECT_EQ(Client::connect(options).status().code(), ErrorCode::InvalidArgument);
  options.max_message_mib = 2048;
  EXPECT_EQ(Client::connect(options).status().code(), ErrorCode::InvalidArgument);
}

TEST_F(ClientTransportTest, UnreachableServerIsUnavailableByName) {
  const std::string target = "127.0.0.1:" + std::to_string(port_);
  server_->Shutdown(std::chrono::system_clock::now() + seconds(5));
  server_.reset();
  ClientOptions options;
  options.target = target;                // nothing listens there any more
  options.default_timeout = seconds(20);  // connection refused comes back long before
  Result<Client> client = Client::connect(options);
  ASSERT_TRUE(client.ok());
  const Status status = client->session_info({"s1", "t"}).status();
  EXPECT_EQ(status.code(), ErrorCode::Unavailable) << status.to_string();
  EXPECT_NE(status.message().find("UNAVAILABLE"), std::string::npos) << status.message();
}

}  // namespace
}  // namespace meshdeform::client
