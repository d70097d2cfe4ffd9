#include "server/transport/http_router.h"

#include <memory>
#include <utility>

#include "server/transport/grpc_web_gateway.h"
#include "server/transport/ops_endpoints.h"
#include "server/transport/static_files.h"

namespace meshdeform::transport {

AsyncHttpHandler make_http_router(GrpcWebGateway& gateway, const StaticFileServer* files,
                                  HttpHandler fallback) {
  HttpHandler synchronous = [files, fallback = std::move(fallback)](const HttpRequest& request) {
    return files != nullptr && request.method == "GET" && !is_ops_path(target_path(request.target))
               ? files->serve(request)
               : fallback(request);
  };
  return [&gateway, synchronous = std::move(synchronous)](HttpRequest request,
                                                          std::shared_ptr<HttpExchange> exchange) {
    if (gateway.handles(request.method, request.target)) {
      gateway.handle(std::move(request), std::move(exchange));
      return;
    }
    respond_synchronously(synchronous, request, *exchange);
  };
}

std::function<std::size_t(std::string_view, std::string_view)> make_body_limit(
    const GrpcWebGateway& gateway, std::size_t other_limit) {
  return [&gateway, other_limit](std::string_view method, std::string_view target) {
    return gateway.handles(method, target) ? gateway.max_request_bytes() : other_limit;
  };
}

}  // namespace meshdeform::transport
