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


std::uint32_t load_u32_le(const char* p) {
  std::uint32_t v = 0;
  for (int i = 3; i >= 0; --i) v = (v << 8U) | static_cast<unsigned char>(p[i]);
  return v;
}

float load_f32_le(const char* p) { return std::bit_cast<float>(load_u32_le(p)); }

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

void append_u32_le(std::string& out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i)
    out += static_cast<char>((v >> (8U * static_cast<unsigned>(i))) & 0xffU);
}
void append_f32_le(std::string& out, float v) {
  append_u32_le(out, std::bit_cast<std::uint32_t>(v));
}

void append_vertex_and_face_lines(std::string& out, const MeshData& mesh) {
  for (Eigen::Index i = 0; i < mesh.V.rows(); ++i) {
    append_xyz(out, mesh, i);
    out += '\n';
  }
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    out += "3 " + std::to_string(mesh.F(f, 0)) + ' ' + std::to_string(mesh.F(f, 1)) + ' ' +
           std::to_string(mesh.F(f, 2)) + '\n';
  }
}

}  // namespace meshdeform::io::detail
