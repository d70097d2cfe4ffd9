#include "client_cpp/client_conversions.h"

#include <algorithm>
#include <bit>
#include <cstring>
#include <limits>
#include <optional>
#include <utility>

#include "proto/wire/wire_mapping.h"

namespace meshdeform::client {
namespace detail {
namespace {

/// UNSPECIFIED is nullopt (SessionInfo.last_method before the first move).
Result<std::optional<core::Method>> method_from_proto(v1::Method method, const char* rpc) {
  Result<std::optional<core::Method>> known = wire::method_from_proto(method);
  if (!known.ok()) return malformed(rpc, known.status().message());
  return known;
}

Result<std::vector<int>> indices_from_proto(
    const google::protobuf::RepeatedField<std::uint32_t>& in, const char* rpc) {
  int bad = 0;
  std::optional<std::vector<int>> out = wire::indices_from_proto(in, &bad);
  if (!out) {
    return malformed(rpc, "vertex index " + std::to_string(in.Get(bad)) + " exceeds INT_MAX");
  }
  return *std::move(out);
}

Result<Positions> positions_from_proto(const google::protobuf::RepeatedField<double>& flat,
                                       const char* rpc, const char* what) {
  std::optional<Positions> rows = wire::rows_from_proto(flat);
  if (!rows) {
    return malformed(rpc, std::string(what) + " has " + std::to_string(flat.size()) +
                              " values, not a multiple of 3");
  }
  return *std::move(rows);
}

Result<std::vector<HandleGroup>> groups_from_proto(
    const google::protobuf::RepeatedPtrField<v1::HandleGroup>& in, const char* rpc) {
  std::vector<HandleGroup> out;
  for (const v1::HandleGroup& g : in) {
    HandleGroup group;
    const std::optional<HandleRole> role = wire::role_from_proto(g.role());
    if (!role) return malformed(rpc, "handle role " + std::to_string(static_cast<int>(g.role())));
    group.role = *role;
    MD_ASSIGN_OR_RETURN(group.vertices, indices_from_proto(g.vertices(), rpc));
    out.push_back(std::move(group));
  }
  return out;
}

}  // namespace

Status invalid(std::string message) {
  return Error(ErrorCode::InvalidArgument, std::move(message));
}

Status malformed(const char* rpc, const std::string& what) {
  return Error(ErrorCode::InvalidArgument, std::string(rpc) + ": malformed response: " + what);
}

Status from_grpc(const char* rpc, const grpc::Status& status) {
  if (status.ok()) return Status::success();
  const int code = static_cast<int>(status.error_code());
  return Error(to_error_code(code),
               std::string(rpc) + ": " + grpc_code_name(code) + ": " + status.error_message());
}

Status groups_to_proto(const std::vector<HandleGroup>& groups,
                       google::protobuf::RepeatedPtrField<v1::HandleGroup>* out) {
  for (std::size_t g = 0; g < groups.size(); ++g) {
    v1::HandleGroup* group = out->Add();
    group->set_role(wire::role_to_proto(groups[g].role));
    const std::optional<std::size_t> negative =
        wire::indices_to_proto(groups[g].vertices, group->mutable_vertices());
    if (negative) {
      return invalid("handle group " + std::to_string(g) + " has negative vertex index " +
                     std::to_string(groups[g].vertices[*negative]));
    }
  }
  return Status::success();
}

Result<SessionInfo> info_from_proto(const v1::SessionInfo& in, const char* rpc) {
  SessionInfo info;
  info.session_id = in.session_id();
  info.vertices = static_cast<int>(in.vertices());
  info.faces = static_cast<int>(in.faces());
  info.boundary_loops = static_cast<int>(in.boundary_loops());
  info.components = static_cast<int>(in.components());
  info.bbox_min = wire::vec_from_proto(in.bbox_min());
  info.bbox_max = wire::vec_from_proto(in.bbox_max());
  info.revision = in.revision();
  MD_ASSIGN_OR_RETURN(info.groups, groups_from_proto(in.groups(), rpc));
  MD_ASSIGN_OR_RETURN(info.last_method, method_from_proto(in.last_method(), rpc));
  info.estimated_bytes = in.estimated_bytes();
  info.cached_deformers = static_cast<int>(in.cached_deformers());
  info.watchers = static_cast<int>(in.watchers());
  info.history_steps = std::max(1, in.edit().steps_size());
  info.history_position = static_cast<int>(in.edit().position());
  if (in.edit().has_settings()) {
    MD_ASSIGN_OR_RETURN(info.settings_method, method_from_proto(in.edit().settings().method(), rpc));
  }
  return info;
}

Result<Session> session_from_proto(const v1::CreateSessionResponse& in) {
  constexpr const char* kRpc = "CreateSession";
  Session session;
  session.id = in.session_id();
  session.edit_token = in.edit_token();
  session.view_token = in.view_token();
  MD_ASSIGN_OR_RETURN(session.info, info_from_proto(in.info(), kRpc));
  session.welded_vertices = static_cast<int>(in.welded_vertices());
  session.dropped_unreferenced = static_cast<int>(in.dropped_unreferenced());
  MD_ASSIGN_OR_RETURN(session.suggested_groups, groups_from_proto(in.suggested_groups(), kRpc));
  return session;
}

Result<DeformResult> result_from_proto(const v1::DeformResult& in, const char* rpc) {
  DeformResult out;
  out.revision = in.revision();
  MD_ASSIGN_OR_RETURN(const std::optional<core::Method> method,
                      method_from_proto(in.method(), rpc));
  out.method = method.value_or(core::Method::ScaleAware);  // UNSPECIFIED means the default
  MD_ASSIGN_OR_RETURN(out.changed_indices, indices_from_proto(in.changed_indices(), rpc));
  MD_ASSIGN_OR_RETURN(out.changed_positions,
                      positions_from_proto(in.changed_positions(), rpc, "changed_positions"));
  if (out.changed_positions.rows() != static_cast<Eigen::Index>(out.changed_indices.size())) {
    return malformed(rpc, std::to_string(out.changed_indices.size()) + " changed indices but " +
                              std::to_string(out.changed_positions.rows()) + " positions");
  }
  if (in.positions_size() > 0) {
    MD_ASSIGN_OR_RETURN(out.positions, positions_from_proto(in.positions(), rpc, "positions"));
  }
  out.e_theta = in.e_theta();
  out.e_phi = in.e_phi();
  out.area_log_rms = in.area_log_rms();
  out.rigidity = in.rigidity();
  out.iterations = static_cast<int>(in.iterations());
  out.converged = in.converged();
  out.solve_seconds = in.solve_seconds();
  out.queue_seconds = in.queue_seconds();
  out.built_deformer = in.built_deformer();
  out.editor = in.editor();
  out.refinement = in.refinement();
  out.settled = in.settled();
  return out;
}

Status move_to_proto(const MoveSpec& spec, v1::MoveHandlesRequest* out) {
  for (std::size_t m = 0; m < spec.moves.size(); ++m) {
    const GroupMove& move = spec.moves[m];
    if (move.group < 0) {
      return invalid("move " + std::to_string(m) + ": negative group index " +
                     std::to_string(move.group));
    }
    wire::group_move_to_proto(move, out->add_moves());
  }
  for (std::size_t t = 0; t < spec.targets.size(); ++t) {
    const VertexTarget& target = spec.targets[t];
    if (target.vertex < 0) {
      return invalid("target " + std::to_string(t) + ": negative vertex index " +
                     std::to_string(target.vertex));
    }
    out->mutable_targets()->add_vertices(static_cast<std::uint32_t>(target.vertex));
    for (int k = 0; k < 3; ++k) out->mutable_targets()->add_positions(target.position(k));
  }
  if (spec.max_iterations < 0) {
    return invalid("max_iterations " + std::to_string(spec.max_iterations) + " is negative");
  }
  out->set_method(wire::method_to_proto(spec.method));
  out->set_ora(spec.ora);
  if (spec.rigidity) out->set_rigidity(*spec.rigidity);
  out->set_max_iterations(static_cast<std::uint32_t>(spec.max_iterations));
  if (spec.tolerance) out->set_tolerance(*spec.tolerance);
  out->set_editor(spec.editor);
  out->set_full_positions(spec.full_positions);
  out->set_history(wire::history_to_proto(spec.history));
  out->set_gesture(spec.gesture);
  out->set_keep_settings(spec.keep_settings);
  out->set_omit_positions(spec.omit_positions);
  return Status::success();
}

Result<WatchUpdate> update_from_proto(const v1::DeformUpdate& in) {
  WatchUpdate update;
  MD_ASSIGN_OR_RETURN(update.result, result_from_proto(in.result(), "Watch"));
  update.is_snapshot = in.is_snapshot();
  update.skipped_revisions = in.skipped_revisions();
  return update;
}

Result<CoarseLevel> CoarseLevelDecoder::decode(const v1::CoarseLevel& in) {
  const auto bad = [&in](const std::string& why) {
    return malformed("Watch", "coarse level " + std::to_string(in.key()) + ": " + why);
  };
  const std::uint32_t nc = in.vertex_count();
  if (in.positions().size() != 12ull * nc) {
    return bad(std::to_string(in.positions().size()) + " position bytes for " + std::to_string(nc) +
               " vertices (12 per vertex)");
  }
  if (in.to_fine_size() > 0 || in.triangles_size() > 0) {
    if (static_cast<std::uint32_t>(in.to_fine_size()) != nc) {
      return bad(std::to_string(in.to_fine_size()) + " to_fine entries for " + std::to_string(nc) +
                 " vertices");
    }
    if (in.triangles_size() == 0 || in.triangles_size() % 3 != 0) {
      return bad(std::to_string(in.triangles_size()) +
                 " triangle indices (a positive multiple of 3)");
    }
    Mesh mesh;
    mesh.triangles.resize(in.triangles_size() / 3, 3);
    for (int k = 0; k < in.triangles_size(); ++k) {
      if (in.triangles(k) >= nc) {
        return bad("triangle index " + std::to_string(in.triangles(k)) + " of " +
                   std::to_string(nc) + " vertices");
      }
      mesh.triangles(k / 3, k % 3) = static_cast<int>(in.triangles(k));
    }
    for (const std::uint32_t v : in.to_fine()) {
      if (v > static_cast<std::uint32_t>(std::numeric_limits<int>::max())) {
        return bad("to_fine index " + std::to_string(v) + " above INT_MAX");
      }
      mesh.to_fine.push_back(static_cast<int>(v));
    }
    meshes_[in.key()] = std::move(mesh);
  }
  const auto known = meshes_.find(in.key());
  if (known == meshes_.end()) return bad("its mesh never came on this stream");
  if (known->second.to_fine.size() != nc) {
    return bad(std::to_string(nc) + " vertices, its mesh has " +
               std::to_string(known->second.to_fine.size()));
  }
  CoarseLevel out;
  out.key = in.key();
  // Little-endian float32 on the wire, as on every machine this builds for.
  static_assert(std::endian::native == std::endian::little && sizeof(float) == 4);
  std::vector<float> xyz(3u * nc);
  if (nc > 0) std::memcpy(xyz.data(), in.positions().data(), in.positions().size());
  out.positions.resize(nc, 3);
  for (std::uint32_t i = 0; i < nc; ++i) {
    for (int c = 0; c < 3; ++c) out.positions(i, c) = xyz[3u * i + static_cast<unsigned>(c)];
  }
  out.triangles = known->second.triangles;
  out.to_fine = known->second.to_fine;
  return out;
}

ServerStats stats_from_proto(const v1::GetServerStatsResponse& in) {
  ServerStats stats;
  stats.sessions = in.sessions();
  stats.estimated_bytes = in.estimated_bytes();
  stats.resident_bytes = in.resident_bytes();
  stats.moves_committed = in.moves_committed();
  stats.moves_cancelled = in.moves_cancelled();
  stats.refinements_committed = in.refinements_committed();
  stats.deformer_constructions = in.deformer_constructions();
  stats.evicted_lru = in.evicted_lru();
  stats.evicted_idle = in.evicted_idle();
  stats.workers = in.workers();
  stats.uptime_seconds = in.uptime_seconds();
  return stats;
}

}  // namespace detail

// ---------------------------------------------------------------------------- status mapping

ErrorCode to_error_code(int grpc_code) {
  // Out-of-range values are not valid grpc::StatusCode values: never cast them.
  if (grpc_code < 0 || grpc_code > static_cast<int>(grpc::StatusCode::UNAUTHENTICATED)) {
    return ErrorCode::Internal;
  }
  // One switch and no default: -Wswitch flags a code added to grpc::StatusCode.
  switch (static_cast<grpc::StatusCode>(grpc_code)) {
    case grpc::StatusCode::OK:
      return ErrorCode::Ok;
    case grpc::StatusCode::CANCELLED:
      return ErrorCode::Cancelled;
    case grpc::StatusCode::INVALID_ARGUMENT:
    case grpc::StatusCode::OUT_OF_RANGE:
      return ErrorCode::InvalidArgument;
    case grpc::StatusCode::DEADLINE_EXCEEDED:
      return ErrorCode::DeadlineExceeded;
    case grpc::StatusCode::NOT_FOUND:
      return ErrorCode::NotFound;
    case grpc::StatusCode::PERMISSION_DENIED:
    case grpc::StatusCode::UNAUTHENTICATED:
      return ErrorCode::PermissionDenied;
    case grpc::StatusCode::RESOURCE_EXHAUSTED:
      return ErrorCode::ResourceExhausted;
    // The request cannot be served in the current state of the system (or by this server
    // version, for UNIMPLEMENTED): retrying unchanged does not help.
    case grpc::StatusCode::FAILED_PRECONDITION:
    case grpc::StatusCode::ALREADY_EXISTS:
    case grpc::StatusCode::UNIMPLEMENTED:
      return ErrorCode::FailedPrecondition;
    // A concurrent change won (another replica edited the session): retrying may succeed.
    case grpc::StatusCode::ABORTED:
      return ErrorCode::Aborted;
    // The server, or a store it needs, cannot be reached now: retrying later may succeed.
    case grpc::StatusCode::UNAVAILABLE:
      return ErrorCode::Unavailable;
    // Server faults: not the caller's input. The message keeps the gRPC name.
    case grpc::StatusCode::UNKNOWN:
    case grpc::StatusCode::INTERNAL:
    case grpc::StatusCode::DATA_LOSS:
    case grpc::StatusCode::DO_NOT_USE:
      return ErrorCode::Internal;
  }
  return ErrorCode::Internal;  // unreachable (range checked above); keeps -Wreturn-type quiet
}

std::string grpc_code_name(int grpc_code) { return wire::grpc_code_label(grpc_code); }

}  // namespace meshdeform::client
