#pragma once
/// @file ops_endpoints.h
/// The operations endpoints of the HTTP listener: GET /metrics and GET /healthz.

#include <string_view>

#include "server/transport/http_message.h"

namespace meshdeform::service {
class DeformationService;
}

namespace meshdeform::transport {

/// True for the paths handle_ops_request answers ("/metrics", "/healthz").
bool is_ops_path(std::string_view path);

/// The operations endpoints: GET /metrics (service.render_metrics(), Prometheus text 0.0.4),
/// GET /healthz (200 "ok", or 503 once shutting down, `serving` false); 404 for other paths,
/// 405 for methods other than GET.
HttpResponse handle_ops_request(const HttpRequest& request,
                                const service::DeformationService& service, bool serving);

}  // namespace meshdeform::transport
