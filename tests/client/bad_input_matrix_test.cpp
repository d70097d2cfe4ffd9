// The bad-input matrix (issue 6), through the real meshdeform-server binary on loopback, on both
// front ends: native gRPC (HTTP/2) and gRPC-Web (HTTP/1.1, the browser gateway). Every hostile or
// broken request gets its documented status on both, identically, while a well-behaved editor
// keeps moving its own session the whole time without a single error; afterwards the server
// still serves. Every call has a deadline and every loop a bound.
#include <gtest/gtest.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>

#include <boost/asio/connect.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>

#include <atomic>
#include <condition_variable>
#include <mutex>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <functional>
#include <regex>
#include <string>
#include <thread>
#include <vector>

#include "meshdeform/v1/deformation.grpc.pb.h"
#include "tests/support/grpc_calls.h"
#include "tests/support/server_process.h"

namespace meshdeform {
namespace {

using std::chrono::seconds;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = boost::asio::ip::tcp;

constexpr int kMaxMessageMib = 1;  // the server's limit in this test: oversize is cheap to build

using test::bound;

/// One gRPC-Web unary call (binary framing) to 127.0.0.1:port; returns the grpc-status (from the
/// headers of a trailers-only answer or from the trailer frame) and fills `reply` with the
/// message frame, if any. -1 when the HTTP exchange itself failed.
int grpc_web_call(int port, const std::string& method, const std::string& message,
                  std::string* reply = nullptr, std::string* grpc_message = nullptr) {
  try {
    boost::asio::io_context io;
    beast::tcp_stream stream(io);
    stream.expires_after(seconds(30));
    stream.connect(tcp::endpoint(boost::asio::ip::make_address("127.0.0.1"),
                                 static_cast<unsigned short>(port)));
    std::string body(5, '\0');
    const std::uint32_t n = static_cast<std::uint32_t>(message.size());
    body[1] = static_cast<char>(n >> 24);
    body[2] = static_cast<char>(n >> 16);
    body[3] = static_cast<char>(n >> 8);
    body[4] = static_cast<char>(n);
    body += message;
    http::request<http::string_body> request(http::verb::post,
                                             "/meshdeform.v1.DeformationService/" + method, 11);
    request.set(http::field::host, "127.0.0.1");
    request.set(http::field::content_type, "application/grpc-web+proto");
    request.set("x-grpc-web", "1");
    request.set("grpc-timeout", "30S");
    request.body() = std::move(body);
    request.prepare_payload();
    http::write(stream, request);
    beast::flat_buffer buffer;
    http::response_parser<http::string_body> parser;
    parser.body_limit(64u << 20);
    http::read(stream, buffer, parser);
    const auto& response = parser.get();
    if (response.result_int() != 200) return -1;
    std::string status_text(response["grpc-status"]);
    std::string message_text(response["grpc-message"]);
    const std::string& data = response.body();
    std::size_t at = 0;
    while (at + 5 <= data.size()) {
      const unsigned char flags = static_cast<unsigned char>(data[at]);
      const std::size_t len = (std::size_t(static_cast<unsigned char>(data[at + 1])) << 24) |
                              (std::size_t(static_cast<unsigned char>(data[at + 2])) << 16) |
                              (std::size_t(static_cast<unsigned char>(data[at + 3])) << 8) |
                              std::size_t(static_cast<unsigned char>(data[at + 4]));
      if (at + 5 + len > data.size()) return -1;
      const std::string payload = data.substr(at + 5, len);
      if (flags & 0x80) {
        std::smatch m;
        if (std::regex_search(payload, m, std::regex("grpc-status: ?([0-9]+)"))) status_text = m[1];
        if (std::regex_search(payload, m, std::regex("grpc-message: ?([^\r\n]*)"))) {
          message_text = m[1];
        }
      } else if (reply != nullptr) {
        *reply = payload;
      }
      at += 5 + len;
    }
    if (grpc_message != nullptr) *grpc_message = message_text;
    return status_text.empty() ? -1 : std::stoi(status_text);
  } catch (const std::exception&) {
    return -1;
  }
}

class BadInputMatrixTest : public ::testing::Test {
 protected:
  void SetUp() override {
    std::string error;
    server_ = test::ServerProcess::start(
        MESHDEFORM_SERVER_PATH,
        {"--http-listen", "127.0.0.1:0", "--max-message-mib", std::to_string(kMaxMessageMib),
         "--refine-budget", "0", "--test-hooks", "--max-vertices", "30000"},
        error);
    ASSERT_NE(server_, nullptr) << error;
    ASSERT_TRUE(server_->wait_for_log("\"event\":\"http_listening\"", std::chrono::seconds(10)));
    std::smatch m;
    const std::string log = server_->log();
    ASSERT_TRUE(std::regex_search(log, m,
                                  std::regex("\"event\":\"http_listening\"[^\n]*\"port\":([0-9]+)")));
    http_port_ = std::stoi(m[1]);
    grpc::ChannelArguments args;
    args.SetMaxReceiveMessageSize(64 << 20);
    args.SetMaxSendMessageSize(64 << 20);  // let oversize requests reach the server
    stub_ = v1::DeformationService::NewStub(
        grpc::CreateCustomChannel(server_->address(), grpc::InsecureChannelCredentials(), args));
  }

  v1::CreateSessionResponse create_with_handles(const std::string& sample) {
    v1::CreateSessionResponse created;
    const grpc::Status status = test::create_sample_with_handles(*stub_, sample, &created);
    EXPECT_TRUE(status.ok()) << status.error_message();
    return created;
  }

  /// Calls `method` with `message` through a generic stub (exact bytes) on the native port.
  grpc::StatusCode native_call(const std::string& method, const std::string& message) {
    grpc::GenericStub generic(grpc::CreateCustomChannel(
        server_->address(), grpc::InsecureChannelCredentials(), [] {
          grpc::ChannelArguments args;
          args.SetMaxSendMessageSize(64 << 20);
          args.SetMaxReceiveMessageSize(64 << 20);
          return args;
        }()));
    grpc::ClientContext context;
    bound(context);
    grpc::Slice slice(message);
    grpc::ByteBuffer request(&slice, 1), response;
    std::mutex mutex;
    std::condition_variable done_cv;
    bool done = false;
    grpc::Status status;
    generic.UnaryCall(&context, "/meshdeform.v1.DeformationService/" + method,
                      grpc::StubOptions(), &request, &response, [&](grpc::Status s) {
                        const std::lock_guard lock(mutex);
                        status = std::move(s);
                        done = true;
                        done_cv.notify_all();
                      });
    std::unique_lock lock(mutex);
    done_cv.wait_for(lock, seconds(40), [&] { return done; });
    return done ? status.error_code() : grpc::StatusCode::UNKNOWN;
  }

  std::unique_ptr<test::ServerProcess> server_;
  int http_port_ = 0;
  std::unique_ptr<v1::DeformationService::Stub> stub_;
};

v1::MoveHandlesRequest bend(const v1::CreateSessionResponse& s, double z) {
  v1::MoveHandlesRequest move;
  move.set_session_id(s.session_id());
  move.set_token(s.edit_token());
  move.set_max_iterations(1);
  v1::GroupMove* g = move.add_moves();
  g->set_group(1);
  g->mutable_translation()->set_z(z);
  return move;
}

TEST_F(BadInputMatrixTest, EveryBadInputGetsItsStatusOnBothFrontEndsAndOthersKeepWorking) {
  // A well-behaved editor on its own session for the whole test.
  const v1::CreateSessionResponse good = create_with_handles("cylinder_small");
  std::atomic<bool> stop{false};
  std::atomic<int> good_moves{0}, good_errors{0};
  // A jthread: an early ASSERT below ends the test with the editor stopped and joined (its
  // destructor requests the stop), never with a joinable std::thread and std::terminate.
  std::jthread editor([&](const std::stop_token& token) {
    for (int i = 1; i <= 2000 && !stop.load() && !token.stop_requested(); ++i) {  // bounded
      grpc::ClientContext context;
      bound(context);
      v1::MoveHandlesResponse response;
      const grpc::Status status = stub_->MoveHandles(&context, bend(good, 0.001 * (i % 100)), &response);
      (status.ok() ? good_moves : good_errors).fetch_add(1);
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
  });

  const v1::CreateSessionResponse victim = create_with_handles("cylinder_small");
  v1::CreateSessionResponse closed = create_with_handles("bar_small");
  {
    v1::CloseSessionRequest request;
    request.set_session_id(closed.session_id());
    request.set_token(closed.edit_token());
    v1::CloseSessionResponse response;
    grpc::ClientContext context;
    bound(context);
    ASSERT_TRUE(stub_->CloseSession(&context, request, &response).ok());
  }
  v1::CreateSessionRequest no_handles_request;
  no_handles_request.set_sample("cylinder_small");
  v1::CreateSessionResponse no_handles;
  {
    grpc::ClientContext context;
    bound(context);
    ASSERT_TRUE(stub_->CreateSession(&context, no_handles_request, &no_handles).ok());
  }

  struct Case {
    std::string name, method;
    std::string bytes;
    grpc::StatusCode expected;
  };
  std::vector<Case> cases;
  auto mesh_case = [&](const std::string& name, const std::string& bytes, v1::MeshFormat format,
                       grpc::StatusCode expected) {
    v1::CreateSessionRequest request;
    request.set_mesh_bytes(bytes);
    request.set_format(format);
    cases.push_back({name, "CreateSession", request.SerializeAsString(), expected});
  };
  // Oversized: a 1.5 MiB upload against a 1 MiB limit.
  mesh_case("oversized upload", std::string(3 << 19, ' '), v1::MESH_FORMAT_OBJ,
            grpc::StatusCode::RESOURCE_EXHAUSTED);
  // Huge declared counts, with almost no data behind them.
  mesh_case("OFF declaring 2e9 vertices", "OFF\n2000000000 1 0\n0 0 0\n", v1::MESH_FORMAT_OFF,
            grpc::StatusCode::INVALID_ARGUMENT);
  mesh_case("PLY declaring 4e9 vertices",
            "ply\nformat ascii 1.0\nelement vertex 4294967295\nproperty float x\nproperty float y\n"
            "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
            "0 0 0\n",
            v1::MESH_FORMAT_PLY, grpc::StatusCode::INVALID_ARGUMENT);
  {
    std::string stl(80, '\0');
    const std::uint32_t count = 0xFFFFFFFFu;
    stl.append(reinterpret_cast<const char*>(&count), 4);
    stl.append(100, '\0');
    mesh_case("binary STL declaring 4e9 triangles", stl, v1::MESH_FORMAT_STL,
              grpc::StatusCode::INVALID_ARGUMENT);
  }
  {
    v1::CreateSessionRequest request;
    request.set_sample("bumpy_plane");  // 40,401 vertices against --max-vertices 30000
    cases.push_back({"mesh over --max-vertices", "CreateSession", request.SerializeAsString(),
                     grpc::StatusCode::RESOURCE_EXHAUSTED});
  }
  {
    v1::CreateSessionRequest request;
    request.set_sample("bumpy_plane_small");
    request.set_lambda(std::nan(""));
    cases.push_back({"NaN lambda", "CreateSession", request.SerializeAsString(),
                     grpc::StatusCode::INVALID_ARGUMENT});
  }
  {
    v1::MoveHandlesRequest move = bend(victim, 0.1);
    move.mutable_targets()->add_vertices(victim.suggested_groups(1).vertices(0));
    for (double x : {0.0, std::nan(""), 0.0}) move.mutable_targets()->add_positions(x);
    cases.push_back({"NaN target", "MoveHandles", move.SerializeAsString(),
                     grpc::StatusCode::INVALID_ARGUMENT});
    move = bend(victim, 0.1);
    move.mutable_moves(0)->mutable_translation()->set_x(INFINITY);
    cases.push_back({"infinite translation", "MoveHandles", move.SerializeAsString(),
                     grpc::StatusCode::INVALID_ARGUMENT});
    move = bend(victim, 0.1);
    move.mutable_moves(0)->set_group(9);
    cases.push_back({"unknown handle group", "MoveHandles", move.SerializeAsString(),
                     grpc::StatusCode::INVALID_ARGUMENT});
    move = bend(victim, 0.1);
    move.mutable_moves(0)->set_group(0);
    cases.push_back({"moving the fixed group", "MoveHandles", move.SerializeAsString(),
                     grpc::StatusCode::INVALID_ARGUMENT});
    move = bend(victim, 0.1);
    move.set_token(std::string(64, '0'));
    cases.push_back({"wrong token", "MoveHandles", move.SerializeAsString(),
                     grpc::StatusCode::PERMISSION_DENIED});
    move.set_token(victim.view_token());
    cases.push_back({"view token used to edit", "MoveHandles", move.SerializeAsString(),
                     grpc::StatusCode::PERMISSION_DENIED});
    move = bend(closed, 0.1);
    cases.push_back({"replayed move on a closed session", "MoveHandles", move.SerializeAsString(),
                     grpc::StatusCode::NOT_FOUND});
    move = bend(no_handles, 0.1);
    cases.push_back({"move before handles", "MoveHandles", move.SerializeAsString(),
                     grpc::StatusCode::FAILED_PRECONDITION});
    move = bend(victim, 0.1);
    move.set_max_iterations(5000);
    cases.push_back({"iteration budget over 1000", "MoveHandles", move.SerializeAsString(),
                     grpc::StatusCode::INVALID_ARGUMENT});
    move = bend(victim, 0.1);
    move.set_encoding(static_cast<v1::PositionEncoding>(77));
    cases.push_back({"unknown position encoding", "MoveHandles", move.SerializeAsString(),
                     grpc::StatusCode::INVALID_ARGUMENT});
  }
  {
    v1::SetHandlesRequest handles;
    handles.set_session_id(victim.session_id());
    handles.set_token(victim.edit_token());
    v1::HandleGroup* g = handles.add_groups();
    g->set_role(v1::HANDLE_ROLE_HANDLE);
    g->add_vertices(4000000000u);
    cases.push_back({"handle index out of range", "SetHandles", handles.SerializeAsString(),
                     grpc::StatusCode::INVALID_ARGUMENT});
  }
  // A request gRPC itself cannot parse never reaches the service: gRPC 1.51's callback server
  // answers UNIMPLEMENTED (what matters here: an error, the same on both front ends).
  cases.push_back({"bytes that are no protobuf", "MoveHandles", std::string("\xff\xff\xff\xff", 4),
                   grpc::StatusCode::UNIMPLEMENTED});
  {
    v1::GetMeshRequest get;
    get.set_session_id(victim.session_id());
    get.set_token(victim.view_token());
    get.set_revision(999);
    cases.push_back({"revision not kept", "GetMesh", get.SerializeAsString(),
                     grpc::StatusCode::NOT_FOUND});
    get.set_session_id(std::string(32, 'f'));
    cases.push_back({"unknown session", "GetMesh", get.SerializeAsString(),
                     grpc::StatusCode::NOT_FOUND});
  }

  for (const Case& c : cases) {
    const grpc::StatusCode native = native_call(c.method, c.bytes);
    std::string message;
    const int web = grpc_web_call(http_port_, c.method, c.bytes, nullptr, &message);
    EXPECT_EQ(native, c.expected) << c.name << " (native gRPC)";
    EXPECT_EQ(web, static_cast<int>(c.expected)) << c.name << " (gRPC-Web): " << message;
  }
  // Nothing the bad moves did was committed to the victim.
  {
    v1::GetSessionInfoRequest request;
    request.set_session_id(victim.session_id());
    request.set_token(victim.view_token());
    v1::GetSessionInfoResponse response;
    grpc::ClientContext context;
    bound(context);
    ASSERT_TRUE(stub_->GetSessionInfo(&context, request, &response).ok());
    EXPECT_EQ(response.info().revision(), 0u);
  }

  // Concurrent conflicting edits of one session from two front ends and four threads: every
  // call ends OK or with a documented refusal (never INTERNAL / UNKNOWN), and the OK moves got
  // one revision each (edits are serialised).
  std::atomic<int> ok_moves{0}, bad{0};
  std::vector<std::jthread> editors;
  for (int t = 0; t < 4; ++t) {
    editors.emplace_back([&, t] {
      for (int i = 0; i < 6; ++i) {  // bounded
        v1::MoveHandlesRequest move = bend(victim, 0.01 * (t + 1) + 0.001 * i);
        int code = 0;
        if (t % 2 == 0) {
          code = static_cast<int>(native_call("MoveHandles", move.SerializeAsString()));
        } else {
          code = grpc_web_call(http_port_, "MoveHandles", move.SerializeAsString());
        }
        if (t == 3 && i == 2) {  // one editor also replaces the handle set mid-way
          v1::SetHandlesRequest handles;
          handles.set_session_id(victim.session_id());
          handles.set_token(victim.edit_token());
          *handles.mutable_groups() = victim.suggested_groups();
          const int set = grpc_web_call(http_port_, "SetHandles", handles.SerializeAsString());
          if (set != 0) bad.fetch_add(1);
        }
        if (code == 0) {
          ok_moves.fetch_add(1);
        } else {
          bad.fetch_add(1);
        }
      }
    });
  }
  for (std::jthread& e : editors) e.join();
  EXPECT_EQ(bad.load(), 0);
  {
    v1::GetSessionInfoRequest request;
    request.set_session_id(victim.session_id());
    request.set_token(victim.view_token());
    v1::GetSessionInfoResponse response;
    grpc::ClientContext context;
    bound(context);
    ASSERT_TRUE(stub_->GetSessionInfo(&context, request, &response).ok());
    EXPECT_EQ(response.info().revision(), static_cast<std::uint64_t>(ok_moves.load()));
  }

  stop.store(true);
  editor.join();
  EXPECT_GT(good_moves.load(), 0);
  EXPECT_EQ(good_errors.load(), 0);

  // Expired sessions answer NOT_FOUND on both front ends. Expiry is triggered explicitly
  // (--test-hooks: SIGUSR1 expires every idle session) rather than by a short TTL, which on a
  // loaded machine expired the other sessions of this test between its steps.
  const v1::CreateSessionResponse idle = create_with_handles("bar_small");
  v1::GetSessionInfoRequest info;
  info.set_session_id(idle.session_id());
  info.set_token(idle.view_token());
  // A session is idle once its last edit's bookkeeping ends, which may be just after the
  // client saw the reply: trigger again until it is gone (bounded).
  bool expired = false;
  for (int attempt = 0; attempt < 100 && !expired; ++attempt) {
    ASSERT_TRUE(server_->expire_idle_sessions()) << server_->log();
    expired = native_call("GetSessionInfo", info.SerializeAsString()) ==
              grpc::StatusCode::NOT_FOUND;
  }
  EXPECT_TRUE(expired);
  EXPECT_EQ(native_call("GetSessionInfo", info.SerializeAsString()), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(grpc_web_call(http_port_, "GetSessionInfo", info.SerializeAsString()),
            static_cast<int>(grpc::StatusCode::NOT_FOUND));

  // And the server still serves.
  const v1::CreateSessionResponse after = create_with_handles("cylinder_small");
  grpc::ClientContext context;
  bound(context);
  v1::MoveHandlesResponse response;
  EXPECT_TRUE(stub_->MoveHandles(&context, bend(after, 0.05), &response).ok());
}

}  // namespace
}  // namespace meshdeform
