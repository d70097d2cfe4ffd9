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

// STL: binary when the size matches 84 + 50 * count (some binary files also start with "solid"),
// ASCII when it starts with "solid". Vertices are not merged here: the reader returns the soup,
// and load_mesh welds exactly equal positions.



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

}  // namespace

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

}  // namespace meshdeform::io::detail
