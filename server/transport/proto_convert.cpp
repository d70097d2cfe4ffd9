#include "server/transport/proto_convert.h"

#include <meshoptimizer.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "proto/wire/wire_mapping.h"

namespace meshdeform::transport {
namespace {

Status invalid(std::string message) {
  return Error(ErrorCode::InvalidArgument, std::move(message));
}

Result<int> index_from_proto(std::uint32_t value, const std::string& field) {
  const std::optional<int> index = wire::index_from_proto(value);
  if (!index) return invalid(field + " = " + std::to_string(value) + " is out of range");
  return *index;
}

/// `where`.vertices as ints; InvalidArgument naming the first index > INT_MAX.
Result<std::vector<int>> indices_from_proto(const google::protobuf::RepeatedField<std::uint32_t>& in,
                                            const std::string& where) {
  int bad = 0;
  std::optional<std::vector<int>> out = wire::indices_from_proto(in, &bad);
  if (!out) {
    return invalid(where + ".vertices[" + std::to_string(bad) + "] = " +
                   std::to_string(in.Get(bad)) + " is out of range");
  }
  return *std::move(out);
}

/// METHOD_UNSPECIFIED is scale-aware. @return InvalidArgument for an unknown value.
Result<core::Method> method_from_proto(v1::Method method) {
  MD_ASSIGN_OR_RETURN(const std::optional<core::Method> known, wire::method_from_proto(method));
  return known.value_or(core::Method::ScaleAware);
}

void groups_to_proto(const std::vector<service::HandleGroup>& groups,
                     google::protobuf::RepeatedPtrField<v1::HandleGroup>* out) {
  for (const service::HandleGroup& group : groups) {
    v1::HandleGroup* g = out->Add();
    g->set_role(wire::role_to_proto(group.role));
    // The service's indices are >= 0: all of them are written.
    (void)wire::indices_to_proto(group.vertices, g->mutable_vertices());
  }
}

}  // namespace

Result<io::MeshFormat> format_from_proto(v1::MeshFormat format, bool allow_unspecified) {
  MD_ASSIGN_OR_RETURN(const std::optional<io::MeshFormat> known, wire::format_from_proto(format));
  if (known) return *known;
  if (allow_unspecified) return io::MeshFormat::Glb;
  return invalid("format is MESH_FORMAT_UNSPECIFIED; name the format of mesh_bytes");
}

Result<service::CreateSessionRequest> create_request_from_proto(
    const v1::CreateSessionRequest& request) {
  service::CreateSessionRequest out;
  switch (request.source_case()) {
    case v1::CreateSessionRequest::kMeshBytes: {
      if (request.mesh_bytes().empty()) return invalid("mesh_bytes is empty");
      MD_ASSIGN_OR_RETURN(out.format, format_from_proto(request.format(), false));
      out.mesh_bytes = request.mesh_bytes();
      break;
    }
    case v1::CreateSessionRequest::kSample:
      if (request.sample().empty()) return invalid("sample is empty");
      out.sample = request.sample();
      break;
    case v1::CreateSessionRequest::SOURCE_NOT_SET:
      return invalid("give one of mesh_bytes and sample (got neither)");
  }
  out.weld = request.weld();
  // Ranges (lambda > 0, rigidity) are the service's to check.
  if (request.has_lambda()) out.settings.lambda = request.lambda();
  if (request.has_rigidity()) out.rigidity = request.rigidity();
  return out;
}

Result<service::SetHandlesRequest> set_handles_from_proto(const v1::SetHandlesRequest& request) {
  service::SetHandlesRequest out;
  MD_ASSIGN_OR_RETURN(out.prepare, method_from_proto(request.prepare()));
  out.groups.reserve(static_cast<std::size_t>(request.groups_size()));
  for (int g = 0; g < request.groups_size(); ++g) {
    const v1::HandleGroup& group = request.groups(g);
    const std::string where = "groups[" + std::to_string(g) + "]";
    service::HandleGroup converted;
    const std::optional<service::HandleRole> role =
        wire::role_from_proto(group.role());
    if (!role) {
      return invalid(where + ".role " + std::to_string(static_cast<int>(group.role())) +
                     " is not FIXED or HANDLE");
    }
    converted.role = *role;
    MD_ASSIGN_OR_RETURN(converted.vertices, indices_from_proto(group.vertices(), where));
    out.groups.push_back(std::move(converted));
  }
  return out;
}

Result<service::MoveRequest> move_from_proto(const v1::MoveHandlesRequest& request) {
  service::MoveRequest out;
  for (int m = 0; m < request.moves_size(); ++m) {
    const v1::GroupMove& move = request.moves(m);
    const std::string where = "moves[" + std::to_string(m) + "]";
    MD_RETURN_IF_ERROR(index_from_proto(move.group(), where + ".group").status());
    // Absent fields are the defaults (zero, identity, 1, none). The values (finite, a non-zero
    // quaternion, scale > 0) are the service's to check.
    out.moves.push_back(wire::group_move_from_proto(move));
  }
  const v1::VertexTargets& targets = request.targets();
  if (static_cast<std::size_t>(targets.positions_size()) !=
      3 * static_cast<std::size_t>(targets.vertices_size())) {
    return invalid("targets: " + std::to_string(targets.positions_size()) + " positions for " +
                   std::to_string(targets.vertices_size()) + " vertices (need 3 per vertex)");
  }
  out.targets.reserve(static_cast<std::size_t>(targets.vertices_size()));
  for (int i = 0; i < targets.vertices_size(); ++i) {
    service::VertexTarget t;
    MD_ASSIGN_OR_RETURN(t.vertex, index_from_proto(targets.vertices(i),
                                                   "targets.vertices[" + std::to_string(i) + "]"));
    t.position = Eigen::Vector3d(targets.positions(3 * i), targets.positions(3 * i + 1),
                                 targets.positions(3 * i + 2));
    out.targets.push_back(t);
  }
  MD_ASSIGN_OR_RETURN(out.method, method_from_proto(request.method()));
  out.ora = request.ora();
  // 0 is "unset" on the wire (the service's default). Ranges (max_iterations, tolerance,
  // rigidity, magnify scales and count) are the service's to check.
  if (request.max_iterations() != 0) {
    if (request.max_iterations() > static_cast<std::uint32_t>(std::numeric_limits<int>::max())) {
      return invalid("max_iterations = " + std::to_string(request.max_iterations()) +
                     " is out of range");
    }
    out.max_iterations = static_cast<int>(request.max_iterations());
  }
  if (request.has_rigidity()) out.rigidity = request.rigidity();
  if (request.has_tolerance()) out.tolerance = request.tolerance();
  for (int r = 0; r < request.magnify_size(); ++r) {
    const v1::MagnifyRegion& region = request.magnify(r);
    const std::string where = "magnify[" + std::to_string(r) + "]";
    core::MagnifyRegion converted;
    converted.scale = region.scale();
    MD_ASSIGN_OR_RETURN(const std::vector<int> vertices,
                        indices_from_proto(region.vertices(), where));
    converted.vertices = Eigen::Map<const Eigen::VectorXi>(
        vertices.data(), static_cast<Eigen::Index>(vertices.size()));
    out.magnify.push_back(std::move(converted));
  }
  const std::optional<service::HistoryAction> history =
      wire::history_from_proto(request.history());
  if (!history) {
    return invalid("unknown history action " + std::to_string(static_cast<int>(request.history())));
  }
  out.history = *history;
  out.gesture = request.gesture();
  out.keep_settings = request.keep_settings();
  if (request.has_restore_revision()) out.restore_revision = request.restore_revision();
  out.editor = request.editor().substr(0, 256);
  return out;
}

Result<v1::PositionEncoding> encoding_from_proto(int value) {
  switch (value) {
    case v1::POSITION_ENCODING_UNSPECIFIED:
    case v1::POSITION_ENCODING_FLOAT32:
    case v1::POSITION_ENCODING_MESHOPT:
      return static_cast<v1::PositionEncoding>(value);
    default:
      return invalid("unknown position encoding " + std::to_string(value));
  }
}

void pack_positions(const Positions& rows, v1::PositionEncoding encoding, std::string* out) {
  static_assert(sizeof(float) == 4);
  if (rows.rows() == 0) return;  // no vertex, no bytes (in either encoding)
  std::vector<float> floats(static_cast<std::size_t>(rows.rows()) * 3);
  for (Eigen::Index r = 0; r < rows.rows(); ++r) {
    for (int c = 0; c < 3; ++c) {
      floats[static_cast<std::size_t>(3 * r + c)] = static_cast<float>(rows(r, c));
    }
  }
  // The wire is little-endian; so is every machine this builds for (x86-64, aarch64).
  static_assert(std::endian::native == std::endian::little);
  constexpr std::size_t kStride = 3 * sizeof(float);
  if (encoding == v1::POSITION_ENCODING_MESHOPT) {
    const std::size_t count = static_cast<std::size_t>(rows.rows());
    const std::size_t offset = out->size();
    out->resize(offset + meshopt_encodeVertexBufferBound(count, kStride));
    const std::size_t written =
        meshopt_encodeVertexBuffer(reinterpret_cast<unsigned char*>(out->data() + offset),
                                   out->size() - offset, floats.data(), count, kStride);
    out->resize(offset + written);
    return;
  }
  const std::size_t offset = out->size();
  out->resize(offset + floats.size() * sizeof(float));
  std::memcpy(out->data() + offset, floats.data(), floats.size() * sizeof(float));
}

namespace {
void settings_to_proto(const service::EditSettings& s, v1::EditSettings* settings) {
  settings->set_method(wire::method_to_proto(s.method));
  settings->set_ora(s.ora);
  settings->set_max_iterations(static_cast<std::uint32_t>(s.max_iterations));
  settings->set_tolerance(s.tolerance);
  settings->set_rigidity(s.rigidity);
  for (const core::MagnifyRegion& region : s.magnify) {
    v1::MagnifyRegion* r = settings->add_magnify();
    const std::vector<int> vertices(region.vertices.begin(), region.vertices.end());
    (void)wire::indices_to_proto(vertices, r->mutable_vertices());
    r->set_scale(region.scale);
  }
}

/// `revision`: the session's current one, which shows the current step.
void edit_state_to_proto(const service::EditState& edit, std::uint64_t revision,
                         v1::EditState* out) {
  if (edit.settings) settings_to_proto(*edit.settings, out->mutable_settings());
  for (std::size_t i = 0; i < edit.steps.size(); ++i) {
    const service::EditStep& step = edit.steps[i];
    v1::EditStep* st = out->add_steps();
    for (const service::GroupMove& move : step.moves) wire::group_move_to_proto(move, st->add_moves());
    for (const service::VertexTarget& t : step.targets) {
      st->mutable_targets()->add_vertices(static_cast<std::uint32_t>(t.vertex));
      for (int c = 0; c < 3; ++c) st->mutable_targets()->add_positions(t.position[c]);
    }
    st->set_gesture(step.gesture);
    if (step.settings) settings_to_proto(*step.settings, st->mutable_settings());
    if (static_cast<int>(i) == edit.position) {
      st->set_revision(revision);
    } else if (step.revision) {
      st->set_revision(*step.revision);
    }
  }
  out->set_position(static_cast<std::uint32_t>(edit.position));
}
}  // namespace

void session_info_to_proto(const service::SessionInfo& info, v1::SessionInfo* out) {
  out->set_session_id(info.id.value);
  out->set_vertices(static_cast<std::uint32_t>(info.vertices));
  out->set_faces(static_cast<std::uint32_t>(info.faces));
  out->set_boundary_loops(static_cast<std::uint32_t>(info.boundary_loops));
  out->set_components(static_cast<std::uint32_t>(info.components));
  wire::vec_to_proto(info.bbox_min, out->mutable_bbox_min());
  wire::vec_to_proto(info.bbox_max, out->mutable_bbox_max());
  out->set_revision(info.revision);
  groups_to_proto(info.groups, out->mutable_groups());
  out->set_rigidity(info.rigidity);
  out->set_last_method(info.last_method ? wire::method_to_proto(*info.last_method)
                                        : v1::METHOD_UNSPECIFIED);
  out->set_estimated_bytes(info.estimated_bytes);
  out->set_cached_deformers(static_cast<std::uint32_t>(info.cached_deformers));
  out->set_watchers(static_cast<std::uint32_t>(info.watchers));
  edit_state_to_proto(info.edit, info.revision, out->mutable_edit());
  wire::rows_to_proto(info.group_anchors, out->mutable_group_anchors());
}

void progress_to_proto(const service::ProgressEvent& event, v1::Progress* out) {
  out->set_phase(event.phase);
  out->set_fraction(event.fraction);
  out->set_elapsed_seconds(event.elapsed_seconds);
}

void created_to_proto(const service::CreatedSession& created, v1::CreateSessionResponse* out) {
  out->set_session_id(created.id.value);
  out->set_edit_token(created.edit_token.value);
  out->set_view_token(created.view_token.value);
  session_info_to_proto(created.info, out->mutable_info());
  out->set_welded_vertices(static_cast<std::uint32_t>(created.welded_vertices));
  out->set_dropped_unreferenced(static_cast<std::uint32_t>(created.dropped_unreferenced));
  groups_to_proto(created.suggested_groups, out->mutable_suggested_groups());
}

namespace {
void result_metrics_to_proto(const service::DeformResult& result, v1::DeformResult* out) {
  out->set_revision(result.revision);
  out->set_method(wire::method_to_proto(result.method));
  out->set_e_theta(result.e_theta);
  out->set_e_phi(result.e_phi);
  out->set_area_log_rms(result.area_log_rms);
  out->set_rigidity(result.rigidity);
  out->set_iterations(static_cast<std::uint32_t>(result.iterations));
  out->set_converged(result.converged);
  out->set_solve_seconds(result.solve_seconds);
  out->set_queue_seconds(result.queue_seconds);
  out->set_built_deformer(result.built_deformer);
  out->set_editor(result.editor);
  out->set_refinement(result.refinement);
  out->set_settled(result.settled);
  out->set_pcg_iterations(static_cast<std::uint32_t>(std::max(result.pcg_iterations, 0)));
  if (result.history_position) {
    out->set_history_position(static_cast<std::uint32_t>(std::max(*result.history_position, 0)));
  }
}

// Which of a result's position arrays to send (Coarse: its coarse level's, result.coarse).
enum class Rows { Positions = 0, Changed = 1, Coarse = 2 };

// A result's positions, changed positions or coarse-level positions: doubles in `doubles` for
// UNSPECIFIED, else packed into `packed`, once per result, rows and encoding
// (service::DeformResult::encoded): the move's response and every watcher's update of a
// revision share the bytes.
void positions_to_proto(const service::DeformResult& result, Rows rows,
                        v1::PositionEncoding encoding,
                        google::protobuf::RepeatedField<double>* doubles, std::string* packed) {
  const Positions& values = rows == Rows::Positions ? *result.positions
                            : rows == Rows::Changed ? result.changed_positions
                                                    : result.coarse->V;
  if (encoding == v1::POSITION_ENCODING_UNSPECIFIED) {
    wire::rows_to_proto(values, doubles);
    return;
  }
  if (!result.encoded) {
    pack_positions(values, encoding, packed);
    return;
  }
  const int key = 3 * static_cast<int>(encoding) + static_cast<int>(rows);
  const std::shared_ptr<const std::string> bytes = result.encoded->get(key, [&] {
    std::string out;
    pack_positions(values, encoding, &out);
    return out;
  });
  packed->append(*bytes);
}
}  // namespace

void result_figures_to_proto(const service::DeformResult& result, v1::DeformResult* out) {
  result_metrics_to_proto(result, out);
}

void result_to_proto(const service::DeformResult& result, bool full_positions,
                     v1::PositionEncoding encoding, v1::DeformResult* out) {
  result_metrics_to_proto(result, out);
  out->set_encoding(encoding);
  // A browser-bound delta that moves nearly every vertex (a drag does) is smaller dense: 12
  // bytes per vertex against 12 plus a 2-3 byte index per changed vertex.
  if (encoding != v1::POSITION_ENCODING_UNSPECIFIED && result.positions &&
      result.positions->rows() > 0 &&
      static_cast<double>(result.changed.size()) >
          kDenseFraction * static_cast<double>(result.positions->rows())) {
    out->set_dense(true);
    positions_to_proto(result, Rows::Positions, encoding, out->mutable_positions(),
                       out->mutable_packed_positions());
    return;
  }
  // The service's indices are >= 0: all of them are written.
  (void)wire::indices_to_proto(result.changed, out->mutable_changed_indices());
  positions_to_proto(result, Rows::Changed, encoding, out->mutable_changed_positions(),
                     out->mutable_packed_changed_positions());
  if (full_positions && result.positions) {
    positions_to_proto(result, Rows::Positions, encoding, out->mutable_positions(),
                       out->mutable_packed_positions());
  }
}

void update_to_proto(const service::DeformUpdate& update, v1::PositionEncoding encoding,
                     v1::DeformUpdate* out) {
  out->Clear();
  out->set_is_snapshot(update.is_snapshot);
  out->set_skipped_revisions(update.skipped_revisions);
  if (!update.result) return;
  if (update.is_snapshot) {
    v1::DeformResult* result = out->mutable_result();
    result_metrics_to_proto(*update.result, result);
    result->set_encoding(encoding);
    if (update.result->positions) {
      positions_to_proto(*update.result, Rows::Positions, encoding, result->mutable_positions(),
                         result->mutable_packed_positions());
    }
  } else {
    result_to_proto(*update.result, false, encoding, out->mutable_result());
  }
}

void coarse_to_proto(const service::DeformResult& result, std::optional<std::uint64_t>* sent_key,
                     v1::DeformUpdate* out) {
  if (!result.coarse || !result.coarse->mesh) return;
  const core::CoarseLevelMesh& mesh = *result.coarse->mesh;
  v1::CoarseLevel* coarse = out->mutable_coarse();
  coarse->set_key(mesh.key);
  coarse->set_vertex_count(static_cast<std::uint32_t>(result.coarse->V.rows()));
  positions_to_proto(result, Rows::Coarse, v1::POSITION_ENCODING_FLOAT32, nullptr,
                     coarse->mutable_positions());
  if (*sent_key == mesh.key) return;
  // Indices of a level are >= 0 (a level's triangles and its subset of the fine vertices).
  coarse->mutable_triangles()->Reserve(static_cast<int>(mesh.F.size()));
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int c = 0; c < 3; ++c) coarse->add_triangles(static_cast<std::uint32_t>(mesh.F(f, c)));
  }
  coarse->mutable_to_fine()->Reserve(static_cast<int>(mesh.to_fine.size()));
  for (Eigen::Index i = 0; i < mesh.to_fine.size(); ++i) {
    coarse->add_to_fine(static_cast<std::uint32_t>(mesh.to_fine(i)));
  }
  *sent_key = mesh.key;
}

void server_stats_to_proto(const service::ServiceStats& stats, double uptime_seconds,
                           v1::GetServerStatsResponse* out) {
  out->set_sessions(static_cast<std::uint32_t>(stats.sessions));
  out->set_estimated_bytes(stats.estimated_bytes);
  out->set_resident_bytes(stats.resident_bytes);
  out->set_moves_committed(stats.moves_committed);
  out->set_moves_cancelled(stats.moves_cancelled);
  out->set_refinements_committed(stats.refinements_committed);
  out->set_deformer_constructions(stats.deformer_constructions);
  out->set_evicted_lru(stats.evicted_lru);
  out->set_evicted_idle(stats.evicted_idle);
  out->set_workers(static_cast<std::uint32_t>(std::max(stats.workers, 0)));
  out->set_uptime_seconds(uptime_seconds);
  out->set_watchers(static_cast<std::uint32_t>(std::max(stats.watchers, 0)));
  out->set_heavy_work_admitted(static_cast<std::uint32_t>(std::max(stats.heavy_admitted, 0)));
  out->set_heavy_work_running(static_cast<std::uint32_t>(std::max(stats.heavy_running, 0)));
  out->set_heavy_work_rejected(stats.heavy_rejected);
  out->set_uploads_cancelled(stats.uploads_cancelled);
  out->set_precomputes_cancelled(stats.precomputes_cancelled);
  out->set_queued_tasks(stats.queued_normal + stats.queued_heavy + stats.queued_background);
}

}  // namespace meshdeform::transport
