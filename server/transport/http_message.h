#pragma once
/// @file http_message.h
/// What HTTP handlers see, whatever serves them (http_server.h's listener): the request, the
/// response, the answer channel of an asynchronous handler (HttpExchange), the handler types,
/// and small helpers shared by the handlers (router, gRPC-Web gateway, static files, ops).

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace meshdeform::transport {

using HttpHeaders = std::vector<std::pair<std::string, std::string>>;

struct HttpRequest {
  std::string method;   ///< "GET", "POST", ...
  std::string target;   ///< path and query, e.g. "/metrics"
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

/// Answers `request` through `exchange` with a synchronous handler, at once: 413 for a body over
/// the route's limit (the handler is not called), 500 when the handler throws.
void respond_synchronously(const HttpHandler& handler, const HttpRequest& request,
                           HttpExchange& exchange);

/// A text/plain (UTF-8) response.
HttpResponse text_response(int status, std::string body, HttpHeaders headers = {});

/// The request path without query or fragment; empty when the target is not origin-form.
std::string_view target_path(std::string_view target);

/// 'A'..'Z' to lower case, other bytes unchanged (no locale).
char lower_ascii(char c);

/// ASCII case-insensitive equality (header names and tokens).
bool iequals_ascii(std::string_view a, std::string_view b);

}  // namespace meshdeform::transport
