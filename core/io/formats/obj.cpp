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

}  // namespace meshdeform::io::detail
