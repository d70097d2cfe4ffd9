#include "core/io/mesh_io.h"

#include "core/io/json_depth.h"

#include <tiny_gltf.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <exception>
#include <fstream>
#include <iterator>
#include <limits>
#include <new>
#include <sstream>
#include <system_error>
#include <utility>
#include <vector>

namespace meshdeform::io {
namespace {

static_assert(std::endian::native == std::endian::little ||
              std::endian::native == std::endian::big);

Status invalid(std::string message) {
  return Error(ErrorCode::InvalidArgument, std::move(message));
}

std::string lower(std::string_view s) {
  std::string out(s);
  std::transform(out.begin(), out.end(), out.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  return out;
}

// ---------------------------------------------------------------------------------------------
// Text helpers

bool is_space(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\n' || c == '\f' || c == '\v';
}

// Control bytes never occur in the text formats; they mean binary data or the wrong format.
bool has_binary_bytes(std::string_view s) {
  return std::any_of(s.begin(), s.end(), [](char ch) {
    const auto c = static_cast<unsigned char>(ch);
    return (c < 0x20 && !is_space(ch)) || c == 0x7f;
  });
}

std::vector<std::string_view> split_ws(std::string_view s) {
  std::vector<std::string_view> tokens;
  std::size_t i = 0;
  while (i < s.size()) {
    while (i < s.size() && is_space(s[i])) ++i;
    const std::size_t start = i;
    while (i < s.size() && !is_space(s[i])) ++i;
    if (i > start) tokens.push_back(s.substr(start, i - start));
  }
  return tokens;
}

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

bool parse_double(std::string_view s, double& out) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  if (s.empty()) return false;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && ptr == s.data() + s.size();
}

bool parse_int64(std::string_view s, std::int64_t& out) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  if (s.empty()) return false;
  const auto [ptr, ec] = std::from_chars(s.data(), s.data() + s.size(), out);
  return ec == std::errc() && ptr == s.data() + s.size();
}

std::string quoted(std::string_view token) {
  constexpr std::size_t kMax = 40;
  std::string out = "'";
  for (char c : token.substr(0, kMax)) {
    out += (std::isprint(static_cast<unsigned char>(c)) != 0) ? c : '?';
  }
  if (token.size() > kMax) out += "...";
  return out + "'";
}

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

// ---------------------------------------------------------------------------------------------
// OBJ: v / f only; everything else (vt, vn, g, o, s, usemtl, mtllib, ...) is ignored. mtllib is
// deliberately not followed: request bytes must not make the server read files.

Result<MeshData> read_obj(std::string_view bytes, WorkMeter& work) {
  MeshBuilder builder;
  LineReader lines(bytes);
  std::string_view line;
  std::vector<std::int64_t> polygon;
  while (lines.next(line)) {
    MD_RETURN_IF_ERROR(work.step(1 + line.size() / 16));  // a line and its tokens
    const std::string where = "line " + std::to_string(lines.line_number());
    if (has_binary_bytes(line)) return invalid(where + ": unexpected binary data in OBJ text");
    const std::size_t hash = line.find('#');
    if (hash != std::string_view::npos) line = line.substr(0, hash);
    const auto tokens = split_ws(line);
    if (tokens.empty()) continue;
    if (tokens[0] == "v") {
      if (tokens.size() < 4) {
        return invalid(where + ": vertex needs 3 coordinates, got " +
                       std::to_string(tokens.size() - 1));
      }
      std::array<double, 3> p{};
      for (int c = 0; c < 3; ++c) {
        if (!parse_double(tokens[static_cast<std::size_t>(c + 1)],
                          p[static_cast<std::size_t>(c)])) {
          return invalid(where + ": vertex coordinate " +
                         quoted(tokens[static_cast<std::size_t>(c + 1)]) + " is not a number");
        }
      }
      builder.add_vertex(p[0], p[1], p[2]);
    } else if (tokens[0] == "f") {
      polygon.clear();
      for (std::size_t t = 1; t < tokens.size(); ++t) {
        const std::string_view ref = tokens[t].substr(0, tokens[t].find('/'));
        std::int64_t index = 0;
        if (!parse_int64(ref, index) || index == 0) {
          return invalid(where + ": face vertex reference " + quoted(tokens[t]) +
                         " is not a valid OBJ index (1-based, or negative for relative)");
        }
        // Negative indices are relative to the vertices read so far (-1 = the last one).
        polygon.push_back(index > 0 ? index - 1
                                    : static_cast<std::int64_t>(builder.vertex_count()) + index);
      }
      MD_RETURN_IF_ERROR(builder.add_polygon(polygon, where));
    }
  }
  return builder.finish("OBJ");
}

// ---------------------------------------------------------------------------------------------
// OFF (ASCII; optional C/N/ST prefixes whose extra per-vertex values are ignored).

Result<MeshData> read_off(std::string_view bytes, WorkMeter& work) {
  LineReader lines(bytes);
  std::string_view line;
  // Next non-empty, comment-stripped line as tokens; false at the end of the data.
  std::string error;
  Status stopped = Status::success();  // Cancelled: the stop was requested mid-read
  auto next_tokens = [&](std::vector<std::string_view>& tokens) {
    while (lines.next(line)) {
      if (const Status counted = work.step(1 + line.size() / 16); !counted.ok()) {
        stopped = counted;
        return false;
      }
      if (has_binary_bytes(line)) {
        error =
            "line " + std::to_string(lines.line_number()) + ": unexpected binary data in OFF text";
        return false;
      }
      const std::size_t hash = line.find('#');
      if (hash != std::string_view::npos) line = line.substr(0, hash);
      tokens = split_ws(line);
      if (!tokens.empty()) return true;
    }
    return false;
  };
  std::vector<std::string_view> tokens;
  if (!next_tokens(tokens)) {
    if (!stopped.ok()) return stopped;
    return invalid(error.empty() ? "OFF data is empty" : error);
  }
  const std::string keyword(tokens[0]);
  const bool is_off = keyword.size() >= 3 && keyword.compare(keyword.size() - 3, 3, "OFF") == 0 &&
                      keyword.find_first_not_of("STCN") == keyword.size() - 3;
  if (!is_off) return invalid("line 1: expected the OFF header keyword, got " + quoted(tokens[0]));
  if (tokens.size() > 1 && tokens[1] == "BINARY") return invalid("binary OFF is not supported");
  std::vector<std::string_view> counts(tokens.begin() + 1, tokens.end());
  if (counts.empty()) {
    if (!next_tokens(counts)) {
      if (!stopped.ok()) return stopped;
      return invalid(error.empty() ? "OFF data ends before the counts line" : error);
    }
  }
  std::int64_t nv = 0;
  std::int64_t nf = 0;
  if (counts.size() < 2 || !parse_int64(counts[0], nv) || !parse_int64(counts[1], nf) || nv < 0 ||
      nf < 0) {
    return invalid("line " + std::to_string(lines.line_number()) +
                   ": expected '#vertices #faces #edges' counts");
  }
  // Every vertex and face takes at least one line: bound the counts by the data size before
  // reserving memory, so a forged header cannot allocate gigabytes.
  const auto remaining =
      static_cast<std::int64_t>(bytes.size() - std::min(bytes.size(), lines.position()));
  if (nv > remaining || nf > remaining) {
    return invalid("OFF header declares " + std::to_string(nv) + " vertices and " +
                   std::to_string(nf) + " faces, more than the data can hold (truncated?)");
  }
  MeshBuilder builder;
  builder.reserve(static_cast<std::size_t>(nv), static_cast<std::size_t>(nf));
  for (std::int64_t i = 0; i < nv; ++i) {
    if (!next_tokens(tokens)) {
      if (!stopped.ok()) return stopped;
      return invalid(error.empty() ? "OFF data ends after " + std::to_string(i) + " of " +
                                         std::to_string(nv) + " vertices (truncated)"
                                   : error);
    }
    const std::string where =
        "line " + std::to_string(lines.line_number()) + " (vertex " + std::to_string(i) + ")";
    if (tokens.size() < 3) return invalid(where + ": vertex needs 3 coordinates");
    std::array<double, 3> p{};
    for (std::size_t c = 0; c < 3; ++c) {
      if (!parse_double(tokens[c], p[c])) {
        return invalid(where + ": coordinate " + quoted(tokens[c]) + " is not a number");
      }
    }
    builder.add_vertex(p[0], p[1], p[2]);
  }
  std::vector<std::int64_t> polygon;
  for (std::int64_t f = 0; f < nf; ++f) {
    if (!next_tokens(tokens)) {
      if (!stopped.ok()) return stopped;
      return invalid(error.empty() ? "OFF data ends after " + std::to_string(f) + " of " +
                                         std::to_string(nf) + " faces (truncated)"
                                   : error);
    }
    const std::string where =
        "line " + std::to_string(lines.line_number()) + " (face " + std::to_string(f) + ")";
    std::int64_t n = 0;
    if (!parse_int64(tokens[0], n) || n < 0) {
      return invalid(where + ": vertex count " + quoted(tokens[0]) + " is not a count");
    }
    if (static_cast<std::int64_t>(tokens.size()) < n + 1) {
      return invalid(where + ": face declares " + std::to_string(n) + " vertices but lists " +
                     std::to_string(tokens.size() - 1));
    }
    polygon.clear();
    for (std::int64_t k = 1; k <= n; ++k) {
      std::int64_t index = 0;
      if (!parse_int64(tokens[static_cast<std::size_t>(k)], index)) {
        return invalid(where + ": vertex index " + quoted(tokens[static_cast<std::size_t>(k)]) +
                       " is not an integer");
      }
      polygon.push_back(index);
    }
    MD_RETURN_IF_ERROR(builder.add_polygon(polygon, where));
  }
  return builder.finish("OFF");
}

// ---------------------------------------------------------------------------------------------
// PLY (ascii, binary_little_endian, binary_big_endian).

enum class PlyType { Int8, UInt8, Int16, UInt16, Int32, UInt32, Float32, Float64 };

bool parse_ply_type(std::string_view name, PlyType& type) {
  static const std::array<std::pair<std::string_view, PlyType>, 16> kTypes = {{
      {"char", PlyType::Int8},
      {"int8", PlyType::Int8},
      {"uchar", PlyType::UInt8},
      {"uint8", PlyType::UInt8},
      {"short", PlyType::Int16},
      {"int16", PlyType::Int16},
      {"ushort", PlyType::UInt16},
      {"uint16", PlyType::UInt16},
      {"int", PlyType::Int32},
      {"int32", PlyType::Int32},
      {"uint", PlyType::UInt32},
      {"uint32", PlyType::UInt32},
      {"float", PlyType::Float32},
      {"float32", PlyType::Float32},
      {"double", PlyType::Float64},
      {"float64", PlyType::Float64},
  }};
  for (const auto& [n, t] : kTypes) {
    if (n == name) {
      type = t;
      return true;
    }
  }
  return false;
}

std::size_t ply_size(PlyType type) {
  switch (type) {
    case PlyType::Int8:
    case PlyType::UInt8:
      return 1;
    case PlyType::Int16:
    case PlyType::UInt16:
      return 2;
    case PlyType::Int32:
    case PlyType::UInt32:
    case PlyType::Float32:
      return 4;
    case PlyType::Float64:
      return 8;
  }
  return 8;
}

bool ply_is_integer(PlyType type) { return type != PlyType::Float32 && type != PlyType::Float64; }

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::Float32;
  bool is_list = false;
  PlyType count_type = PlyType::UInt8;
};

struct PlyElement {
  std::string name;
  std::uint64_t count = 0;
  std::vector<PlyProperty> properties;
};

// Reads one scalar of the body; both sources report how much input is left so that list counts
// and element counts from the header can be checked before allocating.
class PlyAsciiSource {
 public:
  explicit PlyAsciiSource(std::string_view body) : tokens_(split_ws(body)) {}
  bool read(PlyType /*type*/, double& value) {
    if (next_ >= tokens_.size()) return false;
    return parse_double(tokens_[next_++], value);
  }
  std::size_t remaining_values(PlyType /*type*/) const { return tokens_.size() - next_; }

 private:
  std::vector<std::string_view> tokens_;
  std::size_t next_ = 0;
};

class PlyBinarySource {
 public:
  PlyBinarySource(std::string_view body, bool big_endian) : body_(body), big_endian_(big_endian) {}
  bool read(PlyType type, double& value) {
    const std::size_t n = ply_size(type);
    if (body_.size() - pos_ < n) return false;
    std::array<unsigned char, 8> b{};
    std::memcpy(b.data(), body_.data() + pos_, n);
    pos_ += n;
    if (big_endian_ != (std::endian::native == std::endian::big))
      std::reverse(b.begin(), b.begin() + static_cast<long>(n));
    switch (type) {
      case PlyType::Int8:
        value = static_cast<double>(std::bit_cast<std::int8_t>(b[0]));
        break;
      case PlyType::UInt8:
        value = static_cast<double>(b[0]);
        break;
      case PlyType::Int16:
        value = load<std::int16_t>(b);
        break;
      case PlyType::UInt16:
        value = load<std::uint16_t>(b);
        break;
      case PlyType::Int32:
        value = load<std::int32_t>(b);
        break;
      case PlyType::UInt32:
        value = load<std::uint32_t>(b);
        break;
      case PlyType::Float32:
        value = static_cast<double>(load<float>(b));
        break;
      case PlyType::Float64:
        value = load<double>(b);
        break;
    }
    return true;
  }
  std::size_t remaining_values(PlyType type) const {
    return (body_.size() - pos_) / ply_size(type);
  }

 private:
  template <typename T>
  static double load(const std::array<unsigned char, 8>& b) {
    T v;
    std::memcpy(&v, b.data(), sizeof(T));
    return static_cast<double>(v);
  }
  std::string_view body_;
  std::size_t pos_ = 0;
  bool big_endian_;
};

template <typename Source>
Result<MeshData> read_ply_body(Source& source, const std::vector<PlyElement>& elements,
                               WorkMeter& work) {
  MeshBuilder builder;
  bool has_vertex = false;
  bool has_face = false;
  std::vector<std::int64_t> polygon;
  for (const PlyElement& element : elements) {
    const bool is_vertex = element.name == "vertex";
    const bool is_face = element.name == "face";
    std::array<int, 3> xyz = {-1, -1, -1};
    int indices_property = -1;
    for (std::size_t p = 0; p < element.properties.size(); ++p) {
      const PlyProperty& prop = element.properties[p];
      if (is_vertex && !prop.is_list) {
        if (prop.name == "x") xyz[0] = static_cast<int>(p);
        if (prop.name == "y") xyz[1] = static_cast<int>(p);
        if (prop.name == "z") xyz[2] = static_cast<int>(p);
      }
      if (is_face && prop.is_list &&
          (prop.name == "vertex_indices" || prop.name == "vertex_index")) {
        indices_property = static_cast<int>(p);
      }
    }
    if (is_vertex) {
      has_vertex = true;
      if (std::find(xyz.begin(), xyz.end(), -1) != xyz.end()) {
        return invalid("PLY element 'vertex' lacks an x, y or z scalar property");
      }
    }
    if (is_face) {
      has_face = true;
      if (indices_property < 0) {
        return invalid("PLY element 'face' lacks a 'vertex_indices' list property");
      }
    }
    if (element.properties.empty()) {
      // A row without properties consumes no input, so its count is not backed by any bytes:
      // skip the element in O(1) (looping over a forged count of 2e9 rows took minutes).
      MD_RETURN_IF_ERROR(work.step());
      continue;
    }
    if (element.count > source.remaining_values(PlyType::UInt8)) {
      return invalid("PLY element '" + element.name + "' declares " +
                     std::to_string(element.count) +
                     " entries, more than the data holds (truncated?)");
    }
    if (is_vertex) builder.reserve(static_cast<std::size_t>(element.count), 0);
    std::array<double, 3> position{};
    for (std::uint64_t i = 0; i < element.count; ++i) {
      MD_RETURN_IF_ERROR(work.step(element.properties.size()));
      const std::string where = "PLY " + element.name + " " + std::to_string(i);
      for (std::size_t p = 0; p < element.properties.size(); ++p) {
        const PlyProperty& prop = element.properties[p];
        double value = 0.0;
        if (!prop.is_list) {
          if (!source.read(prop.type, value)) {
            return invalid(where + ": missing or malformed value of property '" + prop.name +
                           "' (truncated?)");
          }
          for (std::size_t c = 0; c < 3; ++c) {
            if (xyz[c] == static_cast<int>(p)) position[c] = value;
          }
          continue;
        }
        double count_value = 0.0;
        if (!source.read(prop.count_type, count_value) || !(count_value >= 0.0) ||
            count_value != std::floor(count_value)) {
          return invalid(where + ": missing or malformed list length of '" + prop.name + "'");
        }
        if (count_value > static_cast<double>(source.remaining_values(prop.type))) {
          // ASCII PLY does not bound the count by its type, so it may exceed 2^64: converting
          // such a double to an integer is undefined behaviour (found by fuzz_mesh_ply).
          const std::string declared = count_value < 1e18
                                           ? std::to_string(static_cast<std::uint64_t>(count_value))
                                           : std::to_string(count_value);
          return invalid(where + ": list '" + prop.name + "' declares " + declared +
                         " values, more than the data holds (truncated?)");
        }
        const auto count = static_cast<std::size_t>(count_value);
        const bool keep = static_cast<int>(p) == indices_property;
        if (keep) polygon.clear();
        MD_RETURN_IF_ERROR(work.step(count));
        for (std::size_t k = 0; k < count; ++k) {
          if (!source.read(prop.type, value)) {
            return invalid(where + ": missing or malformed list value of '" + prop.name + "'");
          }
          if (keep) {
            if (!ply_is_integer(prop.type) && value != std::floor(value)) {
              return invalid(where + ": vertex index " + std::to_string(value) +
                             " is not an integer");
            }
            if (!(std::abs(value) < 9.0e15)) {
              return invalid(where + ": vertex index " + std::to_string(value) +
                             " is out of range");
            }
            polygon.push_back(static_cast<std::int64_t>(value));
          }
        }
        if (keep) MD_RETURN_IF_ERROR(builder.add_polygon(polygon, where));
      }
      if (is_vertex) builder.add_vertex(position[0], position[1], position[2]);
    }
  }
  if (!has_vertex) return invalid("PLY header has no 'vertex' element");
  if (!has_face) return invalid("PLY header has no 'face' element");
  return builder.finish("PLY");
}

Result<MeshData> read_ply(std::string_view bytes, WorkMeter& work) {
  LineReader lines(bytes);
  std::string_view line;
  if (!lines.next(line) || split_ws(line) != std::vector<std::string_view>{"ply"}) {
    return invalid("PLY data does not start with the 'ply' magic line");
  }
  enum class Encoding { None, Ascii, Little, Big } encoding = Encoding::None;
  std::vector<PlyElement> elements;
  bool ended = false;
  while (!ended && lines.next(line)) {
    MD_RETURN_IF_ERROR(work.step(1 + line.size() / 16));
    const std::string where = "PLY header line " + std::to_string(lines.line_number());
    if (has_binary_bytes(line)) return invalid(where + ": unexpected binary data");
    const auto tokens = split_ws(line);
    if (tokens.empty()) continue;
    if (tokens[0] == "comment" || tokens[0] == "obj_info") continue;
    if (tokens[0] == "end_header") {
      ended = true;
    } else if (tokens[0] == "format") {
      if (tokens.size() < 2) return invalid(where + ": format line lacks the encoding");
      if (tokens[1] == "ascii") {
        encoding = Encoding::Ascii;
      } else if (tokens[1] == "binary_little_endian") {
        encoding = Encoding::Little;
      } else if (tokens[1] == "binary_big_endian") {
        encoding = Encoding::Big;
      } else {
        return invalid(where + ": unknown format " + quoted(tokens[1]));
      }
    } else if (tokens[0] == "element") {
      std::int64_t count = 0;
      if (tokens.size() != 3 || !parse_int64(tokens[2], count) || count < 0 ||
          count > std::numeric_limits<int>::max()) {
        return invalid(where + ": expected 'element <name> <count>' with a count below 2^31");
      }
      elements.push_back({std::string(tokens[1]), static_cast<std::uint64_t>(count), {}});
    } else if (tokens[0] == "property") {
      if (elements.empty()) return invalid(where + ": property before any element");
      PlyProperty prop;
      bool ok = false;
      if (tokens.size() == 5 && tokens[1] == "list") {
        prop.is_list = true;
        prop.name = std::string(tokens[4]);
        ok = parse_ply_type(tokens[2], prop.count_type) && ply_is_integer(prop.count_type) &&
             parse_ply_type(tokens[3], prop.type);
      } else if (tokens.size() == 3) {
        prop.name = std::string(tokens[2]);
        ok = parse_ply_type(tokens[1], prop.type);
      }
      if (!ok) return invalid(where + ": malformed property line " + quoted(line));
      elements.back().properties.push_back(std::move(prop));
    } else {
      return invalid(where + ": unknown header keyword " + quoted(tokens[0]));
    }
  }
  if (!ended) return invalid("PLY header has no 'end_header' line (truncated?)");
  if (encoding == Encoding::None) return invalid("PLY header has no 'format' line");
  const std::string_view body = bytes.substr(std::min(bytes.size(), lines.position()));
  if (encoding == Encoding::Ascii) {
    if (has_binary_bytes(body)) return invalid("ASCII PLY body contains binary data");
    PlyAsciiSource source(body);
    MD_RETURN_IF_ERROR(work.step(source.remaining_values(PlyType::UInt8)));  // tokenising
    return read_ply_body(source, elements, work);
  }
  PlyBinarySource source(body, encoding == Encoding::Big);
  return read_ply_body(source, elements, work);
}

// ---------------------------------------------------------------------------------------------
// STL: binary when the size matches 84 + 50 * count (some binary files also start with "solid"),
// ASCII when it starts with "solid". Vertices are not merged here: the reader returns the soup,
// and load_mesh welds exactly equal positions.

constexpr std::size_t kStlHeader = 84;
constexpr std::size_t kStlTriangle = 50;

std::uint32_t load_u32_le(const char* p) {
  std::uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8U) | static_cast<unsigned char>(p[i]);
  return v;
}

float load_f32_le(const char* p) { return std::bit_cast<float>(load_u32_le(p)); }

Result<MeshData> read_stl_binary(std::string_view bytes, WorkMeter& work) {
  // read_stl checked that the size is exactly 84 + 50 * count: the count is backed by bytes.
  const std::uint32_t count = load_u32_le(bytes.data() + 80);
  MeshBuilder builder;
  builder.reserve(3 * static_cast<std::size_t>(count), count);
  for (std::uint32_t t = 0; t < count; ++t) {
    MD_RETURN_IF_ERROR(work.step());
    const char* p = bytes.data() + kStlHeader + kStlTriangle * t + 12;  // skip the normal
    for (int k = 0; k < 3; ++k) {
      builder.add_vertex(load_f32_le(p + 12 * k), load_f32_le(p + 12 * k + 4),
                         load_f32_le(p + 12 * k + 8));
    }
    const int base = static_cast<int>(3 * t);
    builder.add_triangle(base, base + 1, base + 2);
  }
  return builder.finish("STL");
}

Result<MeshData> read_stl_ascii(std::string_view bytes, WorkMeter& work) {
  if (has_binary_bytes(bytes)) return invalid("ASCII STL contains binary data");
  const auto tokens = split_ws(bytes);
  MD_RETURN_IF_ERROR(work.step(tokens.size()));  // tokenising
  MeshBuilder builder;
  std::size_t t = 0;
  int facet = 0;
  std::vector<std::int64_t> polygon;
  auto expect = [&](std::string_view word) {
    if (t < tokens.size() && lower(tokens[t]) == word) {
      ++t;
      return Status::success();
    }
    return invalid("ASCII STL facet " + std::to_string(facet) + ": expected '" + std::string(word) +
                   "', got " +
                   (t < tokens.size() ? quoted(tokens[t]) : "end of data (truncated?)"));
  };
  bool in_solid = false;
  // Every pass of this loop and of the inner ones advances t: the work is bounded by the tokens.
  std::size_t counted = 0;
  while (t < tokens.size()) {
    MD_RETURN_IF_ERROR(work.step(t - counted + 1));
    counted = t;
    const std::string word = lower(tokens[t]);
    if (!in_solid) {
      if (word != "solid") return invalid("ASCII STL: expected 'solid', got " + quoted(tokens[t]));
      in_solid = true;
      ++t;
      // The solid's name runs to the first facet/endsolid keyword.
      while (t < tokens.size() && lower(tokens[t]) != "facet" && lower(tokens[t]) != "endsolid")
        ++t;
      continue;
    }
    if (word == "endsolid") {
      in_solid = false;
      ++t;
      // Skip the optional name that repeats the solid's name.
      while (t < tokens.size() && lower(tokens[t]) != "solid") ++t;
      continue;
    }
    MD_RETURN_IF_ERROR(expect("facet"));
    MD_RETURN_IF_ERROR(expect("normal"));
    t += 3;  // the normal is recomputed from the vertices by anyone who needs it
    MD_RETURN_IF_ERROR(expect("outer"));
    MD_RETURN_IF_ERROR(expect("loop"));
    polygon.clear();
    while (t < tokens.size() && lower(tokens[t]) == "vertex") {
      if (t + 3 >= tokens.size()) break;
      std::array<double, 3> p{};
      for (std::size_t c = 0; c < 3; ++c) {
        if (!parse_double(tokens[t + 1 + c], p[c])) {
          return invalid("ASCII STL facet " + std::to_string(facet) + ": coordinate " +
                         quoted(tokens[t + 1 + c]) + " is not a number");
        }
      }
      // STL stores float32; round like a binary file would so both encodings agree.
      polygon.push_back(static_cast<std::int64_t>(builder.vertex_count()));
      builder.add_vertex(static_cast<float>(p[0]), static_cast<float>(p[1]),
                         static_cast<float>(p[2]));
      t += 4;
    }
    MD_RETURN_IF_ERROR(expect("endloop"));
    MD_RETURN_IF_ERROR(expect("endfacet"));
    MD_RETURN_IF_ERROR(builder.add_polygon(polygon, "ASCII STL facet " + std::to_string(facet)));
    ++facet;
  }
  if (in_solid) return invalid("ASCII STL ends without 'endsolid' (truncated?)");
  return builder.finish("STL");
}

Result<MeshData> read_stl(std::string_view bytes, WorkMeter& work) {
  if (bytes.size() >= kStlHeader) {
    const std::uint64_t count = load_u32_le(bytes.data() + 80);
    if (kStlHeader + kStlTriangle * count == bytes.size()) return read_stl_binary(bytes, work);
  }
  const std::size_t start = std::min(bytes.size(), bytes.find_first_not_of(" \t\r\n"));
  if (lower(bytes.substr(start, 5)) == "solid") return read_stl_ascii(bytes, work);
  if (bytes.size() >= kStlHeader) {
    const std::uint64_t count = load_u32_le(bytes.data() + 80);
    return invalid("binary STL declares " + std::to_string(count) + " triangles (" +
                   std::to_string(kStlHeader + kStlTriangle * count) + " bytes) but has " +
                   std::to_string(bytes.size()) + " bytes (truncated or not STL)");
  }
  return invalid("STL data of " + std::to_string(bytes.size()) +
                 " bytes is neither binary (84-byte header) nor ASCII ('solid')");
}

// ---------------------------------------------------------------------------------------------
// glTF 2.0 / GLB via tinygltf.

bool refuse_file_exists(const std::string& /*path*/, void* /*user*/) { return false; }
std::string keep_path(const std::string& path, void* /*user*/) { return path; }
bool refuse_read(std::vector<unsigned char>* /*out*/, std::string* err, const std::string& path,
                 void* /*user*/) {
  if (err != nullptr) *err += "external file access is disabled (uri '" + path + "')\n";
  return false;
}
bool refuse_write(std::string* err, const std::string& path,
                  const std::vector<unsigned char>& /*contents*/, void* /*user*/) {
  if (err != nullptr) *err += "file writing is disabled ('" + path + "')\n";
  return false;
}
// Images are irrelevant to the geometry; skipping them also avoids running an image decoder on
// untrusted bytes.
bool ignore_image(tinygltf::Image* /*image*/, const int /*index*/, std::string* /*err*/,
                  std::string* /*warn*/, int /*req_width*/, int /*req_height*/,
                  const unsigned char* /*bytes*/, int /*size*/, void* /*user*/) {
  return true;
}

std::size_t component_size(int component_type) {
  switch (component_type) {
    case TINYGLTF_COMPONENT_TYPE_BYTE:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
      return 1;
    case TINYGLTF_COMPONENT_TYPE_SHORT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
      return 2;
    case TINYGLTF_COMPONENT_TYPE_INT:
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
    case TINYGLTF_COMPONENT_TYPE_FLOAT:
      return 4;
    case TINYGLTF_COMPONENT_TYPE_DOUBLE:
      return 8;
    default:
      return 0;
  }
}

double load_component(const unsigned char* p, int component_type) {
  // glTF binary data is little-endian.
  std::array<unsigned char, 8> b{};
  const std::size_t n = component_size(component_type);
  std::memcpy(b.data(), p, n);
  if constexpr (std::endian::native == std::endian::big)
    std::reverse(b.begin(), b.begin() + static_cast<long>(n));
  auto as = [&b](auto v) {
    std::memcpy(&v, b.data(), sizeof(v));
    return static_cast<double>(v);
  };
  switch (component_type) {
    case TINYGLTF_COMPONENT_TYPE_BYTE:
      return as(std::int8_t{});
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE:
      return as(std::uint8_t{});
    case TINYGLTF_COMPONENT_TYPE_SHORT:
      return as(std::int16_t{});
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT:
      return as(std::uint16_t{});
    case TINYGLTF_COMPONENT_TYPE_INT:
      return as(std::int32_t{});
    case TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT:
      return as(std::uint32_t{});
    case TINYGLTF_COMPONENT_TYPE_FLOAT:
      return as(float{});
    case TINYGLTF_COMPONENT_TYPE_DOUBLE:
      return as(double{});
    default:
      return 0.0;
  }
}

// Bounds-checked view of an accessor's elements: the model comes from untrusted bytes, so every
// offset, stride and count is checked against the real buffer size before reading.
struct AccessorView {
  const unsigned char* data = nullptr;
  std::size_t count = 0;
  std::size_t stride = 0;
  int component_type = 0;
  int components = 0;
  double get(std::size_t i, int c) const {
    return load_component(
        data + i * stride + static_cast<std::size_t>(c) * component_size(component_type),
        component_type);
  }
};

Result<AccessorView> view_accessor(const tinygltf::Model& model, int index,
                                   const std::string& what) {
  if (index < 0 || static_cast<std::size_t>(index) >= model.accessors.size()) {
    return invalid(what + ": accessor " + std::to_string(index) + " does not exist");
  }
  const tinygltf::Accessor& accessor = model.accessors[static_cast<std::size_t>(index)];
  const std::string name = what + " (accessor " + std::to_string(index) + ")";
  if (accessor.sparse.isSparse) return invalid(name + ": sparse accessors are not supported");
  if (accessor.bufferView < 0 ||
      static_cast<std::size_t>(accessor.bufferView) >= model.bufferViews.size()) {
    return invalid(name + ": missing or invalid bufferView " + std::to_string(accessor.bufferView));
  }
  const tinygltf::BufferView& view =
      model.bufferViews[static_cast<std::size_t>(accessor.bufferView)];
  if (view.buffer < 0 || static_cast<std::size_t>(view.buffer) >= model.buffers.size()) {
    return invalid(name + ": bufferView refers to missing buffer " + std::to_string(view.buffer));
  }
  const std::vector<unsigned char>& buffer =
      model.buffers[static_cast<std::size_t>(view.buffer)].data;
  AccessorView out;
  out.component_type = accessor.componentType;
  const std::size_t csize = component_size(accessor.componentType);
  if (csize == 0)
    return invalid(name + ": unknown componentType " + std::to_string(accessor.componentType));
  if (accessor.type == TINYGLTF_TYPE_SCALAR) {
    out.components = 1;
  } else if (accessor.type == TINYGLTF_TYPE_VEC3) {
    out.components = 3;
  } else {
    return invalid(name + ": unexpected accessor type " + std::to_string(accessor.type));
  }
  const std::size_t element = csize * static_cast<std::size_t>(out.components);
  out.stride = view.byteStride != 0 ? view.byteStride : element;
  out.count = accessor.count;
  if (out.stride < element) return invalid(name + ": byteStride smaller than an element");
  if (view.byteOffset > buffer.size() || view.byteLength > buffer.size() - view.byteOffset) {
    return invalid(name + ": bufferView exceeds its buffer (" + std::to_string(buffer.size()) +
                   " bytes)");
  }
  if (accessor.byteOffset > view.byteLength)
    return invalid(name + ": byteOffset exceeds its bufferView");
  const std::size_t available = view.byteLength - accessor.byteOffset;
  if (out.count > 0 && (out.count - 1 > available / out.stride ||
                        (out.count - 1) * out.stride + element > available)) {
    return invalid(name + ": " + std::to_string(out.count) + " elements exceed the bufferView (" +
                   std::to_string(view.byteLength) + " bytes)");
  }
  out.data = buffer.data() + view.byteOffset + accessor.byteOffset;
  return out;
}

// Nodes may share a mesh (instancing), so the output is not bounded by the input: a few kB of
// nodes referencing one large mesh would expand to gigabytes. Each primitive draws its vertices
// and corners from this budget, a fixed multiple of the input size.
struct GltfBudget {
  std::uint64_t elements_left = 0;
  Status take(std::uint64_t elements, const std::string& where) {
    if (elements > elements_left) {
      return invalid(where + ": instancing expands the mesh past " +
                     std::to_string(kExpansion) + " vertices and corners per input byte");
    }
    elements_left -= elements;
    return Status::success();
  }
  static constexpr std::uint64_t kExpansion = 2;
};

Status append_primitive(const tinygltf::Model& model, const tinygltf::Primitive& primitive,
                        const Eigen::Matrix4d& transform, bool is_identity,
                        const std::string& where, MeshBuilder& builder, WorkMeter& work,
                        GltfBudget& budget) {
  if (primitive.mode != TINYGLTF_MODE_TRIANGLES && primitive.mode != TINYGLTF_MODE_TRIANGLE_STRIP &&
      primitive.mode != TINYGLTF_MODE_TRIANGLE_FAN) {
    return Status::success();  // points and lines carry no surface
  }
  const auto position = primitive.attributes.find("POSITION");
  if (position == primitive.attributes.end()) return invalid(where + ": no POSITION attribute");
  MD_ASSIGN_OR_RETURN(const AccessorView positions,
                      view_accessor(model, position->second, where + " POSITION"));
  if (positions.components != 3 || (positions.component_type != TINYGLTF_COMPONENT_TYPE_FLOAT &&
                                    positions.component_type != TINYGLTF_COMPONENT_TYPE_DOUBLE)) {
    return invalid(where + ": POSITION must be VEC3 of float or double");
  }
  const std::size_t base = builder.vertex_count();
  if (base + positions.count > static_cast<std::size_t>(std::numeric_limits<int>::max())) {
    return invalid(where + ": too many vertices");
  }
  MD_RETURN_IF_ERROR(budget.take(positions.count, where));
  for (std::size_t i = 0; i < positions.count; ++i) {
    if ((i & 1023U) == 0) MD_RETURN_IF_ERROR(work.step(std::min<std::size_t>(1024, positions.count - i)));
    Eigen::Vector4d p(positions.get(i, 0), positions.get(i, 1), positions.get(i, 2), 1.0);
    if (!is_identity) p = transform * p;
    builder.add_vertex(p[0], p[1], p[2]);
  }
  std::vector<std::int64_t> corners;
  if (primitive.indices >= 0) {
    MD_ASSIGN_OR_RETURN(const AccessorView indices,
                        view_accessor(model, primitive.indices, where + " indices"));
    if (indices.components != 1 || indices.component_type == TINYGLTF_COMPONENT_TYPE_FLOAT ||
        indices.component_type == TINYGLTF_COMPONENT_TYPE_DOUBLE) {
      return invalid(where + ": indices must be integer scalars");
    }
    MD_RETURN_IF_ERROR(budget.take(indices.count, where));
    corners.reserve(indices.count);
    for (std::size_t i = 0; i < indices.count; ++i) {
      if ((i & 1023U) == 0) MD_RETURN_IF_ERROR(work.step(std::min<std::size_t>(1024, indices.count - i)));
      const double value = indices.get(i, 0);
      if (value < 0.0 || value >= static_cast<double>(positions.count)) {
        return invalid(where + ": index " + std::to_string(static_cast<std::int64_t>(value)) +
                       " at position " + std::to_string(i) + " is outside POSITION (count " +
                       std::to_string(positions.count) + ")");
      }
      corners.push_back(static_cast<std::int64_t>(value));
    }
  } else {
    MD_RETURN_IF_ERROR(budget.take(positions.count, where));
    corners.resize(positions.count);
    for (std::size_t i = 0; i < positions.count; ++i) corners[i] = static_cast<std::int64_t>(i);
  }
  const auto b = static_cast<int>(base);
  auto corner = [&](std::size_t i) { return b + static_cast<int>(corners[i]); };
  if (primitive.mode == TINYGLTF_MODE_TRIANGLES) {
    if (corners.size() % 3 != 0) {
      return invalid(where + ": TRIANGLES index count " + std::to_string(corners.size()) +
                     " is not a multiple of 3");
    }
    for (std::size_t i = 0; i < corners.size(); i += 3)
      builder.add_triangle(corner(i), corner(i + 1), corner(i + 2));
  } else if (primitive.mode == TINYGLTF_MODE_TRIANGLE_STRIP) {
    for (std::size_t i = 0; i + 2 < corners.size(); ++i) {
      if (i % 2 == 0) {
        builder.add_triangle(corner(i), corner(i + 1), corner(i + 2));
      } else {
        builder.add_triangle(corner(i + 1), corner(i), corner(i + 2));
      }
    }
  } else {
    for (std::size_t i = 1; i + 1 < corners.size(); ++i)
      builder.add_triangle(corner(0), corner(i), corner(i + 1));
  }
  return Status::success();
}

Eigen::Matrix4d node_transform(const tinygltf::Node& node) {
  Eigen::Matrix4d m = Eigen::Matrix4d::Identity();
  if (node.matrix.size() == 16) {
    for (int c = 0; c < 4; ++c) {
      for (int r = 0; r < 4; ++r)
        m(r, c) = node.matrix[static_cast<std::size_t>(4 * c + r)];  // column-major
    }
    return m;
  }
  Eigen::Affine3d t = Eigen::Affine3d::Identity();
  if (node.translation.size() == 3) {
    t.translate(Eigen::Vector3d(node.translation[0], node.translation[1], node.translation[2]));
  }
  if (node.rotation.size() == 4) {  // glTF order: x, y, z, w
    t.rotate(
        Eigen::Quaterniond(node.rotation[3], node.rotation[0], node.rotation[1], node.rotation[2])
            .normalized());
  }
  if (node.scale.size() == 3) t.scale(Eigen::Vector3d(node.scale[0], node.scale[1], node.scale[2]));
  return t.matrix();
}

Status append_mesh(const tinygltf::Model& model, int mesh_index, const Eigen::Matrix4d& transform,
                   MeshBuilder& builder, WorkMeter& work, GltfBudget& budget) {
  if (mesh_index < 0 || static_cast<std::size_t>(mesh_index) >= model.meshes.size()) {
    return invalid("glTF node refers to missing mesh " + std::to_string(mesh_index));
  }
  const bool is_identity = transform == Eigen::Matrix4d::Identity();
  const auto& primitives = model.meshes[static_cast<std::size_t>(mesh_index)].primitives;
  for (std::size_t p = 0; p < primitives.size(); ++p) {
    MD_RETURN_IF_ERROR(work.step());
    MD_RETURN_IF_ERROR(append_primitive(
        model, primitives[p], transform, is_identity,
        "glTF mesh " + std::to_string(mesh_index) + " primitive " + std::to_string(p), builder,
        work, budget));
  }
  return Status::success();
}

Result<MeshData> gltf_to_mesh(const tinygltf::Model& model, std::size_t input_bytes,
                              WorkMeter& work) {
  MeshBuilder builder;
  GltfBudget budget{GltfBudget::kExpansion * input_bytes};
  const int scene = model.defaultScene >= 0 ? model.defaultScene : (model.scenes.empty() ? -1 : 0);
  bool any_mesh_node = false;
  if (scene >= 0 && static_cast<std::size_t>(scene) < model.scenes.size()) {
    // Depth-first over the node hierarchy with world transforms. Cycles and exponential fan-out
    // are possible in hostile files: guard with an on-path flag and a visit budget.
    struct Item {
      int node;
      Eigen::Matrix4d parent;
    };
    std::vector<Item> stack;
    for (const int root : model.scenes[static_cast<std::size_t>(scene)].nodes) {
      stack.push_back({root, Eigen::Matrix4d::Identity()});
    }
    std::size_t visits = 0;
    const std::size_t visit_budget = 16 * (model.nodes.size() + 1);
    while (!stack.empty()) {
      const Item item = stack.back();
      stack.pop_back();
      if (item.node < 0 || static_cast<std::size_t>(item.node) >= model.nodes.size()) {
        return invalid("glTF scene refers to missing node " + std::to_string(item.node));
      }
      if (++visits > visit_budget) return invalid("glTF node hierarchy is cyclic or too deep");
      MD_RETURN_IF_ERROR(work.step());
      const tinygltf::Node& node = model.nodes[static_cast<std::size_t>(item.node)];
      const Eigen::Matrix4d world = item.parent * node_transform(node);
      if (node.mesh >= 0) {
        any_mesh_node = true;
        MD_RETURN_IF_ERROR(append_mesh(model, node.mesh, world, builder, work, budget));
      }
      for (auto it = node.children.rbegin(); it != node.children.rend(); ++it)
        stack.push_back({*it, world});
    }
  }
  if (!any_mesh_node) {
    // No scene graph: take every mesh as is.
    for (std::size_t m = 0; m < model.meshes.size(); ++m) {
      MD_RETURN_IF_ERROR(append_mesh(model, static_cast<int>(m), Eigen::Matrix4d::Identity(),
                                     builder, work, budget));
    }
  }
  return builder.finish("glTF");
}

// The JSON text of a .gltf, or the JSON chunk of a .glb (its binary chunk is not JSON); the
// whole input when the GLB header is malformed (tinygltf reports that).
std::string_view gltf_json_text(std::string_view bytes, bool is_binary) {
  if (!is_binary) return bytes;
  constexpr std::size_t kGlbHeader = 12, kChunkHeader = 8;
  if (bytes.size() < kGlbHeader + kChunkHeader) return {};
  const std::uint32_t length = load_u32_le(bytes.data() + kGlbHeader);
  return bytes.substr(kGlbHeader + kChunkHeader,
                      std::min<std::size_t>(length, bytes.size() - kGlbHeader - kChunkHeader));
}

Result<MeshData> read_gltf(std::string_view bytes, bool allow_files, const std::string& base_dir,
                           WorkMeter& work) {
  if (bytes.size() > std::numeric_limits<unsigned int>::max())
    return invalid("glTF data is too large");
  {
    const bool glb = bytes.size() >= 4 && bytes.substr(0, 4) == "glTF";
    const std::string_view json_text = gltf_json_text(bytes, glb);
    MD_RETURN_IF_ERROR(work.step(json_text.size() / 16 + 1));
    if (json_nesting_depth(json_text, kMaxJsonDepth) > kMaxJsonDepth) {
      return invalid("glTF JSON nests arrays/objects deeper than " + std::to_string(kMaxJsonDepth) +
                     " levels");
    }
  }
  tinygltf::TinyGLTF loader;
  loader.SetImageLoader(&ignore_image, nullptr);
  if (!allow_files) {
    loader.SetFsCallbacks({&refuse_file_exists, &keep_path, &refuse_read, &refuse_write, nullptr});
  }
  tinygltf::Model model;
  std::string err;
  std::string warn;
  const bool is_binary = bytes.size() >= 4 && bytes.substr(0, 4) == "glTF";
  bool ok = false;
  if (is_binary) {
    ok = loader.LoadBinaryFromMemory(
        &model, &err, &warn, reinterpret_cast<const unsigned char*>(bytes.data()),
        static_cast<unsigned int>(bytes.size()), allow_files ? base_dir : "");
  } else {
    ok = loader.LoadASCIIFromString(&model, &err, &warn, bytes.data(),
                                    static_cast<unsigned int>(bytes.size()),
                                    allow_files ? base_dir : "");
  }
  if (!ok) {
    while (!err.empty() && is_space(err.back())) err.pop_back();
    return invalid("glTF reader: " + (err.empty() ? std::string("cannot parse data") : err));
  }
  MD_RETURN_IF_ERROR(work.poll());  // tinygltf's own parse cannot be stopped: check after it
  return gltf_to_mesh(model, bytes.size(), work);
}

// ---------------------------------------------------------------------------------------------
// Writers

Status check_writable(const MeshData& mesh, bool needs_float32) {
  static constexpr std::array<char, 3> kAxis = {'x', 'y', 'z'};
  for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
    for (int c = 0; c < 3; ++c) {
      const double v = mesh.V(i, c);
      if (!std::isfinite(v)) {
        return invalid("vertex " + std::to_string(i) + " has a non-finite " + kAxis[c] +
                       " coordinate");
      }
      if (needs_float32 && std::abs(v) > static_cast<double>(std::numeric_limits<float>::max())) {
        return invalid("vertex " + std::to_string(i) + " " + kAxis[c] + " coordinate " +
                       std::to_string(v) + " does not fit in float32");
      }
    }
  }
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      if (mesh.F(f, k) < 0 || mesh.F(f, k) >= mesh.V.rows()) {
        return invalid("face " + std::to_string(f) + " references vertex " +
                       std::to_string(mesh.F(f, k)) + " (#V=" + std::to_string(mesh.V.rows()) +
                       ")");
      }
    }
  }
  return Status::success();
}

// Shortest decimal text that reads back to exactly the same double (at most max_digits10 digits).
void append_double(std::string& out, double v) {
  std::array<char, 32> buf{};
  const auto [ptr, ec] = std::to_chars(buf.data(), buf.data() + buf.size(), v);
  out.append(buf.data(), ec == std::errc() ? static_cast<std::size_t>(ptr - buf.data()) : 0);
}

void append_xyz(std::string& out, const MeshData& mesh, Eigen::Index i) {
  for (int c = 0; c < 3; ++c) {
    out += ' ';
    append_double(out, mesh.V(i, c));
  }
}

std::string write_obj(const MeshData& mesh) {
  std::string out = "# meshdeform\n";
  for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
    out += 'v';
    append_xyz(out, mesh, i);
    out += '\n';
  }
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    out += "f " + std::to_string(mesh.F(f, 0) + 1) + ' ' + std::to_string(mesh.F(f, 1) + 1) + ' ' +
           std::to_string(mesh.F(f, 2) + 1) + '\n';
  }
  return out;
}

std::string write_off(const MeshData& mesh) {
  std::string out =
      "OFF\n" + std::to_string(mesh.V.rows()) + ' ' + std::to_string(mesh.F.rows()) + " 0\n";
  for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
    append_xyz(out, mesh, i);
    out += '\n';
  }
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    out += "3 " + std::to_string(mesh.F(f, 0)) + ' ' + std::to_string(mesh.F(f, 1)) + ' ' +
           std::to_string(mesh.F(f, 2)) + '\n';
  }
  return out;
}

std::string write_ply(const MeshData& mesh) {
  std::string out =
      "ply\nformat ascii 1.0\ncomment meshdeform\nelement vertex " + std::to_string(mesh.V.rows()) +
      "\nproperty double x\nproperty double y\nproperty double z\nelement face " +
      std::to_string(mesh.F.rows()) + "\nproperty list uchar int vertex_indices\nend_header\n";
  for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
    append_xyz(out, mesh, i);
    out += '\n';
  }
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    out += "3 " + std::to_string(mesh.F(f, 0)) + ' ' + std::to_string(mesh.F(f, 1)) + ' ' +
           std::to_string(mesh.F(f, 2)) + '\n';
  }
  return out;
}

void append_u32_le(std::string& out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i)
    out += static_cast<char>((v >> (8U * static_cast<unsigned>(i))) & 0xffU);
}
void append_f32_le(std::string& out, float v) {
  append_u32_le(out, std::bit_cast<std::uint32_t>(v));
}

std::string write_stl(const MeshData& mesh) {
  std::string out(80, ' ');
  const std::string_view title = "meshdeform binary STL";
  std::copy(title.begin(), title.end(), out.begin());
  out.reserve(kStlHeader + kStlTriangle * static_cast<std::size_t>(mesh.F.rows()));
  append_u32_le(out, static_cast<std::uint32_t>(mesh.F.rows()));
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    const Eigen::RowVector3d a = mesh.V.row(mesh.F(f, 0));
    const Eigen::RowVector3d b = mesh.V.row(mesh.F(f, 1));
    const Eigen::RowVector3d c = mesh.V.row(mesh.F(f, 2));
    Eigen::RowVector3d n = (b - a).cross(c - a);
    const double length = n.norm();
    if (length > 0.0) n /= length;
    for (int k = 0; k < 3; ++k) append_f32_le(out, static_cast<float>(n[k]));
    for (int corner = 0; corner < 3; ++corner) {
      for (int k = 0; k < 3; ++k)
        append_f32_le(out, static_cast<float>(mesh.V(mesh.F(f, corner), k)));
    }
    out += std::string(2, '\0');  // attribute byte count
  }
  return out;
}

Result<std::string> write_gltf(const MeshData& mesh, bool binary) {
  const auto nv = static_cast<std::size_t>(mesh.V.rows());
  const auto nf = static_cast<std::size_t>(mesh.F.rows());
  tinygltf::Model model;
  model.asset.version = "2.0";
  model.asset.generator = "meshdeform";
  tinygltf::Buffer buffer;
  std::string bytes;
  bytes.reserve(12 * nv + 12 * nf);
  std::vector<double> lo(3, std::numeric_limits<double>::infinity());
  std::vector<double> hi(3, -std::numeric_limits<double>::infinity());
  for (std::size_t i = 0; i < nv; ++i) {
    for (int c = 0; c < 3; ++c) {
      const float v = static_cast<float>(mesh.V(static_cast<Eigen::Index>(i), c));
      append_f32_le(bytes, v);
      lo[static_cast<std::size_t>(c)] =
          std::min(lo[static_cast<std::size_t>(c)], static_cast<double>(v));
      hi[static_cast<std::size_t>(c)] =
          std::max(hi[static_cast<std::size_t>(c)], static_cast<double>(v));
    }
  }
  for (std::size_t f = 0; f < nf; ++f) {
    for (int c = 0; c < 3; ++c)
      append_u32_le(bytes, static_cast<std::uint32_t>(mesh.F(static_cast<Eigen::Index>(f), c)));
  }
  buffer.data.assign(bytes.begin(), bytes.end());
  model.buffers.push_back(std::move(buffer));

  tinygltf::BufferView positions_view;
  positions_view.buffer = 0;
  positions_view.byteOffset = 0;
  positions_view.byteLength = 12 * nv;
  positions_view.target = TINYGLTF_TARGET_ARRAY_BUFFER;
  tinygltf::BufferView indices_view;
  indices_view.buffer = 0;
  indices_view.byteOffset = 12 * nv;
  indices_view.byteLength = 12 * nf;
  indices_view.target = TINYGLTF_TARGET_ELEMENT_ARRAY_BUFFER;
  model.bufferViews = {positions_view, indices_view};

  tinygltf::Accessor positions;
  positions.bufferView = 0;
  positions.componentType = TINYGLTF_COMPONENT_TYPE_FLOAT;
  positions.type = TINYGLTF_TYPE_VEC3;
  positions.count = nv;
  positions.minValues = lo;  // required for POSITION by the glTF spec
  positions.maxValues = hi;
  tinygltf::Accessor indices;
  indices.bufferView = 1;
  indices.componentType = TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT;
  indices.type = TINYGLTF_TYPE_SCALAR;
  indices.count = 3 * nf;
  model.accessors = {positions, indices};

  tinygltf::Primitive primitive;
  primitive.attributes["POSITION"] = 0;
  primitive.indices = 1;
  primitive.mode = TINYGLTF_MODE_TRIANGLES;
  tinygltf::Mesh gltf_mesh;
  gltf_mesh.primitives.push_back(primitive);
  model.meshes.push_back(gltf_mesh);
  tinygltf::Node node;
  node.mesh = 0;
  model.nodes.push_back(node);
  tinygltf::Scene scene;
  scene.nodes.push_back(0);
  model.scenes.push_back(scene);
  model.defaultScene = 0;

  tinygltf::TinyGLTF writer;
  writer.SetFsCallbacks({&refuse_file_exists, &keep_path, &refuse_read, &refuse_write, nullptr});
  std::ostringstream stream;
  if (!writer.WriteGltfSceneToStream(&model, stream, /*prettyPrint=*/!binary, binary)) {
    return Error(ErrorCode::Internal, "glTF writer failed");
  }
  return stream.str();
}

// Every public entry point funnels through here so that no exception (bad_alloc from a huge
// allocation, anything thrown inside tinygltf/nlohmann) escapes the API.
template <typename F>
auto guarded(const char* what, F&& body) -> decltype(body()) {
  return guard_exceptions(what, ErrorCode::InvalidArgument, std::forward<F>(body));
}

Result<MeshData> read_any(std::string_view bytes, MeshFormat format, bool allow_files,
                          const std::string& base_dir, const ReadControl& control) {
  WorkMeter work(control);
  switch (format) {
    case MeshFormat::Obj:
      return read_obj(bytes, work);
    case MeshFormat::Off:
      return read_off(bytes, work);
    case MeshFormat::Ply:
      return read_ply(bytes, work);
    case MeshFormat::Stl:
      return read_stl(bytes, work);
    case MeshFormat::Glb:
    case MeshFormat::Gltf:
      return read_gltf(bytes, allow_files, base_dir, work);
  }
  return invalid("unknown mesh format");
}

Result<std::string> read_file(const std::filesystem::path& path) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return Error(ErrorCode::NotFound, "mesh file '" + path.string() + "' not found");
  }
  if (std::filesystem::is_directory(path, ec)) {
    return invalid("'" + path.string() + "' is a directory, not a mesh file");
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
    MD_RETURN_IF_ERROR(check_writable(mesh, float32));
    switch (format) {
      case MeshFormat::Obj:
        return write_obj(mesh);
      case MeshFormat::Off:
        return write_off(mesh);
      case MeshFormat::Ply:
        return write_ply(mesh);
      case MeshFormat::Stl:
        return write_stl(mesh);
      case MeshFormat::Glb:
        return write_gltf(mesh, /*binary=*/true);
      case MeshFormat::Gltf:
        return write_gltf(mesh, /*binary=*/false);
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
