#pragma once
/// @file http_server.h
/// A small HTTP/1.1 listener (Boost.Beast) beside the gRPC port. It serves the operations
/// endpoints (GET /metrics, GET /healthz) with a synchronous HttpHandler, and the browser gateway
/// (grpc_web_gateway.h) with an AsyncHttpHandler that answers later, from any thread, either in
/// one piece or as a chunked stream.
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
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "core/status.h"

namespace meshdeform::service {
class DeformationService;
}

namespace meshdeform::transport {

using HttpHeaders = std::vector<std::pair<std::string, std::string>>;

struct HttpRequest {
  std::string method;  ///< "GET", "POST", ...
  std::string target;  ///< path and query, e.g. "/metrics"
  HttpHeaders headers;  ///< names as sent (compare case-insensitively: find_header)
  std::string body;
  /// True when the declared body (Content-Length) exceeded the route's limit: `body` is empty,
  /// `declared_body_bytes` holds the declared size and the connection closes after the answer.
  /// Only asynchronous handlers see such requests; synchronous ones are spared (the server
  /// answers 413 for them).
  bool is_body_over_limit = false;
  std::uint64_t declared_body_bytes = 0;
  /// The client's address without the port, in gRPC's peer() form: "ipv4:127.0.0.1" or
  /// "ipv6:[::1]" (an IPv4-mapped IPv6 address is reported as IPv4); empty if the socket could
  /// not tell (it was already reset).
  std::string peer;

  /// The value of the first header named `name` (ASCII case-insensitive), or empty.
  std::string_view find_header(std::string_view name) const;
};

struct HttpResponse {
  int status = 200;
  std::string content_type = "text/plain; charset=utf-8";
  std::string body;
  HttpHeaders headers;  ///< extra headers (CR and LF in values are dropped)
};

/// One request's answer channel, handed to an AsyncHttpHandler. Thread-safe: any thread may
/// call it, and calls return at once (the work runs on the listener's threads). Answer once:
/// either respond(), or start_stream() + write_chunk()* + end_stream(); later or mismatched
/// calls are ignored, as is everything after the connection closed. An exchange dropped without
/// an answer answers 500. It may outlive the HttpServer (then every call is ignored).
class HttpExchange {
 public:
  virtual ~HttpExchange() = default;

  /// Sends a complete response (Content-Length).
  virtual void respond(HttpResponse response) = 0;
  /// Sends the status line and headers of a chunked response (Transfer-Encoding: chunked; for
  /// an HTTP/1.0 client the body is delimited by closing the connection instead).
  virtual void start_stream(int status, std::string content_type, HttpHeaders headers) = 0;
  /// Queues `data` as one chunk, written (flushed) as soon as the ones before it are.
  /// @param[in] done  optional; runs on a listener thread with true once the chunk is written,
  ///                  or false when the connection closed first (or the write timed out).
  ///                  Empty data writes nothing and completes with true.
  virtual void write_chunk(std::string data, std::function<void(bool ok)> done) = 0;
  /// Ends the chunked response (the last chunk); the connection then serves its next request.
  virtual void end_stream() = 0;
  /// Registers `callback` (replacing an earlier one), run once on a listener thread (or the
  /// thread calling HttpServer::stop) if the client disconnects, a write times out or the server
  /// stops before the response is complete; run at once (on a listener thread) if that already
  /// happened. Never run once the response is complete.
  virtual void on_close(std::function<void()> callback) = 0;
};

using HttpHandler = std::function<HttpResponse(const HttpRequest&)>;
/// Called on a listener thread; must return quickly and answer through `exchange`, now or later.
using AsyncHttpHandler =
    std::function<void(HttpRequest request, std::shared_ptr<HttpExchange> exchange)>;

/// PEM text of a TLS server identity, shared by the gRPC port and the HTTP listener.
struct TlsConfig {
  std::string cert_chain_pem;   ///< the server certificate, then any intermediates
  std::string private_key_pem;  ///< the certificate's key (unencrypted)
  /// Non-empty: clients must present a certificate issued by one of these CAs (mutual TLS).
  std::string client_ca_pem;
};

/// Reads the PEM files of --tls-cert, --tls-key and (optionally, when not empty) --tls-client-ca
/// and checks them with OpenSSL, so that a bad file stops the server at startup with a message
/// naming it rather than failing every handshake later.
/// @return the files' text; InvalidArgument naming the file when it cannot be read, holds no
///         PEM certificate (cert, client CA) or private key (key), or when the key does not
///         belong to the certificate.
[[nodiscard]] Result<TlsConfig> load_tls_config(const std::string& cert_path,
                                                const std::string& key_path,
                                                const std::string& client_ca_path);

struct HttpServerOptions {
  int threads = 1;
  std::size_t max_request_bytes = 1 << 20;  ///< body limit when `body_limit` is empty
  /// Per-request body limit chosen from the request line (e.g. raised for the gRPC-Web routes:
  /// GrpcWebGateway::max_request_bytes()). Called on a listener thread; empty: max_request_bytes.
  /// Larger declared bodies go to asynchronous handlers flagged is_body_over_limit (413 for
  /// synchronous ones); a chunked body that grows past the limit gets 413.
  std::function<std::size_t(std::string_view method, std::string_view target)> body_limit;
  int read_timeout_seconds = 30;   ///< per request (header and body), also the keep-alive idle bound
  int write_timeout_seconds = 30;  ///< per write (a response, or one chunk); then the client is
                                   ///< dropped (a stalled reader cannot pin a stream forever)
  std::size_t max_connections = 1024;          ///< more are closed on accept
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

/// The operations endpoints: GET /metrics (service.render_metrics(), Prometheus text 0.0.4),
/// GET /healthz (200 "ok", or 503 once shutting down, `serving` false); 404 for other paths,
/// 405 for methods other than GET.
HttpResponse handle_ops_request(const HttpRequest& request,
                                const service::DeformationService& service, bool serving);

}  // namespace meshdeform::transport
