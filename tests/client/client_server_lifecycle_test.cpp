// The real meshdeform-server binary under configurations of its own, driven through
// meshdeform::client on loopback: limits (--max-sessions, --max-vertices), the idle TTL, a
// graceful shutdown (SIGTERM) with an open Watch stream, and gRPC server reflection. Each test
// starts its own server with --refine-budget 0; every wait is bounded, and time bounds are safety
// nets, never assertions.
#include <google/protobuf/descriptor.pb.h>
#include <grpcpp/create_channel.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/security/credentials.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "client_cpp/client.h"
#include "tests/support/server_process.h"

namespace meshdeform::client {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

template <typename T>
std::string message_of(const Result<T>& r) {
  return r.ok() ? std::string("ok") : r.status().to_string();
}

std::unique_ptr<test::ServerProcess> start_server(std::vector<std::string> flags) {
  flags.insert(flags.begin(), {"--refine-budget", "0"});
  std::string error;
  std::unique_ptr<test::ServerProcess> server =
      test::ServerProcess::start(MESHDEFORM_SERVER_PATH, flags, error);
  EXPECT_NE(server, nullptr) << error;
  return server;
}

Client connect_to(const test::ServerProcess& server) {
  ClientOptions options;
  options.target = server.address();
  options.default_timeout = seconds(60);  // a safety bound
  options.watch_timeout = seconds(120);
  Result<Client> client = Client::connect(options);
  EXPECT_TRUE(client.ok()) << message_of(client);
  return std::move(client).value();
}

TEST(ClientServerLifecycleTest, LimitsAreResourceExhausted) {
  auto server = start_server({"--max-sessions", "1", "--max-vertices", "500"});
  ASSERT_NE(server, nullptr);
  const Client client = connect_to(*server);
  // Over --max-vertices: the 4,802-vertex cylinder.
  const Status too_big = client.create_session_from_sample("cylinder").status();
  EXPECT_EQ(too_big.code(), ErrorCode::ResourceExhausted) << too_big.to_string();
  EXPECT_NE(too_big.message().find("500"), std::string::npos) << too_big.message();
  // Over --max-sessions.
  Result<Session> first = client.create_session_from_sample("cylinder_small");
  ASSERT_TRUE(first.ok()) << message_of(first);
  const Status second = client.create_session_from_sample("cylinder_small").status();
  EXPECT_EQ(second.code(), ErrorCode::ResourceExhausted) << second.to_string();
  // Closing frees the slot.
  ASSERT_TRUE(client.close_session(first->edit()).ok());
  Result<Session> third = client.create_session_from_sample("cylinder_small");
  EXPECT_TRUE(third.ok()) << message_of(third);
}

TEST(ClientServerLifecycleTest, MessageLimitIsResourceExhausted) {
  auto server = start_server({"--max-message-mib", "1"});
  ASSERT_NE(server, nullptr);
  const Client client = connect_to(*server);
  // 2 MiB of (bad) OBJ bytes: refused by the server's receive limit before any parsing.
  const Status status =
      client.create_session_from_bytes(std::string(2u << 20, '#'), io::MeshFormat::Obj).status();
  EXPECT_EQ(status.code(), ErrorCode::ResourceExhausted) << status.to_string();
}

TEST(ClientServerLifecycleTest, IdleSessionsExpire) {
  // Expiry by an explicit trigger (--test-hooks: SIGUSR1), not a short TTL and a sleep.
  auto server = start_server({"--test-hooks"});
  ASSERT_NE(server, nullptr);
  const Client client = connect_to(*server);
  Result<Session> session = client.create_session_from_sample("bar_small");
  ASSERT_TRUE(session.ok()) << message_of(session);
  EXPECT_TRUE(client.session_info(session->view()).ok());  // not expired by itself
  ASSERT_TRUE(server->expire_idle_sessions()) << server->log();
  Status status = client.session_info(session->view()).status();
  for (int attempt = 0; attempt < 100 && status.ok(); ++attempt) {  // see the matrix test
    ASSERT_TRUE(server->expire_idle_sessions()) << server->log();
    status = client.session_info(session->view()).status();
  }
  EXPECT_EQ(status.code(), ErrorCode::NotFound) << status.to_string();
  // Expired means closed for edits too.
  EXPECT_EQ(client.close_session(session->edit()).code(), ErrorCode::NotFound);
}

TEST(ClientServerLifecycleTest, SigtermEndsAnOpenWatchAndExitsCleanly) {
  auto server = start_server({"--shutdown-grace-seconds", "1"});
  ASSERT_NE(server, nullptr);
  const Client client = connect_to(*server);
  Result<Session> session = client.create_session_from_sample("cylinder_small");
  ASSERT_TRUE(session.ok()) << message_of(session);
  WatchStream stream = client.open_watch(session->view());
  Result<std::optional<WatchUpdate>> snapshot = stream.next();
  ASSERT_TRUE(snapshot.ok()) << message_of(snapshot);
  ASSERT_TRUE(snapshot->has_value());
  EXPECT_TRUE((*snapshot)->is_snapshot);

  // The stream is open and idle; a reader blocks on it while the server shuts down.
  std::future<Result<std::optional<WatchUpdate>>> end =
      std::async(std::launch::async, [&stream] { return stream.next(); });
  const std::optional<int> wait_status = server->stop(SIGTERM, std::chrono::seconds(30));
  ASSERT_TRUE(wait_status.has_value()) << "no exit after SIGTERM; log:\n" << server->log();
  EXPECT_TRUE(WIFEXITED(*wait_status)) << server->log();
  EXPECT_EQ(WEXITSTATUS(*wait_status), 0) << server->log();
  ASSERT_EQ(end.wait_for(seconds(30)), std::future_status::ready);
  Result<std::optional<WatchUpdate>> last = end.get();
  // The stream ended without a further update: OK (the session closed) or, as the server does
  // today, cancelled when the grace period ran out (UNAVAILABLE "Cancelling all calls").
  if (last.ok()) {
    EXPECT_FALSE(last->has_value());
  } else {
    const std::string message = last.status().message();
    EXPECT_TRUE(message.find("UNAVAILABLE") != std::string::npos ||
                message.find("CANCELLED") != std::string::npos)
        << last.status().to_string();
  }
  EXPECT_NE(server->log().find("\"event\":\"shutdown\""), std::string::npos) << server->log();
}

// --- reflection ---------------------------------------------------------------------------------

/// The minimal protobuf wire reader the reflection test needs (Debian ships no reflection stubs).
struct WireField {
  std::uint32_t number = 0;
  std::uint32_t type = 0;  // 0 varint, 1 fixed64, 2 length-delimited, 5 fixed32
  std::string_view bytes;  // length-delimited payload
};

std::optional<std::vector<WireField>> parse_wire(std::string_view in) {
  std::vector<WireField> out;
  std::size_t pos = 0;
  auto varint = [&](std::uint64_t& value) {
    value = 0;
    for (int shift = 0; shift < 64 && pos < in.size(); shift += 7) {
      const auto byte = static_cast<unsigned char>(in[pos++]);
      value |= static_cast<std::uint64_t>(byte & 0x7F) << shift;
      if (!(byte & 0x80)) return true;
    }
    return false;
  };
  while (pos < in.size()) {
    std::uint64_t key = 0;
    if (!varint(key)) return std::nullopt;
    WireField field{static_cast<std::uint32_t>(key >> 3), static_cast<std::uint32_t>(key & 7), {}};
    std::uint64_t length = 0;
    switch (field.type) {
      case 0:
        if (!varint(length)) return std::nullopt;
        break;
      case 1:
        pos += 8;
        break;
      case 2:
        if (!varint(length) || length > in.size() - pos) return std::nullopt;
        field.bytes = in.substr(pos, length);
        pos += length;
        break;
      case 5:
        pos += 4;
        break;
      default:
        return std::nullopt;
    }
    if (pos > in.size()) return std::nullopt;
    out.push_back(field);
  }
  return out;
}

/// A length-delimited field: tag, length (< 128 here), payload.
std::string wire_string(std::uint32_t number, const std::string& value) {
  std::string out;
  out.push_back(static_cast<char>((number << 3) | 2));
  out.push_back(static_cast<char>(value.size()));
  return out + value;
}

/// One ServerReflectionInfo exchange: writes `request` (a serialized ServerReflectionRequest),
/// half-closes, and collects the responses.
class ReflectionCall final : public grpc::ClientBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer> {
 public:
  ReflectionCall(grpc::GenericStub& stub, const std::string& request) {
    context_.set_deadline(std::chrono::system_clock::now() + seconds(30));
    const grpc::Slice slice(request);
    request_ = grpc::ByteBuffer(&slice, 1);
    stub.PrepareBidiStreamingCall(&context_,
                                  "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
                                  grpc::StubOptions(), this);
    StartWriteLast(&request_, grpc::WriteOptions());
    StartRead(&response_);
    StartCall();
  }

  void OnReadDone(bool ok) override {
    if (!ok) return;
    std::vector<grpc::Slice> slices;
    std::string body;
    if (response_.Dump(&slices).ok()) {
      for (const grpc::Slice& s : slices) {
        body.append(reinterpret_cast<const char*>(s.begin()), s.size());
      }
    }
    {
      const std::lock_guard lock(mutex_);
      responses_.push_back(std::move(body));
    }
    StartRead(&response_);
  }

  void OnDone(const grpc::Status& status) override {
    // Notify under the lock: once the waiter has the lock, this object is no longer touched.
    const std::lock_guard lock(mutex_);
    status_ = status;
    is_done_ = true;
    done_.notify_all();
  }

  /// Waits for the end of the call (bounded by its deadline).
  grpc::Status wait(std::vector<std::string>* responses) {
    std::unique_lock lock(mutex_);
    if (!done_.wait_for(lock, seconds(60), [this] { return is_done_; })) {
      context_.TryCancel();
      done_.wait(lock, [this] { return is_done_; });
    }
    *responses = responses_;
    return status_;
  }

 private:
  grpc::ClientContext context_;
  grpc::ByteBuffer request_, response_;
  std::mutex mutex_;
  std::vector<std::string> responses_;
  std::condition_variable done_;
  bool is_done_ = false;
  grpc::Status status_;
};

/// The payloads of `number` in a message (empty when absent or malformed).
std::vector<std::string_view> fields_of(std::string_view message, std::uint32_t number) {
  std::vector<std::string_view> out;
  if (auto fields = parse_wire(message)) {
    for (const WireField& f : *fields) {
      if (f.number == number && f.type == 2) out.push_back(f.bytes);
    }
  }
  return out;
}

TEST(ClientServerLifecycleTest, ReflectionDescribesTheService) {
  auto server = start_server({});
  ASSERT_NE(server, nullptr);
  auto channel = grpc::CreateChannel(server->address(), grpc::InsecureChannelCredentials());
  grpc::GenericStub stub(channel);

  // list_services (ServerReflectionRequest field 7) -> list_services_response (6) -> service (1)
  // -> name (1).
  std::vector<std::string> responses;
  ReflectionCall list(stub, wire_string(7, ""));
  const grpc::Status listed = list.wait(&responses);
  ASSERT_TRUE(listed.ok()) << listed.error_message();
  ASSERT_EQ(responses.size(), 1u);
  std::vector<std::string> names;
  for (std::string_view list_response : fields_of(responses[0], 6)) {
    for (std::string_view service : fields_of(list_response, 1)) {
      for (std::string_view name : fields_of(service, 1)) names.emplace_back(name);
    }
  }
  EXPECT_NE(std::find(names.begin(), names.end(), "meshdeform.v1.DeformationService"), names.end())
      << testing::PrintToString(names);

  // file_containing_symbol (4) -> file_descriptor_response (4) -> file_descriptor_proto (1).
  ReflectionCall file(stub, wire_string(4, "meshdeform.v1.DeformationService"));
  const grpc::Status described = file.wait(&responses);
  ASSERT_TRUE(described.ok()) << described.error_message();
  ASSERT_EQ(responses.size(), 1u);
  bool found = false;
  for (std::string_view descriptor_response : fields_of(responses[0], 4)) {
    for (std::string_view bytes : fields_of(descriptor_response, 1)) {
      google::protobuf::FileDescriptorProto proto;
      ASSERT_TRUE(proto.ParseFromArray(bytes.data(), static_cast<int>(bytes.size())));
      if (proto.package() != "meshdeform.v1") continue;
      for (const auto& service : proto.service()) {
        if (service.name() != "DeformationService") continue;
        found = true;
        std::vector<std::string> methods;
        for (const auto& method : service.method()) {
          methods.push_back(method.name());
          if (method.name() == "Watch") {
            EXPECT_TRUE(method.server_streaming());
          }
        }
        for (const char* expected :
             {"CreateSession", "SetHandles", "MoveHandles", "Watch", "GetMesh", "GetSessionInfo",
              "CloseSession", "GetServerStats"}) {
          EXPECT_NE(std::find(methods.begin(), methods.end(), expected), methods.end()) << expected;
        }
      }
    }
  }
  EXPECT_TRUE(found) << "no meshdeform.v1.DeformationService in the reflection answer";
}

}  // namespace
}  // namespace meshdeform::client
