#pragma once
/// @file mesh_io.h
/// Mesh files <-> MeshData: OBJ, OFF, PLY, STL, glTF 2.0 (.gltf) and binary glTF (.glb).
///
/// Readers are lossless and never decide what a valid mesh is: they record every vertex and every
/// face as written (polygons are fan-triangulated, vertex indices are kept raw), so that
/// `core::validate_triangle_mesh` / `core::clean_mesh` report problems instead of a reader silently
/// dropping them. In particular OpenMesh's readers are not used for reading, because they drop
/// "complex" and degenerate faces (STL, OBJ), remove repeated vertices from OBJ faces, read
/// coordinates as float, and follow OBJ `mtllib` paths on disk. OBJ, OFF and PLY coordinates keep
/// full double precision; STL is float32 by definition; glTF POSITION may be float or double.
///
/// Reading from memory never touches the filesystem: external glTF buffers/images are refused and
/// OBJ material libraries are ignored. Every reader returns InvalidArgument on malformed, truncated
/// or empty (no vertices or no faces) input; none of them throws or crashes.
///
/// Work bounded by bytes (hostile input): every loop of every reader either consumes input or is
/// bounded by a constant times the input size, so a small file cannot buy a long parse. Counts
/// declared in a header (PLY elements and lists, OFF counts, binary STL triangles, glTF accessor
/// counts) are checked against the bytes that remain before any loop runs over them or any memory
/// is reserved; rows that would consume no input (a PLY element without properties) are skipped
/// in O(1); glTF instancing (nodes sharing a mesh) may not expand the output past a fixed multiple
/// of the input; JSON nesting is limited before a JSON parser sees it. `ReadControl::work_steps`
/// counts the loop steps so that tests assert the bound instead of timing it.

#include <filesystem>
#include <string>
#include <string_view>

#include "core/io/read_control.h"
#include "core/mesh/mesh_data.h"
#include "core/base/status.h"
#include "core/mesh/validate.h"

namespace meshdeform::io {

/// Supported mesh file formats.
enum class MeshFormat { Obj, Off, Ply, Stl, Glb, Gltf };

/// Lower-case name and extension of a format ("obj", "off", "ply", "stl", "glb", "gltf").
const char* format_name(MeshFormat format);

/// Format from a file extension, case-insensitive (".OBJ" -> Obj).
/// @return the format; InvalidArgument naming the path for a missing or unknown extension.
[[nodiscard]] Result<MeshFormat> format_from_path(const std::filesystem::path& path);

/// Format from its name, case-insensitive, with or without a leading dot ("obj", ".Ply").
/// @return the format; InvalidArgument naming the value otherwise.
[[nodiscard]] Result<MeshFormat> parse_format(std::string_view name);

/// Reads a mesh file; the format comes from the extension. A .gltf file may reference external
/// buffers next to it (local files are trusted); use read_mesh_from_memory for untrusted data.
/// @param[in] path  file to read.
/// @return the raw mesh (not validated); NotFound if the file does not exist; InvalidArgument for
///         an unknown extension or malformed/empty content (the message names the file, and the
///         line, element or face where possible); Internal if the file cannot be read.
[[nodiscard]] Result<MeshData> read_mesh(const std::filesystem::path& path);

/// Reads a mesh from bytes (e.g. a request). Never accesses the filesystem.
/// @param[in] bytes   whole file contents.
/// @param[in] format  how to interpret them (STL: binary vs ASCII is detected).
/// @param[in] control  stop token and work counter (optional).
/// @return the raw mesh (not validated); InvalidArgument for malformed or empty content;
///         Cancelled when control.stop is requested.
[[nodiscard]] Result<MeshData> read_mesh_from_memory(std::string_view bytes, MeshFormat format,
                                                     const ReadControl& control = {});

/// Writes a mesh; the format comes from the extension. OBJ/OFF/PLY (ASCII) keep full double
/// precision (max_digits10 digits); STL is binary float32; GLB/glTF store float32 POSITION and
/// uint32 indices (a .gltf embeds its buffer as a data URI).
/// @param[in] path  file to (over)write.
/// @param[in] mesh  #V x 3 positions, #F x 3 indices; indices must be in range.
/// @return success; InvalidArgument for an unknown extension, an index out of range, or a
///         coordinate that is not finite / not representable in float32 (STL, glTF);
///         Internal if the file cannot be written.
[[nodiscard]] Status write_mesh(const std::filesystem::path& path, const MeshData& mesh);

/// Serialises a mesh to bytes in the given format (see write_mesh).
/// @return the file contents; InvalidArgument as for write_mesh.
[[nodiscard]] Result<std::string> write_mesh_to_memory(const MeshData& mesh, MeshFormat format);

/// How load_mesh post-processes what it read.
struct LoadOptions {
  /// Run core::clean_mesh (which validates). When false the raw mesh is returned unvalidated.
  bool clean = true;
  /// Weld exactly coincident vertices for every format. STL is always welded (a triangle soup
  /// has no shared vertices); other formats are welded only when this is true.
  bool weld = false;
  /// Stops reading and cleaning (Cancelled) and counts their work.
  ReadControl control;
};

/// A mesh read and cleaned by load_mesh.
struct LoadedMesh {
  MeshData mesh;             ///< cleaned (and validated) mesh, or the raw one if !options.clean
  MeshFormat format{};       ///< the format that was read
  core::CleanReport report;  ///< what cleaning changed; identity old_to_new if !options.clean
};

/// Reads a mesh file, then cleans and validates it (see LoadOptions).
/// @return the mesh and cleaning report; errors of read_mesh, or the InvalidArgument of
///         core::clean_mesh naming the first offending vertex/face.
[[nodiscard]] Result<LoadedMesh> load_mesh(const std::filesystem::path& path,
                                           const LoadOptions& options = {});

/// Reads a mesh from bytes, then cleans and validates it (see LoadOptions).
/// @return the mesh and cleaning report; errors of read_mesh_from_memory or core::clean_mesh;
///         Cancelled when options.control.stop is requested.
[[nodiscard]] Result<LoadedMesh> load_mesh_from_memory(std::string_view bytes, MeshFormat format,
                                                       const LoadOptions& options = {});

}  // namespace meshdeform::io
