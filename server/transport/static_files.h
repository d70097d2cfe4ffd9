#pragma once
/// @file static_files.h
/// The static file server of the HTTP listener: the built browser viewer's files.

#include <cstddef>
#include <filesystem>

#include "core/base/status.h"
#include "server/transport/http_message.h"

namespace meshdeform::transport {

/// Serves the files under a directory (the built viewer) for GET: "/" and directories
/// serve their index.html; content types for .html .js .mjs .css .wasm .svg .png .json .map
/// .ico .txt (others application/octet-stream), with X-Content-Type-Options: nosniff and
/// Cache-Control: no-cache. Paths are percent-decoded, then refused (400) if they contain a NUL,
/// a backslash, or a "." / ".." / hidden (".name") segment; a path whose resolved file (symlinks
/// followed) is outside the root is 404, as are missing and non-regular files. Files over
/// max_file_bytes: 404 (logged). Thread-safe (stateless besides the root).
class StaticFileServer {
 public:
  /// @param[in] root  an existing directory; resolved (symlinks followed) once, here.
  /// @return the server; InvalidArgument when `root` is not a directory.
  [[nodiscard]] static Result<StaticFileServer> open(const std::filesystem::path& root,
                                                     std::size_t max_file_bytes = 64 << 20);

  /// The response to one request (405 for methods other than GET).
  HttpResponse serve(const HttpRequest& request) const;

 private:
  StaticFileServer(std::filesystem::path root, std::size_t max_file_bytes)
      : root_(std::move(root)), max_file_bytes_(max_file_bytes) {}
  std::filesystem::path root_;
  std::size_t max_file_bytes_;
};

}  // namespace meshdeform::transport
