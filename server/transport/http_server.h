#pragma once
/// @file http_server.h
/// A small HTTP/1.1 listener (Boost.Beast) beside the gRPC port. It serves the operations
/// endpoints (GET /metrics, GET /healthz: ops_endpoints.h) with a synchronous HttpHandler, and the
/// browser gateway (grpc_web_gateway.h, mounted by http_router.h) with an AsyncHttpHandler that
/// answers later, from any thread, either in one piece or as a chunked stream. What handlers see
/// (request, response, HttpExchange) is http_message.h; the TLS identity is tls_config.h.
///
/// Requests are read with a size limit (per route, see HttpServerOptions::body_limit) and a
/// timeout, and answered with keep-alive. While a response is pending or streaming the connection
/// keeps reading, so that a client closing its socket is noticed at once (HttpExchange::on_close)
/// and bytes of a pipelined next request are kept (up to max_pipelined_bytes) for later.
///
/// With HttpServerOptions::tls the listener speaks HTTPS only (TLS 1.2 or later): every
/// connection starts with a handshake, bounded by the read timeout; a client that fails it (a
/// plaintext request, an untrusted or missing client certificate) is dropped without an answer.

#include <cstddef>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include "core/base/status.h"
#include "server/transport/connection_gate.h"
#include "server/transport/http_message.h"
#include "server/transport/tls_config.h"

namespace meshdeform::transport {

struct HttpServerOptions {
  int threads = 1;
  std::size_t max_request_bytes = 1 << 20;  ///< body limit when `body_limit` is empty
  /// Per-request body limit chosen from the request line (e.g. raised for the gRPC-Web routes:
  /// GrpcWebGateway::max_request_bytes()). Called on a listener thread; empty: max_request_bytes.
  /// Larger declared bodies go to asynchronous handlers flagged is_body_over_limit (413 for
  /// synchronous ones); a chunked body that grows past the limit gets 413.
  std::function<std::size_t(std::string_view method, std::string_view target)> body_limit;
  /// A request's header (and a TLS handshake) must arrive within this; also the keep-alive idle
  /// bound. Short, so that connections that say nothing (or dribble) do not hold places.
  int header_timeout_seconds = 10;
  int read_timeout_seconds = 30;   ///< per request body
  int write_timeout_seconds = 30;  ///< per write (a response, or one chunk); then the client is
                                   ///< dropped (a stalled reader cannot pin a stream forever)
  std::size_t max_connections = 1024;          ///< more are closed on accept (0: no cap)
  std::size_t max_connections_per_address = 64;  ///< from one client address (0: no cap)
  /// The gate that enforces those two caps and counts refusals (for /metrics); empty: one is
  /// made from them.
  std::shared_ptr<ConnectionGate> gate;
  std::size_t max_pipelined_bytes = 64 * 1024;  ///< buffered while a response is pending
  /// Set: serve HTTPS (TLS 1.2+) with this identity instead of plaintext HTTP.
  std::optional<TlsConfig> tls;
};

class HttpServer {
 public:
  /// Binds `address` ("127.0.0.1:9464", "[::1]:0", "0.0.0.0:9464"; port 0 picks a free one) and
  /// starts serving `handler` on its threads (the handler's response is sent at once).
  /// @return the running server; InvalidArgument for a malformed address, or for a
  ///         HttpServerOptions::tls whose certificate, key or client CAs OpenSSL rejects;
  ///         Unavailable-style Internal error naming the address when it cannot be bound.
  [[nodiscard]] static Result<std::unique_ptr<HttpServer>> start(const std::string& address,
                                                                 HttpHandler handler,
                                                                 HttpServerOptions options = {});
  /// As start(), with a handler that answers through an HttpExchange, possibly later and from
  /// another thread, possibly as a chunked stream.
  /// @return as start().
  [[nodiscard]] static Result<std::unique_ptr<HttpServer>> start_async(
      const std::string& address, AsyncHttpHandler handler, HttpServerOptions options = {});
  /// Stops accepting, joins the threads, then closes open connections, running the on_close
  /// callbacks of unfinished exchanges on the calling thread (idempotent).
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

}  // namespace meshdeform::transport
