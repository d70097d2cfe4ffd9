// The operations surface of the server: GET /metrics (Prometheus text) and /healthz on the HTTP
// listener (loopback, a raw Asio client), GetServerStats, and background refinement as seen by a
// Watch stream. A real DeformationService behind DeformServiceImpl in an in-process grpc::Server.
#include <gtest/gtest.h>
#include <sys/socket.h>

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/read.hpp>
#include <boost/asio/write.hpp>

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <regex>
#include <string>
#include <thread>

#include "meshdeform/v1/deformation.grpc.pb.h"
#include "server/service/deformation_service.h"
#include "server/transport/deform_service_impl.h"
#include "server/transport/http_server.h"
#include "server/transport/ops_endpoints.h"
#include "server/transport/server_setup.h"

namespace meshdeform::transport {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

/// One HTTP/1.1 request to 127.0.0.1:port with Connection: close; the whole response text.
/// Bounded: reads use POSIX recv with a 10 s SO_RCVTIMEO (Asio's blocking reads would ignore it).
std::string http_request(int port, const std::string& request_text) {
  namespace asio = boost::asio;
  asio::io_context io;
  asio::ip::tcp::socket socket(io);
  socket.connect({asio::ip::make_address("127.0.0.1"), static_cast<unsigned short>(port)});
  asio::write(socket, asio::buffer(request_text));
  const int fd = socket.native_handle();
  timeval timeout{10, 0};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout);
  std::string response;
  char buffer[4096];
  for (int i = 0; i < 100000; ++i) {
    const ssize_t n = ::recv(fd, buffer, sizeof buffer, 0);
    if (n <= 0) break;  // eof (Connection: close), error or timeout
    response.append(buffer, static_cast<std::size_t>(n));
  }
  return response;
}

std::string http_get(int port, const std::string& path) {
  return http_request(port, "GET " + path + " HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n");
}

int status_of(const std::string& response) {
  const std::regex line(R"(^HTTP/1\.1 ([0-9]{3}))");
  std::smatch match;
  return std::regex_search(response, match, line) ? std::stoi(match[1].str()) : -1;
}

/// The value of a sample line `name{labels} value` (labels exactly as rendered), or -1.
double metric_value(const std::string& body, const std::string& series) {
  const std::size_t at = body.find("\n" + series + " ");
  if (at == std::string::npos) return -1;
  return std::stod(body.substr(at + series.size() + 2));
}

class OpsTest : public ::testing::Test {
 protected:
  void start(service::ServiceOptions options) {
    options.workers = 2;
    service_ = std::make_unique<service::DeformationService>(options);
    impl_ = std::make_unique<DeformServiceImpl>(*service_);
    enable_health_and_reflection();
    grpc::ServerBuilder builder;
    configure_builder(builder, *impl_, 64);
    server_ = builder.BuildAndStart();
    ASSERT_NE(server_, nullptr);
    stub_ = v1::DeformationService::NewStub(server_->InProcessChannel(grpc::ChannelArguments()));
    auto http = HttpServer::start(
        "127.0.0.1:0", [this](const HttpRequest& request) {
          return handle_ops_request(request, *service_, serving_.load());
        });
    ASSERT_TRUE(http.ok()) << http.status().to_string();
    http_ = std::move(http).value();
  }
  void TearDown() override {
    if (http_) http_->stop();
    if (server_) server_->Shutdown(std::chrono::system_clock::now() + seconds(10));
  }

  v1::CreateSessionResponse create_with_handles(const std::string& sample) {
    v1::CreateSessionRequest request;
    request.set_sample(sample);
    v1::CreateSessionResponse created;
    {
      grpc::ClientContext context;
      context.set_deadline(std::chrono::system_clock::now() + seconds(60));
      EXPECT_TRUE(stub_->CreateSession(&context, request, &created).ok());
    }
    v1::SetHandlesRequest handles;
    handles.set_session_id(created.session_id());
    handles.set_token(created.edit_token());
    *handles.mutable_groups() = created.suggested_groups();
    v1::SetHandlesResponse set;
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + seconds(60));
    EXPECT_TRUE(stub_->SetHandles(&context, handles, &set).ok());
    return created;
  }

  grpc::Status move(const v1::CreateSessionResponse& created, double angle_deg, int iterations,
                    v1::MoveHandlesResponse* out) {
    v1::MoveHandlesRequest request;
    request.set_session_id(created.session_id());
    request.set_token(created.edit_token());
    request.set_max_iterations(static_cast<std::uint32_t>(iterations));
    v1::GroupMove* m = request.add_moves();
    m->set_group(1);
    m->mutable_rotation()->set_w(std::cos(angle_deg * M_PI / 360.0));
    m->mutable_rotation()->set_y(std::sin(angle_deg * M_PI / 360.0));
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + seconds(60));
    return stub_->MoveHandles(&context, request, out);
  }

  std::atomic<bool> serving_{true};
  std::unique_ptr<service::DeformationService> service_;
  std::unique_ptr<DeformServiceImpl> impl_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<v1::DeformationService::Stub> stub_;
  std::unique_ptr<HttpServer> http_;
};

TEST_F(OpsTest, MetricsCountCallsByCodeAndExposeServiceCounters) {
  start(service::ServiceOptions{});
  const v1::CreateSessionResponse created = create_with_handles("cylinder_small");
  v1::MoveHandlesResponse moved;
  ASSERT_TRUE(move(created, 30, 2, &moved).ok());
  v1::MoveHandlesResponse ignored;
  v1::CreateSessionResponse wrong = created;
  wrong.set_edit_token(created.view_token());
  EXPECT_EQ(move(wrong, 30, 2, &ignored).error_code(), grpc::StatusCode::PERMISSION_DENIED);

  const std::string response = http_get(http_->port(), "/metrics");
  ASSERT_EQ(status_of(response), 200) << response.substr(0, 200);
  EXPECT_NE(response.find("Content-Type: text/plain; version=0.0.4"), std::string::npos);
  const std::string body = response.substr(response.find("\r\n\r\n") + 4);
  EXPECT_EQ(metric_value(body, R"(meshdeform_rpc_requests_total{frontend="grpc",method="CreateSession",code="OK"})"), 1);
  EXPECT_EQ(metric_value(body, R"(meshdeform_rpc_requests_total{frontend="grpc",method="MoveHandles",code="OK"})"), 1);
  EXPECT_EQ(metric_value(body, R"(meshdeform_rpc_requests_total{frontend="grpc",method="MoveHandles",code="PERMISSION_DENIED"})"), 1);
  EXPECT_EQ(metric_value(body, R"(meshdeform_rpc_latency_seconds_count{frontend="grpc",method="MoveHandles"})"), 2);
  EXPECT_EQ(metric_value(body, R"(meshdeform_rpc_latency_seconds_bucket{frontend="grpc",method="MoveHandles",le="+Inf"})"), 2);
  EXPECT_EQ(metric_value(body, R"(meshdeform_solve_seconds_count{kind="move"})"), 1);
  EXPECT_EQ(metric_value(body, "meshdeform_move_queue_seconds_count"), 1);
  EXPECT_EQ(metric_value(body, "meshdeform_sessions"), 1);
  EXPECT_EQ(metric_value(body, "meshdeform_factorizations_total"), 1);
  EXPECT_EQ(metric_value(body, "meshdeform_moves_committed_total"), 1);
  EXPECT_EQ(metric_value(body, "meshdeform_outer_iterations_total"), moved.result().iterations());
  EXPECT_EQ(metric_value(body, "meshdeform_pcg_iterations_total"), moved.result().pcg_iterations());
  EXPECT_GT(moved.result().pcg_iterations(), 0u);
  EXPECT_GT(metric_value(body, "process_resident_memory_bytes"), 0);
  // Tokens never appear in the exposition.
  EXPECT_EQ(body.find(created.edit_token()), std::string::npos);
  // Every sample line parses as `name{...} number`.
  const std::regex sample_line(R"(^[a-z_]+(\{[^}]*\})? [-+0-9.eInfa]+$)");
  std::size_t start = 0, lines = 0;
  while (start < body.size()) {
    const std::size_t end = body.find('\n', start);
    const std::string line = body.substr(start, end - start);
    if (!line.empty() && line[0] != '#') {
      EXPECT_TRUE(std::regex_match(line, sample_line)) << line;
      ++lines;
    }
    start = end == std::string::npos ? body.size() : end + 1;
  }
  EXPECT_GT(lines, 20u);
}

TEST_F(OpsTest, HealthzAndHttpErrors) {
  start(service::ServiceOptions{});
  EXPECT_EQ(status_of(http_get(http_->port(), "/healthz")), 200);
  serving_.store(false);
  EXPECT_EQ(status_of(http_get(http_->port(), "/healthz")), 503);
  EXPECT_EQ(status_of(http_get(http_->port(), "/nothing-here")), 404);
  EXPECT_EQ(status_of(http_request(http_->port(),
                                   "POST /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 0\r\n"
                                   "Connection: close\r\n\r\n")),
            405);
  // A body over the 1 MiB limit is refused before it is read.
  EXPECT_EQ(status_of(http_request(http_->port(),
                                   "POST /metrics HTTP/1.1\r\nHost: x\r\nContent-Length: 99999999\r\n"
                                   "Connection: close\r\n\r\n")),
            413);
  EXPECT_FALSE(HttpServer::start("no-port-here", [](const HttpRequest&) { return HttpResponse{}; }).ok());
  EXPECT_FALSE(HttpServer::start("example.com:80", [](const HttpRequest&) { return HttpResponse{}; }).ok());
}

TEST_F(OpsTest, ServerStatsReportSessionsAndMemory) {
  start(service::ServiceOptions{});
  const v1::CreateSessionResponse created = create_with_handles("cylinder_small");
  v1::MoveHandlesResponse moved;
  ASSERT_TRUE(move(created, 30, 2, &moved).ok());
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + seconds(30));
  v1::GetServerStatsResponse stats;
  ASSERT_TRUE(stub_->GetServerStats(&context, v1::GetServerStatsRequest(), &stats).ok());
  EXPECT_EQ(stats.sessions(), 1u);
  EXPECT_EQ(stats.moves_committed(), 1u);
  EXPECT_EQ(stats.deformer_constructions(), 1u);
  EXPECT_EQ(stats.workers(), 2u);
  EXPECT_GT(stats.resident_bytes(), 0u);
  EXPECT_GT(stats.estimated_bytes(), 0u);
  EXPECT_GE(stats.uptime_seconds(), 0.0);
}

TEST_F(OpsTest, WatchersReceiveBackgroundRefinements) {
  service::ServiceOptions options;
  options.refine_budget = 6;
  start(options);
  const v1::CreateSessionResponse created = create_with_handles("cylinder_small");
  grpc::ClientContext watch_context;
  watch_context.set_deadline(std::chrono::system_clock::now() + seconds(60));
  v1::WatchRequest watch;
  watch.set_session_id(created.session_id());
  watch.set_token(created.view_token());
  auto reader = stub_->Watch(&watch_context, watch);
  v1::DeformUpdate update;
  ASSERT_TRUE(reader->Read(&update));
  EXPECT_TRUE(update.is_snapshot());

  v1::MoveHandlesResponse moved;
  ASSERT_TRUE(move(created, 60, 1, &moved).ok());
  EXPECT_FALSE(moved.result().refinement());
  // Read until a refinement arrives (bounded by count and by the stream deadline).
  bool saw_refinement = false;
  std::uint64_t last_revision = 0;
  for (int i = 0; i < 50 && !saw_refinement && reader->Read(&update); ++i) {
    EXPECT_GT(update.result().revision(), last_revision);
    last_revision = update.result().revision();
    if (update.result().refinement()) {
      saw_refinement = true;
      EXPECT_EQ(update.result().editor(), "refinement");
      EXPECT_GE(update.result().revision(), 2u);
    }
  }
  EXPECT_TRUE(saw_refinement);
  watch_context.TryCancel();
  while (reader->Read(&update)) {
  }
  reader->Finish();
}

}  // namespace
}  // namespace meshdeform::transport
