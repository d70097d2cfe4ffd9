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

std::string write_off(const MeshData& mesh) {
  std::string out =
      "OFF\n" + std::to_string(mesh.V.rows()) + ' ' + std::to_string(mesh.F.rows()) + " 0\n";
  append_vertex_and_face_lines(out, mesh);
  return out;
}

}  // namespace meshdeform::io::detail
