// The browser gateway at the protocol level: gRPC-Web requests written by hand on a raw loopback
// socket (POSIX, every read bounded by poll), against a real DeformationService behind
// DeformServiceImpl in an in-process grpc::Server, with GrpcWebGateway mounted on the HttpServer
// (make_http_router) next to /metrics and a StaticFileServer.
#include <gtest/gtest.h>

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "meshdeform/v1/deformation.grpc.pb.h"
#include "server/service/deformation_service.h"
#include "server/transport/deform_service_impl.h"
#include "server/transport/grpc_web_codec.h"
#include "server/transport/grpc_web_gateway.h"
#include "server/transport/http_router.h"
#include "server/transport/http_server.h"
#include "server/transport/ops_endpoints.h"
#include "server/transport/server_setup.h"
#include "server/transport/static_files.h"

namespace meshdeform::transport {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

constexpr std::string_view kService = "/meshdeform.v1.DeformationService/";

// ------------------------------------------------------------------------------------------------
// A minimal HTTP/1.1 client: blocking socket, every wait bounded by poll().

struct Response {
  int status = -1;
  std::map<std::string, std::string> headers;  ///< lower-case names
  std::string body;                            ///< de-chunked
  std::vector<std::string> chunks;             ///< chunk data, in order (chunked responses)
  std::string header(const std::string& name) const {
    const auto found = headers.find(name);
    return found == headers.end() ? std::string() : found->second;
  }
};

class Client {
 public:
  /// @param[in] source  local IPv4 address to connect from (host order; 0: any), e.g. 127.0.0.2
  ///                    to look like another browser on loopback.
  explicit Client(int port, std::uint32_t source = 0) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    if (source != 0) {
      sockaddr_in local{};
      local.sin_family = AF_INET;
      local.sin_addr.s_addr = htonl(source);
      if (::bind(fd_, reinterpret_cast<sockaddr*>(&local), sizeof local) != 0) close();
    }
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_port = htons(static_cast<std::uint16_t>(port));
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    if (::connect(fd_, reinterpret_cast<sockaddr*>(&address), sizeof address) != 0) close();
  }
  ~Client() { close(); }
  Client(const Client&) = delete;
  Client& operator=(const Client&) = delete;

  bool is_connected() const { return fd_ >= 0; }

  void close() {
    if (fd_ >= 0) ::close(fd_);
    fd_ = -1;
  }

  bool send_all(std::string_view bytes) {
    while (!bytes.empty() && fd_ >= 0) {
      const ssize_t n = ::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL);
      if (n <= 0) return false;
      bytes.remove_prefix(static_cast<std::size_t>(n));
    }
    return bytes.empty();
  }

  /// Reads what is available within `timeout` into the buffer; false on EOF, error or timeout.
  bool fill(milliseconds timeout = seconds(10)) {
    if (fd_ < 0) return false;
    pollfd p{fd_, POLLIN, 0};
    if (::poll(&p, 1, static_cast<int>(timeout.count())) <= 0) return false;
    char data[16384];
    const ssize_t n = ::recv(fd_, data, sizeof data, 0);
    if (n <= 0) return false;
    buffer_.append(data, static_cast<std::size_t>(n));
    return true;
  }

  /// True when the server closes the connection within `timeout` (buffered bytes are dropped).
  bool sees_eof(milliseconds timeout) {
    const auto deadline = std::chrono::steady_clock::now() + timeout;
    while (std::chrono::steady_clock::now() < deadline && fd_ >= 0) {
      pollfd p{fd_, POLLIN, 0};
      if (::poll(&p, 1, 100) <= 0) continue;
      char data[4096];
      if (::recv(fd_, data, sizeof data, 0) <= 0) return true;
    }
    return false;
  }

  std::optional<std::string> read_line() {
    for (int i = 0; i < 10000; ++i) {
      if (const std::size_t end = buffer_.find("\r\n"); end != std::string::npos) {
        std::string line = buffer_.substr(0, end);
        buffer_.erase(0, end + 2);
        return line;
      }
      if (!fill()) return std::nullopt;
    }
    return std::nullopt;
  }

  std::optional<std::string> read_exact(std::size_t n) {
    for (int i = 0; i < 100000 && buffer_.size() < n; ++i) {
      if (!fill()) return std::nullopt;
    }
    if (buffer_.size() < n) return std::nullopt;
    std::string out = buffer_.substr(0, n);
    buffer_.erase(0, n);
    return out;
  }

  /// The status line and headers.
  bool read_head(Response& response) {
    const std::optional<std::string> status_line = read_line();
    if (!status_line || status_line->rfind("HTTP/1.", 0) != 0 || status_line->size() < 12) {
      return false;
    }
    response.status = std::stoi(status_line->substr(9, 3));
    for (int i = 0; i < 200; ++i) {
      const std::optional<std::string> line = read_line();
      if (!line) return false;
      if (line->empty()) return true;
      const std::size_t colon = line->find(':');
      if (colon == std::string::npos) return false;
      std::string name = line->substr(0, colon);
      for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
      std::string value = line->substr(colon + 1);
      while (!value.empty() && value.front() == ' ') value.erase(0, 1);
      response.headers[name] = value;
    }
    return false;
  }

  /// The next chunk's data; "" for the last chunk; nullopt on a timeout or a broken stream.
  std::optional<std::string> read_chunk() {
    const std::optional<std::string> size_line = read_line();
    if (!size_line) return std::nullopt;
    const std::size_t size = std::stoul(*size_line, nullptr, 16);
    if (size == 0) {
      read_line();  // the empty line after the last chunk (no trailers)
      return std::string();
    }
    std::optional<std::string> data = read_exact(size + 2);
    if (!data || data->substr(size) != "\r\n") return std::nullopt;
    data->resize(size);
    return data;
  }

  /// A whole response: Content-Length, chunked (each chunk kept) or until EOF.
  bool read_response(Response& response) {
    if (!read_head(response)) return false;
    if (response.status == 204 || response.status == 304) return true;
    if (response.header("transfer-encoding") == "chunked") {
      for (int i = 0; i < 10000; ++i) {
        std::optional<std::string> chunk = read_chunk();
        if (!chunk) return false;
        if (chunk->empty()) return true;
        response.body += *chunk;
        response.chunks.push_back(std::move(*chunk));
      }
      return false;
    }
    if (const std::string length = response.header("content-length"); !length.empty()) {
      std::optional<std::string> body = read_exact(std::stoul(length));
      if (!body) return false;
      response.body = std::move(*body);
      return true;
    }
    for (int i = 0; i < 100000 && fill(); ++i) {
    }
    response.body = std::move(buffer_);
    buffer_.clear();
    return true;
  }

 private:
  int fd_ = -1;
  std::string buffer_;
};

// ------------------------------------------------------------------------------------------------
// gRPC-Web framing, as a browser client does it.

std::string frame(unsigned char flag, std::string_view payload) {
  std::string out(5, '\0');
  out[0] = static_cast<char>(flag);
  const auto n = static_cast<std::uint32_t>(payload.size());
  out[1] = static_cast<char>(n >> 24);
  out[2] = static_cast<char>(n >> 16);
  out[3] = static_cast<char>(n >> 8);
  out[4] = static_cast<char>(n);
  out += payload;
  return out;
}

struct Frames {
  bool is_valid = false;  ///< data frames, then exactly one trailer frame, nothing after it
  std::vector<std::string> messages;
  std::map<std::string, std::string> trailer;  ///< "grpc-status" -> "0"
  bool has_trailer = false;
  int status() const {
    const auto found = trailer.find("grpc-status");
    return found == trailer.end() ? -1 : std::stoi(found->second);
  }
  std::string message() const {
    const auto found = trailer.find("grpc-message");
    return found == trailer.end() ? std::string() : found->second;
  }
};

Frames parse_frames(std::string_view body) {
  Frames frames;
  while (!body.empty()) {
    if (body.size() < 5 || frames.has_trailer) return frames;
    const auto flag = static_cast<unsigned char>(body[0]);
    const std::uint32_t n = (std::uint32_t{static_cast<unsigned char>(body[1])} << 24) |
                            (std::uint32_t{static_cast<unsigned char>(body[2])} << 16) |
                            (std::uint32_t{static_cast<unsigned char>(body[3])} << 8) |
                            std::uint32_t{static_cast<unsigned char>(body[4])};
    if (body.size() - 5 < n) return frames;
    const std::string_view payload = body.substr(5, n);
    body.remove_prefix(5 + n);
    if (flag == 0x00) {
      frames.messages.emplace_back(payload);
    } else if (flag == 0x80) {
      frames.has_trailer = true;
      std::size_t start = 0;
      while (start < payload.size()) {
        const std::size_t end = payload.find("\r\n", start);
        if (end == std::string_view::npos) return frames;  // lines end with CRLF
        const std::string_view line = payload.substr(start, end - start);
        const std::size_t colon = line.find(':');
        if (colon == std::string_view::npos) return frames;
        std::string_view value = line.substr(colon + 1);
        while (!value.empty() && value.front() == ' ') value.remove_prefix(1);
        frames.trailer[std::string(line.substr(0, colon))] = std::string(value);
        start = end + 2;
      }
    } else {
      return frames;
    }
  }
  frames.is_valid = frames.has_trailer;
  return frames;
}

std::string grpc_web_request(std::string_view path, std::string_view body,
                             std::string_view content_type = "application/grpc-web+proto",
                             std::string_view extra_headers = "") {
  std::string text = "POST " + std::string(path) + " HTTP/1.1\r\nHost: 127.0.0.1\r\n";
  text += "Content-Type: " + std::string(content_type) + "\r\nX-Grpc-Web: 1\r\n";
  text += std::string(extra_headers);
  text += "Content-Length: " + std::to_string(body.size()) + "\r\n\r\n";
  text += body;
  return text;
}

std::string base64(std::string_view bytes) {
  static constexpr char kAlphabet[] =
      "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  std::size_t i = 0;
  for (; i + 3 <= bytes.size(); i += 3) {
    const std::uint32_t n = (std::uint32_t{static_cast<unsigned char>(bytes[i])} << 16) |
                            (std::uint32_t{static_cast<unsigned char>(bytes[i + 1])} << 8) |
                            std::uint32_t{static_cast<unsigned char>(bytes[i + 2])};
    for (int k = 3; k >= 0; --k) out += kAlphabet[(n >> (6 * k)) & 63];
  }
  if (i < bytes.size()) {
    std::uint32_t n = std::uint32_t{static_cast<unsigned char>(bytes[i])} << 16;
    if (i + 1 < bytes.size()) n |= std::uint32_t{static_cast<unsigned char>(bytes[i + 1])} << 8;
    out += kAlphabet[(n >> 18) & 63];
    out += kAlphabet[(n >> 12) & 63];
    out += i + 1 < bytes.size() ? kAlphabet[(n >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

std::string unbase64(std::string_view text) {
  std::string out;
  std::uint32_t n = 0;
  int bits = 0;
  for (const char c : text) {
    const char* at = std::strchr("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/", c);
    if (c == '=' || at == nullptr || c == '\0') {
      n = 0;  // padding ends a segment
      bits = 0;
      continue;
    }
    n = (n << 6) | static_cast<std::uint32_t>(at - "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/");
    bits += 6;
    if (bits >= 8) {
      bits -= 8;
      out += static_cast<char>((n >> bits) & 0xFF);
    }
  }
  return out;
}

// ------------------------------------------------------------------------------------------------

class GrpcWebTest : public ::testing::Test {
 protected:
  void start(GrpcWebGatewayOptions options = {}, std::size_t max_message_bytes = 64 << 20,
             const StaticFileServer* files = nullptr) {
    service::ServiceOptions service_options;
    service_options.workers = 2;
    service_options.refine_budget = 0;  // no background revisions: Watch sees only our moves
    if (create_rate_) service_options.create_rate = *create_rate_;
    service_ = std::make_unique<service::DeformationService>(service_options);
    impl_ = std::make_unique<DeformServiceImpl>(*service_);
    enable_health_and_reflection();
    grpc::ServerBuilder builder;
    configure_builder(builder, *impl_, 64);
    server_ = builder.BuildAndStart();
    ASSERT_NE(server_, nullptr);
    grpc::ChannelArguments arguments;
    arguments.SetMaxReceiveMessageSize(64 << 20);
    stub_ = v1::DeformationService::NewStub(server_->InProcessChannel(arguments));
    gateway_ = std::make_unique<GrpcWebGateway>(*server_, max_message_bytes, std::move(options),
                                                &service_->metrics());
    HttpServerOptions http_options;
    http_options.threads = 2;
    http_options.body_limit = make_body_limit(*gateway_);
    auto http = HttpServer::start_async(
        "127.0.0.1:0",
        make_http_router(*gateway_, files,
                         [this](const HttpRequest& request) {
                           return handle_ops_request(request, *service_, true);
                         }),
        http_options);
    ASSERT_TRUE(http.ok()) << http.status().to_string();
    http_ = std::move(http).value();
  }

  std::optional<service::RateLimit> create_rate_;  ///< set before start() to limit creations

  void TearDown() override {
    if (gateway_) gateway_->stop();
    if (http_) http_->stop();
    if (server_) server_->Shutdown(std::chrono::system_clock::now() + seconds(10));
  }

  int port() const { return http_->port(); }

  /// One gRPC-Web call on its own connection; the whole response.
  Response call(std::string_view method, const google::protobuf::Message& request,
                std::string_view extra_headers = "") {
    return raw_call(std::string(kService) + std::string(method),
                    frame(0x00, request.SerializeAsString()), "application/grpc-web+proto",
                    extra_headers);
  }

  Response raw_call(const std::string& path, std::string_view body,
                    std::string_view content_type = "application/grpc-web+proto",
                    std::string_view extra_headers = "", std::uint32_t source = 0) {
    Client client(port(), source);
    Response response;
    EXPECT_TRUE(client.is_connected());
    EXPECT_TRUE(client.send_all(grpc_web_request(path, body, content_type, extra_headers)));
    EXPECT_TRUE(client.read_response(response)) << path;
    return response;
  }

  Response http(const std::string& request_text) {
    Client client(port());
    Response response;
    EXPECT_TRUE(client.send_all(request_text));
    EXPECT_TRUE(client.read_response(response));
    return response;
  }

  template <typename Message>
  static Message parse_only_message(const Frames& frames) {
    Message message;
    EXPECT_EQ(frames.messages.size(), 1u);
    if (!frames.messages.empty()) {
      EXPECT_TRUE(message.ParseFromString(frames.messages.front()));
    }
    return message;
  }

  v1::CreateSessionResponse create_natively(const std::string& sample, bool set_handles) {
    v1::CreateSessionRequest request;
    request.set_sample(sample);
    v1::CreateSessionResponse created;
    {
      grpc::ClientContext context;
      context.set_deadline(std::chrono::system_clock::now() + seconds(60));
      EXPECT_TRUE(stub_->CreateSession(&context, request, &created).ok());
    }
    if (set_handles) {
      v1::SetHandlesResponse set;
      grpc::ClientContext context;
      context.set_deadline(std::chrono::system_clock::now() + seconds(60));
      EXPECT_TRUE(stub_->SetHandles(&context, set_handles_request(created), &set).ok());
    }
    return created;
  }

  static v1::SetHandlesRequest set_handles_request(const v1::CreateSessionResponse& created) {
    v1::SetHandlesRequest request;
    request.set_session_id(created.session_id());
    request.set_token(created.edit_token());
    *request.mutable_groups() = created.suggested_groups();
    return request;
  }

  static v1::MoveHandlesRequest move_request(const v1::CreateSessionResponse& created,
                                             double angle_deg, int iterations) {
    v1::MoveHandlesRequest request;
    request.set_session_id(created.session_id());
    request.set_token(created.edit_token());
    request.set_max_iterations(static_cast<std::uint32_t>(iterations));
    request.set_full_positions(true);
    v1::GroupMove* move = request.add_moves();
    move->set_group(1);
    move->mutable_rotation()->set_w(std::cos(angle_deg * M_PI / 360.0));
    move->mutable_rotation()->set_y(std::sin(angle_deg * M_PI / 360.0));
    return request;
  }

  grpc::Status move_natively(const v1::MoveHandlesRequest& request, v1::MoveHandlesResponse* out) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + seconds(60));
    return stub_->MoveHandles(&context, request, out);
  }

  std::uint32_t watchers() {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + seconds(10));
    v1::GetServerStatsResponse stats;
    EXPECT_TRUE(stub_->GetServerStats(&context, v1::GetServerStatsRequest(), &stats).ok());
    return stats.watchers();
  }

  /// Polls (at most 200 x 50 ms) until the server reports `expected` open Watch streams.
  std::uint32_t wait_for_watchers(std::uint32_t expected) {
    std::uint32_t now = watchers();
    for (int i = 0; i < 200 && now != expected; ++i) {
      std::this_thread::sleep_for(milliseconds(50));
      now = watchers();
    }
    return now;
  }

  /// Opens a Watch through the gateway and reads the response head and the snapshot chunk.
  void open_watch(Client& client, const v1::CreateSessionResponse& created,
                  v1::DeformUpdate* snapshot) {
    v1::WatchRequest watch;
    watch.set_session_id(created.session_id());
    watch.set_token(created.view_token());
    ASSERT_TRUE(client.send_all(grpc_web_request(std::string(kService) + "Watch",
                                                 frame(0x00, watch.SerializeAsString()))));
    Response head;
    ASSERT_TRUE(client.read_head(head));
    ASSERT_EQ(head.status, 200);
    EXPECT_EQ(head.header("content-type"), "application/grpc-web+proto");
    ASSERT_EQ(head.header("transfer-encoding"), "chunked");
    const std::optional<std::string> chunk = client.read_chunk();
    ASSERT_TRUE(chunk.has_value());
    // One chunk, one complete data frame.
    Frames frames = parse_frames(*chunk + frame(0x80, "grpc-status: 0\r\n"));
    ASSERT_TRUE(frames.is_valid);
    ASSERT_EQ(frames.messages.size(), 1u);
    ASSERT_TRUE(snapshot->ParseFromString(frames.messages.front()));
  }

  std::unique_ptr<service::DeformationService> service_;
  std::unique_ptr<DeformServiceImpl> impl_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<v1::DeformationService::Stub> stub_;
  std::unique_ptr<GrpcWebGateway> gateway_;  // after server_, before http_ (destruction order)
  std::unique_ptr<HttpServer> http_;
};

TEST_F(GrpcWebTest, UnaryCreateSessionReturnsOneMessageAndAnOkTrailer) {
  start();
  v1::CreateSessionRequest request;
  request.set_sample("cylinder_small");
  const Response response = call("CreateSession", request);
  ASSERT_EQ(response.status, 200);
  EXPECT_EQ(response.header("content-type"), "application/grpc-web+proto");
  EXPECT_EQ(response.header("grpc-status"), "");  // not trailers-only: the status is in the body
  const Frames frames = parse_frames(response.body);
  ASSERT_TRUE(frames.is_valid);
  EXPECT_EQ(frames.status(), 0);
  const auto created = parse_only_message<v1::CreateSessionResponse>(frames);
  EXPECT_FALSE(created.session_id().empty());
  EXPECT_FALSE(created.edit_token().empty());
  EXPECT_GT(created.info().vertices(), 0u);
  EXPECT_EQ(created.suggested_groups_size(), 2);

  // Counted with front end "grpc-web" (and, by the service itself, "grpc").
  const std::string metrics = service_->render_metrics();
  EXPECT_NE(metrics.find(R"(meshdeform_rpc_requests_total{frontend="grpc-web",method="CreateSession",code="OK"} 1)"),
            std::string::npos);
  EXPECT_NE(metrics.find(R"(meshdeform_rpc_requests_total{frontend="grpc",method="CreateSession",code="OK"} 1)"),
            std::string::npos);
}

TEST_F(GrpcWebTest, GatewayMovesMatchNativeMovesExactly) {
  start();
  v1::CreateSessionRequest create;
  create.set_sample("cylinder_small");
  const Frames created_frames = parse_frames(call("CreateSession", create).body);
  ASSERT_EQ(created_frames.status(), 0);
  const auto web = parse_only_message<v1::CreateSessionResponse>(created_frames);
  const v1::CreateSessionResponse native = create_natively("cylinder_small", true);

  const std::string session_header = "X-Session-Id: " + web.session_id() + "\r\n";
  const Frames set_frames =
      parse_frames(call("SetHandles", set_handles_request(web), session_header).body);
  ASSERT_EQ(set_frames.status(), 0) << set_frames.message();
  EXPECT_EQ(parse_only_message<v1::SetHandlesResponse>(set_frames).info().groups_size(), 2);

  for (const double angle : {30.0, 75.0}) {
    const Frames moved_frames =
        parse_frames(call("MoveHandles", move_request(web, angle, 3), session_header).body);
    ASSERT_EQ(moved_frames.status(), 0) << moved_frames.message();
    const auto through_gateway = parse_only_message<v1::MoveHandlesResponse>(moved_frames);
    v1::MoveHandlesResponse direct;
    ASSERT_TRUE(move_natively(move_request(native, angle, 3), &direct).ok());
    ASSERT_GT(direct.result().positions_size(), 0);
    ASSERT_EQ(through_gateway.result().positions_size(), direct.result().positions_size());
    for (int i = 0; i < direct.result().positions_size(); ++i) {
      ASSERT_EQ(through_gateway.result().positions(i), direct.result().positions(i)) << i;
    }
    EXPECT_EQ(through_gateway.result().revision(), direct.result().revision());
    EXPECT_EQ(through_gateway.result().e_theta(), direct.result().e_theta());
  }
}

TEST_F(GrpcWebTest, ErrorsAreTrailersOnlyWithTheStatusAlsoInHeaders) {
  start();
  v1::GetSessionInfoRequest request;
  request.set_session_id("no-such-session");
  request.set_token("x");
  const Response response = call("GetSessionInfo", request);
  ASSERT_EQ(response.status, 200);
  EXPECT_EQ(response.header("content-type"), "application/grpc-web+proto");
  EXPECT_EQ(response.header("grpc-status"), "5");
  const Frames frames = parse_frames(response.body);
  ASSERT_TRUE(frames.is_valid);
  EXPECT_TRUE(frames.messages.empty());
  EXPECT_EQ(frames.status(), 5);

  // The same message as a native client gets (percent-encoded on the wire).
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + seconds(10));
  v1::GetSessionInfoResponse ignored;
  const grpc::Status native = stub_->GetSessionInfo(&context, request, &ignored);
  ASSERT_EQ(native.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_FALSE(native.error_message().empty());
  EXPECT_EQ(frames.message(), percent_encode_grpc_message(native.error_message()));
  EXPECT_EQ(response.header("grpc-message"), percent_encode_grpc_message(native.error_message()));

  // A header that cannot be metadata.
  const Response bad_header = call("GetSessionInfo", request, "X-Session-Id: caf\xC3\xA9\r\n");
  EXPECT_EQ(bad_header.header("grpc-status"), "3");
}

TEST_F(GrpcWebTest, WatchStreamsEachUpdateAsItsOwnChunkAndEndsWithATrailer) {
  start();
  const v1::CreateSessionResponse created = create_natively("cylinder_small", true);
  Client client(port());
  v1::DeformUpdate snapshot;
  ASSERT_NO_FATAL_FAILURE(open_watch(client, created, &snapshot));
  EXPECT_TRUE(snapshot.is_snapshot());
  EXPECT_EQ(snapshot.result().revision(), 0u);
  EXPECT_EQ(static_cast<std::uint32_t>(snapshot.result().positions_size()),
            3 * created.info().vertices());

  v1::MoveHandlesResponse moved;
  ASSERT_TRUE(move_natively(move_request(created, 40, 2), &moved).ok());
  std::optional<std::string> chunk = client.read_chunk();
  ASSERT_TRUE(chunk.has_value());
  Frames frames = parse_frames(*chunk + frame(0x80, "grpc-status: 0\r\n"));
  ASSERT_TRUE(frames.is_valid);
  ASSERT_EQ(frames.messages.size(), 1u);  // the update alone, flushed before the stream ends
  v1::DeformUpdate update;
  ASSERT_TRUE(update.ParseFromString(frames.messages.front()));
  EXPECT_FALSE(update.is_snapshot());
  EXPECT_EQ(update.result().revision(), moved.result().revision());
  EXPECT_GT(update.result().changed_indices_size(), 0);

  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + seconds(10));
  v1::CloseSessionRequest close;
  close.set_session_id(created.session_id());
  close.set_token(created.edit_token());
  v1::CloseSessionResponse closed;
  ASSERT_TRUE(stub_->CloseSession(&context, close, &closed).ok());
  chunk = client.read_chunk();
  ASSERT_TRUE(chunk.has_value());
  frames = parse_frames(*chunk);
  ASSERT_TRUE(frames.is_valid);
  EXPECT_TRUE(frames.messages.empty());
  EXPECT_EQ(frames.status(), 0);
  EXPECT_EQ(client.read_chunk(), std::string());  // the last chunk
}

TEST_F(GrpcWebTest, BrowserDisconnectCancelsTheForwardedWatch) {
  start();
  const v1::CreateSessionResponse created = create_natively("cylinder_small", false);
  auto client = std::make_unique<Client>(port());
  v1::DeformUpdate snapshot;
  ASSERT_NO_FATAL_FAILURE(open_watch(*client, created, &snapshot));
  EXPECT_EQ(watchers(), 1u);
  EXPECT_EQ(gateway_->open_streams(), 1u);
  client.reset();  // the browser tab goes away
  EXPECT_EQ(wait_for_watchers(0), 0u);
  for (int i = 0; i < 200 && gateway_->open_streams() != 0; ++i) {
    std::this_thread::sleep_for(milliseconds(50));
  }
  EXPECT_EQ(gateway_->open_streams(), 0u);
  const std::string metrics = service_->render_metrics();
  EXPECT_NE(metrics.find(R"(meshdeform_rpc_requests_total{frontend="grpc-web",method="Watch",code="CANCELLED"} 1)"),
            std::string::npos);
}

TEST_F(GrpcWebTest, ManyWatchersSomeLeavingWhileMovesArrive) {
  start();
  const v1::CreateSessionResponse created = create_natively("cylinder_small", true);
  constexpr int kWatchers = 6;
  std::vector<std::unique_ptr<Client>> clients;
  for (int i = 0; i < kWatchers; ++i) {
    clients.push_back(std::make_unique<Client>(port()));
    v1::DeformUpdate snapshot;
    ASSERT_NO_FATAL_FAILURE(open_watch(*clients.back(), created, &snapshot));
  }
  EXPECT_EQ(watchers(), static_cast<std::uint32_t>(kWatchers));
  // Every other browser leaves while moves are being published.
  std::jthread leaver([&clients] {  // joined on every path, an early ASSERT included
    for (int i = 0; i < kWatchers; i += 2) clients[i]->close();
  });
  v1::MoveHandlesResponse moved;
  for (int k = 1; k <= 3; ++k) {
    ASSERT_TRUE(move_natively(move_request(created, 10.0 * k, 1), &moved).ok());
  }
  leaver.join();
  // The others see revisions up to the last (skips allowed), each a single-frame chunk.
  for (int i = 1; i < kWatchers; i += 2) {
    std::uint64_t revision = 0;
    for (int n = 0; n < 10 && revision < moved.result().revision(); ++n) {
      const std::optional<std::string> chunk = clients[i]->read_chunk();
      ASSERT_TRUE(chunk.has_value()) << i;
      const Frames frames = parse_frames(*chunk + frame(0x80, "grpc-status: 0\r\n"));
      ASSERT_TRUE(frames.is_valid);
      ASSERT_EQ(frames.messages.size(), 1u);
      v1::DeformUpdate update;
      ASSERT_TRUE(update.ParseFromString(frames.messages.front()));
      EXPECT_GT(update.result().revision(), revision);
      revision = update.result().revision();
    }
    EXPECT_EQ(revision, moved.result().revision()) << i;
  }
  EXPECT_EQ(wait_for_watchers(kWatchers / 2), static_cast<std::uint32_t>(kWatchers / 2));
  EXPECT_TRUE(gateway_->stop(seconds(10)));
  EXPECT_EQ(wait_for_watchers(0), 0u);
}

TEST_F(GrpcWebTest, StopCancelsOpenStreamsWithATrailer) {
  start();
  const v1::CreateSessionResponse created = create_natively("cylinder_small", false);
  Client client(port());
  v1::DeformUpdate snapshot;
  ASSERT_NO_FATAL_FAILURE(open_watch(client, created, &snapshot));
  EXPECT_TRUE(gateway_->stop(seconds(10)));
  EXPECT_EQ(gateway_->open_calls(), 0u);
  const std::optional<std::string> chunk = client.read_chunk();
  ASSERT_TRUE(chunk.has_value());
  const Frames frames = parse_frames(*chunk);
  ASSERT_TRUE(frames.is_valid);
  EXPECT_EQ(frames.status(), 1);  // CANCELLED
  EXPECT_EQ(client.read_chunk(), std::string());
  EXPECT_EQ(wait_for_watchers(0), 0u);
  // New calls are refused.
  const Response refused = call("GetServerStats", v1::GetServerStatsRequest());
  EXPECT_EQ(refused.header("grpc-status"), "14");
}

TEST_F(GrpcWebTest, MaxStreamsIsEnforced) {
  GrpcWebGatewayOptions options;
  options.max_streams = 1;
  start(options);
  const v1::CreateSessionResponse created = create_natively("cylinder_small", false);
  Client first(port());
  v1::DeformUpdate snapshot;
  ASSERT_NO_FATAL_FAILURE(open_watch(first, created, &snapshot));
  v1::WatchRequest watch;
  watch.set_session_id(created.session_id());
  watch.set_token(created.view_token());
  const Response second = call("Watch", watch);
  EXPECT_EQ(second.header("grpc-status"), "8");
  EXPECT_EQ(parse_frames(second.body).status(), 8);
  // Unary calls are not streams.
  EXPECT_EQ(parse_frames(call("GetServerStats", v1::GetServerStatsRequest()).body).status(), 0);
}

TEST_F(GrpcWebTest, CorsPreflightAndActualResponses) {
  GrpcWebGatewayOptions options;
  options.allowed_origins = {"http://viewer.test"};
  start(options);
  const std::string path = std::string(kService) + "GetServerStats";
  const Response preflight =
      http("OPTIONS " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\nOrigin: http://viewer.test\r\n"
           "Access-Control-Request-Method: POST\r\n"
           "Access-Control-Request-Headers: content-type,x-grpc-web,grpc-timeout\r\n\r\n");
  EXPECT_EQ(preflight.status, 204);
  EXPECT_EQ(preflight.header("access-control-allow-origin"), "http://viewer.test");
  EXPECT_EQ(preflight.header("access-control-allow-methods"), "POST, OPTIONS");
  EXPECT_EQ(preflight.header("access-control-allow-headers"),
            "content-type, x-grpc-web, x-user-agent, grpc-timeout, x-session-id");
  EXPECT_EQ(preflight.header("access-control-expose-headers"), "grpc-status, grpc-message");
  EXPECT_EQ(preflight.header("access-control-max-age"), "600");
  EXPECT_EQ(preflight.header("vary"), "Origin");

  const Response foreign =
      http("OPTIONS " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\nOrigin: http://evil.test\r\n"
           "Access-Control-Request-Method: POST\r\n\r\n");
  EXPECT_EQ(foreign.status, 403);
  EXPECT_EQ(foreign.header("access-control-allow-origin"), "");

  const Response actual =
      call("GetServerStats", v1::GetServerStatsRequest(), "Origin: http://viewer.test\r\n");
  EXPECT_EQ(actual.status, 200);
  EXPECT_EQ(actual.header("access-control-allow-origin"), "http://viewer.test");
  EXPECT_EQ(actual.header("access-control-expose-headers"), "grpc-status, grpc-message");
  EXPECT_EQ(parse_frames(actual.body).status(), 0);
  const Response actual_foreign =
      call("GetServerStats", v1::GetServerStatsRequest(), "Origin: http://evil.test\r\n");
  EXPECT_EQ(actual_foreign.header("access-control-allow-origin"), "");
}

TEST_F(GrpcWebTest, WrongContentTypeIs415) {
  start();
  const Response response =
      raw_call(std::string(kService) + "GetServerStats",
               frame(0x00, v1::GetServerStatsRequest().SerializeAsString()), "application/json");
  EXPECT_EQ(response.status, 415);
  EXPECT_EQ(response.header("grpc-status"), "");
  // Media type parameters and case do not matter.
  const Response ok = raw_call(std::string(kService) + "GetServerStats",
                               frame(0x00, v1::GetServerStatsRequest().SerializeAsString()),
                               "Application/GRPC-Web+proto; charset=utf-8");
  EXPECT_EQ(parse_frames(ok.body).status(), 0);
}

TEST_F(GrpcWebTest, MalformedFramesAreInternal) {
  start();
  const std::string path = std::string(kService) + "GetServerStats";
  struct Case {
    std::string body;
    std::string expected;
  };
  std::string declares_100 = frame(0x00, std::string(10, 'x'));
  declares_100[4] = 100;
  const std::vector<Case> cases = {
      {declares_100, "truncated request message"},
      {std::string("\x00\x00\x00", 3), "truncated frame header"},
      {"", "empty request body"},
      {frame(0x00, "") + "xyz", "3 bytes after the request message"},
      {frame(0x01, "abc"), "compressed"},
      {frame(0x80, "grpc-status: 0\r\n"), "frame flag"},
  };
  for (const Case& c : cases) {
    const Response response = raw_call(path, c.body);
    EXPECT_EQ(response.status, 200);
    EXPECT_EQ(response.header("grpc-status"), "13") << c.expected;
    const Frames frames = parse_frames(response.body);
    EXPECT_EQ(frames.status(), 13);
    EXPECT_NE(frames.message().find(c.expected), std::string::npos) << frames.message();
  }
}

TEST_F(GrpcWebTest, OversizeMessagesAreResourceExhausted) {
  start(GrpcWebGatewayOptions{}, /*max_message_bytes=*/4096);
  v1::CreateSessionRequest big;
  big.set_mesh_bytes(std::string(5000, 'x'));
  big.set_format(v1::MESH_FORMAT_OBJ);
  Response response = call("CreateSession", big);
  EXPECT_EQ(response.header("grpc-status"), "8");
  EXPECT_NE(parse_frames(response.body).message().find("over the limit of 4096 bytes"),
            std::string::npos);

  // A frame header claiming 1 GiB in a small body.
  std::string liar = frame(0x00, "abc");
  liar[1] = 0x40;
  response = raw_call(std::string(kService) + "CreateSession", liar);
  EXPECT_EQ(response.header("grpc-status"), "8");

  // A declared body far over the route's limit is answered without being read, then closed.
  Client client(port());
  ASSERT_TRUE(client.send_all("POST " + std::string(kService) +
                              "CreateSession HTTP/1.1\r\nHost: x\r\nContent-Type: "
                              "application/grpc-web+proto\r\nContent-Length: 99999999\r\n\r\n"));
  Response declared;
  ASSERT_TRUE(client.read_response(declared));
  EXPECT_EQ(declared.status, 200);
  EXPECT_EQ(declared.header("grpc-status"), "8");
  EXPECT_EQ(declared.header("connection"), "close");
  EXPECT_TRUE(client.sees_eof(seconds(10)));

  // The same while the client keeps sending the body: the answer still arrives (the server
  // reads and discards before closing, rather than resetting the connection).
  Client sender(port());
  ASSERT_TRUE(sender.send_all("POST " + std::string(kService) +
                              "CreateSession HTTP/1.1\r\nHost: x\r\nContent-Type: "
                              "application/grpc-web+proto\r\nContent-Length: 200000\r\n\r\n"));
  ASSERT_TRUE(sender.send_all(std::string(200000, 'x')));
  Response sent;
  ASSERT_TRUE(sender.read_response(sent));
  EXPECT_EQ(sent.header("grpc-status"), "8");

  // Within the limit all is well.
  EXPECT_EQ(parse_frames(call("GetServerStats", v1::GetServerStatsRequest()).body).status(), 0);
}

TEST_F(GrpcWebTest, LargeUnaryResponsesArriveWhole) {
  start();
  const v1::CreateSessionResponse created = create_natively("cylinder", false);
  v1::GetMeshRequest request;
  request.set_session_id(created.session_id());
  request.set_token(created.view_token());
  request.set_format(v1::MESH_FORMAT_OBJ);
  const Frames frames = parse_frames(call("GetMesh", request).body);
  ASSERT_EQ(frames.status(), 0) << frames.message();
  const auto through_gateway = parse_only_message<v1::GetMeshResponse>(frames);
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + seconds(30));
  v1::GetMeshResponse direct;
  ASSERT_TRUE(stub_->GetMesh(&context, request, &direct).ok());
  EXPECT_GT(direct.mesh_bytes().size(), 100'000u);  // over the listener's one-write threshold
  EXPECT_EQ(through_gateway.mesh_bytes(), direct.mesh_bytes());
}

TEST_F(GrpcWebTest, GrpcTimeoutBecomesTheForwardedDeadline) {
  start();
  const v1::CreateSessionResponse created = create_natively("cylinder", true);
  v1::MoveHandlesRequest request = move_request(created, 60, 1000);
  request.set_tolerance(0);  // no early stop: 1000 outer iterations take far longer than 300 ms
  request.set_full_positions(false);
  const Response response = call("MoveHandles", request, "grpc-timeout: 300m\r\n");
  EXPECT_EQ(response.header("grpc-status"), "4") << parse_frames(response.body).message();
  EXPECT_EQ(parse_frames(response.body).status(), 4);

  const Response malformed = call("MoveHandles", request, "grpc-timeout: soon\r\n");
  EXPECT_EQ(malformed.header("grpc-status"), "3");
  EXPECT_NE(parse_frames(malformed.body).message().find("grpc-timeout"), std::string::npos);
}

TEST_F(GrpcWebTest, UnknownMethodsAreUnimplemented) {
  start();
  for (const std::string& path : {std::string(kService) + "Nope",
                                 std::string("/grpc.reflection.v1alpha.ServerReflection/"
                                             "ServerReflectionInfo"),
                                 std::string("/other.Service/Method")}) {
    const Response response = raw_call(path, frame(0x00, ""));
    EXPECT_EQ(response.status, 200);
    EXPECT_EQ(response.header("grpc-status"), "12") << path;
    EXPECT_EQ(parse_frames(response.body).status(), 12);
  }
}

TEST_F(GrpcWebTest, HealthCheckAndGrpcWebText) {
  start();
  // grpc.health.v1.HealthCheckResponse{status: SERVING} is the two bytes 08 01.
  const Response health = raw_call("/grpc.health.v1.Health/Check", frame(0x00, ""));
  const Frames frames = parse_frames(health.body);
  EXPECT_EQ(frames.status(), 0);
  ASSERT_EQ(frames.messages.size(), 1u);
  EXPECT_EQ(frames.messages.front(), std::string("\x08\x01", 2));

  // Base64 both ways.
  v1::GetSessionInfoRequest missing;
  missing.set_session_id("nope");
  const Response text =
      raw_call(std::string(kService) + "GetServerStats",
               base64(frame(0x00, v1::GetServerStatsRequest().SerializeAsString())),
               "application/grpc-web-text");
  EXPECT_EQ(text.header("content-type"), "application/grpc-web-text+proto");
  const Frames decoded = parse_frames(unbase64(text.body));
  EXPECT_EQ(decoded.status(), 0);
  EXPECT_EQ(decoded.messages.size(), 1u);
  const Response bad_text = raw_call(std::string(kService) + "GetServerStats", "%%%%",
                                     "application/grpc-web-text");
  EXPECT_EQ(bad_text.header("grpc-status"), "13");
}

TEST_F(GrpcWebTest, KeepAliveAndPipelinedRequestsOnOneConnection) {
  start();
  const std::string request = grpc_web_request(
      std::string(kService) + "GetServerStats",
      frame(0x00, v1::GetServerStatsRequest().SerializeAsString()));
  Client client(port());
  // Sequential requests on one connection, then two pipelined in one write.
  for (int i = 0; i < 2; ++i) {
    ASSERT_TRUE(client.send_all(request));
    Response response;
    ASSERT_TRUE(client.read_response(response));
    EXPECT_EQ(parse_frames(response.body).status(), 0);
  }
  ASSERT_TRUE(client.send_all(request + request));
  for (int i = 0; i < 2; ++i) {
    Response response;
    ASSERT_TRUE(client.read_response(response)) << i;
    EXPECT_EQ(parse_frames(response.body).status(), 0);
  }
  // The operations endpoints share the listener.
  const Response metrics = http("GET /metrics HTTP/1.1\r\nHost: x\r\n\r\n");
  EXPECT_EQ(metrics.status, 200);
  EXPECT_NE(metrics.body.find(R"(frontend="grpc-web",method="GetServerStats",code="OK"} 4)"),
            std::string::npos);
}

TEST(GrpcWebStaticFiles, ServesFilesAndRefusesTraversal) {
  const std::filesystem::path base =
      std::filesystem::temp_directory_path() /
      ("meshdeform_static_" + std::to_string(::getpid()));
  std::filesystem::remove_all(base);
  std::filesystem::create_directories(base / "root" / "sub");
  std::filesystem::create_directories(base / "outside");
  const auto write = [](const std::filesystem::path& path, const std::string& text) {
    std::ofstream(path, std::ios::binary) << text;
  };
  write(base / "root" / "index.html", "<html>viewer</html>");
  write(base / "root" / "app.js", "console.log(1)");
  write(base / "root" / "sub" / "mod.wasm", std::string("\0asm", 4));
  write(base / "root" / ".env", "hidden");
  write(base / "outside" / "secret.txt", "TOP-SECRET");
  std::filesystem::create_symlink(base / "outside" / "secret.txt", base / "root" / "link.txt");
  std::filesystem::create_directory_symlink(base / "outside", base / "root" / "escape");

  Result<StaticFileServer> files = StaticFileServer::open(base / "root");
  ASSERT_TRUE(files.ok()) << files.status().to_string();
  EXPECT_FALSE(StaticFileServer::open(base / "missing").ok());
  const auto get = [&](const std::string& target) {
    HttpRequest request;
    request.method = "GET";
    request.target = target;
    return files->serve(request);
  };
  HttpResponse index = get("/");
  EXPECT_EQ(index.status, 200);
  EXPECT_EQ(index.body, "<html>viewer</html>");
  EXPECT_EQ(index.content_type, "text/html; charset=utf-8");
  EXPECT_EQ(get("/app.js?v=3").content_type, "text/javascript; charset=utf-8");
  EXPECT_EQ(get("/sub/mod.wasm").content_type, "application/wasm");
  EXPECT_EQ(get("/sub/mod.wasm").body.size(), 4u);
  EXPECT_EQ(get("/sub/").status, 404);  // no index.html there
  EXPECT_EQ(get("/nothing.css").status, 404);
  for (const std::string target :
       {"/../outside/secret.txt", "/%2e%2e/outside/secret.txt", "/sub/../../outside/secret.txt",
        "/..%2foutside%2fsecret.txt", "/sub/%2E%2E/%2E%2E/outside/secret.txt", "/link.txt",
        "/escape/secret.txt", "/.env", "/sub/..\\..\\outside\\secret.txt", "/%00", "/%zz",
        "relative"}) {
    const HttpResponse refused = get(target);
    EXPECT_TRUE(refused.status == 400 || refused.status == 404) << target << " " << refused.status;
    EXPECT_EQ(refused.body.find("TOP-SECRET"), std::string::npos) << target;
    EXPECT_EQ(refused.body.find("hidden"), std::string::npos) << target;
  }
  HttpRequest post;
  post.method = "POST";
  post.target = "/index.html";
  EXPECT_EQ(files->serve(post).status, 405);
  std::filesystem::remove_all(base);
}

TEST_F(GrpcWebTest, StaticFilesShareTheListenerWithTheGatewayAndOps) {
  const std::filesystem::path root =
      std::filesystem::temp_directory_path() / ("meshdeform_viewer_" + std::to_string(::getpid()));
  std::filesystem::remove_all(root);
  std::filesystem::create_directories(root);
  std::ofstream(root / "index.html") << "<html>viewer</html>";
  Result<StaticFileServer> files = StaticFileServer::open(root);
  ASSERT_TRUE(files.ok());
  start(GrpcWebGatewayOptions{}, 64 << 20, &*files);
  const Response index = http("GET / HTTP/1.1\r\nHost: x\r\n\r\n");
  EXPECT_EQ(index.status, 200);
  EXPECT_EQ(index.body, "<html>viewer</html>");
  EXPECT_EQ(http("GET /../../etc/passwd HTTP/1.1\r\nHost: x\r\n\r\n").status, 400);
  EXPECT_EQ(http("GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n").status, 200);
  EXPECT_EQ(parse_frames(call("GetServerStats", v1::GetServerStatsRequest()).body).status(), 0);
  // Bodies over the ordinary 1 MiB limit on other routes still get 413.
  EXPECT_EQ(http("POST /upload HTTP/1.1\r\nHost: x\r\nContent-Length: 99999999\r\n\r\n").status,
            413);
  http_->stop();
  std::filesystem::remove_all(root);
}

TEST_F(GrpcWebTest, RateLimitsCountEachBrowserByItsOwnAddress) {
  // The gateway forwards in-process, so without the browser's address every browser would share
  // one rate-limit bucket. Two loopback addresses play two browsers.
  create_rate_ = service::RateLimit{0.001, 1.0};  // one session each, then a ~17-minute wait
  start();
  v1::CreateSessionRequest request;
  request.set_sample("bar_small");
  auto create_from = [&](std::uint32_t source) {
    const Response response =
        raw_call(std::string(kService) + "CreateSession", frame(0x00, request.SerializeAsString()),
                 "application/grpc-web+proto", "", source);
    const Frames frames = parse_frames(response.body);
    return response.header("grpc-status").empty() ? frames.status()
                                                  : std::stoi(std::string(response.header("grpc-status")));
  };
  EXPECT_EQ(create_from(0x7F000001), 0);  // 127.0.0.1
  const int second = create_from(0x7F000001);
  EXPECT_EQ(second, static_cast<int>(grpc::StatusCode::RESOURCE_EXHAUSTED));
  EXPECT_EQ(create_from(0x7F000002), 0);  // 127.0.0.2: another browser, its own bucket
}

TEST_F(GrpcWebTest, ProgressStreamsCarryEveryPhaseAndEndWithTheResponse) {
  // Issue 15: the *WithProgress streams through the gateway, as the viewer calls them. Every
  // round must end with the response event and an OK trailer (bounded: 8 sessions; each
  // precompute runs, nothing is cached).
  start();
  for (int round = 0; round < 8; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    v1::CreateSessionRequest create;
    create.set_sample(round % 2 == 0 ? "cylinder_small" : "cylinder");
    const Frames created = parse_frames(call("CreateSessionWithProgress", create).body);
    ASSERT_TRUE(created.is_valid);
    ASSERT_EQ(created.status(), 0);
    ASSERT_GE(created.messages.size(), 2u);
    v1::CreateSessionEvent last_create;
    ASSERT_TRUE(last_create.ParseFromString(created.messages.back()));
    ASSERT_TRUE(last_create.has_response());

    const Frames set =
        parse_frames(call("SetHandlesWithProgress", set_handles_request(last_create.response())).body);
    ASSERT_TRUE(set.is_valid);
    ASSERT_EQ(set.status(), 0);
    std::vector<std::string> phases;
    for (std::size_t i = 0; i + 1 < set.messages.size(); ++i) {
      v1::SetHandlesEvent event;
      ASSERT_TRUE(event.ParseFromString(set.messages[i]));
      ASSERT_TRUE(event.has_progress()) << "message " << i;
      if (phases.empty() || phases.back() != event.progress().phase())
        phases.push_back(event.progress().phase());
    }
    EXPECT_EQ(phases, (std::vector<std::string>{"queued", "validate", "rigid_start", "step_two"}));
    v1::SetHandlesEvent last;
    ASSERT_TRUE(last.ParseFromString(set.messages.back()));
    ASSERT_TRUE(last.has_response()) << "the stream ended without the response";
    EXPECT_EQ(last.response().info().groups_size(), 2);
  }
}

}  // namespace
}  // namespace meshdeform::transport
