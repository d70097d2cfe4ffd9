#pragma once
/// @file formats.h
/// The per-format readers and writers behind core/io/mesh_io.h (one .cpp per format, like
/// pmp-library's io/), and what they share: text scanning, the raw-mesh builder, float32/LE
/// helpers and the writers' checks. Internal to meshdeform::io: include mesh_io.h instead.
/// Every reader follows "work bounded by bytes" (mesh_io.h) and counts its steps in `work`.

#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

#include "core/io/read_control.h"
#include "core/mesh/mesh_data.h"
#include "core/base/status.h"

namespace meshdeform::io::detail {

// --- readers (obj.cpp, off.cpp, ply.cpp, stl.cpp, gltf.cpp) ------------------------------------
Result<MeshData> read_obj(std::string_view bytes, WorkMeter& work);
Result<MeshData> read_off(std::string_view bytes, WorkMeter& work);
Result<MeshData> read_ply(std::string_view bytes, WorkMeter& work);
Result<MeshData> read_stl(std::string_view bytes, WorkMeter& work);
/// `allow_files`: a local .gltf may load buffers next to it (base_dir); request bytes may not.
Result<MeshData> read_gltf(std::string_view bytes, bool allow_files, const std::string& base_dir,
                           WorkMeter& work);

// --- writers (same files); the mesh passed check_writable ---------------------------------------
std::string write_obj(const MeshData& mesh);
std::string write_off(const MeshData& mesh);
std::string write_ply(const MeshData& mesh);
std::string write_stl(const MeshData& mesh);
Result<std::string> write_gltf(const MeshData& mesh, bool binary);

// --- shared (support.cpp) -----------------------------------------------------------------------
Status invalid(std::string message);
std::string lower(std::string_view s);
bool is_space(char c);
/// Control bytes never occur in the text formats; they mean binary data or the wrong format.
bool has_binary_bytes(std::string_view s);
std::vector<std::string_view> split_ws(std::string_view s);
bool parse_double(std::string_view s, double& out);
bool parse_int64(std::string_view s, std::int64_t& out);
/// A token for an error message: at most 40 printable characters, quoted.
std::string quoted(std::string_view token);
std::uint32_t load_u32_le(const char* p);
float load_f32_le(const char* p);
void append_u32_le(std::string& out, std::uint32_t v);
void append_f32_le(std::string& out, float v);
/// Shortest decimal text that reads back to exactly the same double.
void append_double(std::string& out, double v);
void append_xyz(std::string& out, const MeshData& mesh, Eigen::Index i);
/// The body shared by ASCII OFF and PLY: one " x y z" line per vertex, then "3 a b c" per face.
void append_vertex_and_face_lines(std::string& out, const MeshData& mesh);
/// InvalidArgument for a non-finite coordinate, one outside float32 (needs_float32) or an index
/// out of range.
Status check_writable(const MeshData& mesh, bool needs_float32);

constexpr std::size_t kStlHeader = 84;
constexpr std::size_t kStlTriangle = 50;

// Splits on '\n' and yields 1-based line numbers; '\r' is treated as whitespace by callers.
class LineReader {
 public:
  explicit LineReader(std::string_view data) : data_(data) {}
  bool next(std::string_view& line) {
    if (pos_ >= data_.size()) return false;
    const std::size_t end = data_.find('\n', pos_);
    const std::size_t stop = end == std::string_view::npos ? data_.size() : end;
    line = data_.substr(pos_, stop - pos_);
    pos_ = stop + 1;
    ++line_number_;
    return true;
  }
  int line_number() const { return line_number_; }
  std::size_t position() const { return pos_; }

 private:
  std::string_view data_;
  std::size_t pos_ = 0;
  int line_number_ = 0;
};

// Collects raw vertices and fan-triangulated polygons; indices are kept as written so that
// validation, not the reader, reports out-of-range ones.
class MeshBuilder {
 public:
  void reserve(std::size_t vertices, std::size_t faces) {
    xyz_.reserve(3 * vertices);
    tri_.reserve(3 * faces);
  }
  void add_vertex(double x, double y, double z) {
    xyz_.push_back(x);
    xyz_.push_back(y);
    xyz_.push_back(z);
  }
  std::size_t vertex_count() const { return xyz_.size() / 3; }
  /// `where` names the polygon ("line 12", "face 3") for error messages.
  Status add_polygon(const std::vector<std::int64_t>& indices, const std::string& where) {
    if (indices.size() < 3) {
      return invalid(where + ": a face needs at least 3 vertices, got " +
                     std::to_string(indices.size()));
    }
    for (const std::int64_t i : indices) {
      if (i < std::numeric_limits<int>::min() || i > std::numeric_limits<int>::max()) {
        return invalid(where + ": vertex index " + std::to_string(i) + " does not fit in int");
      }
    }
    if (tri_.size() / 3 + indices.size() - 2 >
        static_cast<std::size_t>(std::numeric_limits<int>::max())) {
      return invalid(where + ": too many faces");
    }
    for (std::size_t k = 1; k + 1 < indices.size(); ++k) {
      tri_.push_back(static_cast<int>(indices[0]));
      tri_.push_back(static_cast<int>(indices[k]));
      tri_.push_back(static_cast<int>(indices[k + 1]));
    }
    return Status::success();
  }
  void add_triangle(int a, int b, int c) {
    tri_.push_back(a);
    tri_.push_back(b);
    tri_.push_back(c);
  }
  /// The mesh; InvalidArgument if it has no vertices or no faces.
  Result<MeshData> finish(std::string_view format) {
    if (xyz_.empty()) return invalid(std::string(format) + " data contains no vertices");
    if (tri_.empty()) return invalid(std::string(format) + " data contains no faces");
    if (xyz_.size() / 3 > static_cast<std::size_t>(std::numeric_limits<int>::max())) {
      return invalid(std::string(format) + " data has too many vertices");
    }
    MeshData mesh;
    mesh.V.resize(static_cast<Eigen::Index>(xyz_.size() / 3), 3);
    for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
      for (int c = 0; c < 3; ++c) mesh.V(i, c) = xyz_[static_cast<std::size_t>(3 * i + c)];
    }
    mesh.F.resize(static_cast<Eigen::Index>(tri_.size() / 3), 3);
    for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
      for (int c = 0; c < 3; ++c) mesh.F(f, c) = tri_[static_cast<std::size_t>(3 * f + c)];
    }
    return mesh;
  }

 private:
  std::vector<double> xyz_;
  std::vector<int> tri_;
};

}  // namespace meshdeform::io::detail
