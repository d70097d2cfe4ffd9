#include "server/transport/http_message.h"

#include <algorithm>

#include "server/service/guard.h"

namespace meshdeform::transport {

std::string_view HttpRequest::find_header(std::string_view name) const {
  for (const auto& [key, value] : headers) {
    if (iequals_ascii(key, name)) return value;
  }
  return {};
}

void respond_synchronously(const HttpHandler& handler, const HttpRequest& request,
                           HttpExchange& exchange) {
  if (request.is_body_over_limit) {
    exchange.respond(text_response(413, "request body of " +
                                            std::to_string(request.declared_body_bytes) +
                                            " bytes over the limit\n"));
    return;
  }
  Result<HttpResponse> response =
      service::run_guarded("http", [&]() -> Result<HttpResponse> { return handler(request); });
  exchange.respond(response.ok() ? std::move(response).value()
                                 : text_response(500, "internal error\n"));
}

HttpResponse text_response(int status, std::string body, HttpHeaders headers) {
  return HttpResponse{status, "text/plain; charset=utf-8", std::move(body), std::move(headers)};
}

std::string_view target_path(std::string_view target) {
  return target.substr(0, target.find_first_of("?#"));
}

char lower_ascii(char c) { return c >= 'A' && c <= 'Z' ? static_cast<char>(c - 'A' + 'a') : c; }

bool iequals_ascii(std::string_view a, std::string_view b) {
  return a.size() == b.size() && std::equal(a.begin(), a.end(), b.begin(), [](char x, char y) {
           return lower_ascii(x) == lower_ascii(y);
         });
}

}  // namespace meshdeform::transport
