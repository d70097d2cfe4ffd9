#pragma once
/// @file paths.h
/// Output-path checks shared by the CLI commands (done before any long solve).

#include <filesystem>
#include <string>

#include "core/base/status.h"

namespace meshdeform::cli {

/// The parent directory of an output file must exist.
/// @return success; NotFound naming the directory and the file otherwise.
inline Status check_output_parent(const std::filesystem::path& path) {
  const std::filesystem::path parent = path.parent_path();
  std::error_code ec;
  if (!parent.empty() && !std::filesystem::is_directory(parent, ec)) {
    return Error(ErrorCode::NotFound, "output directory '" + parent.string() + "' of '" +
                                          path.string() + "' does not exist");
  }
  return Status::success();
}

}  // namespace meshdeform::cli
