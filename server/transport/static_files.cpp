#include "server/transport/static_files.h"

#include <algorithm>
#include <fstream>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <system_error>

#include "server/service/log.h"

namespace meshdeform::transport {
namespace {

/// %XX-decoding of a URL path; nullopt for a malformed escape.
std::optional<std::string> percent_decode(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  const auto hex = [](char c) -> int {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
  };
  for (std::size_t i = 0; i < text.size(); ++i) {
    if (text[i] != '%') {
      out += text[i];
      continue;
    }
    if (i + 2 >= text.size()) return std::nullopt;
    const int high = hex(text[i + 1]), low = hex(text[i + 2]);
    if (high < 0 || low < 0) return std::nullopt;
    out += static_cast<char>(high * 16 + low);
    i += 2;
  }
  return out;
}

std::string_view content_type_of(const std::filesystem::path& file) {
  static const std::map<std::string, std::string_view, std::less<>> kTypes = {
      {".html", "text/html; charset=utf-8"},
      {".htm", "text/html; charset=utf-8"},
      {".js", "text/javascript; charset=utf-8"},
      {".mjs", "text/javascript; charset=utf-8"},
      {".css", "text/css; charset=utf-8"},
      {".wasm", "application/wasm"},
      {".svg", "image/svg+xml"},
      {".png", "image/png"},
      {".json", "application/json"},
      {".map", "application/json"},
      {".ico", "image/x-icon"},
      {".txt", "text/plain; charset=utf-8"},
  };
  std::string extension = file.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(), lower_ascii);
  const auto found = kTypes.find(extension);
  return found == kTypes.end() ? std::string_view("application/octet-stream") : found->second;
}

/// True when `path` is `root` or below it (both canonical).
bool is_within(const std::filesystem::path& root, const std::filesystem::path& path) {
  auto r = root.begin();
  auto p = path.begin();
  for (; r != root.end(); ++r, ++p) {
    if (p == path.end() || *r != *p) return false;
  }
  return true;
}

}  // namespace

Result<StaticFileServer> StaticFileServer::open(const std::filesystem::path& root,
                                                std::size_t max_file_bytes) {
  std::error_code error;
  std::filesystem::path canonical = std::filesystem::canonical(root, error);
  if (error || !std::filesystem::is_directory(canonical, error)) {
    return Error(ErrorCode::InvalidArgument,
                 "static file root '" + root.string() + "' is not a directory");
  }
  return StaticFileServer(std::move(canonical), max_file_bytes);
}

HttpResponse StaticFileServer::serve(const HttpRequest& request) const {
  if (request.method != "GET") return text_response(405, "use GET\n", {{"Allow", "GET"}});
  const std::optional<std::string> decoded = percent_decode(target_path(request.target));
  if (!decoded || decoded->empty() || decoded->front() != '/') {
    return text_response(400, "bad path\n");
  }
  std::filesystem::path relative;
  std::size_t begin = 1;
  while (begin <= decoded->size()) {
    std::size_t end = decoded->find('/', begin);
    if (end == std::string::npos) end = decoded->size();
    const std::string_view segment = std::string_view(*decoded).substr(begin, end - begin);
    if (!segment.empty()) {
      if (segment.front() == '.' || segment.find('\0') != std::string_view::npos ||
          segment.find('\\') != std::string_view::npos) {
        return text_response(400, "bad path\n");
      }
      relative /= std::string(segment);
    }
    begin = end + 1;
  }
  const HttpResponse not_found = text_response(404, "not found\n");
  std::error_code error;
  std::filesystem::path file = root_ / relative;
  if (std::filesystem::is_directory(file, error)) file /= "index.html";
  // Resolve symlinks, then insist on staying under the root.
  const std::filesystem::path resolved = std::filesystem::canonical(file, error);
  if (error || !is_within(root_, resolved) || !std::filesystem::is_regular_file(resolved, error)) {
    return not_found;
  }
  const std::uintmax_t size = std::filesystem::file_size(resolved, error);
  if (error) return not_found;
  if (size > max_file_bytes_) {
    service::log_event(service::LogLevel::Warn, "static_file_too_large",
                       service::LogFields().add("path", resolved.string()));
    return not_found;
  }
  std::ifstream in(resolved, std::ios::binary);
  std::string body(static_cast<std::size_t>(size), '\0');
  if (!in.read(body.data(), static_cast<std::streamsize>(size))) return not_found;
  return HttpResponse{200,
                      std::string(content_type_of(file)),
                      std::move(body),
                      {{"X-Content-Type-Options", "nosniff"}, {"Cache-Control", "no-cache"}}};
}

}  // namespace meshdeform::transport
