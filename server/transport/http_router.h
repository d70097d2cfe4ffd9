#pragma once
/// @file http_router.h
/// Which handler answers a request on the HTTP listener: the gRPC-Web gateway, the static files
/// (the viewer) or the operations endpoints; and the per-route body limit that goes with it.

#include <cstddef>
#include <functional>
#include <string_view>

#include "server/transport/http_message.h"

namespace meshdeform::transport {

class GrpcWebGateway;
class StaticFileServer;

/// One listener's routing: gateway.handles() -> the gateway; GET of any path but /metrics
/// and /healthz -> `files` (when not null); everything else -> `fallback` (handle_ops_request,
/// which answers /metrics, /healthz and 404). `gateway`, `files` must outlive the listener.
/// Synchronous answers are given on the listener thread; bodies over the route limit that are not
/// the gateway's get 413.
AsyncHttpHandler make_http_router(GrpcWebGateway& gateway, const StaticFileServer* files,
                                  HttpHandler fallback);

/// The HttpServerOptions::body_limit for make_http_router: gateway.max_request_bytes() for the
/// gateway's routes, `other_limit` for the rest.
std::function<std::size_t(std::string_view, std::string_view)> make_body_limit(
    const GrpcWebGateway& gateway, std::size_t other_limit = 1 << 20);

}  // namespace meshdeform::transport
