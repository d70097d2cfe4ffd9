// TLS on both listeners of the real meshdeform-server (--tls-cert / --tls-key), with a
// self-signed certificate made by the openssl CLI at test time: the C++ client over TLS edits a
// session; plaintext and untrusting clients are refused while the server keeps serving; HTTPS
// GET /healthz and a gRPC-Web call work with a verifying asio client, plaintext HTTP gets no
// answer; bad TLS flags stop the server with exit code 2 and a message naming the problem. Every
// wait is bounded; skipped (with a message) when the openssl binary is missing.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <openssl/ssl.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/asio/write.hpp>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "client_cpp/client.h"
#include "tests/support/child_process.h"
#include "tests/support/server_process.h"

extern char** environ;

namespace meshdeform::client {
namespace {

namespace asio = boost::asio;
namespace fs = std::filesystem;
using tcp = asio::ip::tcp;

std::string slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

/// A self-signed certificate for localhost and 127.0.0.1 in `dir`/`name`_{cert,key}.pem.
/// @return whether openssl made both files.
bool make_certificate(const fs::path& dir, const std::string& name, const std::string& cn) {
  const fs::path key = dir / (name + "_key.pem");
  const fs::path cert = dir / (name + "_cert.pem");
  const std::string command = "openssl req -x509 -newkey rsa:2048 -nodes -days 2 -subj /CN=" + cn +
                              " -addext subjectAltName=DNS:localhost,IP:127.0.0.1 -keyout '" +
                              key.string() + "' -out '" + cert.string() + "' >/dev/null 2>&1";
  return std::system(command.c_str()) == 0 && fs::file_size(cert) > 0 && fs::file_size(key) > 0;
}

/// What one raw exchange on the HTTP listener saw.
struct RawExchange {
  bool connected = false;
  bool handshake_ok = false;
  std::string handshake_error;
  std::string response;  ///< every byte read until the server closed
  bool closed = false;   ///< the server ended the connection within the time bound
};

/// Sends `request` over TLS (verifying the server against `ca` and the name "localhost") and
/// reads until the server closes; at most 15 s.
RawExchange https_exchange(int port, const fs::path& ca, const std::string& request) {
  RawExchange out;
  asio::io_context io;
  asio::ssl::context context(asio::ssl::context::tls_client);
  context.load_verify_file(ca.string());
  context.set_verify_mode(asio::ssl::verify_peer);
  asio::ssl::stream<tcp::socket> stream(io, context);
  SSL_set_tlsext_host_name(stream.native_handle(), "localhost");
  stream.set_verify_callback(asio::ssl::host_name_verification("localhost"));
  std::array<char, 4096> buffer{};
  std::function<void()> read_more = [&] {
    stream.async_read_some(
        asio::buffer(buffer), [&](boost::system::error_code error, std::size_t n) {
          out.response.append(buffer.data(), n);
          if (error) {
            out.closed = true;  // EOF, or stream_truncated: the server closes without close_notify
            return;
          }
          read_more();
        });
  };
  stream.lowest_layer().async_connect(
      {asio::ip::make_address("127.0.0.1"), static_cast<unsigned short>(port)},
      [&](boost::system::error_code error) {
        if (error) return;
        out.connected = true;
        stream.async_handshake(asio::ssl::stream_base::client, [&](boost::system::error_code e) {
          if (e) {
            out.handshake_error = e.message();
            return;
          }
          out.handshake_ok = true;
          asio::async_write(stream, asio::buffer(request),
                            [&](boost::system::error_code w, std::size_t) {
                              if (!w) read_more();
                            });
        });
      });
  io.run_for(std::chrono::seconds(15));
  return out;
}

/// Sends `request` in plaintext and reads until the server closes; at most 15 s.
RawExchange plain_exchange(int port, const std::string& request) {
  RawExchange out;
  asio::io_context io;
  tcp::socket socket(io);
  std::array<char, 4096> buffer{};
  std::function<void()> read_more = [&] {
    socket.async_read_some(asio::buffer(buffer),
                           [&](boost::system::error_code error, std::size_t n) {
                             out.response.append(buffer.data(), n);
                             if (error) {
                               out.closed = true;
                               return;
                             }
                             read_more();
                           });
  };
  socket.async_connect({asio::ip::make_address("127.0.0.1"), static_cast<unsigned short>(port)},
                       [&](boost::system::error_code error) {
                         if (error) return;
                         out.connected = true;
                         asio::async_write(socket, asio::buffer(request),
                                           [&](boost::system::error_code w, std::size_t) {
                                             if (!w) read_more();
                                           });
                       });
  io.run_for(std::chrono::seconds(15));
  return out;
}

/// meshdeform-server run with `args` (no --listen added), expected to exit on its own.
struct ExitRun {
  int exit_code = -1;  ///< -1: still running after 20 s (then killed)
  std::string err;
};

ExitRun run_server_to_exit(const std::vector<std::string>& extra, const fs::path& dir) {
  std::vector<std::string> args = {MESHDEFORM_SERVER_PATH, "--listen", "127.0.0.1:0"};
  args.insert(args.end(), extra.begin(), extra.end());
  const fs::path err_path = dir / "server_stderr.txt";
  test::ChildStreams streams;
  streams.stderr_path = err_path.string();
  ExitRun run;
  std::string error;
  std::optional<test::ChildProcess> child = test::ChildProcess::spawn(args, streams, error);
  if (!child) return run;
  const std::optional<int> status = child->wait(std::chrono::seconds(60));  // else killed
  if (status) {
    run.exit_code = WIFEXITED(*status) ? WEXITSTATUS(*status) : 128 + WTERMSIG(*status);
  }
  run.err = slurp(err_path);
  return run;
}

class TlsTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (std::system("command -v openssl >/dev/null 2>&1") != 0) {
      skip_reason_ = new std::string("the openssl binary is missing (apt-get install openssl)");
      return;
    }
    dir_ = new fs::path(fs::temp_directory_path() /
                        ("meshdeform_tls_test_" + std::to_string(::getpid())));
    fs::create_directories(*dir_);
    if (!make_certificate(*dir_, "server", "localhost") ||
        !make_certificate(*dir_, "other", "other")) {
      start_error_ = new std::string("openssl could not make the test certificates");
      return;
    }
    std::string error;
    server_ = test::ServerProcess::start(
                  MESHDEFORM_SERVER_PATH,
                  {"--refine-budget", "0", "--http-listen", "127.0.0.1:0", "--tls-cert",
                   cert().string(), "--tls-key", (*dir_ / "server_key.pem").string()},
                  error)
                  .release();
    if (!server_) start_error_ = new std::string(error);
  }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
    if (dir_) {
      std::error_code ec;
      fs::remove_all(*dir_, ec);
    }
    delete dir_;
    dir_ = nullptr;
    delete start_error_;
    start_error_ = nullptr;
    delete skip_reason_;
    skip_reason_ = nullptr;
  }

  void SetUp() override {
    if (skip_reason_) GTEST_SKIP() << *skip_reason_;
    ASSERT_NE(server_, nullptr) << (start_error_ ? *start_error_ : std::string());
  }

  static fs::path cert() { return *dir_ / "server_cert.pem"; }
  static fs::path other_cert() { return *dir_ / "other_cert.pem"; }

  static Client connect(std::optional<TlsOptions> tls, std::string target = "") {
    ClientOptions options;
    options.target = target.empty() ? server_->address() : target;
    options.default_timeout = std::chrono::seconds(10);
    options.tls = std::move(tls);
    Result<Client> client = Client::connect(options);
    EXPECT_TRUE(client.ok()) << client.status().message();
    return std::move(client).value();
  }
  static TlsOptions trusting(const fs::path& ca) {
    TlsOptions tls;
    tls.root_certs_file = ca;
    return tls;
  }

  /// The server still answers a TLS client (after a refused one).
  static void expect_still_serving() {
    const Result<ServerStats> stats = connect(trusting(cert())).server_stats();
    EXPECT_TRUE(stats.ok()) << stats.status().message();
    const RawExchange health = https_exchange(server_->http_port(), cert(),
                                              "GET /healthz HTTP/1.1\r\nHost: localhost\r\n"
                                              "Connection: close\r\n\r\n");
    EXPECT_EQ(health.response.rfind("HTTP/1.1 200 OK\r\n", 0), 0u) << health.response;
  }

  static test::ServerProcess* server_;
  static fs::path* dir_;
  static std::string* start_error_;
  static std::string* skip_reason_;
};

test::ServerProcess* TlsTest::server_ = nullptr;
fs::path* TlsTest::dir_ = nullptr;
std::string* TlsTest::start_error_ = nullptr;
std::string* TlsTest::skip_reason_ = nullptr;

TEST_F(TlsTest, ListeningLinesSayTls) {
  ASSERT_GT(server_->http_port(), 0) << server_->log();  // waits for the second line
  const std::string log = server_->log();
  const std::size_t grpc_line = log.find(R"("event":"listening")");
  const std::size_t http_line = log.find(R"("event":"http_listening")");
  ASSERT_NE(grpc_line, std::string::npos) << log;
  ASSERT_NE(http_line, std::string::npos) << log;
  for (const std::size_t line : {grpc_line, http_line}) {
    const std::string text = log.substr(line, log.find('\n', line) - line);
    EXPECT_NE(text.find(R"("tls":true)"), std::string::npos) << text;
  }
}

TEST_F(TlsTest, TlsClientCreatesSetsHandlesAndMoves) {
  const Client client = connect(trusting(cert()));
  Result<Session> session = client.create_session_from_sample("cylinder_small");
  ASSERT_TRUE(session.ok()) << session.status().message();
  ASSERT_EQ(session->suggested_groups.size(), 2u);
  Result<SessionInfo> info = client.set_handles(session->edit(), session->suggested_groups);
  ASSERT_TRUE(info.ok()) << info.status().message();
  MoveSpec spec;
  GroupMove move;
  move.group = 1;
  move.translation = Eigen::Vector3d(0.1, 0, 0);
  spec.moves.push_back(move);
  const Result<DeformResult> moved = client.move(session->edit(), spec);
  ASSERT_TRUE(moved.ok()) << moved.status().message();
  EXPECT_EQ(moved->revision, 1u);
  EXPECT_FALSE(moved->changed_indices.empty());
}

TEST_F(TlsTest, ServerNameOverrideAndPemText) {
  // The certificate names localhost; dialling by that name needs no override, and an override
  // makes the name checked independent of the target.
  TlsOptions tls;
  tls.root_certs_pem = slurp(cert());
  tls.server_name = "localhost";
  const Result<ServerStats> stats = connect(tls).server_stats();
  EXPECT_TRUE(stats.ok()) << stats.status().message();
  // A name the certificate does not carry fails verification.
  tls.server_name = "not-the-server.test";
  const Result<ServerStats> wrong = connect(tls).server_stats();
  ASSERT_FALSE(wrong.ok());
  EXPECT_NE(wrong.status().message().find("UNAVAILABLE"), std::string::npos)
      << wrong.status().message();
}

TEST_F(TlsTest, PlaintextClientIsRefusedAndTheServerKeepsServing) {
  const Result<ServerStats> stats = connect(std::nullopt).server_stats();
  ASSERT_FALSE(stats.ok());
  EXPECT_NE(stats.status().message().find("UNAVAILABLE"), std::string::npos)
      << stats.status().message();
  expect_still_serving();
}

TEST_F(TlsTest, ClientNotTrustingTheCertificateIsRefused) {
  const Result<ServerStats> stats = connect(trusting(other_cert())).server_stats();
  ASSERT_FALSE(stats.ok());
  EXPECT_NE(stats.status().message().find("UNAVAILABLE"), std::string::npos)
      << stats.status().message();
  expect_still_serving();
}

TEST_F(TlsTest, UnreadableRootFileIsAnInvalidArgumentAtConnect) {
  ClientOptions options;
  options.target = server_->address();
  options.tls = trusting(*dir_ / "no_such_ca.pem");
  const Result<Client> client = Client::connect(options);
  ASSERT_FALSE(client.ok());
  EXPECT_EQ(client.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(client.status().message().find("no_such_ca.pem"), std::string::npos)
      << client.status().message();
}

TEST_F(TlsTest, HttpsHealthzAndGrpcWebCallSucceed) {
  const int port = server_->http_port();
  ASSERT_GT(port, 0);
  const RawExchange health = https_exchange(
      port, cert(), "GET /healthz HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n");
  ASSERT_TRUE(health.handshake_ok) << health.handshake_error;
  EXPECT_TRUE(health.closed);
  EXPECT_EQ(health.response.rfind("HTTP/1.1 200 OK\r\n", 0), 0u) << health.response;
  EXPECT_TRUE(health.response.ends_with("\r\n\r\nok\n")) << health.response;

  // GetServerStats over gRPC-Web: one 5-byte frame header (flag 0, length 0) for the empty
  // request message.
  const std::string body(5, '\0');
  const RawExchange call = https_exchange(
      port, cert(),
      "POST /meshdeform.v1.DeformationService/GetServerStats HTTP/1.1\r\nHost: localhost\r\n"
      "Content-Type: application/grpc-web+proto\r\nX-Grpc-Web: 1\r\nContent-Length: 5\r\n"
      "Connection: close\r\n\r\n" +
          body);
  ASSERT_TRUE(call.handshake_ok) << call.handshake_error;
  ASSERT_EQ(call.response.rfind("HTTP/1.1 200 OK\r\n", 0), 0u) << call.response;
  EXPECT_NE(call.response.find("Content-Type: application/grpc-web+proto"), std::string::npos)
      << call.response;
  const std::size_t end_of_head = call.response.find("\r\n\r\n");
  ASSERT_NE(end_of_head, std::string::npos);
  const std::string frames = call.response.substr(end_of_head + 4);
  ASSERT_GE(frames.size(), 5u);
  EXPECT_EQ(frames[0], '\0');  // a message frame, then the trailer frame with the status
  EXPECT_NE(frames.find("grpc-status: 0"), std::string::npos) << frames;
}

TEST_F(TlsTest, HttpsClientNotTrustingTheCertificateFailsTheHandshake) {
  const RawExchange health = https_exchange(server_->http_port(), other_cert(),
                                            "GET /healthz HTTP/1.1\r\nHost: localhost\r\n\r\n");
  EXPECT_TRUE(health.connected);
  EXPECT_FALSE(health.handshake_ok);
  EXPECT_TRUE(health.response.empty());
  expect_still_serving();
}

TEST_F(TlsTest, PlaintextHttpGetsNoHttpResponse) {
  const RawExchange plain =
      plain_exchange(server_->http_port(),
                     "GET /healthz HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n");
  ASSERT_TRUE(plain.connected);
  EXPECT_TRUE(plain.closed) << "the server kept a plaintext connection open";
  EXPECT_EQ(plain.response.find("HTTP/"), std::string::npos) << plain.response;
  expect_still_serving();
}

TEST_F(TlsTest, ClientCaRequiresClientCertificatesOnBothPorts) {
  // The "other" self-signed certificate is the client CA and, with its key, the one client
  // identity it issued.
  std::string error;
  const std::unique_ptr<test::ServerProcess> mtls = test::ServerProcess::start(
      MESHDEFORM_SERVER_PATH,
      {"--refine-budget", "0", "--http-listen", "127.0.0.1:0", "--tls-cert", cert().string(),
       "--tls-key", (*dir_ / "server_key.pem").string(), "--tls-client-ca", other_cert().string()},
      error);
  ASSERT_NE(mtls, nullptr) << error;

  const Result<ServerStats> anonymous = connect(trusting(cert()), mtls->address()).server_stats();
  ASSERT_FALSE(anonymous.ok());
  EXPECT_NE(anonymous.status().message().find("UNAVAILABLE"), std::string::npos)
      << anonymous.status().message();

  TlsOptions identified = trusting(cert());
  identified.client_cert_chain_pem = slurp(other_cert());
  identified.client_private_key_pem = slurp(*dir_ / "other_key.pem");
  const Result<ServerStats> stats = connect(identified, mtls->address()).server_stats();
  EXPECT_TRUE(stats.ok()) << stats.status().message();

  TlsOptions half = trusting(cert());
  half.client_cert_chain_pem = identified.client_cert_chain_pem;
  ClientOptions options;
  options.target = mtls->address();
  options.tls = half;
  const Result<Client> refused = Client::connect(options);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), ErrorCode::InvalidArgument);

  // HTTPS without a client certificate gets no answer.
  const RawExchange health = https_exchange(mtls->http_port(), cert(),
                                            "GET /healthz HTTP/1.1\r\nHost: localhost\r\n"
                                            "Connection: close\r\n\r\n");
  EXPECT_EQ(health.response.find("HTTP/"), std::string::npos) << health.response;
}

TEST_F(TlsTest, BadTlsFlagsExitWithCode2NamingTheProblem) {
  const std::string cert_path = cert().string();
  const std::string key_path = (*dir_ / "server_key.pem").string();
  const std::string garbage = (*dir_ / "garbage.pem").string();
  std::ofstream(garbage) << "-----BEGIN CERTIFICATE-----\nnot base64 at all\n"
                            "-----END CERTIFICATE-----\n";
  const std::string missing = (*dir_ / "missing.pem").string();

  ExitRun run = run_server_to_exit({"--tls-cert", cert_path}, *dir_);
  EXPECT_EQ(run.exit_code, 2) << run.err;
  EXPECT_NE(run.err.find("--tls-cert and --tls-key go together"), std::string::npos) << run.err;

  run = run_server_to_exit({"--tls-key", key_path}, *dir_);
  EXPECT_EQ(run.exit_code, 2) << run.err;
  EXPECT_NE(run.err.find("--tls-cert and --tls-key go together"), std::string::npos) << run.err;

  run = run_server_to_exit({"--tls-cert", cert_path, "--tls-key", missing}, *dir_);
  EXPECT_EQ(run.exit_code, 2) << run.err;
  EXPECT_NE(run.err.find("cannot read TLS key file '" + missing + "'"), std::string::npos)
      << run.err;

  run = run_server_to_exit({"--tls-cert", garbage, "--tls-key", key_path}, *dir_);
  EXPECT_EQ(run.exit_code, 2) << run.err;
  EXPECT_NE(run.err.find("TLS certificate file '" + garbage + "' is not a PEM certificate"),
            std::string::npos)
      << run.err;

  run = run_server_to_exit({"--tls-cert", cert_path, "--tls-key", garbage}, *dir_);
  EXPECT_EQ(run.exit_code, 2) << run.err;
  EXPECT_NE(run.err.find("TLS key file '" + garbage + "' is not a PEM private key"),
            std::string::npos)
      << run.err;

  run = run_server_to_exit({"--tls-client-ca", cert_path}, *dir_);
  EXPECT_EQ(run.exit_code, 2) << run.err;
  EXPECT_NE(run.err.find("--tls-client-ca needs --tls-cert and --tls-key"), std::string::npos)
      << run.err;

  run = run_server_to_exit(
      {"--tls-cert", cert_path, "--tls-key", key_path, "--tls-client-ca", garbage}, *dir_);
  EXPECT_EQ(run.exit_code, 2) << run.err;
  EXPECT_NE(run.err.find("TLS client CA file '" + garbage + "' is not a PEM certificate"),
            std::string::npos)
      << run.err;

  // A real key of another certificate.
  run = run_server_to_exit(
      {"--tls-cert", cert_path, "--tls-key", (*dir_ / "other_key.pem").string()}, *dir_);
  EXPECT_EQ(run.exit_code, 2) << run.err;
  EXPECT_NE(run.err.find("does not belong to TLS certificate file '" + cert_path + "'"),
            std::string::npos)
      << run.err;
}

}  // namespace
}  // namespace meshdeform::client
