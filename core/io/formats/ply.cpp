#include "core/io/formats/formats.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <bit>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace meshdeform::io::detail {

namespace {

static_assert(std::endian::native == std::endian::little ||
              std::endian::native == std::endian::big);

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

}  // namespace

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

std::string write_ply(const MeshData& mesh) {
  std::string out =
      "ply\nformat ascii 1.0\ncomment meshdeform\nelement vertex " + std::to_string(mesh.V.rows()) +
      "\nproperty double x\nproperty double y\nproperty double z\nelement face " +
      std::to_string(mesh.F.rows()) + "\nproperty list uchar int vertex_indices\nend_header\n";
  append_vertex_and_face_lines(out, mesh);
  return out;
}

}  // namespace meshdeform::io::detail
