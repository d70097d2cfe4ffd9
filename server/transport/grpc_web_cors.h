#pragma once
/// @file grpc_web_cors.h
/// The gRPC-Web gateway's cross-origin policy (CORS): which origins may call it, the headers
/// that say so on its answers, and the answer to a browser's preflight (OPTIONS).

#include <string>
#include <string_view>
#include <vector>

#include "server/transport/http_message.h"

namespace meshdeform::transport {

struct GrpcWebCors {
  /// Origins allowed to call from another origin; "*" allows any (see
  /// GrpcWebGatewayOptions::allowed_origins).
  std::vector<std::string> allowed_origins;
  int max_age_seconds = 600;  ///< Access-Control-Max-Age of preflight answers

  /// The Access-Control-Allow-Origin value for `origin`; empty when not allowed.
  std::string allowed_origin(std::string_view origin) const;

  /// CORS headers of an actual (non-preflight) response to a request from `origin`: none when
  /// the origin is not allowed.
  HttpHeaders response_headers(std::string_view origin) const;

  /// The answer to OPTIONS: 204 with Allow (and, for an allowed `origin`, the
  /// Access-Control-Allow-* headers); 403 for an origin not allowed; a plain 204 without Origin.
  HttpResponse preflight(std::string_view origin) const;
};

}  // namespace meshdeform::transport
