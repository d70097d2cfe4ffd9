#pragma once
/// @file http_server.h
/// A small HTTP/1.1 listener (Boost.Beast) beside the gRPC port: GET /metrics (Prometheus text),
/// GET /healthz. Requests are read with a size limit and a timeout, handled on the listener's
/// own thread(s) (handlers must be quick: no solves), and answered with keep-alive.

#include <cstddef>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "core/status.h"

namespace meshdeform::service {
class DeformationService;
}

namespace meshdeform::transport {

struct HttpRequest {
  std::string method;  ///< "GET", "POST", ...
  std::string target;  ///< path and query, e.g. "/metrics"
  std::vector<std::pair<std::string, std::string>> headers;
  std::string body;
};

struct HttpResponse {
  int status = 200;
  std::string content_type = "text/plain; charset=utf-8";
  std::string body;
  std::vector<std::pair<std::string, std::string>> headers;  ///< extra headers
};

using HttpHandler = std::function<HttpResponse(const HttpRequest&)>;

struct HttpServerOptions {
  int threads = 1;
  std::size_t max_request_bytes = 1 << 20;  ///< larger requests get 413
  int read_timeout_seconds = 30;            ///< per request, also the keep-alive idle bound
};

class HttpServer {
 public:
  /// Binds `address` ("127.0.0.1:9464", "[::1]:0", "0.0.0.0:9464"; port 0 picks a free one) and
  /// starts serving `handler` on its threads.
  /// @return the running server; InvalidArgument for a malformed address; Unavailable-style
  ///         Internal error naming the address when it cannot be bound.
  [[nodiscard]] static Result<std::unique_ptr<HttpServer>> start(const std::string& address,
                                                                 HttpHandler handler,
                                                                 HttpServerOptions options = {});
  /// Stops accepting, closes open connections and joins the threads (idempotent).
  void stop();
  ~HttpServer();
  HttpServer(const HttpServer&) = delete;
  HttpServer& operator=(const HttpServer&) = delete;

  int port() const { return port_; }

  struct Impl;  ///< implementation detail (Beast types stay out of this header)

 private:
  explicit HttpServer(std::unique_ptr<Impl> impl, int port);
  std::unique_ptr<Impl> impl_;
  int port_ = 0;
};

/// The operations endpoints: GET /metrics (service.render_metrics(), Prometheus text 0.0.4),
/// GET /healthz (200 "ok", or 503 once shutting down, `serving` false); 404 for other paths,
/// 405 for methods other than GET.
HttpResponse handle_ops_request(const HttpRequest& request,
                                const service::DeformationService& service, bool serving);

}  // namespace meshdeform::transport
