#include "server/transport/grpc_web_cors.h"

namespace meshdeform::transport {
namespace {

constexpr std::string_view kAllowHeaders =
    "content-type, x-grpc-web, x-user-agent, grpc-timeout, x-session-id";
constexpr std::string_view kExposeHeaders = "grpc-status, grpc-message";

}  // namespace

std::string GrpcWebCors::allowed_origin(std::string_view origin) const {
  if (origin.empty()) return {};
  for (const std::string& allowed : allowed_origins) {
    if (allowed == "*") return "*";
    if (allowed == origin) return std::string(origin);
  }
  return {};
}

HttpHeaders GrpcWebCors::response_headers(std::string_view origin) const {
  HttpHeaders headers;
  const std::string allowed = allowed_origin(origin);
  if (!allowed.empty()) {
    headers.emplace_back("Access-Control-Allow-Origin", allowed);
    if (allowed != "*") headers.emplace_back("Vary", "Origin");
    headers.emplace_back("Access-Control-Expose-Headers", std::string(kExposeHeaders));
  }
  return headers;
}

HttpResponse GrpcWebCors::preflight(std::string_view origin) const {
  HttpResponse response;
  response.status = 204;
  response.content_type.clear();
  response.headers.emplace_back("Allow", "POST, OPTIONS");
  if (origin.empty()) return response;  // not a browser's CORS preflight
  const std::string allowed = allowed_origin(origin);
  if (allowed.empty()) {
    return text_response(403, "origin not allowed: " + std::string(origin.substr(0, 200)) + "\n");
  }
  response.headers.emplace_back("Access-Control-Allow-Origin", allowed);
  if (allowed != "*") response.headers.emplace_back("Vary", "Origin");
  response.headers.emplace_back("Access-Control-Allow-Methods", "POST, OPTIONS");
  response.headers.emplace_back("Access-Control-Allow-Headers", std::string(kAllowHeaders));
  response.headers.emplace_back("Access-Control-Expose-Headers", std::string(kExposeHeaders));
  response.headers.emplace_back("Access-Control-Max-Age", std::to_string(max_age_seconds));
  return response;
}

}  // namespace meshdeform::transport
