#include "core/io/deform_spec.h"

#include "core/io/json_depth.h"
#include "core/methods/similarity.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <exception>
#include <fstream>
#include <initializer_list>
#include <iterator>
#include <limits>
#include <new>
#include <nlohmann/json.hpp>
#include <numbers>
#include <system_error>
#include <utility>

namespace meshdeform::io {
namespace {

using json = nlohmann::json;

Status invalid(std::string message) {
  return Error(ErrorCode::InvalidArgument, std::move(message));
}

std::string number_text(double v) {
  std::array<char, 32> buf{};
  const auto [ptr, ec] = std::to_chars(buf.data(), buf.data() + buf.size(), v);
  return ec == std::errc() ? std::string(buf.data(), ptr) : std::string("?");
}

std::string short_token(std::string_view token) {
  constexpr std::size_t kMax = 40;
  std::string out = "'";
  for (const char c : token.substr(0, kMax)) out += (c >= 0x20 && c < 0x7f) ? c : '?';
  if (token.size() > kMax) out += "...";
  return out + "'";
}

Result<std::string> read_text(const std::filesystem::path& path, const char* what) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return Error(ErrorCode::NotFound,
                 std::string(what) + " file '" + path.string() + "' not found");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error(ErrorCode::Internal, "cannot open '" + path.string() + "' for reading");
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) return Error(ErrorCode::Internal, "error while reading '" + path.string() + "'");
  return text;
}

Status write_text(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return Error(ErrorCode::Internal, "cannot open '" + path.string() + "' for writing");
  out.write(text.data(), static_cast<std::streamsize>(text.size()));
  out.close();
  if (!out) return Error(ErrorCode::Internal, "error while writing '" + path.string() + "'");
  return Status::success();
}

template <typename T>
Result<T> with_path(Result<T> result, const std::filesystem::path& path) {
  if (result.ok()) return result;
  return Error(result.status().code(), path.string() + ": " + result.status().message());
}

// Calls `visit(token, line_number)` for every whitespace-separated token outside '#' lines.
template <typename Visit>
Status for_each_token(std::string_view text, WorkMeter& work, Visit&& visit) {
  std::size_t pos = 0;
  int line_number = 0;
  while (pos < text.size()) {
    MD_RETURN_IF_ERROR(work.step());
    const std::size_t end = std::min(text.find('\n', pos), text.size());
    std::string_view line = text.substr(pos, end - pos);
    pos = end + 1;
    ++line_number;
    const std::size_t first = line.find_first_not_of(" \t\r\f\v");
    if (first == std::string_view::npos || line[first] == '#') continue;
    std::size_t i = first;
    while (i < line.size()) {
      while (i < line.size() &&
             std::string_view(" \t\r\f\v").find(line[i]) != std::string_view::npos)
        ++i;
      const std::size_t start = i;
      while (i < line.size() &&
             std::string_view(" \t\r\f\v").find(line[i]) == std::string_view::npos)
        ++i;
      if (i > start) {
        MD_RETURN_IF_ERROR(work.step());
        MD_RETURN_IF_ERROR(visit(line.substr(start, i - start), line_number));
      }
    }
  }
  return Status::success();
}

// ---------------------------------------------------------------------------------------------
// JSON helpers: every error names the key path ("handles[1].rotation.axis").

Status check_keys(const json& object, std::initializer_list<std::string_view> allowed,
                  const std::string& where) {
  for (auto it = object.begin(); it != object.end(); ++it) {
    if (std::find(allowed.begin(), allowed.end(), it.key()) == allowed.end()) {
      return invalid(where + (where.empty() ? "" : ": ") + "unknown key '" + it.key() + "'");
    }
  }
  return Status::success();
}

Result<double> to_number(const json& value, const std::string& where) {
  if (!value.is_number()) return invalid(where + ": expected a number, got " + value.dump());
  const double v = value.get<double>();
  if (!std::isfinite(v)) return invalid(where + ": number is not finite");
  return v;
}

Result<int> to_int(const json& value, const std::string& where) {
  if (!value.is_number_integer())
    return invalid(where + ": expected an integer, got " + value.dump());
  if (value.is_number_unsigned()) {
    const auto v = value.get<std::uint64_t>();
    if (v > static_cast<std::uint64_t>(std::numeric_limits<int>::max())) {
      return invalid(where + ": " + std::to_string(v) + " does not fit in int");
    }
    return static_cast<int>(v);
  }
  const auto v = value.get<std::int64_t>();
  if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max()) {
    return invalid(where + ": " + std::to_string(v) + " does not fit in int");
  }
  return static_cast<int>(v);
}

Result<std::vector<double>> to_numbers(const json& value, std::size_t expected,
                                       const std::string& where) {
  if (!value.is_array() || value.size() != expected) {
    return invalid(where + ": expected an array of " + std::to_string(expected) + " numbers, got " +
                   (value.is_array() ? std::to_string(value.size()) + " entries" : value.dump()));
  }
  std::vector<double> out;
  for (std::size_t i = 0; i < value.size(); ++i) {
    MD_ASSIGN_OR_RETURN(const double v, to_number(value[i], where + "[" + std::to_string(i) + "]"));
    out.push_back(v);
  }
  return out;
}

Result<Eigen::Vector3d> to_vec3(const json& value, const std::string& where) {
  MD_ASSIGN_OR_RETURN(const std::vector<double> v, to_numbers(value, 3, where));
  return Eigen::Vector3d(v[0], v[1], v[2]);
}

Result<std::vector<int>> to_indices(const json& value, const std::string& where) {
  if (!value.is_array()) return invalid(where + ": expected an array of vertex indices");
  std::vector<int> out;
  out.reserve(value.size());
  for (std::size_t i = 0; i < value.size(); ++i) {
    MD_ASSIGN_OR_RETURN(const int v, to_int(value[i], where + "[" + std::to_string(i) + "]"));
    out.push_back(v);
  }
  return out;
}

Result<HandleMotion> parse_motion(const json& value, const std::string& where) {
  if (!value.is_object()) return invalid(where + ": expected an object");
  MD_RETURN_IF_ERROR(check_keys(
      value,
      {"vertices", "translation", "rotation", "quaternion", "scale", "pivot", "matrix", "targets"},
      where));
  HandleMotion group;
  if (!value.contains("vertices")) return invalid(where + ": missing 'vertices'");
  MD_ASSIGN_OR_RETURN(group.vertices, to_indices(value["vertices"], where + ".vertices"));
  if (group.vertices.empty()) return invalid(where + ".vertices: is empty");

  const bool rigid = value.contains("translation") || value.contains("rotation") ||
                     value.contains("quaternion") || value.contains("scale") ||
                     value.contains("pivot");
  const int forms = static_cast<int>(rigid) + static_cast<int>(value.contains("matrix")) +
                    static_cast<int>(value.contains("targets"));
  if (forms == 0) return invalid(where + ": needs one of 'translation', 'matrix' or 'targets'");
  if (forms > 1) {
    return invalid(where +
                   ": give exactly one of 'translation' (with rotation/scale/pivot), "
                   "'matrix' or 'targets'");
  }
  if (value.contains("matrix")) {
    group.form = HandleForm::Matrix;
    MD_ASSIGN_OR_RETURN(const std::vector<double> m,
                        to_numbers(value["matrix"], 16, where + ".matrix"));
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) group.matrix(r, c) = m[static_cast<std::size_t>(4 * r + c)];
    }
    return group;
  }
  if (value.contains("targets")) {
    group.form = HandleForm::Targets;
    const json& targets = value["targets"];
    if (!targets.is_array()) return invalid(where + ".targets: expected an array of [x, y, z]");
    if (targets.size() != group.vertices.size()) {
      return invalid(where + ".targets: expected " + std::to_string(group.vertices.size()) +
                     " targets (one per vertex), got " + std::to_string(targets.size()));
    }
    group.targets.resize(static_cast<Eigen::Index>(targets.size()), 3);
    for (std::size_t i = 0; i < targets.size(); ++i) {
      MD_ASSIGN_OR_RETURN(const Eigen::Vector3d t,
                          to_vec3(targets[i], where + ".targets[" + std::to_string(i) + "]"));
      group.targets.row(static_cast<Eigen::Index>(i)) = t.transpose();
    }
    return group;
  }
  group.form = HandleForm::Rigid;
  if (value.contains("translation")) {
    MD_ASSIGN_OR_RETURN(group.translation, to_vec3(value["translation"], where + ".translation"));
  }
  if (value.contains("rotation") && value.contains("quaternion")) {
    return invalid(where + ": give either 'rotation' or 'quaternion', not both");
  }
  if (value.contains("rotation")) {
    const json& rotation = value["rotation"];
    const std::string rwhere = where + ".rotation";
    if (!rotation.is_object())
      return invalid(rwhere + ": expected {\"axis\": [x, y, z], \"angle_deg\": a}");
    MD_RETURN_IF_ERROR(check_keys(rotation, {"axis", "angle_deg"}, rwhere));
    if (!rotation.contains("axis") || !rotation.contains("angle_deg")) {
      return invalid(rwhere + ": needs both 'axis' and 'angle_deg'");
    }
    AxisAngle axis_angle;
    MD_ASSIGN_OR_RETURN(axis_angle.axis, to_vec3(rotation["axis"], rwhere + ".axis"));
    if (axis_angle.axis.norm() == 0.0) return invalid(rwhere + ".axis: must not be zero");
    MD_ASSIGN_OR_RETURN(axis_angle.angle_deg,
                        to_number(rotation["angle_deg"], rwhere + ".angle_deg"));
    group.rotation = axis_angle;
  }
  if (value.contains("quaternion")) {
    MD_ASSIGN_OR_RETURN(const std::vector<double> q,
                        to_numbers(value["quaternion"], 4, where + ".quaternion"));
    const Eigen::Vector4d quaternion(q[0], q[1], q[2], q[3]);
    if (quaternion.norm() == 0.0) return invalid(where + ".quaternion: must not be zero");
    group.quaternion = quaternion;
  }
  if (value.contains("scale")) {
    MD_ASSIGN_OR_RETURN(group.scale, to_number(value["scale"], where + ".scale"));
  }
  if (value.contains("pivot")) {
    MD_ASSIGN_OR_RETURN(const Eigen::Vector3d pivot, to_vec3(value["pivot"], where + ".pivot"));
    group.pivot = pivot;
  }
  return group;
}

Result<EditSpec> parse_spec_json(const json& root) {
  if (!root.is_object()) return invalid("edit spec: expected a JSON object at the top level");
  MD_RETURN_IF_ERROR(check_keys(root, {"fixed", "handles", "magnify", "options"}, "edit spec"));
  EditSpec spec;
  if (root.contains("fixed")) {
    MD_ASSIGN_OR_RETURN(spec.fixed, to_indices(root["fixed"], "fixed"));
  }
  if (root.contains("handles")) {
    const json& handles = root["handles"];
    if (!handles.is_array()) return invalid("handles: expected an array of handle groups");
    for (std::size_t k = 0; k < handles.size(); ++k) {
      MD_ASSIGN_OR_RETURN(HandleMotion group,
                          parse_motion(handles[k], "handles[" + std::to_string(k) + "]"));
      spec.handles.push_back(std::move(group));
    }
  }
  if (root.contains("magnify")) {
    const json& magnify = root["magnify"];
    if (!magnify.is_array()) return invalid("magnify: expected an array of regions");
    for (std::size_t k = 0; k < magnify.size(); ++k) {
      const std::string where = "magnify[" + std::to_string(k) + "]";
      const json& region = magnify[k];
      if (!region.is_object()) return invalid(where + ": expected an object");
      MD_RETURN_IF_ERROR(check_keys(region, {"vertices", "scale"}, where));
      if (!region.contains("vertices") || !region.contains("scale")) {
        return invalid(where + ": needs 'vertices' and 'scale'");
      }
      MagnifySpec m;
      MD_ASSIGN_OR_RETURN(m.vertices, to_indices(region["vertices"], where + ".vertices"));
      if (m.vertices.empty()) return invalid(where + ".vertices: must not be empty");
      MD_ASSIGN_OR_RETURN(m.scale, to_number(region["scale"], where + ".scale"));
      if (!(m.scale > 0.0)) {
        return invalid(where + ".scale: must be > 0, got " + number_text(m.scale));
      }
      spec.magnify.push_back(std::move(m));
    }
  }
  if (root.contains("options")) {
    const json& options = root["options"];
    if (!options.is_object()) return invalid("options: expected an object");
    MD_RETURN_IF_ERROR(check_keys(
        options, {"iterations", "tolerance", "inner_iterations", "method", "ora", "rigidity"},
        "options"));
    if (options.contains("method")) {
      if (!options["method"].is_string()) return invalid("options.method: expected a string");
      spec.options.method = options["method"].get<std::string>();
    }
    if (options.contains("ora")) {
      if (!options["ora"].is_boolean()) return invalid("options.ora: expected true or false");
      spec.options.ora = options["ora"].get<bool>();
    }
    if (options.contains("iterations")) {
      MD_ASSIGN_OR_RETURN(const int n, to_int(options["iterations"], "options.iterations"));
      if (n < 1) return invalid("options.iterations: must be >= 1, got " + std::to_string(n));
      spec.options.iterations = n;
    }
    if (options.contains("inner_iterations")) {
      MD_ASSIGN_OR_RETURN(const int n,
                          to_int(options["inner_iterations"], "options.inner_iterations"));
      if (n < 1) return invalid("options.inner_iterations: must be >= 1, got " + std::to_string(n));
      spec.options.inner_iterations = n;
    }
    if (options.contains("rigidity")) {
      MD_ASSIGN_OR_RETURN(const double rigidity, to_number(options["rigidity"], "options.rigidity"));
      if (!(rigidity >= 0.0)) {
        return invalid("options.rigidity: must be >= 0, got " + number_text(rigidity));
      }
      spec.options.rigidity = rigidity;
    }
    if (options.contains("tolerance")) {
      MD_ASSIGN_OR_RETURN(const double tol, to_number(options["tolerance"], "options.tolerance"));
      if (!(tol > 0.0)) return invalid("options.tolerance: must be > 0, got " + number_text(tol));
      spec.options.tolerance = tol;
    }
  }
  return spec;
}

Status check_finite_json(const json& value, const std::string& where) {
  if (value.is_number_float() && !std::isfinite(value.get<double>())) {
    return invalid(where + ": number is not finite");
  }
  if (value.is_array()) {
    for (std::size_t i = 0; i < value.size(); ++i) {
      MD_RETURN_IF_ERROR(check_finite_json(value[i], where + "[" + std::to_string(i) + "]"));
    }
  }
  if (value.is_object()) {
    for (auto it = value.begin(); it != value.end(); ++it) {
      MD_RETURN_IF_ERROR(check_finite_json(it.value(), where + "." + it.key()));
    }
  }
  return Status::success();
}

json vec_json(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

std::string group_name(int group) {
  return group == -1 ? std::string("fixed") : "handles[" + std::to_string(group) + "]";
}

// Targets of one handle motion, row i for vertices[i] (indices already range-checked).
Result<Positions> motion_targets(const HandleMotion& group, const Positions& V,
                                 const std::string& where) {
  const auto n = static_cast<Eigen::Index>(group.vertices.size());
  Positions rest(n, 3);
  for (Eigen::Index i = 0; i < n; ++i)
    rest.row(i) = V.row(group.vertices[static_cast<std::size_t>(i)]);
  Positions out(n, 3);
  switch (group.form) {
    case HandleForm::Rigid: {
      Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
      if (group.rotation && group.quaternion) {
        return invalid(where + ": give either 'rotation' or 'quaternion', not both");
      }
      if (group.rotation) {
        const double norm = group.rotation->axis.norm();
        if (!(norm > 0.0) || !std::isfinite(norm))
          return invalid(where + ".rotation.axis: must be non-zero and finite");
        if (!std::isfinite(group.rotation->angle_deg))
          return invalid(where + ".rotation.angle_deg: is not finite");
        R = Eigen::AngleAxisd(group.rotation->angle_deg * std::numbers::pi / 180.0,
                              group.rotation->axis / norm)
                .toRotationMatrix();
      }
      if (group.quaternion) {
        const Eigen::Vector4d& q = *group.quaternion;
        if (!(q.norm() > 0.0) || !q.allFinite())
          return invalid(where + ".quaternion: must be non-zero and finite");
        R = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized().toRotationMatrix();
      }
      if (!std::isfinite(group.scale)) return invalid(where + ".scale: is not finite");
      if (!group.translation.allFinite()) return invalid(where + ".translation: is not finite");
      core::GroupSimilarity transform;
      transform.rotation = R;
      transform.scale = group.scale;
      transform.translation = group.translation;
      transform.pivot = group.pivot;
      if (!core::similarity_pivot(transform, rest).allFinite()) {
        return invalid(where + ".pivot: is not finite");
      }
      out = core::apply_similarity(transform, rest);
      break;
    }
    case HandleForm::Matrix: {
      if (!group.matrix.allFinite()) return invalid(where + ".matrix: is not finite");
      if (group.matrix.row(3) != Eigen::RowVector4d(0.0, 0.0, 0.0, 1.0)) {
        return invalid(where + ".matrix: last row must be [0, 0, 0, 1] (affine), got [" +
                       number_text(group.matrix(3, 0)) + ", " + number_text(group.matrix(3, 1)) +
                       ", " + number_text(group.matrix(3, 2)) + ", " +
                       number_text(group.matrix(3, 3)) + "]");
      }
      const Eigen::Matrix3d A = group.matrix.topLeftCorner<3, 3>();
      const Eigen::Vector3d b = group.matrix.topRightCorner<3, 1>();
      for (Eigen::Index i = 0; i < n; ++i)
        out.row(i) = (A * rest.row(i).transpose() + b).transpose();
      break;
    }
    case HandleForm::Targets: {
      if (group.targets.rows() != n) {
        return invalid(where + ".targets: expected " + std::to_string(n) +
                       " targets (one per vertex), got " + std::to_string(group.targets.rows()));
      }
      out = group.targets;
      break;
    }
  }
  for (Eigen::Index i = 0; i < n; ++i) {
    if (!out.row(i).allFinite()) {
      return invalid(where + ": target of vertex " +
                     std::to_string(group.vertices[static_cast<std::size_t>(i)]) +
                     " is not finite");
    }
  }
  return out;
}

template <typename F>
auto guarded(const char* what, F&& body) -> decltype(body()) {
  return guard_exceptions(what, ErrorCode::Internal, std::forward<F>(body));
}

}  // namespace

// ------------------------------------------------------------------------------------------ .sel

Result<Eigen::VectorXi> parse_sel(std::string_view text, int expected_vertex_count,
                                  const ReadControl& control) {
  return guarded("parsing .sel", [&]() -> Result<Eigen::VectorXi> {
    WorkMeter work(control);
    std::vector<int> values;
    // Every entry takes at least one byte and a separator: reserve no more than the text holds.
    if (expected_vertex_count > 0) {
      values.reserve(std::min(static_cast<std::size_t>(expected_vertex_count), text.size() / 2 + 1));
    }
    MD_RETURN_IF_ERROR(for_each_token(text, work, [&](std::string_view token, int line) -> Status {
      int value = -1;
      const auto [ptr, ec] = std::from_chars(token.data(), token.data() + token.size(), value);
      if (ec != std::errc() || ptr != token.data() + token.size() || value < 0 || value > 2) {
        return invalid(".sel line " + std::to_string(line) + ": value " + short_token(token) +
                       " (vertex " + std::to_string(values.size()) +
                       ") is not 0 (fixed), 1 (free) or 2 (handle)");
      }
      values.push_back(value);
      return Status::success();
    }));
    if (expected_vertex_count >= 0 &&
        values.size() != static_cast<std::size_t>(expected_vertex_count)) {
      return invalid(".sel has " + std::to_string(values.size()) + " entries but the mesh has " +
                     std::to_string(expected_vertex_count) + " vertices");
    }
    return Eigen::VectorXi(
        Eigen::Map<const Eigen::VectorXi>(values.data(), static_cast<Eigen::Index>(values.size())));
  });
}

Result<Eigen::VectorXi> read_sel(const std::filesystem::path& path, int expected_vertex_count) {
  MD_ASSIGN_OR_RETURN(const std::string text, read_text(path, ".sel"));
  return with_path(parse_sel(text, expected_vertex_count), path);
}

Result<std::string> format_sel(const Eigen::VectorXi& selection) {
  return guarded("formatting .sel", [&]() -> Result<std::string> {
    std::string out = "# meshdeform selection: 0 fixed, 1 free, 2 handle (" +
                      std::to_string(selection.size()) + " vertices)\n";
    out.reserve(out.size() + 2 * static_cast<std::size_t>(selection.size()));
    for (Eigen::Index i = 0; i < selection.size(); ++i) {
      if (selection[i] < 0 || selection[i] > 2) {
        return invalid("selection of vertex " + std::to_string(i) + " is " +
                       std::to_string(selection[i]) + ", not 0 (fixed), 1 (free) or 2 (handle)");
      }
      out += static_cast<char>('0' + selection[i]);
      out += '\n';
    }
    return out;
  });
}

Status write_sel(const std::filesystem::path& path, const Eigen::VectorXi& selection) {
  MD_ASSIGN_OR_RETURN(const std::string text, format_sel(selection));
  return write_text(path, text);
}

// ------------------------------------------------------------------------------------------ .def

Result<Eigen::Matrix4d> parse_def(std::string_view text, const ReadControl& control) {
  return guarded("parsing .def", [&]() -> Result<Eigen::Matrix4d> {
    WorkMeter work(control);
    std::vector<double> values;
    MD_RETURN_IF_ERROR(for_each_token(text, work, [&](std::string_view token, int line) -> Status {
      std::string_view digits = token;
      if (!digits.empty() && digits.front() == '+') digits.remove_prefix(1);
      double value = 0.0;
      const auto [ptr, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
      if (digits.empty() || ec != std::errc() || ptr != digits.data() + digits.size()) {
        return invalid(".def line " + std::to_string(line) + ": " + short_token(token) +
                       " is not a number");
      }
      if (!std::isfinite(value)) {
        return invalid(".def line " + std::to_string(line) + ": " + short_token(token) +
                       " is not finite");
      }
      if (values.size() == 16) {
        return invalid(".def line " + std::to_string(line) +
                       ": more than 16 numbers (extra value " + short_token(token) + ")");
      }
      values.push_back(value);
      return Status::success();
    }));
    if (values.size() != 16) {
      return invalid(".def must hold 16 numbers (a row-major 4x4 matrix), got " +
                     std::to_string(values.size()));
    }
    Eigen::Matrix4d T;
    for (int r = 0; r < 4; ++r) {
      for (int c = 0; c < 4; ++c) T(r, c) = values[static_cast<std::size_t>(4 * r + c)];
    }
    return T;
  });
}

Result<Eigen::Matrix4d> read_def(const std::filesystem::path& path) {
  MD_ASSIGN_OR_RETURN(const std::string text, read_text(path, ".def"));
  return with_path(parse_def(text), path);
}

Result<std::string> format_def(const Eigen::Matrix4d& transform) {
  if (!transform.allFinite()) return invalid(".def transform has a non-finite entry");
  std::string out = "# meshdeform handle transform (row-major 4x4, x' = T * [x; 1])\n";
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      out += number_text(transform(r, c));
      out += c == 3 ? '\n' : ' ';
    }
  }
  return out;
}

Status write_def(const std::filesystem::path& path, const Eigen::Matrix4d& transform) {
  MD_ASSIGN_OR_RETURN(const std::string text, format_def(transform));
  return write_text(path, text);
}

// ------------------------------------------------------------------------------------ JSON spec

Result<EditSpec> parse_edit_spec(std::string_view json_text, const ReadControl& control) {
  return guarded("parsing edit spec", [&]() -> Result<EditSpec> {
    WorkMeter work(control);
    // The scan, the parse and the walks below are each linear in the text.
    MD_RETURN_IF_ERROR(work.step(json_text.size() / 16 + 1));
    // check_finite_json and nlohmann's destructor walk the tree recursively: refuse deep nesting
    // before parsing (a few MB of '[' would otherwise overflow the stack).
    if (json_nesting_depth(json_text, kMaxJsonDepth) > kMaxJsonDepth) {
      return invalid("edit spec nests arrays/objects deeper than " +
                     std::to_string(kMaxJsonDepth) + " levels");
    }
    json root;
    try {
      root =
          json::parse(json_text.begin(), json_text.end(), /*cb=*/nullptr, /*allow_exceptions=*/true,
                      /*ignore_comments=*/true);
    } catch (const json::exception& e) {
      return invalid(std::string("edit spec is not valid JSON: ") + e.what());
    }
    MD_RETURN_IF_ERROR(work.poll());
    MD_RETURN_IF_ERROR(check_finite_json(root, "edit spec"));
    return parse_spec_json(root);
  });
}

Result<EditSpec> read_edit_spec(const std::filesystem::path& path) {
  MD_ASSIGN_OR_RETURN(const std::string text, read_text(path, "edit spec"));
  return with_path(parse_edit_spec(text), path);
}

Result<std::string> format_edit_spec(const EditSpec& spec) {
  return guarded("formatting edit spec", [&]() -> Result<std::string> {
    json root = json::object();
    root["fixed"] = spec.fixed;
    json handles = json::array();
    for (std::size_t k = 0; k < spec.handles.size(); ++k) {
      const HandleMotion& group = spec.handles[k];
      const std::string where = "handles[" + std::to_string(k) + "]";
      json g = json::object();
      g["vertices"] = group.vertices;
      switch (group.form) {
        case HandleForm::Rigid:
          if (!group.translation.allFinite() || !std::isfinite(group.scale)) {
            return invalid(where + ": translation or scale is not finite");
          }
          g["translation"] = vec_json(group.translation);
          if (group.rotation) {
            if (!group.rotation->axis.allFinite() || !std::isfinite(group.rotation->angle_deg)) {
              return invalid(where + ".rotation: is not finite");
            }
            g["rotation"] = {{"axis", vec_json(group.rotation->axis)},
                             {"angle_deg", group.rotation->angle_deg}};
          }
          if (group.quaternion) {
            if (!group.quaternion->allFinite())
              return invalid(where + ".quaternion: is not finite");
            const Eigen::Vector4d& q = *group.quaternion;
            g["quaternion"] = json::array({q[0], q[1], q[2], q[3]});
          }
          if (group.scale != 1.0) g["scale"] = group.scale;
          if (group.pivot) {
            if (!group.pivot->allFinite()) return invalid(where + ".pivot: is not finite");
            g["pivot"] = vec_json(*group.pivot);
          }
          break;
        case HandleForm::Matrix: {
          if (!group.matrix.allFinite()) return invalid(where + ".matrix: is not finite");
          json m = json::array();
          for (int r = 0; r < 4; ++r) {
            for (int c = 0; c < 4; ++c) m.push_back(group.matrix(r, c));
          }
          g["matrix"] = m;
          break;
        }
        case HandleForm::Targets: {
          if (!group.targets.allFinite()) return invalid(where + ".targets: is not finite");
          json t = json::array();
          for (Eigen::Index i = 0; i < group.targets.rows(); ++i) {
            t.push_back(
                json::array({group.targets(i, 0), group.targets(i, 1), group.targets(i, 2)}));
          }
          g["targets"] = t;
          break;
        }
      }
      handles.push_back(g);
    }
    root["handles"] = handles;
    json options = json::object();
    if (spec.options.iterations) options["iterations"] = *spec.options.iterations;
    if (spec.options.tolerance) {
      if (!std::isfinite(*spec.options.tolerance))
        return invalid("options.tolerance: is not finite");
      options["tolerance"] = *spec.options.tolerance;
    }
    if (spec.options.inner_iterations) options["inner_iterations"] = *spec.options.inner_iterations;
    if (spec.options.method) options["method"] = *spec.options.method;
    if (spec.options.ora) options["ora"] = *spec.options.ora;
    if (spec.options.rigidity) {
      if (!std::isfinite(*spec.options.rigidity))
        return invalid("options.rigidity: is not finite");
      options["rigidity"] = *spec.options.rigidity;
    }
    if (!options.empty()) root["options"] = options;
    if (!spec.magnify.empty()) {
      json magnify = json::array();
      for (const MagnifySpec& m : spec.magnify) {
        if (!(m.scale > 0.0) || !std::isfinite(m.scale)) {
          return invalid("magnify: scale must be positive and finite");
        }
        magnify.push_back({{"vertices", m.vertices}, {"scale", m.scale}});
      }
      root["magnify"] = magnify;
    }
    return root.dump(2) + "\n";
  });
}

Status write_edit_spec(const std::filesystem::path& path, const EditSpec& spec) {
  MD_ASSIGN_OR_RETURN(const std::string text, format_edit_spec(spec));
  return write_text(path, text);
}

Result<core::HandleSetup> resolve_edit(const EditSpec& spec, const Positions& V) {
  return guarded("resolving edit spec", [&]() -> Result<core::HandleSetup> {
    const Eigen::Index nv = V.rows();
    constexpr int kFree = -2;
    constexpr int kFixed = -1;
    std::vector<int> owner(static_cast<std::size_t>(nv), kFree);
    Positions target(nv, 3);

    auto check_index = [&](int v, const std::string& where) -> Status {
      if (v < 0 || v >= nv) {
        return invalid(where + ": vertex " + std::to_string(v) +
                       " is out of range (#V=" + std::to_string(nv) + ")");
      }
      return Status::success();
    };
    auto claim = [&](int v, int group) -> Status {
      int& current = owner[static_cast<std::size_t>(v)];
      if (current != kFree && current != group) {
        return invalid("vertex " + std::to_string(v) + " is in both " + group_name(current) +
                       " and " + group_name(group));
      }
      current = group;
      return Status::success();
    };

    for (std::size_t i = 0; i < spec.fixed.size(); ++i) {
      const int v = spec.fixed[i];
      MD_RETURN_IF_ERROR(check_index(v, "fixed[" + std::to_string(i) + "]"));
      MD_RETURN_IF_ERROR(claim(v, kFixed));
      target.row(v) = V.row(v);
    }
    for (std::size_t k = 0; k < spec.handles.size(); ++k) {
      const HandleMotion& group = spec.handles[k];
      const std::string where = "handles[" + std::to_string(k) + "]";
      if (group.vertices.empty()) return invalid(where + ".vertices: is empty");
      for (std::size_t i = 0; i < group.vertices.size(); ++i) {
        MD_RETURN_IF_ERROR(
            check_index(group.vertices[i], where + ".vertices[" + std::to_string(i) + "]"));
      }
      MD_ASSIGN_OR_RETURN(const Positions targets, motion_targets(group, V, where));
      for (std::size_t i = 0; i < group.vertices.size(); ++i) {
        const int v = group.vertices[i];
        const bool seen = owner[static_cast<std::size_t>(v)] == static_cast<int>(k);
        MD_RETURN_IF_ERROR(claim(v, static_cast<int>(k)));
        const auto row = static_cast<Eigen::Index>(i);
        if (seen && target.row(v) != targets.row(row)) {
          return invalid(where + ": vertex " + std::to_string(v) +
                         " is listed twice with different targets");
        }
        target.row(v) = targets.row(row);
      }
    }

    core::HandleSetup setup;
    const auto count = static_cast<Eigen::Index>(
        std::count_if(owner.begin(), owner.end(), [](int o) { return o != kFree; }));
    if (count == 0)
      return invalid("edit spec constrains no vertices ('fixed' and 'handles' are empty)");
    setup.constrained.resize(count);
    setup.targets.resize(count, 3);
    Eigen::Index c = 0;
    for (Eigen::Index v = 0; v < nv; ++v) {
      if (owner[static_cast<std::size_t>(v)] == kFree) continue;
      setup.constrained[c] = static_cast<int>(v);
      setup.targets.row(c) = target.row(v);
      ++c;
    }
    return setup;
  });
}

}  // namespace meshdeform::io
