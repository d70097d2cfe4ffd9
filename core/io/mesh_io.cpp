#include "core/io/mesh_io.h"

#include <cstdint>
#include <exception>
#include <fstream>
#include <iterator>
#include <new>
#include <string>
#include <system_error>
#include <utility>

#include "core/io/formats/formats.h"

namespace meshdeform::io {
namespace {

using detail::invalid;
using detail::lower;
using detail::quoted;

template <typename F>
auto guarded(const char* what, F&& body) -> decltype(body()) {
  return guard_exceptions(what, ErrorCode::InvalidArgument, std::forward<F>(body));
}

Result<MeshData> read_any(std::string_view bytes, MeshFormat format, bool allow_files,
                          const std::string& base_dir, const ReadControl& control) {
  WorkMeter work(control);
  switch (format) {
    case MeshFormat::Obj:
      return detail::read_obj(bytes, work);
    case MeshFormat::Off:
      return detail::read_off(bytes, work);
    case MeshFormat::Ply:
      return detail::read_ply(bytes, work);
    case MeshFormat::Stl:
      return detail::read_stl(bytes, work);
    case MeshFormat::Glb:
    case MeshFormat::Gltf:
      return detail::read_gltf(bytes, allow_files, base_dir, work);
  }
  return invalid("unknown mesh format");
}

Result<std::string> read_file(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return Error(ErrorCode::NotFound, "mesh file '" + path.string() + "' not found");
  }
  if (std::filesystem::is_directory(path, ec)) {
    return invalid("mesh path '" + path.string() + "' is a directory, not a mesh file");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error(ErrorCode::Internal, "cannot open '" + path.string() + "' for reading");
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) return Error(ErrorCode::Internal, "error while reading '" + path.string() + "'");
  return bytes;
}

Status with_context(const Status& status, const std::string& context) {
  return Error(status.code(), context + ": " + status.message());
}

Result<LoadedMesh> finish_load(Result<MeshData> read, MeshFormat format,
                               const LoadOptions& options) {
  if (!read.ok()) return read.status();
  LoadedMesh loaded;
  loaded.mesh = std::move(read).value();
  loaded.format = format;
  if (!options.clean) {
    loaded.report.old_to_new = Eigen::VectorXi::LinSpaced(
        loaded.mesh.V.rows(), 0, static_cast<int>(loaded.mesh.V.rows()) - 1);
    return loaded;
  }
  MD_ASSIGN_OR_RETURN(loaded.report,
                      core::clean_mesh(loaded.mesh, options.weld || format == MeshFormat::Stl,
                                       options.control.stop));
  return loaded;
}

}  // namespace

const char* format_name(MeshFormat format) {
  switch (format) {
    case MeshFormat::Obj:
      return "obj";
    case MeshFormat::Off:
      return "off";
    case MeshFormat::Ply:
      return "ply";
    case MeshFormat::Stl:
      return "stl";
    case MeshFormat::Glb:
      return "glb";
    case MeshFormat::Gltf:
      return "gltf";
  }
  return "unknown";
}

Result<MeshFormat> parse_format(std::string_view name) {
  std::string key = lower(name);
  if (!key.empty() && key.front() == '.') key.erase(0, 1);
  for (const MeshFormat format : {MeshFormat::Obj, MeshFormat::Off, MeshFormat::Ply,
                                  MeshFormat::Stl, MeshFormat::Glb, MeshFormat::Gltf}) {
    if (key == format_name(format)) return format;
  }
  return invalid("unknown mesh format " + quoted(name) +
                 " (expected obj, off, ply, stl, glb or gltf)");
}

Result<MeshFormat> format_from_path(const std::filesystem::path& path) {
  const std::string extension = path.extension().string();
  if (extension.empty()) {
    return invalid("mesh path '" + path.string() +
                   "' has no extension (expected .obj, .off, .ply, "
                   ".stl, .glb or .gltf)");
  }
  auto format = parse_format(extension);
  if (!format.ok()) {
    return invalid("mesh path '" + path.string() + "' has unknown extension '" + extension +
                   "' (expected .obj, .off, .ply, .stl, .glb or .gltf)");
  }
  return format;
}

Result<MeshData> read_mesh_from_memory(std::string_view bytes, MeshFormat format,
                                       const ReadControl& control) {
  return guarded("reading mesh", [&]() -> Result<MeshData> {
    return read_any(bytes, format, /*allow_files=*/false, "", control);
  });
}

Result<MeshData> read_mesh(const std::filesystem::path& path) {
  return guarded("reading mesh", [&]() -> Result<MeshData> {
    MD_ASSIGN_OR_RETURN(const MeshFormat format, format_from_path(path));
    MD_ASSIGN_OR_RETURN(const std::string bytes, read_file(path));
    // A local .gltf may reference buffers next to it; the file is trusted, request bytes are not.
    auto mesh = read_any(bytes, format, /*allow_files=*/true, path.parent_path().string(), {});
    if (!mesh.ok()) return with_context(mesh.status(), path.string());
    return mesh;
  });
}

Result<std::string> write_mesh_to_memory(const MeshData& mesh, MeshFormat format) {
  return guarded("writing mesh", [&]() -> Result<std::string> {
    const bool float32 =
        format == MeshFormat::Stl || format == MeshFormat::Glb || format == MeshFormat::Gltf;
    MD_RETURN_IF_ERROR(detail::check_writable(mesh, float32));
    switch (format) {
      case MeshFormat::Obj:
        return detail::write_obj(mesh);
      case MeshFormat::Off:
        return detail::write_off(mesh);
      case MeshFormat::Ply:
        return detail::write_ply(mesh);
      case MeshFormat::Stl:
        return detail::write_stl(mesh);
      case MeshFormat::Glb:
        return detail::write_gltf(mesh, /*binary=*/true);
      case MeshFormat::Gltf:
        return detail::write_gltf(mesh, /*binary=*/false);
    }
    return invalid("unknown mesh format");
  });
}

Status write_mesh(const std::filesystem::path& path, const MeshData& mesh) {
  return guarded("writing mesh", [&]() -> Status {
    MD_ASSIGN_OR_RETURN(const MeshFormat format, format_from_path(path));
    MD_ASSIGN_OR_RETURN(const std::string bytes, write_mesh_to_memory(mesh, format));
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    if (!out) return Error(ErrorCode::Internal, "cannot open '" + path.string() + "' for writing");
    out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
    out.close();
    if (!out) return Error(ErrorCode::Internal, "error while writing '" + path.string() + "'");
    return Status::success();
  });
}

Result<LoadedMesh> load_mesh(const std::filesystem::path& path, const LoadOptions& options) {
  return guarded("loading mesh", [&]() -> Result<LoadedMesh> {
    MD_ASSIGN_OR_RETURN(const MeshFormat format, format_from_path(path));
    MD_ASSIGN_OR_RETURN(MeshData mesh, read_mesh(path));  // errors already name the file
    auto loaded = finish_load(std::move(mesh), format, options);
    if (!loaded.ok()) return with_context(loaded.status(), path.string());
    return loaded;
  });
}

Result<LoadedMesh> load_mesh_from_memory(std::string_view bytes, MeshFormat format,
                                         const LoadOptions& options) {
  return guarded("loading mesh", [&]() -> Result<LoadedMesh> {
    return finish_load(read_mesh_from_memory(bytes, format, options.control), format, options);
  });
}

}  // namespace meshdeform::io
