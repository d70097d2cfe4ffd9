#pragma once
/// @file wire_mapping.h
/// The one mapping between meshdeform.v1 wire values and C++ values, shared by the server's
/// transport and the C++ client (and the load tester's code names and methods): gRPC status code
/// names, Method, MeshFormat, HandleRole, Vec3, Quaternion, GroupMove, index lists and position
/// rows.
///
/// The mapping is shared; the error texts are not: a failed mapping returns nullopt (or, for the
/// enums, InvalidArgument "unknown <enum> <n>") and each side words the error for its reader (the
/// server names the request field, the client names the RPC of a malformed response). Apart from
/// those unknown values nothing here checks meaning (finiteness, ranges): the callers do.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "core/methods/deformer.h"
#include "core/methods/edit_types.h"
#include "core/io/mesh_io.h"
#include "core/mesh/mesh_data.h"
#include "core/base/status.h"
#include "meshdeform/v1/deformation.pb.h"

namespace meshdeform::wire {

// ------------------------------------------------------------------------- gRPC status codes

/// gRPC's status codes are 0 (OK) .. 16 (UNAUTHENTICATED), grpc::StatusCode's values.
inline constexpr int kGrpcCodeCount = 17;

/// The canonical upper-case name of gRPC status code `code` ("OK", "NOT_FOUND", ...).
/// @return the name; nullopt outside [0, kGrpcCodeCount) (grpc::StatusCode::DO_NOT_USE too).
std::optional<std::string_view> grpc_code_name(int code);

/// grpc_code_name(code), or "CODE_<code>" for a value without a name (client messages, reports).
std::string grpc_code_label(int code);

// --------------------------------------------------------------------------------------- enums

/// core::Method, or an enum naming the same methods (the load tester's Method) -> v1::Method.
template <typename M>
v1::Method method_to_proto(M method) {
  switch (method) {
    case M::ScaleAware:
      return v1::METHOD_SCALE_AWARE;
    case M::Arap:
      return v1::METHOD_ARAP;
    case M::Laplacian:
      return v1::METHOD_LAPLACIAN;
  }
  return v1::METHOD_UNSPECIFIED;
}
/// @return the method; nullopt for METHOD_UNSPECIFIED (whose meaning is the caller's);
///         InvalidArgument "unknown method <n>" for a value outside the enum (proto3 enums are
///         open: any int32 can arrive).
[[nodiscard]] Result<std::optional<core::Method>> method_from_proto(v1::Method method);

v1::MeshFormat format_to_proto(io::MeshFormat format);
/// @return the format; nullopt for MESH_FORMAT_UNSPECIFIED; InvalidArgument "unknown format <n>"
///         for a value outside the enum.
[[nodiscard]] Result<std::optional<io::MeshFormat>> format_from_proto(v1::MeshFormat format);

v1::HandleRole role_to_proto(core::HandleRole role);
/// @return the role; nullopt for HANDLE_ROLE_UNSPECIFIED or a value outside the enum.
std::optional<core::HandleRole> role_from_proto(v1::HandleRole role);

/// Record is HISTORY_ACTION_UNSPECIFIED, the default.
v1::HistoryAction history_to_proto(core::HistoryAction action);
/// @return the action (UNSPECIFIED is Record); nullopt for a value outside the enum.
std::optional<core::HistoryAction> history_from_proto(v1::HistoryAction action);

// -------------------------------------------------------------------------------------- values

Eigen::Vector3d vec_from_proto(const v1::Vec3& v);
void vec_to_proto(const Eigen::Vector3d& v, v1::Vec3* out);

/// (w, x, y, z) as given: no normalisation.
Eigen::Quaterniond quat_from_proto(const v1::Quaternion& q);
void quat_to_proto(const Eigen::Quaterniond& q, v1::Quaternion* out);

/// @return `value` as an int; nullopt above INT_MAX.
std::optional<int> index_from_proto(std::uint32_t value);

/// @param[out] first_bad  when given and the result is nullopt: the position of the first index
///                        above INT_MAX.
/// @return the indices as ints; nullopt when one is above INT_MAX.
std::optional<std::vector<int>> indices_from_proto(
    const google::protobuf::RepeatedField<std::uint32_t>& in, int* first_bad = nullptr);

/// Appends `indices` to `out` up to the first negative one.
/// @return the position of the first negative index; nullopt when all were appended.
[[nodiscard]] std::optional<std::size_t> indices_to_proto(
    const std::vector<int>& indices, google::protobuf::RepeatedField<std::uint32_t>* out);

/// Sets `out` to the #rows x 3 positions, row after row (x, y, z).
void rows_to_proto(const Positions& rows, google::protobuf::RepeatedField<double>* out);
/// @return the rows of `flat` (x, y, z per row); nullopt when its size is not a multiple of 3.
std::optional<Positions> rows_from_proto(const google::protobuf::RepeatedField<double>& flat);

// ---------------------------------------------------------------------------------- GroupMove

/// Every field is sent. @pre move.group >= 0.
void group_move_to_proto(const core::GroupMove& move, v1::GroupMove* out);

/// Absent fields keep GroupMove's defaults (no translation, identity rotation, scale 1, no
/// pivot). Values are taken as they are (the caller checks finiteness, the zero quaternion, the
/// scale). @pre index_from_proto(in.group()) has a value.
core::GroupMove group_move_from_proto(const v1::GroupMove& in);

}  // namespace meshdeform::wire
