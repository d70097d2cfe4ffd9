#pragma once
/// @file grpc_web_gateway.h
/// The browser path (design notes, "Browser path"): a gRPC-Web gateway on the HTTP/1.1 listener
/// (http_server.h), mounted by the router (http_router.h) beside the viewer's static files
/// (static_files.h). The wire format itself is grpc_web_codec.h; CORS is grpc_web_cors.h.
///
/// GrpcWebGateway speaks the gRPC-Web protocol (github.com/grpc/grpc/blob/master/doc/PROTOCOL-WEB.md)
/// and forwards every call, as bytes, through an in-process channel of the grpc::Server to the
/// same registered service (grpc::GenericStub): no per-method code, so the browser sees exactly
/// what native clients see. Calls end on gRPC threads and answer through the HttpExchange.
///
/// Wire behaviour
/// - POST /meshdeform.v1.DeformationService/<Method> (methods read from the proto descriptor:
///   client-streaming methods are refused) and POST /grpc.health.v1.Health/Check. Any other
///   "/<package.Service>/<Method>" path: grpc-status 12 UNIMPLEMENTED.
/// - Content types: application/grpc-web, application/grpc-web+proto (binary) and
///   application/grpc-web-text, application/grpc-web-text+proto (base64 in both directions);
///   anything else: HTTP 415. Other HTTP methods: HTTP 405.
/// - The request body is exactly one uncompressed length-prefixed message. Framing errors (empty
///   or truncated body, a header length beyond the body, bytes after the frame, a compressed or
///   trailer flag, bad base64): grpc-status 13 INTERNAL, as gRPC itself answers framing errors,
///   with a grpc-message naming the fault. A message over max_message_bytes (or a body declared
///   over max_request_bytes()): grpc-status 8 RESOURCE_EXHAUSTED.
/// - Responses: HTTP 200, content-type application/grpc-web+proto (or -text+proto), data frames
///   (flag 0x00) then one trailer frame (flag 0x80) "grpc-status: N\r\ngrpc-message: <pct>\r\n".
///   A call that ends without a message is "trailers-only": the trailer frame is the body and
///   grpc-status / grpc-message are also HTTP headers. Unary calls are sent in one piece
///   (Content-Length); server-streaming calls (Watch) are chunked, one chunk per message, written
///   as soon as it arrives (the next message is read from gRPC only once the chunk is written, so
///   a slow browser applies back-pressure; Watch then skips revisions), the trailer frame last.
/// - grpc-timeout ("500m", "2S", "1H"; units H M S m u n, at most 8 digits) sets the forwarded
///   deadline, capped at the gateway's unary/stream timeout; a malformed value: grpc-status 3
///   INVALID_ARGUMENT. Without one, the unary/stream timeout applies.
/// - The browser closing its connection (or a write timing out) cancels the forwarded call
///   (ClientContext::TryCancel): the service stops the solve or ends the watch.
/// - x-session-id is forwarded as metadata (the balancer affinity key; see deformation.proto).
/// - CORS: see GrpcWebGatewayOptions::allowed_origins.
/// - Each call is recorded in the MetricsRegistry (when given) with front end "grpc-web", method
///   the last path segment ("unknown" for refused paths), and the gRPC code. The forwarded call is
///   also recorded by DeformServiceImpl with front end "grpc": one browser call counts in both.

#include <chrono>
#include <cstddef>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include "server/transport/http_message.h"

namespace grpc {
class Server;
}

namespace meshdeform::service {
class MetricsRegistry;
}

namespace meshdeform::transport {

struct GrpcWebGatewayOptions {
  /// Origins allowed to call from another origin (CORS), e.g. "http://localhost:5173". A request
  /// whose Origin is listed gets it echoed in Access-Control-Allow-Origin (with Vary: Origin);
  /// "*" allows any origin (answered as "*"). Default: none, the safe choice: the viewer is
  /// served by the same listener (same origin, no CORS needed), and preflights from other
  /// origins get 403.
  std::vector<std::string> allowed_origins;
  int cors_max_age_seconds = 600;  ///< Access-Control-Max-Age of preflight answers
  /// Deadline of a unary call without grpc-timeout, and the cap of one with it.
  std::chrono::milliseconds unary_timeout{std::chrono::minutes(5)};
  /// The same for server-streaming calls (a Watch ends DEADLINE_EXCEEDED after it; the viewer
  /// re-opens it). Zero: no default deadline and no cap.
  std::chrono::milliseconds stream_timeout{std::chrono::hours(1)};
  std::size_t max_streams = 64;  ///< open server-streaming calls; more: RESOURCE_EXHAUSTED
  std::size_t max_unary_calls = 256;  ///< unary calls in flight; more: RESOURCE_EXHAUSTED
};

/// Serves gRPC-Web (see the file comment) on an HttpServer started with start_async(); mount it
/// with make_http_router(). Thread-safe.
class GrpcWebGateway {
 public:
  /// @param[in] server             the running server whose services the gateway forwards to (an
  ///                               in-process channel is made with the limits below); must stay
  ///                               alive (not necessarily serving) until stop() returned.
  /// @param[in] max_message_bytes  the server's message limit (configure_builder's MiB in bytes):
  ///                               larger requests get RESOURCE_EXHAUSTED; also the channel's
  ///                               send and receive limit.
  /// @param[in] metrics            where calls are recorded (front end "grpc-web"); may be null,
  ///                               else must outlive the gateway.
  GrpcWebGateway(grpc::Server& server, std::size_t max_message_bytes,
                 GrpcWebGatewayOptions options = {}, service::MetricsRegistry* metrics = nullptr);
  /// Calls stop(), then waits (up to 10 s more) until every call object is gone, so that the
  /// in-process channel is released here, never on a gRPC callback thread.
  ~GrpcWebGateway();
  GrpcWebGateway(const GrpcWebGateway&) = delete;
  GrpcWebGateway& operator=(const GrpcWebGateway&) = delete;

  /// True for the requests this gateway answers: POST or OPTIONS to "/<package.Service>/<Method>"
  /// (a dotted service name), whether or not the method exists. Decided from the request line
  /// alone, so it can pick the body limit (HttpServerOptions::body_limit).
  bool handles(std::string_view method, std::string_view target) const;

  /// The body limit for the gateway's routes: a max_message_bytes message framed and base64
  /// encoded (grpc-web-text), plus slack. Larger declared bodies are answered RESOURCE_EXHAUSTED
  /// without being read.
  std::size_t max_request_bytes() const;

  /// Answers one request (an AsyncHttpHandler): preflight, 405, 415, trailers-only errors, or a
  /// forwarded call that answers later. After stop(): grpc-status 14 UNAVAILABLE.
  void handle(HttpRequest request, std::shared_ptr<HttpExchange> exchange);

  /// Refuses new calls, cancels the open ones (their browsers get a trailer with grpc-status 1
  /// CANCELLED while the HTTP listener runs) and waits, up to `wait`, until they have ended.
  /// Idempotent.
  /// @return true when every call ended within `wait`.
  bool stop(std::chrono::milliseconds wait = std::chrono::seconds(10));

  /// Forwarded calls in flight (unary and streaming), and the streaming ones among them.
  std::size_t open_calls() const;
  std::size_t open_streams() const;

  struct Shared;  ///< implementation detail, used by the calls in flight

 private:
  std::unique_ptr<Shared> shared_;
};

}  // namespace meshdeform::transport
