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

#include "core/deformer.h"
#include "core/io/mesh_io.h"
#include "core/mesh_data.h"
#include "core/status.h"
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

/// HandleRole of either side (service::HandleRole, client::HandleRole: any enum with Fixed and
/// Handle) -> v1::HandleRole.
template <typename Role>
v1::HandleRole role_to_proto(Role role) {
  switch (role) {
    case Role::Fixed:
      return v1::HANDLE_ROLE_FIXED;
    case Role::Handle:
      return v1::HANDLE_ROLE_HANDLE;
  }
  return v1::HANDLE_ROLE_UNSPECIFIED;
}

/// @return the role; nullopt for HANDLE_ROLE_UNSPECIFIED or a value outside the enum.
template <typename Role>
std::optional<Role> role_from_proto(v1::HandleRole role) {
  switch (role) {
    case v1::HANDLE_ROLE_FIXED:
      return Role::Fixed;
    case v1::HANDLE_ROLE_HANDLE:
      return Role::Handle;
    case v1::HANDLE_ROLE_UNSPECIFIED:
    case v1::HandleRole_INT_MIN_SENTINEL_DO_NOT_USE_:
    case v1::HandleRole_INT_MAX_SENTINEL_DO_NOT_USE_:
      break;
  }
  return std::nullopt;
}

/// HistoryAction of either side (service::HistoryAction, client::HistoryAction: any enum with
/// Record, Undo and Redo) -> v1::HistoryAction (Record is UNSPECIFIED, the default).
template <typename Action>
v1::HistoryAction history_to_proto(Action action) {
  switch (action) {
    case Action::Undo:
      return v1::HISTORY_ACTION_UNDO;
    case Action::Redo:
      return v1::HISTORY_ACTION_REDO;
    case Action::Record:
      break;
  }
  return v1::HISTORY_ACTION_UNSPECIFIED;
}

/// @return the action (UNSPECIFIED is Record); nullopt for a value outside the enum.
template <typename Action>
std::optional<Action> history_from_proto(v1::HistoryAction action) {
  switch (action) {
    case v1::HISTORY_ACTION_UNSPECIFIED:
      return Action::Record;
    case v1::HISTORY_ACTION_UNDO:
      return Action::Undo;
    case v1::HISTORY_ACTION_REDO:
      return Action::Redo;
    case v1::HistoryAction_INT_MIN_SENTINEL_DO_NOT_USE_:
    case v1::HistoryAction_INT_MAX_SENTINEL_DO_NOT_USE_:
      break;
  }
  return std::nullopt;
}

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

/// A GroupMove of either side (service::GroupMove, client::GroupMove: group, translation,
/// rotation, scale, optional pivot) -> v1::GroupMove. Every field is sent.
/// @pre move.group >= 0.
template <typename Move>
void group_move_to_proto(const Move& move, v1::GroupMove* out) {
  out->set_group(static_cast<std::uint32_t>(move.group));
  vec_to_proto(move.translation, out->mutable_translation());
  quat_to_proto(move.rotation, out->mutable_rotation());
  out->set_scale(move.scale);
  if (move.pivot) vec_to_proto(*move.pivot, out->mutable_pivot());
}

/// v1::GroupMove -> a GroupMove of either side; absent fields keep Move's defaults (no
/// translation, identity rotation, scale 1, no pivot). Values are taken as they are (the caller
/// checks finiteness, the zero quaternion, the scale).
/// @pre index_from_proto(in.group()) has a value.
template <typename Move>
Move group_move_from_proto(const v1::GroupMove& in) {
  Move out;
  out.group = static_cast<int>(in.group());
  if (in.has_translation()) out.translation = vec_from_proto(in.translation());
  if (in.has_rotation()) out.rotation = quat_from_proto(in.rotation());
  if (in.has_scale()) out.scale = in.scale();
  if (in.has_pivot()) out.pivot = vec_from_proto(in.pivot());
  return out;
}

}  // namespace meshdeform::wire
