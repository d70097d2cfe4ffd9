// HttpServer with HttpServerOptions::tls (HTTPS) and HttpRequest::peer, on loopback: the peer
// address of plain and TLS requests, keep-alive and a chunked stream over TLS (one read and one
// write outstanding at once), load_tls_config's errors, and client certificates (mTLS). The test
// certificate comes from the openssl CLI (skipped, with a message, when it is missing); clients
// are asio ssl streams verifying it; every wait is bounded.
#include <gtest/gtest.h>
#include <openssl/ssl.h>
#include <unistd.h>

#include <array>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/asio/write.hpp>
#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <thread>

#include "server/transport/http_server.h"

namespace meshdeform::transport {
namespace {

namespace asio = boost::asio;
namespace fs = std::filesystem;
using tcp = asio::ip::tcp;

/// An asio client connection (TLS or plain) whose every step runs the io_context for a bound.
class TestConnection {
 public:
  /// TLS trusting `ca` (verifying the name "localhost"), presenting `cert`/`key` when given.
  TestConnection(int port, const fs::path& ca, const fs::path& cert = {}, const fs::path& key = {})
      : context_(asio::ssl::context::tls_client) {
    context_.load_verify_file(ca.string());
    context_.set_verify_mode(asio::ssl::verify_peer);
    if (!cert.empty()) {
      context_.use_certificate_chain_file(cert.string());
      context_.use_private_key_file(key.string(), asio::ssl::context::pem);
    }
    tls_.emplace(io_, context_);
    SSL_set_tlsext_host_name(tls_->native_handle(), "localhost");
    tls_->set_verify_callback(asio::ssl::host_name_verification("localhost"));
    boost::system::error_code error;
    tls_->lowest_layer().connect(endpoint(port), error);
    if (error) return;
    tls_->async_handshake(asio::ssl::stream_base::client,
                          [this](boost::system::error_code e) { is_ready_ = !e; });
    run();
  }
  /// Plaintext, to `host` (a numeric address).
  explicit TestConnection(int port, const std::string& host = "127.0.0.1")
      : context_(asio::ssl::context::tls_client), plain_(io_) {
    boost::system::error_code error;
    plain_->connect({asio::ip::make_address(host), static_cast<unsigned short>(port)}, error);
    is_ready_ = !error;
  }

  bool is_ready() const { return is_ready_; }

  bool send(const std::string& bytes) {
    bool ok = false;
    const auto done = [&ok](boost::system::error_code e, std::size_t) { ok = !e; };
    if (tls_) {
      asio::async_write(*tls_, asio::buffer(bytes), done);
    } else {
      asio::async_write(*plain_, asio::buffer(bytes), done);
    }
    run();
    return ok;
  }

  /// Reads until `needle` was received (or the connection closed, or 10 s passed).
  /// @return whether `needle` is in received().
  bool read_until(const std::string& needle) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (received_.find(needle) == std::string::npos && !is_closed_ &&
           std::chrono::steady_clock::now() < deadline) {
      read_some();
    }
    return received_.find(needle) != std::string::npos;
  }
  /// Reads until the server closes (at most 10 s). @return whether it did.
  bool read_to_close() {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (!is_closed_ && std::chrono::steady_clock::now() < deadline) read_some();
    return is_closed_;
  }
  const std::string& received() const { return received_; }

 private:
  static tcp::endpoint endpoint(int port) {
    return {asio::ip::make_address("127.0.0.1"), static_cast<unsigned short>(port)};
  }
  void run() {
    io_.restart();
    io_.run_for(std::chrono::seconds(10));
  }
  void read_some() {
    const auto done = [this](boost::system::error_code e, std::size_t n) {
      received_.append(buffer_.data(), n);
      if (e) is_closed_ = true;  // EOF, or stream_truncated (no close_notify)
    };
    if (tls_) {
      tls_->async_read_some(asio::buffer(buffer_), done);
    } else {
      plain_->async_read_some(asio::buffer(buffer_), done);
    }
    run();
  }

  asio::io_context io_;
  asio::ssl::context context_;
  std::optional<asio::ssl::stream<tcp::socket>> tls_;
  std::optional<tcp::socket> plain_;
  std::array<char, 4096> buffer_{};
  std::string received_;
  bool is_ready_ = false;
  bool is_closed_ = false;
};

/// Answers every request with its peer address.
HttpResponse echo_peer(const HttpRequest& request) {
  return HttpResponse{200, "text/plain", "peer=" + request.peer + ";", {}};
}

constexpr const char* kGet = "GET /peer HTTP/1.1\r\nHost: localhost\r\n\r\n";
constexpr const char* kGetClose =
    "GET /peer HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n";

class HttpTlsTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    if (std::system("command -v openssl >/dev/null 2>&1") != 0) return;
    dir_ = new fs::path(fs::temp_directory_path() /
                        ("meshdeform_http_tls_test_" + std::to_string(::getpid())));
    fs::create_directories(*dir_);
    for (const std::string name : {"server", "other"}) {
      const std::string command =
          "openssl req -x509 -newkey rsa:2048 -nodes -days 2 -subj /CN=localhost"
          " -addext subjectAltName=DNS:localhost,IP:127.0.0.1 -keyout '" +
          (*dir_ / (name + "_key.pem")).string() + "' -out '" +
          (*dir_ / (name + "_cert.pem")).string() + "' >/dev/null 2>&1";
      if (std::system(command.c_str()) != 0) return;
    }
    has_certificates_ = true;
  }
  static void TearDownTestSuite() {
    if (dir_) {
      std::error_code ec;
      fs::remove_all(*dir_, ec);
    }
    delete dir_;
    dir_ = nullptr;
  }
  void SetUp() override {
    if (!has_certificates_) GTEST_SKIP() << "the openssl binary is missing or failed";
  }

  static fs::path file(const std::string& name) { return *dir_ / name; }

  static std::unique_ptr<HttpServer> start_tls(HttpHandler handler, bool require_client = false) {
    Result<TlsConfig> tls =
        load_tls_config(file("server_cert.pem").string(), file("server_key.pem").string(),
                        require_client ? file("other_cert.pem").string() : std::string());
    EXPECT_TRUE(tls.ok()) << tls.status().message();
    HttpServerOptions options;
    options.tls = std::move(tls).value();
    auto started = HttpServer::start("127.0.0.1:0", std::move(handler), options);
    EXPECT_TRUE(started.ok()) << started.status().message();
    return started.ok() ? std::move(started).value() : nullptr;
  }

  static bool has_certificates_;
  static fs::path* dir_;
};

bool HttpTlsTest::has_certificates_ = false;
fs::path* HttpTlsTest::dir_ = nullptr;

TEST(HttpPeerTest, PlainRequestsCarryThePeerAddress) {
  auto v4 = HttpServer::start("127.0.0.1:0", echo_peer);
  ASSERT_TRUE(v4.ok()) << v4.status().message();
  TestConnection connection((*v4)->port());
  ASSERT_TRUE(connection.is_ready());
  ASSERT_TRUE(connection.send(kGetClose));
  EXPECT_TRUE(connection.read_to_close());
  EXPECT_NE(connection.received().find("peer=ipv4:127.0.0.1;"), std::string::npos)
      << connection.received();

  auto v6 = HttpServer::start("[::1]:0", echo_peer);
  if (!v6.ok()) GTEST_SKIP() << "no IPv6 loopback here: " << v6.status().message();
  TestConnection over_v6((*v6)->port(), std::string("::1"));
  ASSERT_TRUE(over_v6.is_ready());
  ASSERT_TRUE(over_v6.send(kGetClose));
  EXPECT_TRUE(over_v6.read_to_close());
  EXPECT_NE(over_v6.received().find("peer=ipv6:[::1];"), std::string::npos) << over_v6.received();
}

TEST_F(HttpTlsTest, HttpsRequestsCarryThePeerAndKeepAlive) {
  auto server = start_tls(echo_peer);
  ASSERT_NE(server, nullptr);
  TestConnection connection(server->port(), file("server_cert.pem"));
  ASSERT_TRUE(connection.is_ready());
  // Sequential requests on one connection: the second is read after the first response, when
  // the monitor read was cancelled.
  ASSERT_TRUE(connection.send(kGet));
  ASSERT_TRUE(connection.read_until("peer=ipv4:127.0.0.1;")) << connection.received();
  ASSERT_TRUE(connection.send(kGetClose));
  EXPECT_TRUE(connection.read_to_close());
  std::size_t answers = 0;
  for (std::size_t at = 0;
       (at = connection.received().find("HTTP/1.1 200 OK", at)) != std::string::npos; ++at) {
    ++answers;
  }
  EXPECT_EQ(answers, 2u) << connection.received();
}

TEST_F(HttpTlsTest, PipelinedRequestsOverTls) {
  auto server = start_tls(echo_peer);
  ASSERT_NE(server, nullptr);
  TestConnection connection(server->port(), file("server_cert.pem"));
  ASSERT_TRUE(connection.is_ready());
  ASSERT_TRUE(connection.send(std::string(kGet) + kGet + kGetClose));
  EXPECT_TRUE(connection.read_to_close());
  std::size_t answers = 0;
  for (std::size_t at = 0;
       (at = connection.received().find("peer=ipv4:127.0.0.1;", at)) != std::string::npos; ++at) {
    ++answers;
  }
  EXPECT_EQ(answers, 3u) << connection.received();
}

TEST_F(HttpTlsTest, ChunkedStreamOverTls) {
  Result<TlsConfig> tls =
      load_tls_config(file("server_cert.pem").string(), file("server_key.pem").string(), "");
  ASSERT_TRUE(tls.ok()) << tls.status().message();
  HttpServerOptions options;
  options.tls = std::move(tls).value();
  std::vector<std::jthread> writers;
  auto started = HttpServer::start_async(
      "127.0.0.1:0",
      [&writers](HttpRequest, std::shared_ptr<HttpExchange> exchange) {
        exchange->start_stream(200, "text/plain", {});
        // Chunks come later from another thread, while the connection's monitor read is open.
        writers.emplace_back([exchange] {
          for (int i = 0; i < 5; ++i) {
            std::this_thread::sleep_for(std::chrono::milliseconds(20));
            exchange->write_chunk("chunk" + std::to_string(i) + ";", nullptr);
          }
          exchange->end_stream();
        });
      },
      options);
  ASSERT_TRUE(started.ok()) << started.status().message();
  {
    TestConnection connection((*started)->port(), file("server_cert.pem"));
    ASSERT_TRUE(connection.is_ready());
    ASSERT_TRUE(connection.send(kGetClose));
    EXPECT_TRUE(connection.read_to_close());
    EXPECT_NE(connection.received().find("Transfer-Encoding: chunked"), std::string::npos);
    for (int i = 0; i < 5; ++i) {
      EXPECT_NE(connection.received().find("chunk" + std::to_string(i) + ";"), std::string::npos)
          << connection.received();
    }
    EXPECT_NE(connection.received().find("\r\n0\r\n\r\n"), std::string::npos);
  }
  for (std::jthread& writer : writers) writer.join();
  (*started)->stop();
}

TEST_F(HttpTlsTest, PlaintextAndUntrustingClientsAreDroppedWithoutAnAnswer) {
  auto server = start_tls(echo_peer);
  ASSERT_NE(server, nullptr);
  TestConnection plain(server->port());
  ASSERT_TRUE(plain.is_ready());
  ASSERT_TRUE(plain.send(kGetClose));
  EXPECT_TRUE(plain.read_to_close());
  EXPECT_EQ(plain.received().find("HTTP/"), std::string::npos) << plain.received();

  TestConnection untrusting(server->port(), file("other_cert.pem"));
  EXPECT_FALSE(untrusting.is_ready());

  TestConnection good(server->port(), file("server_cert.pem"));  // still serving
  ASSERT_TRUE(good.is_ready());
  ASSERT_TRUE(good.send(kGetClose));
  EXPECT_TRUE(good.read_until("peer=ipv4:127.0.0.1;")) << good.received();
}

TEST_F(HttpTlsTest, ClientCertificatesAreRequiredWithAClientCa) {
  auto server = start_tls(echo_peer, /*require_client=*/true);
  ASSERT_NE(server, nullptr);
  {
    // Without a certificate the server fails the handshake (TLS 1.3 clients may see it only on
    // their first read).
    TestConnection anonymous(server->port(), file("server_cert.pem"));
    if (anonymous.is_ready()) {
      anonymous.send(kGetClose);
      anonymous.read_to_close();
    }
    EXPECT_EQ(anonymous.received().find("HTTP/"), std::string::npos) << anonymous.received();
  }
  TestConnection wrong(server->port(), file("server_cert.pem"), file("server_cert.pem"),
                       file("server_key.pem"));  // not issued by the client CA
  if (wrong.is_ready()) {
    wrong.send(kGetClose);
    wrong.read_to_close();
  }
  EXPECT_EQ(wrong.received().find("HTTP/"), std::string::npos) << wrong.received();

  TestConnection issued(server->port(), file("server_cert.pem"), file("other_cert.pem"),
                        file("other_key.pem"));
  ASSERT_TRUE(issued.is_ready());
  ASSERT_TRUE(issued.send(kGetClose));
  EXPECT_TRUE(issued.read_until("peer=ipv4:127.0.0.1;")) << issued.received();
}

TEST_F(HttpTlsTest, LoadTlsConfigNamesTheBadFile) {
  const std::string cert = file("server_cert.pem").string();
  const std::string key = file("server_key.pem").string();
  const std::string garbage = file("garbage.pem").string();
  std::ofstream(garbage) << "hello\n";

  Result<TlsConfig> ok = load_tls_config(cert, key, file("other_cert.pem").string());
  ASSERT_TRUE(ok.ok()) << ok.status().message();
  EXPECT_NE(ok->cert_chain_pem.find("BEGIN CERTIFICATE"), std::string::npos);
  EXPECT_NE(ok->private_key_pem.find("PRIVATE KEY"), std::string::npos);
  EXPECT_NE(ok->client_ca_pem.find("BEGIN CERTIFICATE"), std::string::npos);

  const auto expect_error = [](const Result<TlsConfig>& result, const std::string& text) {
    ASSERT_FALSE(result.ok());
    EXPECT_EQ(result.status().code(), ErrorCode::InvalidArgument);
    EXPECT_NE(result.status().message().find(text), std::string::npos) << result.status().message();
  };
  expect_error(load_tls_config(file("missing.pem").string(), key, ""),
               "cannot read TLS certificate file '" + file("missing.pem").string() + "'");
  expect_error(load_tls_config(garbage, key, ""),
               "TLS certificate file '" + garbage + "' is not a PEM certificate");
  expect_error(load_tls_config(cert, garbage, ""),
               "TLS key file '" + garbage + "' is not a PEM private key");
  expect_error(load_tls_config(cert, file("other_key.pem").string(), ""),
               "does not belong to TLS certificate file '" + cert + "'");
  expect_error(load_tls_config(cert, key, garbage),
               "TLS client CA file '" + garbage + "' is not a PEM certificate");

  HttpServerOptions options;
  options.tls = TlsConfig{"not a certificate", "not a key", ""};
  const auto refused = HttpServer::start("127.0.0.1:0", echo_peer, options);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), ErrorCode::InvalidArgument);
}

}  // namespace
}  // namespace meshdeform::transport
