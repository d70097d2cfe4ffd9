#include "proto/wire/wire_mapping.h"

#include <grpcpp/support/status.h>

#include <array>
#include <climits>

namespace meshdeform::wire {
namespace {

Status unknown(const char* what, int value) {
  return Error(ErrorCode::InvalidArgument,
               std::string("unknown ") + what + " " + std::to_string(value));
}

/// Indexed by the code's value.
constexpr std::array<std::string_view, kGrpcCodeCount> kGrpcCodeNames = {
    "OK",                  // 0
    "CANCELLED",           // 1
    "UNKNOWN",             // 2
    "INVALID_ARGUMENT",    // 3
    "DEADLINE_EXCEEDED",   // 4
    "NOT_FOUND",           // 5
    "ALREADY_EXISTS",      // 6
    "PERMISSION_DENIED",   // 7
    "RESOURCE_EXHAUSTED",  // 8
    "FAILED_PRECONDITION", // 9
    "ABORTED",             // 10
    "OUT_OF_RANGE",        // 11
    "UNIMPLEMENTED",       // 12
    "INTERNAL",            // 13
    "UNAVAILABLE",         // 14
    "DATA_LOSS",           // 15
    "UNAUTHENTICATED",     // 16
};
static_assert(static_cast<int>(grpc::StatusCode::OK) == 0);
static_assert(static_cast<int>(grpc::StatusCode::UNAUTHENTICATED) == kGrpcCodeCount - 1);

}  // namespace

std::optional<std::string_view> grpc_code_name(int code) {
  if (code < 0 || code >= kGrpcCodeCount) return std::nullopt;
  return kGrpcCodeNames[static_cast<std::size_t>(code)];
}

std::string grpc_code_label(int code) {
  const std::optional<std::string_view> name = grpc_code_name(code);
  return name ? std::string(*name) : "CODE_" + std::to_string(code);
}

Result<std::optional<core::Method>> method_from_proto(v1::Method method) {
  switch (method) {
    case v1::METHOD_UNSPECIFIED:
      return std::optional<core::Method>();
    case v1::METHOD_SCALE_AWARE:
      return std::optional<core::Method>(core::Method::ScaleAware);
    case v1::METHOD_ARAP:
      return std::optional<core::Method>(core::Method::Arap);
    case v1::METHOD_LAPLACIAN:
      return std::optional<core::Method>(core::Method::Laplacian);
    case v1::Method_INT_MIN_SENTINEL_DO_NOT_USE_:
    case v1::Method_INT_MAX_SENTINEL_DO_NOT_USE_:
      break;
  }
  return unknown("method", static_cast<int>(method));
}

v1::MeshFormat format_to_proto(io::MeshFormat format) {
  switch (format) {
    case io::MeshFormat::Obj:
      return v1::MESH_FORMAT_OBJ;
    case io::MeshFormat::Off:
      return v1::MESH_FORMAT_OFF;
    case io::MeshFormat::Ply:
      return v1::MESH_FORMAT_PLY;
    case io::MeshFormat::Stl:
      return v1::MESH_FORMAT_STL;
    case io::MeshFormat::Glb:
      return v1::MESH_FORMAT_GLB;
    case io::MeshFormat::Gltf:
      return v1::MESH_FORMAT_GLTF;
  }
  return v1::MESH_FORMAT_UNSPECIFIED;
}

Result<std::optional<io::MeshFormat>> format_from_proto(v1::MeshFormat format) {
  switch (format) {
    case v1::MESH_FORMAT_UNSPECIFIED:
      return std::optional<io::MeshFormat>();
    case v1::MESH_FORMAT_OBJ:
      return std::optional<io::MeshFormat>(io::MeshFormat::Obj);
    case v1::MESH_FORMAT_OFF:
      return std::optional<io::MeshFormat>(io::MeshFormat::Off);
    case v1::MESH_FORMAT_PLY:
      return std::optional<io::MeshFormat>(io::MeshFormat::Ply);
    case v1::MESH_FORMAT_STL:
      return std::optional<io::MeshFormat>(io::MeshFormat::Stl);
    case v1::MESH_FORMAT_GLB:
      return std::optional<io::MeshFormat>(io::MeshFormat::Glb);
    case v1::MESH_FORMAT_GLTF:
      return std::optional<io::MeshFormat>(io::MeshFormat::Gltf);
    case v1::MeshFormat_INT_MIN_SENTINEL_DO_NOT_USE_:
    case v1::MeshFormat_INT_MAX_SENTINEL_DO_NOT_USE_:
      break;
  }
  return unknown("format", static_cast<int>(format));
}

Eigen::Vector3d vec_from_proto(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

void vec_to_proto(const Eigen::Vector3d& v, v1::Vec3* out) {
  out->set_x(v.x());
  out->set_y(v.y());
  out->set_z(v.z());
}

Eigen::Quaterniond quat_from_proto(const v1::Quaternion& q) {
  return Eigen::Quaterniond(q.w(), q.x(), q.y(), q.z());
}

void quat_to_proto(const Eigen::Quaterniond& q, v1::Quaternion* out) {
  out->set_w(q.w());
  out->set_x(q.x());
  out->set_y(q.y());
  out->set_z(q.z());
}

std::optional<int> index_from_proto(std::uint32_t value) {
  if (value > static_cast<std::uint32_t>(INT_MAX)) return std::nullopt;
  return static_cast<int>(value);
}

std::optional<std::vector<int>> indices_from_proto(
    const google::protobuf::RepeatedField<std::uint32_t>& in, int* first_bad) {
  std::vector<int> out;
  out.reserve(static_cast<std::size_t>(in.size()));
  for (int i = 0; i < in.size(); ++i) {
    const std::optional<int> index = index_from_proto(in.Get(i));
    if (!index) {
      if (first_bad) *first_bad = i;
      return std::nullopt;
    }
    out.push_back(*index);
  }
  return out;
}

std::optional<std::size_t> indices_to_proto(const std::vector<int>& indices,
                                            google::protobuf::RepeatedField<std::uint32_t>* out) {
  out->Reserve(out->size() + static_cast<int>(indices.size()));
  for (std::size_t i = 0; i < indices.size(); ++i) {
    if (indices[i] < 0) return i;
    out->Add(static_cast<std::uint32_t>(indices[i]));
  }
  return std::nullopt;
}

void rows_to_proto(const Positions& rows, google::protobuf::RepeatedField<double>* out) {
  out->Resize(static_cast<int>(rows.rows() * 3), 0.0);
  double* data = out->mutable_data();
  for (Eigen::Index r = 0; r < rows.rows(); ++r) {
    data[3 * r + 0] = rows(r, 0);
    data[3 * r + 1] = rows(r, 1);
    data[3 * r + 2] = rows(r, 2);
  }
}

std::optional<Positions> rows_from_proto(const google::protobuf::RepeatedField<double>& flat) {
  if (flat.size() % 3 != 0) return std::nullopt;
  Positions rows(flat.size() / 3, 3);
  for (Eigen::Index r = 0; r < rows.rows(); ++r) {
    for (int k = 0; k < 3; ++k) rows(r, k) = flat.Get(static_cast<int>(3 * r + k));
  }
  return rows;
}

v1::HandleRole role_to_proto(core::HandleRole role) {
  switch (role) {
    case core::HandleRole::Fixed:
      return v1::HANDLE_ROLE_FIXED;
    case core::HandleRole::Handle:
      return v1::HANDLE_ROLE_HANDLE;
  }
  return v1::HANDLE_ROLE_UNSPECIFIED;
}

std::optional<core::HandleRole> role_from_proto(v1::HandleRole role) {
  switch (role) {
    case v1::HANDLE_ROLE_FIXED:
      return core::HandleRole::Fixed;
    case v1::HANDLE_ROLE_HANDLE:
      return core::HandleRole::Handle;
    case v1::HANDLE_ROLE_UNSPECIFIED:
    case v1::HandleRole_INT_MIN_SENTINEL_DO_NOT_USE_:
    case v1::HandleRole_INT_MAX_SENTINEL_DO_NOT_USE_:
      break;
  }
  return std::nullopt;
}

v1::HistoryAction history_to_proto(core::HistoryAction action) {
  switch (action) {
    case core::HistoryAction::Undo:
      return v1::HISTORY_ACTION_UNDO;
    case core::HistoryAction::Redo:
      return v1::HISTORY_ACTION_REDO;
    case core::HistoryAction::Record:
      break;
  }
  return v1::HISTORY_ACTION_UNSPECIFIED;
}

std::optional<core::HistoryAction> history_from_proto(v1::HistoryAction action) {
  switch (action) {
    case v1::HISTORY_ACTION_UNSPECIFIED:
      return core::HistoryAction::Record;
    case v1::HISTORY_ACTION_UNDO:
      return core::HistoryAction::Undo;
    case v1::HISTORY_ACTION_REDO:
      return core::HistoryAction::Redo;
    case v1::HistoryAction_INT_MIN_SENTINEL_DO_NOT_USE_:
    case v1::HistoryAction_INT_MAX_SENTINEL_DO_NOT_USE_:
      break;
  }
  return std::nullopt;
}

void group_move_to_proto(const core::GroupMove& move, v1::GroupMove* out) {
  out->set_group(static_cast<std::uint32_t>(move.group));
  vec_to_proto(move.translation, out->mutable_translation());
  quat_to_proto(move.rotation, out->mutable_rotation());
  out->set_scale(move.scale);
  if (move.pivot) vec_to_proto(*move.pivot, out->mutable_pivot());
}

core::GroupMove group_move_from_proto(const v1::GroupMove& in) {
  core::GroupMove out;
  out.group = static_cast<int>(in.group());
  if (in.has_translation()) out.translation = vec_from_proto(in.translation());
  if (in.has_rotation()) out.rotation = quat_from_proto(in.rotation());
  if (in.has_scale()) out.scale = in.scale();
  if (in.has_pivot()) out.pivot = vec_from_proto(in.pivot());
  return out;
}

}  // namespace meshdeform::wire
