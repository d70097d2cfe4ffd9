#include "client_cpp/client.h"

#include <grpcpp/create_channel.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/security/credentials.h>
#include <grpcpp/support/channel_arguments.h>

#include <atomic>
#include <fstream>
#include <iterator>
#include <utility>

#include "client_cpp/client_conversions.h"
#include "codec/update_codec.h"
#include "proto/wire/delta_mapping.h"
#include "meshdeform/v1/deformation.grpc.pb.h"
#include "proto/wire/wire_mapping.h"

namespace meshdeform::client {
namespace {

namespace v1 = ::meshdeform::v1;
using detail::from_grpc;
using detail::invalid;
using detail::malformed;

constexpr const char* kSessionIdHeader = "x-session-id";
/// Longest session id sent as metadata (server ids are 32 hex digits).
constexpr std::size_t kMaxSessionIdBytes = 1024;

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

}  // namespace

// ------------------------------------------------------------------------------------ client

struct Client::Impl {
  ClientOptions options;
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<v1::DeformationService::Stub> stub;

  std::chrono::milliseconds timeout_of(const CallOptions& call) const {
    return call.timeout.value_or(options.default_timeout);
  }

  /// What every call checks before it is sent: the timeout, the session id (when set) and a
  /// stop already requested.
  static Status check_call(const char* rpc, const CallOptions& call,
                           const std::string* session_id) {
    MD_RETURN_IF_ERROR(check_timeout(call));
    if (session_id) MD_RETURN_IF_ERROR(check_session_id(*session_id));
    if (call.stop.stop_requested()) {
      return Error(ErrorCode::Cancelled, std::string(rpc) + ": cancelled before it was sent");
    }
    return Status::success();
  }

  /// The call's deadline and x-session-id header (when `session_id` is set).
  void configure(grpc::ClientContext& context, const CallOptions& call,
                 const std::string* session_id) const {
    context.set_deadline(deadline_after(timeout_of(call)));
    if (session_id) context.AddMetadata(kSessionIdHeader, *session_id);
  }

  /// Runs one unary call with the deadline, the x-session-id header (when `session_id` is set)
  /// and cancellation by `call.stop`.
  template <typename Request, typename Response, typename Method>
  Status unary(const char* rpc, const CallOptions& call, const std::string* session_id,
               Method method, const Request& request, Response* response) const {
    MD_RETURN_IF_ERROR(check_call(rpc, call, session_id));
    grpc::ClientContext context;
    configure(context, call, session_id);
    // TryCancel is thread-safe; a stop before the call starts cancels it as soon as it does.
    const std::stop_callback on_stop(call.stop, [&context] { context.TryCancel(); });
    const grpc::Status status = ((*stub).*method)(&context, request, response);
    return from_grpc(rpc, status);
  }

  /// Runs a *WithProgress call (a server stream of Event: progress, then the response) like
  /// unary(): call.on_progress hears every progress event, `response` gets the last event's.
  /// Falls back to the unary `plain` method when the server does not know the streaming one.
  template <typename Event, typename Request, typename Response, typename StreamMethod,
            typename Method>
  Status with_progress(const char* rpc, const CallOptions& call, const std::string* session_id,
                       StreamMethod stream_method, Method plain, const Request& request,
                       Response* response) const {
    if (!call.on_progress) return unary(rpc, call, session_id, plain, request, response);
    MD_RETURN_IF_ERROR(check_call(rpc, call, session_id));
    bool heard = false, answered = false;
    grpc::Status status;
    {
      grpc::ClientContext context;
      configure(context, call, session_id);
      const std::stop_callback on_stop(call.stop, [&context] { context.TryCancel(); });
      std::unique_ptr<grpc::ClientReader<Event>> reader = ((*stub).*stream_method)(&context, request);
      Event event;
      while (reader->Read(&event)) {
        heard = true;
        if (event.has_response()) {
          *response = std::move(*event.mutable_response());
          answered = true;
        } else if (event.has_progress() && !answered) {
          Progress progress;
          progress.phase = event.progress().phase();
          progress.fraction = event.progress().fraction();
          progress.elapsed_seconds = event.progress().elapsed_seconds();
          call.on_progress(progress);
        }
      }
      status = reader->Finish();
    }
    if (status.error_code() == grpc::StatusCode::UNIMPLEMENTED && !heard) {
      return unary(rpc, call, session_id, plain, request, response);
    }
    MD_RETURN_IF_ERROR(from_grpc(rpc, status));
    if (!answered) return malformed(rpc, "the progress stream ended without a response");
    return Status::success();
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
  request.set_format(wire::format_to_proto(format));
  request.set_weld(create.weld);
  if (create.lambda) request.set_lambda(*create.lambda);
  if (create.rigidity) request.set_rigidity(*create.rigidity);
  v1::CreateSessionResponse response;
  MD_RETURN_IF_ERROR(impl_->with_progress<v1::CreateSessionEvent>(
      "CreateSession", call, nullptr, &v1::DeformationService::Stub::CreateSessionWithProgress,
      &v1::DeformationService::Stub::CreateSession, request, &response));
  return detail::session_from_proto(response);
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
  MD_RETURN_IF_ERROR(impl_->with_progress<v1::CreateSessionEvent>(
      "CreateSession", call, nullptr, &v1::DeformationService::Stub::CreateSessionWithProgress,
      &v1::DeformationService::Stub::CreateSession, request, &response));
  return detail::session_from_proto(response);
}

Result<SessionInfo> Client::set_handles(const SessionRef& session,
                                        const std::vector<HandleGroup>& groups,
                                        core::Method prepare, const CallOptions& call) const {
  v1::SetHandlesRequest request;
  request.set_session_id(session.id);
  request.set_token(session.token);
  MD_RETURN_IF_ERROR(detail::groups_to_proto(groups, request.mutable_groups()));
  request.set_prepare(wire::method_to_proto(prepare));
  v1::SetHandlesResponse response;
  MD_RETURN_IF_ERROR(impl_->with_progress<v1::SetHandlesEvent>(
      "SetHandles", call, &session.id, &v1::DeformationService::Stub::SetHandlesWithProgress,
      &v1::DeformationService::Stub::SetHandles, request, &response));
  return detail::info_from_proto(response.info(), "SetHandles");
}

Result<DeformResult> Client::move(const SessionRef& session, const MoveSpec& spec,
                                  const CallOptions& call) const {
  v1::MoveHandlesRequest request;
  request.set_session_id(session.id);
  request.set_token(session.token);
  MD_RETURN_IF_ERROR(detail::move_to_proto(spec, &request));
  v1::MoveHandlesResponse response;
  MD_RETURN_IF_ERROR(impl_->unary("MoveHandles", call, &session.id,
                                  &v1::DeformationService::Stub::MoveHandles, request, &response));
  return detail::result_from_proto(response.result(), "MoveHandles");
}

Result<std::string> Client::get_mesh(const SessionRef& session, io::MeshFormat format,
                                     std::optional<std::uint64_t> revision,
                                     const CallOptions& call) const {
  v1::GetMeshRequest request;
  request.set_session_id(session.id);
  request.set_token(session.token);
  request.set_format(wire::format_to_proto(format));
  if (revision) request.set_revision(*revision);
  v1::GetMeshResponse response;
  MD_RETURN_IF_ERROR(impl_->unary("GetMesh", call, &session.id,
                                  &v1::DeformationService::Stub::GetMesh, request, &response));
  if (response.format() != wire::format_to_proto(format)) {
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
  return detail::info_from_proto(response.info(), "GetSessionInfo");
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
  return detail::stats_from_proto(response);
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
  /// Link-sized updates: the positions reconstructed so far.
  std::optional<codec::StreamDecoder> decoder;
  /// Coarse preview: the levels' meshes this stream received.
  detail::CoarseLevelDecoder coarse;

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
    Result<WatchUpdate> update = detail::update_from_proto(message);
    if (update.ok() && message.has_delta()) {
      // A link-sized update: apply the delta to what this stream delivered so far.
      Result<codec::UpdateHeader> header =
          wire::delta_header_from_proto(message.delta(), message.result().revision());
      Status applied = header.status();
      if (applied.ok()) {
        if (!state_->decoder) state_->decoder.emplace();
        applied = state_->decoder->apply(*header, message.delta().payload());
      }
      if (!applied.ok()) {
        update = Error(ErrorCode::InvalidArgument,
                       "Watch: malformed response: update " +
                           std::to_string(message.delta().sequence()) + ": " + applied.message());
      } else {
        DeltaStats stats;
        stats.sequence = header->sequence;
        stats.vertices_sent = header->vertices_sent;
        stats.shift = header->shift;
        stats.max_error = header->max_error;
        stats.pending_vertices = header->pending_vertices;
        stats.payload_bytes = message.delta().payload().size();
        stats.raw_bytes = header->raw_bytes;
        stats.continuation = message.continuation();
        stats.lossless = header->mode == codec::DeltaMode::Lossless;
        update->delta = stats;
        update->result.positions = state_->decoder->positions();
      }
    }
    if (update.ok() && message.has_coarse()) {
      Result<CoarseLevel> coarse = state_->coarse.decode(message.coarse());
      if (coarse.ok()) {
        update->coarse = std::move(coarse).value();
      } else {
        update = coarse.status();
      }
    }
    if (update.ok()) update->wire_bytes = message.ByteSizeLong();
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

WatchStream Client::open_watch(const SessionRef& session, const CallOptions& call,
                               const UpdateOptions& updates) const {
  WatchOptions options;
  options.updates = updates;
  return open_watch(session, call, options);
}

WatchStream Client::open_watch(const SessionRef& session, const CallOptions& call,
                               const WatchOptions& watch_options) const {
  const UpdateOptions& updates = watch_options.updates;
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
  if (updates.mode != UpdateOptions::Mode::Off) {
    v1::UpdateOptions* options = request.mutable_updates();
    options->set_mode(updates.mode == UpdateOptions::Mode::Lossless ? v1::DELTA_MODE_LOSSLESS
                                                                    : v1::DELTA_MODE_QUANTIZED);
    options->set_tolerance(updates.tolerance);
    options->set_relative_tolerance(updates.relative_tolerance);
    options->set_max_update_bytes(updates.max_update_bytes);
    options->set_lossless_settled(updates.lossless_settled);
  }
  request.set_coarse_preview(watch_options.coarse_preview);
  state->reader = impl_->stub->Watch(&state->context, request);
  WatchStream::State* raw = state.get();
  state->on_stop.emplace(call.stop, std::function<void()>([raw] { raw->cancel(); }));
  return WatchStream(std::move(state));
}

Result<WatchEnd> Client::watch(const SessionRef& session,
                               const std::function<bool(const WatchUpdate&)>& on_update,
                               const CallOptions& call, const UpdateOptions& updates) const {
  WatchOptions options;
  options.updates = updates;
  return watch(session, on_update, call, options);
}

Result<WatchEnd> Client::watch(const SessionRef& session,
                               const std::function<bool(const WatchUpdate&)>& on_update,
                               const CallOptions& call, const WatchOptions& options) const {
  WatchStream stream = open_watch(session, call, options);
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

}  // namespace meshdeform::client
