#include "client_cpp/client.h"

#include <grpcpp/create_channel.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/security/credentials.h>
#include <grpcpp/support/channel_arguments.h>

#include <atomic>
#include <climits>
#include <cmath>
#include <fstream>
#include <iterator>
#include <mutex>
#include <sstream>
#include <utility>

#include "meshdeform/v1/deformation.grpc.pb.h"

namespace meshdeform::client {
namespace {

namespace v1 = ::meshdeform::v1;

constexpr const char* kSessionIdHeader = "x-session-id";
/// Longest session id sent as metadata (server ids are 32 hex digits).
constexpr std::size_t kMaxSessionIdBytes = 1024;

Status invalid(std::string message) {
  return Error(ErrorCode::InvalidArgument, std::move(message));
}

/// A response the server should never send (a protocol mismatch).
Status malformed(const char* rpc, const std::string& what) {
  return Error(ErrorCode::InvalidArgument, std::string(rpc) + ": malformed response: " + what);
}

Status from_grpc(const char* rpc, const grpc::Status& status) {
  if (status.ok()) return Status::success();
  const int code = static_cast<int>(status.error_code());
  return Error(to_error_code(code),
               std::string(rpc) + ": " + grpc_code_name(code) + ": " + status.error_message());
}

/// The id goes into an HTTP/2 header: gRPC refuses (by aborting) values that are not printable
/// ASCII, so check before sending. The message names the position, never the token.
Status check_session_id(const std::string& id) {
  if (id.size() > kMaxSessionIdBytes) {
    return invalid("session id has " + std::to_string(id.size()) + " bytes (at most " +
                   std::to_string(kMaxSessionIdBytes) + ")");
  }
  for (std::size_t i = 0; i < id.size(); ++i) {
    const auto c = static_cast<unsigned char>(id[i]);
    if (c < 0x20 || c > 0x7E) {
      return invalid("session id byte " + std::to_string(i) + " is not printable ASCII");
    }
  }
  return Status::success();
}

std::chrono::system_clock::time_point deadline_after(std::chrono::milliseconds timeout) {
  return std::chrono::system_clock::now() + timeout;
}

Status check_timeout(const CallOptions& call) {
  if (call.timeout && call.timeout->count() <= 0) {
    return invalid("call timeout " + std::to_string(call.timeout->count()) + " ms is not positive");
  }
  return Status::success();
}

// --------------------------------------------------------------------------------- conversions

v1::Method method_to_proto(core::Method method) {
  switch (method) {
    case core::Method::ScaleAware:
      return v1::METHOD_SCALE_AWARE;
    case core::Method::Arap:
      return v1::METHOD_ARAP;
    case core::Method::Laplacian:
      return v1::METHOD_LAPLACIAN;
  }
  return v1::METHOD_UNSPECIFIED;
}

/// UNSPECIFIED is nullopt (SessionInfo.last_method before the first move).
Result<std::optional<core::Method>> method_from_proto(v1::Method method, const char* rpc) {
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
  return malformed(rpc, "unknown method " + std::to_string(static_cast<int>(method)));
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

Result<std::vector<int>> indices_from_proto(
    const google::protobuf::RepeatedField<std::uint32_t>& in, const char* rpc) {
  std::vector<int> out;
  out.reserve(static_cast<std::size_t>(in.size()));
  for (const std::uint32_t v : in) {
    if (v > static_cast<std::uint32_t>(INT_MAX)) {
      return malformed(rpc, "vertex index " + std::to_string(v) + " exceeds INT_MAX");
    }
    out.push_back(static_cast<int>(v));
  }
  return out;
}

Result<Positions> positions_from_proto(const google::protobuf::RepeatedField<double>& flat,
                                       const char* rpc, const char* what) {
  if (flat.size() % 3 != 0) {
    return malformed(rpc, std::string(what) + " has " + std::to_string(flat.size()) +
                              " values, not a multiple of 3");
  }
  Positions P(flat.size() / 3, 3);
  for (Eigen::Index i = 0; i < P.rows(); ++i) {
    for (int k = 0; k < 3; ++k) P(i, k) = flat.Get(static_cast<int>(3 * i + k));
  }
  return P;
}

Eigen::Vector3d vec_from_proto(const v1::Vec3& v) { return {v.x(), v.y(), v.z()}; }

void vec_to_proto(const Eigen::Vector3d& v, v1::Vec3* out) {
  out->set_x(v.x());
  out->set_y(v.y());
  out->set_z(v.z());
}

Result<HandleRole> role_from_proto(v1::HandleRole role, const char* rpc) {
  switch (role) {
    case v1::HANDLE_ROLE_FIXED:
      return HandleRole::Fixed;
    case v1::HANDLE_ROLE_HANDLE:
      return HandleRole::Handle;
    case v1::HANDLE_ROLE_UNSPECIFIED:
    case v1::HandleRole_INT_MIN_SENTINEL_DO_NOT_USE_:
    case v1::HandleRole_INT_MAX_SENTINEL_DO_NOT_USE_:
      break;
  }
  return malformed(rpc, "handle role " + std::to_string(static_cast<int>(role)));
}

v1::HandleRole role_to_proto(HandleRole role) {
  switch (role) {
    case HandleRole::Fixed:
      return v1::HANDLE_ROLE_FIXED;
    case HandleRole::Handle:
      return v1::HANDLE_ROLE_HANDLE;
  }
  return v1::HANDLE_ROLE_UNSPECIFIED;
}

Result<std::vector<HandleGroup>> groups_from_proto(
    const google::protobuf::RepeatedPtrField<v1::HandleGroup>& in, const char* rpc) {
  std::vector<HandleGroup> out;
  for (const v1::HandleGroup& g : in) {
    HandleGroup group;
    MD_ASSIGN_OR_RETURN(group.role, role_from_proto(g.role(), rpc));
    MD_ASSIGN_OR_RETURN(group.vertices, indices_from_proto(g.vertices(), rpc));
    out.push_back(std::move(group));
  }
  return out;
}

Status groups_to_proto(const std::vector<HandleGroup>& groups,
                       google::protobuf::RepeatedPtrField<v1::HandleGroup>* out) {
  for (std::size_t g = 0; g < groups.size(); ++g) {
    v1::HandleGroup* group = out->Add();
    group->set_role(role_to_proto(groups[g].role));
    for (const int v : groups[g].vertices) {
      if (v < 0) {
        return invalid("handle group " + std::to_string(g) + " has negative vertex index " +
                       std::to_string(v));
      }
      group->add_vertices(static_cast<std::uint32_t>(v));
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
  info.bbox_min = vec_from_proto(in.bbox_min());
  info.bbox_max = vec_from_proto(in.bbox_max());
  info.revision = in.revision();
  MD_ASSIGN_OR_RETURN(info.groups, groups_from_proto(in.groups(), rpc));
  MD_ASSIGN_OR_RETURN(info.last_method, method_from_proto(in.last_method(), rpc));
  info.estimated_bytes = in.estimated_bytes();
  info.cached_deformers = static_cast<int>(in.cached_deformers());
  info.watchers = static_cast<int>(in.watchers());
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
  out.built_deformer = in.built_deformer();
  out.editor = in.editor();
  out.refinement = in.refinement();
  return out;
}

Status move_to_proto(const MoveSpec& spec, v1::MoveHandlesRequest* out) {
  for (std::size_t m = 0; m < spec.moves.size(); ++m) {
    const GroupMove& move = spec.moves[m];
    if (move.group < 0) {
      return invalid("move " + std::to_string(m) + ": negative group index " +
                     std::to_string(move.group));
    }
    v1::GroupMove* g = out->add_moves();
    g->set_group(static_cast<std::uint32_t>(move.group));
    vec_to_proto(move.translation, g->mutable_translation());
    g->mutable_rotation()->set_w(move.rotation.w());
    g->mutable_rotation()->set_x(move.rotation.x());
    g->mutable_rotation()->set_y(move.rotation.y());
    g->mutable_rotation()->set_z(move.rotation.z());
    g->set_scale(move.scale);
    if (move.pivot) vec_to_proto(*move.pivot, g->mutable_pivot());
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
  out->set_method(method_to_proto(spec.method));
  out->set_ora(spec.ora);
  if (spec.rigidity) out->set_rigidity(*spec.rigidity);
  out->set_max_iterations(static_cast<std::uint32_t>(spec.max_iterations));
  if (spec.tolerance) out->set_tolerance(*spec.tolerance);
  out->set_editor(spec.editor);
  out->set_full_positions(spec.full_positions);
  return Status::success();
}

Result<WatchUpdate> update_from_proto(const v1::DeformUpdate& in) {
  WatchUpdate update;
  MD_ASSIGN_OR_RETURN(update.result, result_from_proto(in.result(), "Watch"));
  update.is_snapshot = in.is_snapshot();
  update.skipped_revisions = in.skipped_revisions();
  return update;
}

}  // namespace

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
    // Transport failures and server faults: not the caller's input. The message keeps the gRPC
    // name (e.g. "UNAVAILABLE") for callers that retry.
    case grpc::StatusCode::UNKNOWN:
    case grpc::StatusCode::INTERNAL:
    case grpc::StatusCode::UNAVAILABLE:
    case grpc::StatusCode::DATA_LOSS:
    case grpc::StatusCode::DO_NOT_USE:
      return ErrorCode::Internal;
  }
  return ErrorCode::Internal;  // unreachable (range checked above); keeps -Wreturn-type quiet
}

std::string grpc_code_name(int grpc_code) {
  static constexpr const char* kNames[] = {"OK",
                                           "CANCELLED",
                                           "UNKNOWN",
                                           "INVALID_ARGUMENT",
                                           "DEADLINE_EXCEEDED",
                                           "NOT_FOUND",
                                           "ALREADY_EXISTS",
                                           "PERMISSION_DENIED",
                                           "RESOURCE_EXHAUSTED",
                                           "FAILED_PRECONDITION",
                                           "ABORTED",
                                           "OUT_OF_RANGE",
                                           "UNIMPLEMENTED",
                                           "INTERNAL",
                                           "UNAVAILABLE",
                                           "DATA_LOSS",
                                           "UNAUTHENTICATED"};
  if (grpc_code >= 0 && grpc_code < static_cast<int>(std::size(kNames))) return kNames[grpc_code];
  return "CODE_" + std::to_string(grpc_code);
}

// ------------------------------------------------------------------------------------ client

struct Client::Impl {
  ClientOptions options;
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::DeformationService::Stub> stub;

  std::chrono::milliseconds timeout_of(const CallOptions& call) const {
    return call.timeout.value_or(options.default_timeout);
  }

  /// Runs one unary call with the deadline, the x-session-id header (when `session_id` is set)
  /// and cancellation by `call.stop`.
  template <typename Request, typename Response, typename Method>
  Status unary(const char* rpc, const CallOptions& call, const std::string* session_id,
               Method method, const Request& request, Response* response) const {
    MD_RETURN_IF_ERROR(check_timeout(call));
    if (session_id) MD_RETURN_IF_ERROR(check_session_id(*session_id));
    if (call.stop.stop_requested()) {
      return Error(ErrorCode::Cancelled, std::string(rpc) + ": cancelled before it was sent");
    }
    grpc::ClientContext context;
    context.set_deadline(deadline_after(timeout_of(call)));
    if (session_id) context.AddMetadata(kSessionIdHeader, *session_id);
    // TryCancel is thread-safe; a stop before the call starts cancels it as soon as it does.
    const std::stop_callback on_stop(call.stop, [&context] { context.TryCancel(); });
    const grpc::Status status = ((*stub).*method)(&context, request, response);
    return from_grpc(rpc, status);
  }
};

Result<Client> Client::connect(const ClientOptions& options) {
  if (options.target.empty()) return invalid("client target is empty (expected host:port)");
  if (options.default_timeout.count() <= 0) {
    return invalid("default_timeout " + std::to_string(options.default_timeout.count()) +
                   " ms is not positive");
  }
  if (options.watch_timeout.count() <= 0) {
    return invalid("watch_timeout " + std::to_string(options.watch_timeout.count()) +
                   " ms is not positive");
  }
  if (options.max_message_mib < 1 || options.max_message_mib > 2047) {
    return invalid("max_message_mib " + std::to_string(options.max_message_mib) +
                   " is outside [1, 2047]");
  }
  std::string root_certs;
  if (options.tls) {
    if (options.tls->client_cert_chain_pem.empty() != options.tls->client_private_key_pem.empty()) {
      return invalid("set both TLS client_cert_chain_pem and client_private_key_pem, or neither");
    }
    root_certs = options.tls->root_certs_pem;
    if (!options.tls->root_certs_file.empty()) {
      if (!root_certs.empty()) {
        return invalid("set TLS root_certs_pem or root_certs_file, not both");
      }
      std::ifstream in(options.tls->root_certs_file, std::ios::binary);
      root_certs.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
      if (!in.good() && !in.eof()) {
        return invalid("cannot read TLS root certificates " +
                       options.tls->root_certs_file.string());
      }
      if (root_certs.empty()) {
        return invalid("TLS root certificates " + options.tls->root_certs_file.string() +
                       " are missing or empty");
      }
    }
  }
  return guard_exceptions("connect", ErrorCode::Internal, [&]() -> Result<Client> {
    auto impl = std::make_shared<Impl>();
    impl->options = options;
    grpc::ChannelArguments args;
    const int limit = options.max_message_mib * 1024 * 1024;  // <= 2047 MiB fits in int
    args.SetMaxReceiveMessageSize(limit);
    args.SetMaxSendMessageSize(limit);
    // BDP probing grows each stream's receive window (to megabytes on a fast link); without it
    // the window stays at gRPC's default 64 KiB and a slow reader pushes back on the server.
    if (!options.adaptive_receive_window) args.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
    std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::InsecureChannelCredentials();
    if (options.tls) {
      grpc::SslCredentialsOptions ssl;
      ssl.pem_root_certs = root_certs;  // empty: gRPC's default roots
      ssl.pem_cert_chain = options.tls->client_cert_chain_pem;
      ssl.pem_private_key = options.tls->client_private_key_pem;
      credentials = grpc::SslCredentials(ssl);
      if (!options.tls->server_name.empty()) {
        args.SetSslTargetNameOverride(options.tls->server_name);
      }
    }
    impl->channel = grpc::CreateCustomChannel(options.target, credentials, args);
    if (!impl->channel) return Error(ErrorCode::Internal, "cannot create a channel");
    impl->stub = v1::DeformationService::NewStub(impl->channel);
    return Client(std::move(impl));
  });
}

const ClientOptions& Client::options() const { return impl_->options; }

Result<Session> Client::create_session_from_file(const std::filesystem::path& path,
                                                 const CreateOptions& create,
                                                 const CallOptions& call) const {
  MD_ASSIGN_OR_RETURN(const io::MeshFormat format, io::format_from_path(path));
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) {
    return Error(ErrorCode::NotFound, "mesh file " + path.string() + " does not exist");
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return Error(ErrorCode::Internal, "cannot open mesh file " + path.string());
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (in.bad()) return Error(ErrorCode::Internal, "cannot read mesh file " + path.string());
  return create_session_from_bytes(std::move(bytes), format, create, call);
}

Result<Session> Client::create_session_from_bytes(std::string bytes, io::MeshFormat format,
                                                  const CreateOptions& create,
                                                  const CallOptions& call) const {
  v1::CreateSessionRequest request;
  request.set_mesh_bytes(std::move(bytes));
  request.set_format(format_to_proto(format));
  request.set_weld(create.weld);
  if (create.lambda) request.set_lambda(*create.lambda);
  if (create.rigidity) request.set_rigidity(*create.rigidity);
  v1::CreateSessionResponse response;
  MD_RETURN_IF_ERROR(impl_->unary("CreateSession", call, nullptr,
                                  &v1::DeformationService::Stub::CreateSession, request,
                                  &response));
  return session_from_proto(response);
}

Result<Session> Client::create_session_from_sample(const std::string& name,
                                                   const CreateOptions& create,
                                                   const CallOptions& call) const {
  v1::CreateSessionRequest request;
  request.set_sample(name);
  request.set_weld(create.weld);
  if (create.lambda) request.set_lambda(*create.lambda);
  if (create.rigidity) request.set_rigidity(*create.rigidity);
  v1::CreateSessionResponse response;
  MD_RETURN_IF_ERROR(impl_->unary("CreateSession", call, nullptr,
                                  &v1::DeformationService::Stub::CreateSession, request,
                                  &response));
  return session_from_proto(response);
}

Result<SessionInfo> Client::set_handles(const SessionRef& session,
                                        const std::vector<HandleGroup>& groups,
                                        core::Method prepare, const CallOptions& call) const {
  v1::SetHandlesRequest request;
  request.set_session_id(session.id);
  request.set_token(session.token);
  MD_RETURN_IF_ERROR(groups_to_proto(groups, request.mutable_groups()));
  request.set_prepare(method_to_proto(prepare));
  v1::SetHandlesResponse response;
  MD_RETURN_IF_ERROR(impl_->unary("SetHandles", call, &session.id,
                                  &v1::DeformationService::Stub::SetHandles, request, &response));
  return info_from_proto(response.info(), "SetHandles");
}

Result<DeformResult> Client::move(const SessionRef& session, const MoveSpec& spec,
                                  const CallOptions& call) const {
  v1::MoveHandlesRequest request;
  request.set_session_id(session.id);
  request.set_token(session.token);
  MD_RETURN_IF_ERROR(move_to_proto(spec, &request));
  v1::MoveHandlesResponse response;
  MD_RETURN_IF_ERROR(impl_->unary("MoveHandles", call, &session.id,
                                  &v1::DeformationService::Stub::MoveHandles, request, &response));
  return result_from_proto(response.result(), "MoveHandles");
}

Result<std::string> Client::get_mesh(const SessionRef& session, io::MeshFormat format,
                                     std::optional<std::uint64_t> revision,
                                     const CallOptions& call) const {
  v1::GetMeshRequest request;
  request.set_session_id(session.id);
  request.set_token(session.token);
  request.set_format(format_to_proto(format));
  if (revision) request.set_revision(*revision);
  v1::GetMeshResponse response;
  MD_RETURN_IF_ERROR(impl_->unary("GetMesh", call, &session.id,
                                  &v1::DeformationService::Stub::GetMesh, request, &response));
  if (response.format() != format_to_proto(format)) {
    return malformed("GetMesh", "asked for " + std::string(io::format_name(format)) +
                                    ", got format " + std::to_string(response.format()));
  }
  return std::move(*response.mutable_mesh_bytes());
}

Result<SessionInfo> Client::session_info(const SessionRef& session, const CallOptions& call) const {
  v1::GetSessionInfoRequest request;
  request.set_session_id(session.id);
  request.set_token(session.token);
  v1::GetSessionInfoResponse response;
  MD_RETURN_IF_ERROR(impl_->unary("GetSessionInfo", call, &session.id,
                                  &v1::DeformationService::Stub::GetSessionInfo, request,
                                  &response));
  return info_from_proto(response.info(), "GetSessionInfo");
}

Status Client::close_session(const SessionRef& session, const CallOptions& call) const {
  v1::CloseSessionRequest request;
  request.set_session_id(session.id);
  request.set_token(session.token);
  v1::CloseSessionResponse response;
  return impl_->unary("CloseSession", call, &session.id,
                      &v1::DeformationService::Stub::CloseSession, request, &response);
}

Result<ServerStats> Client::server_stats(const CallOptions& call) const {
  const v1::GetServerStatsRequest request;
  v1::GetServerStatsResponse response;
  MD_RETURN_IF_ERROR(impl_->unary("GetServerStats", call, nullptr,
                                  &v1::DeformationService::Stub::GetServerStats, request,
                                  &response));
  ServerStats stats;
  stats.sessions = response.sessions();
  stats.estimated_bytes = response.estimated_bytes();
  stats.resident_bytes = response.resident_bytes();
  stats.moves_committed = response.moves_committed();
  stats.moves_cancelled = response.moves_cancelled();
  stats.refinements_committed = response.refinements_committed();
  stats.deformer_constructions = response.deformer_constructions();
  stats.evicted_lru = response.evicted_lru();
  stats.evicted_idle = response.evicted_idle();
  stats.workers = response.workers();
  stats.uptime_seconds = response.uptime_seconds();
  return stats;
}

// ------------------------------------------------------------------------------------- watch

struct WatchStream::State {
  grpc::ClientContext context;
  std::unique_ptr<grpc::ClientReader<v1::DeformUpdate>> reader;
  /// Set when the stream could not start (bad id or timeout); returned by the first next().
  std::optional<Status> start_error;
  std::atomic<bool> is_cancelled_by_caller{false};
  bool is_done = false;
  std::optional<std::stop_callback<std::function<void()>>> on_stop;

  void cancel() {
    is_cancelled_by_caller.store(true);
    context.TryCancel();
  }

  /// Drains and finishes the stream; the final status.
  grpc::Status finish() {
    v1::DeformUpdate ignored;
    // After a cancel the server sends nothing more; reading to the end is what Finish expects.
    while (reader->Read(&ignored)) {
    }
    return reader->Finish();
  }
};

WatchStream::WatchStream(std::unique_ptr<State> state) : state_(std::move(state)) {}
WatchStream::WatchStream(WatchStream&&) noexcept = default;
WatchStream& WatchStream::operator=(WatchStream&& other) noexcept {
  if (this != &other) {
    WatchStream doomed(std::move(*this));  // cancels and finishes the old stream
    state_ = std::move(other.state_);
  }
  return *this;
}

WatchStream::~WatchStream() {
  if (!state_ || state_->is_done || !state_->reader) return;
  state_->on_stop.reset();
  state_->cancel();
  (void)state_->finish();
}

void WatchStream::cancel() {
  if (state_ && state_->reader) state_->cancel();
}

Result<std::optional<WatchUpdate>> WatchStream::next() {
  if (!state_) return Error(ErrorCode::FailedPrecondition, "Watch: stream was moved from");
  if (state_->start_error) {
    state_->is_done = true;
    return *state_->start_error;
  }
  if (state_->is_done) return std::optional<WatchUpdate>();
  if (state_->is_cancelled_by_caller.load()) {
    // Updates already buffered are dropped: the caller asked to stop.
    (void)state_->finish();
    state_->is_done = true;
    state_->on_stop.reset();
    return std::optional<WatchUpdate>();
  }
  v1::DeformUpdate message;
  if (state_->reader->Read(&message)) {
    Result<WatchUpdate> update = update_from_proto(message);
    if (!update.ok()) {
      state_->cancel();
      (void)state_->finish();
      state_->is_done = true;
      return update.status();
    }
    return std::optional<WatchUpdate>(std::move(update).value());
  }
  const grpc::Status status = state_->reader->Finish();
  state_->is_done = true;
  state_->on_stop.reset();
  if (status.ok()) return std::optional<WatchUpdate>();
  if (status.error_code() == grpc::StatusCode::CANCELLED && state_->is_cancelled_by_caller.load()) {
    return std::optional<WatchUpdate>();
  }
  return from_grpc("Watch", status);
}

WatchStream Client::open_watch(const SessionRef& session, const CallOptions& call) const {
  auto state = std::make_unique<WatchStream::State>();
  Status ok = check_timeout(call);
  if (ok.ok()) ok = check_session_id(session.id);
  if (!ok.ok()) {
    state->start_error = ok;
    return WatchStream(std::move(state));
  }
  state->context.set_deadline(deadline_after(call.timeout.value_or(impl_->options.watch_timeout)));
  state->context.AddMetadata(kSessionIdHeader, session.id);
  v1::WatchRequest request;
  request.set_session_id(session.id);
  request.set_token(session.token);
  state->reader = impl_->stub->Watch(&state->context, request);
  WatchStream::State* raw = state.get();
  state->on_stop.emplace(call.stop, std::function<void()>([raw] { raw->cancel(); }));
  return WatchStream(std::move(state));
}

Result<WatchEnd> Client::watch(const SessionRef& session,
                               const std::function<bool(const WatchUpdate&)>& on_update,
                               const CallOptions& call) const {
  WatchStream stream = open_watch(session, call);
  // Bounded by the stream's deadline: every Read returns by then.
  for (;;) {
    Result<std::optional<WatchUpdate>> next = stream.next();
    if (!next.ok()) return next.status();
    if (!next->has_value()) {
      return call.stop.stop_requested() ? WatchEnd::StoppedByToken : WatchEnd::StreamEnded;
    }
    if (!on_update(**next)) return WatchEnd::StoppedByCallback;  // ~WatchStream cancels
  }
}

// ------------------------------------------------------------------------------------ mirror

Status SessionMirror::apply_snapshot(const DeformResult& result) {
  if (!result.positions) {
    return invalid("snapshot of revision " + std::to_string(result.revision) + " has no positions");
  }
  if (has_snapshot_ && result.positions->rows() != positions_.rows()) {
    return invalid("snapshot of revision " + std::to_string(result.revision) + " has " +
                   std::to_string(result.positions->rows()) + " vertices, the mirror " +
                   std::to_string(positions_.rows()));
  }
  positions_ = *result.positions;
  revision_ = result.revision;
  has_snapshot_ = true;
  return Status::success();
}

Status SessionMirror::apply_delta(const DeformResult& result) {
  if (!has_snapshot_) {
    return Error(ErrorCode::FailedPrecondition,
                 "delta for revision " + std::to_string(result.revision) + " before any snapshot");
  }
  if (result.revision != revision_ + 1) {
    return Error(ErrorCode::FailedPrecondition,
                 "delta for revision " + std::to_string(result.revision) +
                     " does not follow the mirrored revision " + std::to_string(revision_));
  }
  if (result.changed_positions.rows() != static_cast<Eigen::Index>(result.changed_indices.size())) {
    return invalid("delta for revision " + std::to_string(result.revision) + " has " +
                   std::to_string(result.changed_indices.size()) + " indices but " +
                   std::to_string(result.changed_positions.rows()) + " positions");
  }
  // Check everything before writing, so a bad delta leaves the mirror unchanged.
  for (const int v : result.changed_indices) {
    if (v < 0 || v >= positions_.rows()) {
      return invalid("delta for revision " + std::to_string(result.revision) + " changes vertex " +
                     std::to_string(v) + " (#V=" + std::to_string(positions_.rows()) + ")");
    }
  }
  for (std::size_t j = 0; j < result.changed_indices.size(); ++j) {
    positions_.row(result.changed_indices[j]) =
        result.changed_positions.row(static_cast<Eigen::Index>(j));
  }
  revision_ = result.revision;
  return Status::success();
}

Status SessionMirror::apply(const WatchUpdate& update) {
  return update.is_snapshot ? apply_snapshot(update.result) : apply_delta(update.result);
}

Status SessionMirror::apply(const DeformResult& result) {
  return result.positions ? apply_snapshot(result) : apply_delta(result);
}

}  // namespace meshdeform::client
