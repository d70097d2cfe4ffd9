#include "server/transport/http_server.h"

#include "server/service/deformation_service.h"

#include <boost/asio/dispatch.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/strand.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>

#include <charconv>
#include <chrono>
#include <mutex>
#include <optional>
#include <set>
#include <thread>

namespace meshdeform::transport {
namespace {

namespace asio = boost::asio;
namespace beast = boost::beast;
namespace http = beast::http;
using tcp = asio::ip::tcp;

/// "host:port" or "[v6]:port".
Result<tcp::endpoint> parse_endpoint(const std::string& address) {
  std::string host, port_text;
  if (!address.empty() && address.front() == '[') {
    const std::size_t close = address.find(']');
    if (close == std::string::npos || close + 1 >= address.size() || address[close + 1] != ':') {
      return Error(ErrorCode::InvalidArgument, "bad address '" + address + "' (want [v6]:port)");
    }
    host = address.substr(1, close - 1);
    port_text = address.substr(close + 2);
  } else {
    const std::size_t colon = address.rfind(':');
    if (colon == std::string::npos) {
      return Error(ErrorCode::InvalidArgument, "bad address '" + address + "' (want host:port)");
    }
    host = address.substr(0, colon);
    port_text = address.substr(colon + 1);
  }
  int port = -1;
  const auto [end, ec] = std::from_chars(port_text.data(), port_text.data() + port_text.size(), port);
  if (ec != std::errc() || end != port_text.data() + port_text.size() || port < 0 || port > 65535) {
    return Error(ErrorCode::InvalidArgument, "bad port in address '" + address + "'");
  }
  if (host == "localhost") host = "127.0.0.1";
  boost::system::error_code error;
  const asio::ip::address ip = asio::ip::make_address(host, error);
  if (error) {
    return Error(ErrorCode::InvalidArgument,
                 "bad host '" + host + "' in address '" + address + "' (want a numeric IP)");
  }
  return tcp::endpoint(ip, static_cast<unsigned short>(port));
}

class Connection;

}  // namespace

struct HttpServer::Impl {
  asio::io_context io;
  tcp::acceptor acceptor{io};
  HttpHandler handler;
  HttpServerOptions options;
  std::vector<std::thread> threads;
  std::mutex mutex;
  std::set<std::shared_ptr<Connection>> connections;
  bool stopped = false;

  void accept();
};

namespace {

class Connection : public std::enable_shared_from_this<Connection> {
 public:
  Connection(tcp::socket socket, HttpServer::Impl& server)
      : stream_(std::move(socket)), server_(server) {}

  void start() {
    asio::dispatch(stream_.get_executor(),
                   beast::bind_front_handler(&Connection::read, shared_from_this()));
  }

  void close() {
    asio::dispatch(stream_.get_executor(), [self = shared_from_this()] {
      beast::error_code ignored;
      self->stream_.socket().shutdown(tcp::socket::shutdown_both, ignored);
      self->stream_.close();
    });
  }

 private:
  void read() {
    parser_.emplace();
    parser_->body_limit(server_.options.max_request_bytes);
    parser_->header_limit(64 * 1024);
    stream_.expires_after(std::chrono::seconds(server_.options.read_timeout_seconds));
    http::async_read(stream_, buffer_, *parser_,
                     beast::bind_front_handler(&Connection::on_read, shared_from_this()));
  }

  void on_read(beast::error_code error, std::size_t) {
    if (error == http::error::body_limit) {
      HttpResponse response;
      response.status = 413;
      response.body = "request body over " + std::to_string(server_.options.max_request_bytes) +
                      " bytes\n";
      write(response, /*keep_alive=*/false, 11);
      return;
    }
    if (error) {
      finish();
      return;
    }
    const http::request<http::string_body>& request = parser_->get();
    HttpRequest in;
    in.method = std::string(request.method_string());
    in.target = std::string(request.target());
    for (const auto& field : request) {
      in.headers.emplace_back(std::string(field.name_string()), std::string(field.value()));
    }
    in.body = request.body();
    HttpResponse response;
    try {
      response = server_.handler(in);
    } catch (const std::exception&) {
      response = HttpResponse{500, "text/plain; charset=utf-8", "internal error\n", {}};
    }
    write(response, request.keep_alive(), request.version());
  }

  void write(const HttpResponse& response, bool keep_alive, unsigned version) {
    auto message = std::make_shared<http::response<http::string_body>>(
        static_cast<http::status>(response.status), version);
    message->set(http::field::server, "meshdeform");
    message->set(http::field::content_type, response.content_type);
    for (const auto& [name, value] : response.headers) message->set(name, value);
    message->keep_alive(keep_alive);
    message->body() = response.body;
    message->prepare_payload();
    http::async_write(stream_, *message,
                      [self = shared_from_this(), message](beast::error_code error, std::size_t) {
                        if (error || !message->keep_alive()) {
                          beast::error_code ignored;
                          self->stream_.socket().shutdown(tcp::socket::shutdown_send, ignored);
                          self->finish();
                          return;
                        }
                        self->read();
                      });
  }

  void finish() {
    const std::lock_guard lock(server_.mutex);
    server_.connections.erase(shared_from_this());
  }

  beast::tcp_stream stream_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  HttpServer::Impl& server_;
};

}  // namespace

void HttpServer::Impl::accept() {
  acceptor.async_accept(asio::make_strand(io), [this](beast::error_code error, tcp::socket socket) {
    if (error) {
      if (error == asio::error::operation_aborted) return;  // stopping
    } else {
      auto connection = std::make_shared<Connection>(std::move(socket), *this);
      {
        const std::lock_guard lock(mutex);
        if (stopped) return;
        connections.insert(connection);
      }
      connection->start();
    }
    accept();
  });
}

Result<std::unique_ptr<HttpServer>> HttpServer::start(const std::string& address,
                                                      HttpHandler handler,
                                                      HttpServerOptions options) {
  MD_ASSIGN_OR_RETURN(tcp::endpoint endpoint, parse_endpoint(address));
  auto impl = std::make_unique<Impl>();
  impl->handler = std::move(handler);
  impl->options = options;
  beast::error_code error;
  impl->acceptor.open(endpoint.protocol(), error);
  if (!error) impl->acceptor.set_option(asio::socket_base::reuse_address(true), error);
  if (!error) impl->acceptor.bind(endpoint, error);
  if (!error) impl->acceptor.listen(asio::socket_base::max_listen_connections, error);
  if (error) {
    return Error(ErrorCode::Internal, "cannot listen on " + address + ": " + error.message());
  }
  const int port = impl->acceptor.local_endpoint().port();
  impl->accept();
  for (int i = 0; i < std::max(1, options.threads); ++i) {
    impl->threads.emplace_back([raw = impl.get()] { raw->io.run(); });
  }
  return std::unique_ptr<HttpServer>(new HttpServer(std::move(impl), port));
}

HttpServer::HttpServer(std::unique_ptr<Impl> impl, int port) : impl_(std::move(impl)), port_(port) {}

void HttpServer::stop() {
  if (!impl_) return;
  std::set<std::shared_ptr<Connection>> connections;
  {
    const std::lock_guard lock(impl_->mutex);
    if (impl_->stopped) return;
    impl_->stopped = true;
    connections = impl_->connections;
  }
  asio::dispatch(impl_->acceptor.get_executor(), [impl = impl_.get()] {
    beast::error_code ignored;
    impl->acceptor.close(ignored);
  });
  for (const auto& connection : connections) connection->close();
  impl_->io.stop();
  for (std::thread& thread : impl_->threads) thread.join();
  impl_->threads.clear();
  const std::lock_guard lock(impl_->mutex);
  impl_->connections.clear();
}

HttpServer::~HttpServer() { stop(); }

HttpResponse handle_ops_request(const HttpRequest& request,
                                const service::DeformationService& service, bool serving) {
  const std::string path = request.target.substr(0, request.target.find('?'));
  if (path != "/metrics" && path != "/healthz") {
    return HttpResponse{404, "text/plain; charset=utf-8", "not found: " + path.substr(0, 200) + "\n", {}};
  }
  if (request.method != "GET") {
    return HttpResponse{405, "text/plain; charset=utf-8", "use GET\n", {{"Allow", "GET"}}};
  }
  if (path == "/healthz") {
    return serving ? HttpResponse{200, "text/plain; charset=utf-8", "ok\n", {}}
                   : HttpResponse{503, "text/plain; charset=utf-8", "shutting down\n", {}};
  }
  return HttpResponse{200, "text/plain; version=0.0.4; charset=utf-8", service.render_metrics(), {}};
}

}  // namespace meshdeform::transport
