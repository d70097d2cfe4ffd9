#include "server/transport/ops_endpoints.h"

#include <string>

#include "server/service/deformation_service.h"

namespace meshdeform::transport {

bool is_ops_path(std::string_view path) { return path == "/metrics" || path == "/healthz"; }

HttpResponse handle_ops_request(const HttpRequest& request,
                                const service::DeformationService& service, bool serving) {
  const std::string path = request.target.substr(0, request.target.find('?'));
  if (!is_ops_path(path)) {
    return text_response(404, "not found: " + path.substr(0, 200) + "\n");
  }
  if (request.method != "GET") return text_response(405, "use GET\n", {{"Allow", "GET"}});
  if (path == "/healthz") {
    return serving ? text_response(200, "ok\n") : text_response(503, "shutting down\n");
  }
  return HttpResponse{
      200, "text/plain; version=0.0.4; charset=utf-8", service.render_metrics(), {}};
}

}  // namespace meshdeform::transport
