#pragma once
/// @file deform_spec.h
/// Deformation inputs: the Botsch & Sorkine 2008 benchmark files (.sel per-vertex roles, .def
/// handle transform) and a JSON edit spec with several handle groups.
///
/// [Botsch & Sorkine 2008] "On Linear Variational Surface Deformation Methods", IEEE TVCG 14(1).
///
/// JSON edit spec (every key optional unless noted; unknown keys are errors so typos surface):
/// @code{.json}
/// {
///   "fixed": [0, 1, 2],
///   "handles": [
///     { "vertices": [10, 11],                       // required, non-empty
///       "translation": [0, 0, 1],                   // rigid form: target = pivot + t +
///       "rotation": {"axis": [0, 0, 1], "angle_deg": 90},  //   R * (s * (rest - pivot))
///       "scale": 1.0,                               //   (or "quaternion": [w, x, y, z])
///       "pivot": [0, 0, 0] },                       //   default: centroid of the rest vertices
///     { "vertices": [20], "matrix": [16 numbers, row-major affine, last row 0 0 0 1] },
///     { "vertices": [30, 31], "targets": [[x, y, z], [x, y, z]] }   // one per vertex
///   ],
///   "magnify": [ { "vertices": [40, 41, 42], "scale": 2.0 } ],   // regions grown by k
///   "options": { "iterations": 10, "tolerance": 1e-6, "inner_iterations": 5,
///                "method": "scale_aware" | "arap" | "laplacian", "ora": true,
///                "rigidity": 1.0 }
/// }
/// @endcode
/// A handle group uses exactly one of the three forms; the rigid form is chosen by any of
/// "translation", "rotation", "quaternion", "scale", "pivot" (missing parts are identity).

#include <Eigen/Core>
#include <filesystem>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/io/read_control.h"
#include "core/mesh/mesh_data.h"
#include "core/samples/samples.h"
#include "core/base/status.h"

namespace meshdeform::io {

// ----------------------------------------------------------------------------------- .sel files

/// Parses a .sel selection: '#' comment lines, then one role per vertex (0 fixed, 1 free,
/// 2 handle), separated by any whitespace.
/// @param[in] text                   file contents.
/// @param[in] expected_vertex_count  #V of the mesh; a negative value accepts any count.
/// @param[in] control                stop token and work counter (work is linear in the text).
/// @return #V roles; InvalidArgument naming the line and value of a non-integer or a value outside
///         {0, 1, 2}, or stating both counts when the number of entries differs from #V;
///         Cancelled when control.stop is requested.
[[nodiscard]] Result<Eigen::VectorXi> parse_sel(std::string_view text, int expected_vertex_count,
                                               const ReadControl& control = {});

/// Reads a .sel file (see parse_sel).
/// @return the roles; NotFound if the file does not exist; parse_sel's errors prefixed by the path.
[[nodiscard]] Result<Eigen::VectorXi> read_sel(const std::filesystem::path& path,
                                               int expected_vertex_count);

/// Serialises a selection: a '#' header line, then one value per line.
/// @return the text; InvalidArgument naming the first vertex whose value is outside {0, 1, 2}.
[[nodiscard]] Result<std::string> format_sel(const Eigen::VectorXi& selection);

/// Writes a .sel file (see format_sel).
/// @return success; format_sel's errors; Internal if the file cannot be written.
[[nodiscard]] Status write_sel(const std::filesystem::path& path, const Eigen::VectorXi& selection);

// ----------------------------------------------------------------------------------- .def files

/// Parses a .def transform: '#' comment lines, then 16 numbers forming a row-major 4x4 matrix
/// (x' = T * [x; 1]) applied to every handle vertex.
/// @param[in] control  stop token and work counter (work is linear in the text).
/// @return the matrix; InvalidArgument naming the line and token of a non-number or non-finite
///         value, or stating the count when there are not exactly 16 numbers; Cancelled when
///         control.stop is requested.
[[nodiscard]] Result<Eigen::Matrix4d> parse_def(std::string_view text,
                                               const ReadControl& control = {});

/// Reads a .def file (see parse_def).
/// @return the matrix; NotFound if the file does not exist; parse_def's errors prefixed by the
/// path.
[[nodiscard]] Result<Eigen::Matrix4d> read_def(const std::filesystem::path& path);

/// Serialises a transform: a '#' header line and four rows, full double precision.
/// @return the text; InvalidArgument if an entry is not finite.
[[nodiscard]] Result<std::string> format_def(const Eigen::Matrix4d& transform);

/// Writes a .def file (see format_def).
/// @return success; format_def's errors; Internal if the file cannot be written.
[[nodiscard]] Status write_def(const std::filesystem::path& path, const Eigen::Matrix4d& transform);

// ----------------------------------------------------------------------------- JSON edit spec

/// Rotation of a rigid handle group.
struct AxisAngle {
  Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();  ///< non-zero; normalised when applied
  double angle_deg = 0.0;                           ///< right-handed about axis, in degrees
};

/// How a handle group's targets are given.
enum class HandleForm {
  Rigid,    ///< translation / rotation / scale about a pivot
  Matrix,   ///< 4x4 affine matrix applied to the rest positions
  Targets,  ///< one explicit target per vertex
};

/// A motion of handle vertices from the edit spec: which vertices (one entry of "handles") and
/// how they move together (a rigid transform, a matrix, or explicit targets).
struct HandleMotion {
  std::vector<int> vertices;  ///< indices into V (non-empty)
  HandleForm form = HandleForm::Rigid;
  // Rigid form: target = pivot + translation + R * (scale * (rest - pivot)).
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();
  std::optional<AxisAngle> rotation;          ///< at most one of rotation / quaternion
  std::optional<Eigen::Vector4d> quaternion;  ///< (w, x, y, z), non-zero; normalised when applied
  double scale = 1.0;
  std::optional<Eigen::Vector3d> pivot;  ///< default: centroid of the rest vertices
  // Matrix form: row-major meaning, target = matrix * [rest; 1]; last row must be 0 0 0 1.
  Eigen::Matrix4d matrix = Eigen::Matrix4d::Identity();
  // Targets form: #vertices x 3, row i is the target of vertices[i].
  Positions targets;
};

/// Solver options carried by the spec (absent = solver default).
struct EditOptions {
  std::optional<int> iterations;        ///< >= 1
  std::optional<double> tolerance;      ///< > 0
  std::optional<int> inner_iterations;  ///< >= 1
  std::optional<std::string> method;    ///< "scale_aware", "arap" or "laplacian" (checked by caller)
  std::optional<bool> ora;              ///< optimal rigidity approximation after the solve
  /// Scale control (core::SolveOptions::rigidity), >= 0 and finite; 0 is the paper's method.
  std::optional<double> rigidity;
};

/// A region to magnify by `scale` (paper Figs. 12-13): the faces whose three corners are listed.
struct MagnifySpec {
  std::vector<int> vertices;  ///< non-empty
  double scale = 1.0;         ///< > 0
};

/// A parsed JSON edit spec.
struct EditSpec {
  std::vector<int> fixed;            ///< vertices held at their rest position
  std::vector<HandleMotion> handles;  ///< moved groups
  std::vector<MagnifySpec> magnify;  ///< regions to magnify (empty: none)
  EditOptions options;
};

/// Parses a JSON edit spec (format in the file comment). Checks types, array lengths, finiteness
/// and option ranges; index ranges need the mesh and are checked by resolve_edit.
/// @return the spec; InvalidArgument naming the offending key path (e.g. "handles[1].translation:
///         expected 3 numbers, got 2") for malformed JSON, unknown keys, wrong types or lengths,
///         non-finite numbers, a group with zero or several forms, both rotation and quaternion,
///         or arrays/objects nested deeper than kMaxJsonDepth (refused before parsing); Cancelled
///         when control.stop is requested. Work is linear in the text (control.work_steps).
[[nodiscard]] Result<EditSpec> parse_edit_spec(std::string_view json_text,
                                              const ReadControl& control = {});

/// Reads a JSON edit spec file (see parse_edit_spec).
/// @return the spec; NotFound if the file does not exist; parse errors prefixed by the path.
[[nodiscard]] Result<EditSpec> read_edit_spec(const std::filesystem::path& path);

/// Serialises a spec to JSON text that parse_edit_spec reads back to an equal spec (doubles are
/// written with round-trip precision; only the fields of each group's form are written).
/// @return the JSON text; InvalidArgument (naming the key) if a number is not finite.
[[nodiscard]] Result<std::string> format_edit_spec(const EditSpec& spec);

/// Writes a JSON edit spec file (see format_edit_spec).
/// @return success; format_edit_spec's errors; Internal if the file cannot be written.
[[nodiscard]] Status write_edit_spec(const std::filesystem::path& path, const EditSpec& spec);

/// Turns a spec into solver constraints on a mesh.
/// @param[in] spec  the edit.
/// @param[in] V     #V x 3 rest positions.
/// @return constrained indices (ascending, unique) and their targets (fixed: rest position;
///         handles: transformed); InvalidArgument naming the key and index for an index out of
///         range, a vertex in two groups (fixed counts as a group), conflicting targets for a
///         vertex listed twice in a targets group, a mismatched targets length, an empty group,
///         a zero rotation axis/quaternion, a non-affine matrix, a non-finite value or target, or
///         no constrained vertex at all.
[[nodiscard]] Result<core::HandleSetup> resolve_edit(const EditSpec& spec, const Positions& V);

}  // namespace meshdeform::io
