#include "server/transport/deform_service_impl.h"

#include <chrono>
#include <deque>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>
#include <string_view>
#include <utility>

#include "codec/update_codec.h"
#include "proto/wire/delta_mapping.h"
#include "proto/wire/wire_mapping.h"
#include "server/service/guard.h"
#include "server/service/log.h"
#include "server/transport/proto_convert.h"
#include "server/transport/serial_executor.h"
#include "server/transport/status_mapping.h"

namespace meshdeform::transport {
namespace {

/// A unary reactor whose cancellation (client cancel, deadline, server shutdown) requests a stop
/// of the work it started. Finish may be called from any thread, once.
class StoppableUnaryReactor final : public grpc::ServerUnaryReactor {
 public:
  std::stop_token stop_token() const { return stop_.get_token(); }
  void OnCancel() override { stop_.request_stop(); }
  void OnDone() override { delete this; }

 private:
  std::stop_source stop_;
};

/// The call's deadline on the steady clock; nullopt when there is none (or it is years away).
std::optional<std::chrono::steady_clock::time_point> steady_deadline(
    const grpc::CallbackServerContext& context) {
  const std::chrono::system_clock::time_point deadline = context.deadline();
  const std::chrono::system_clock::time_point now = std::chrono::system_clock::now();
  if (deadline == std::chrono::system_clock::time_point::max() ||
      deadline - now > std::chrono::hours(24 * 365)) {
    return std::nullopt;
  }
  return std::chrono::steady_clock::now() +
         std::chrono::duration_cast<std::chrono::steady_clock::duration>(deadline - now);
}

/// One call's bookkeeping: when it finishes, its status is mapped (to_grpc_status), counted and
/// timed in the service's metrics, and logged as one structured line. Session ids are logged;
/// tokens never are. Routine successes of high-rate calls (moves, reads) log at debug level.
class CallRecord {
 public:
  CallRecord(service::DeformationService& service, std::string_view rpc, std::string session)
      : service_(&service), rpc_(rpc), session_(std::move(session)),
        start_(std::chrono::steady_clock::now()) {}

  grpc::Status finish(const Status& status) const {
    grpc::Status mapped = to_grpc_status(status, rpc_);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    const std::string_view code = grpc_code_name(mapped.error_code());
    service_->metrics().record_rpc("grpc", rpc_, code, seconds);
    const bool routine = rpc_ == "MoveHandles" || rpc_ == "GetSessionInfo" || rpc_ == "GetMesh" ||
                         rpc_ == "GetServerStats";
    const service::LogLevel level =
        !status.ok() ? (mapped.error_code() == grpc::StatusCode::INTERNAL ? service::LogLevel::Error
                                                                          : service::LogLevel::Info)
        : routine   ? service::LogLevel::Debug
                    : service::LogLevel::Info;
    service::LogFields fields;
    fields.add("frontend", "grpc").add("method", rpc_).add("code", code).add("ms", seconds * 1e3);
    if (!session_.empty()) fields.add("session", session_.substr(0, 64));
    if (!status.ok()) fields.add("message", mapped.error_message());
    service::log_event(level, "rpc", fields);
    return mapped;
  }

  std::string_view rpc() const { return rpc_; }

 private:
  service::DeformationService* service_;
  std::string_view rpc_;
  std::string session_;
  std::chrono::steady_clock::time_point start_;
};

/// The completion of a call handed to the service's workers: `fill(value)` writes the response
/// (or the result's error passes on), then the reactor finishes with the recorded status.
template <typename T, typename Fill>
auto finish_with(StoppableUnaryReactor* reactor, CallRecord call, Fill fill) {
  return [reactor, call = std::move(call), fill = std::move(fill)](Result<T> result) {
    const Status status = service::run_guarded(call.rpc(), [&]() -> Status {
      if (!result.ok()) return result.status();
      fill(std::move(result).value());
      return Status::success();
    });
    reactor->Finish(call.finish(status));
  };
}

/// Starts a call whose work runs on the service's workers: `start(reactor)` converts the request
/// and hands it over (the completion from finish_with then finishes the call exactly once). Only
/// an error before the hand-over (a conversion error, an exception) finishes the call here.
template <typename Start>
grpc::ServerUnaryReactor* start_async(const CallRecord& call, Start&& start) {
  auto* reactor = new StoppableUnaryReactor();
  const Status started = service::run_guarded(call.rpc(), [&]() -> Status { return start(reactor); });
  if (!started.ok()) reactor->Finish(call.finish(started));
  return reactor;
}

grpc::ServerUnaryReactor* finish_now(grpc::CallbackServerContext* context, const CallRecord& call,
                                     const Status& status) {
  grpc::ServerUnaryReactor* reactor = context->DefaultReactor();
  reactor->Finish(call.finish(status));
  return reactor;
}

/// The first value of metadata `key`, or empty.
std::string metadata_value(const grpc::CallbackServerContext& context, std::string_view key) {
  const auto& metadata = context.client_metadata();
  const auto it = metadata.find(grpc::string_ref(key.data(), key.size()));
  if (it == metadata.end()) return {};
  return std::string(it->second.data(), it->second.size());
}

/// A client name fit for a map key and a log: printable ASCII, at most 64 bytes.
std::string sanitize_client(std::string_view text) {
  std::string out;
  for (char c : text.substr(0, 64)) {
    if (c > ' ' && c < 127) out += c;
  }
  return out;
}

/// How long a link-sized stream waits after its last new revision before it sends the rest of
/// a budget-limited one (continuations): the server's default refinement delay, the pause that
/// ends a drag.
constexpr std::chrono::milliseconds kContinuationDelay{150};

/// Streams a subscription. Owned by itself (self_) until OnDone; the watcher's notify holds only a
/// weak_ptr, so a notify racing with OnDone keeps the object alive but does nothing.
class WatchReactor final : public grpc::ServerWriteReactor<v1::DeformUpdate> {
 public:
  /// @param[in] deltas    link-sized updates (UpdateOptions), encoded on `executor`; nullopt:
  ///                      positions as `encoding` says, encoded where the update is taken.
  /// @param[in] coarse_preview  WatchRequest.coarse_preview: add each coarse move's level.
  static WatchReactor* start(service::Subscription subscription, v1::PositionEncoding encoding,
                             CallRecord call,
                             std::optional<codec::StreamSettings> deltas = std::nullopt,
                             SerialExecutor* executor = nullptr, bool coarse_preview = false) {
    auto reactor = std::shared_ptr<WatchReactor>(
        new WatchReactor(std::move(subscription), encoding, std::move(call)));
    reactor->deltas_ = std::move(deltas);
    reactor->coarse_preview_ = coarse_preview;
    reactor->executor_ = executor;
    reactor->self_ = reactor;
    std::weak_ptr<WatchReactor> weak = reactor;
    // The join snapshot is already pending, so this starts the first write at once (allowed
    // before the handler returns the reactor).
    reactor->subscription_->set_notify([weak] {
      if (std::shared_ptr<WatchReactor> strong = weak.lock()) strong->pump();
    });
    return reactor.get();
  }

  void OnWriteDone(bool ok) override {
    {
      const std::lock_guard lock(mutex_);
      is_writing_ = false;
      if (!ok) is_cancelled_ = true;  // the stream is broken (client gone)
    }
    pump();
  }

  void OnCancel() override {
    {
      const std::lock_guard lock(mutex_);
      is_cancelled_ = true;
    }
    pump();
  }

  void OnDone() override {
    service::Subscription subscription;
    std::shared_ptr<WatchReactor> keep;
    {
      const std::lock_guard lock(mutex_);
      subscription = std::move(subscription_);
      keep = std::move(self_);
    }
    subscription->set_notify(nullptr);
    subscription.reset();  // unsubscribes; may close the watcher, which notifies nobody now
    // `keep` releases this object (or a racing notify's weak_ptr lock does, later).
  }

 private:
  WatchReactor(service::Subscription subscription, v1::PositionEncoding encoding, CallRecord call)
      : subscription_(std::move(subscription)), encoding_(encoding), call_(std::move(call)) {}

  /// Starts the next write or the finish, if neither a write is in flight nor we are finished.
  /// gRPC operations are started outside the lock.
  void pump() {
    enum class Next { Nothing, Write, Encode, FinishClosed, FinishCancelled } next = Next::Nothing;
    std::optional<service::DeformUpdate> to_encode;
    std::optional<std::chrono::steady_clock::time_point> continuation_at;
    {
      const std::lock_guard lock(mutex_);
      if (is_finished_ || is_writing_ || is_encoding_) return;
      if (is_cancelled_) {
        next = Next::FinishCancelled;
      } else if (deltas_) {
        // Link-sized updates: the newest revision if one came, else the next step toward the
        // last one while a byte budget left vertices pending; encoded off this thread.
        to_encode = subscription_->try_take();
        if (to_encode) {
          next = Next::Encode;
          is_encoding_ = true;
        } else if (encoder_ && encoder_->pending()) {
          // The rest of a budget-limited revision waits until revisions stop coming for
          // kContinuationDelay: during a drag the line carries new revisions, not the remainder
          // of ones about to be replaced.
          const auto due = last_revision_at_ + kContinuationDelay;
          if (std::chrono::steady_clock::now() >= due) {
            next = Next::Encode;
            is_encoding_ = true;
          } else if (!is_continuation_scheduled_) {
            is_continuation_scheduled_ = true;
            continuation_at = due;
          }
        } else if (subscription_->closed()) {
          next = Next::FinishClosed;
        }
      } else if (std::optional<service::DeformUpdate> update = subscription_->try_take()) {
        update_to_proto(*update, encoding_, &message_);
        if (coarse_preview_ && update->result) {
          coarse_to_proto(*update->result, &coarse_key_sent_, &message_);
        }
        next = Next::Write;
      } else if (subscription_->closed()) {
        // OK when the session was closed; otherwise what ended the watch (shutdown: UNAVAILABLE).
        next = Next::FinishClosed;
      }
      if (next == Next::Write) is_writing_ = true;
      if (next == Next::FinishClosed || next == Next::FinishCancelled) is_finished_ = true;
    }
    if (continuation_at) {
      std::weak_ptr<WatchReactor> weak;
      {
        const std::lock_guard lock(mutex_);
        weak = self_;
      }
      executor_->post_at(*continuation_at, [weak] {
        if (std::shared_ptr<WatchReactor> strong = weak.lock()) {
          {
            const std::lock_guard lock(strong->mutex_);
            strong->is_continuation_scheduled_ = false;
          }
          strong->pump();
        }
      });
    }
    switch (next) {
      case Next::Nothing:
        break;
      case Next::Write:
        StartWrite(&message_);
        break;
      case Next::Encode: {
        std::shared_ptr<WatchReactor> self;
        {
          const std::lock_guard lock(mutex_);
          self = self_;
        }
        if (!self) {  // OnDone ran: nothing more to write
          const std::lock_guard lock(mutex_);
          is_encoding_ = false;
          break;
        }
        executor_->post([self, update = std::move(to_encode)]() mutable {
          self->encode_and_write(std::move(update));
        });
        break;
      }
      case Next::FinishClosed:
        Finish(call_.finish(subscription_->close_status()));
        break;
      case Next::FinishCancelled:
        Finish(call_.finish(Error(ErrorCode::Cancelled, "watch cancelled")));
        break;
    }
  }

  /// On the executor: encodes the next delta into message_ (only this runs while is_encoding_,
  /// so the encoder and the message need no lock), then writes it, or finishes on an error.
  void encode_and_write(std::optional<service::DeformUpdate> update) {
    const Status encoded = service::run_guarded("Watch", [&]() -> Status {
      message_.Clear();
      if (update) {
        if (!update->result || !update->result->positions) {
          return Error(ErrorCode::Internal, "watch update without positions");
        }
        const Positions& positions = *update->result->positions;
        if (!encoder_) {
          MD_ASSIGN_OR_RETURN(codec::StreamEncoder created,
                              codec::StreamEncoder::create(*deltas_,
                                                           static_cast<int>(positions.rows())));
          encoder_.emplace(std::move(created));
        }
        MD_ASSIGN_OR_RETURN(
            codec::EncodedUpdate delta,
            encoder_->encode(positions, update->result->revision,
                             deltas_->lossless_settled && update->result->settled));
        last_result_ = update->result;
        last_revision_at_ = std::chrono::steady_clock::now();
        message_.set_skipped_revisions(update->skipped_revisions);
        wire::delta_to_proto(delta, message_.mutable_delta());
        if (coarse_preview_) coarse_to_proto(*update->result, &coarse_key_sent_, &message_);
      } else {
        MD_ASSIGN_OR_RETURN(codec::EncodedUpdate delta, encoder_->encode_pending());
        message_.set_continuation(true);
        wire::delta_to_proto(delta, message_.mutable_delta());
      }
      result_figures_to_proto(*last_result_, message_.mutable_result());
      message_.set_is_snapshot(is_first_);
      is_first_ = false;
      return Status::success();
    });
    bool write = false;
    bool finish_error = false;
    {
      const std::lock_guard lock(mutex_);
      is_encoding_ = false;
      if (!is_finished_ && !is_cancelled_) {
        if (encoded.ok()) {
          is_writing_ = true;
          write = true;
        } else {
          is_finished_ = true;
          finish_error = true;
        }
      }
    }
    if (write) {
      StartWrite(&message_);
    } else if (finish_error) {
      Finish(call_.finish(encoded));
    } else {
      pump();  // cancelled meanwhile: finish
    }
  }

  std::mutex mutex_;
  service::Subscription subscription_;
  const v1::PositionEncoding encoding_;
  v1::DeformUpdate message_;  // owned by gRPC while is_writing_, by the executor while encoding
  // Link-sized updates (UpdateOptions): the stream's settings, its encoder (created with the
  // first update, when the vertex count is known), the revision continuations carry.
  std::optional<codec::StreamSettings> deltas_;
  std::optional<codec::StreamEncoder> encoder_;
  std::shared_ptr<const service::DeformResult> last_result_;
  // WatchRequest.coarse_preview, and the key of the coarse level whose mesh this stream sent
  // last (read and written where updates are made: under mutex_, or by the one encoding task).
  bool coarse_preview_ = false;
  std::optional<std::uint64_t> coarse_key_sent_;
  SerialExecutor* executor_ = nullptr;
  // When the last new revision was encoded: written while encoding, read by pump() after.
  std::chrono::steady_clock::time_point last_revision_at_{};
  bool is_continuation_scheduled_ = false;
  bool is_first_ = true;
  bool is_encoding_ = false;
  bool is_writing_ = false;
  bool is_cancelled_ = false;
  bool is_finished_ = false;
  CallRecord call_;
  std::shared_ptr<WatchReactor> self_;
};

template <typename Message>
class FailedWriteReactor final : public grpc::ServerWriteReactor<Message> {
 public:
  explicit FailedWriteReactor(const grpc::Status& status) { this->Finish(status); }
  void OnDone() override { delete this; }
};

/// Streams the progress of heavy work, then its response (CreateSessionWithProgress,
/// SetHandlesWithProgress). Progress events wait in a queue that keeps one event per phase in a
/// row (a newer event of the phase at its tail replaces it): a slow reader skips fractions, never
/// a phase, and the queue stays as short as the list of phases. The response, or the error
/// status, comes last. Cancellation requests the
/// work's stop; the call finishes when the work reports (the service always does). Owned by
/// itself (self_) until OnDone and by the work's callbacks, which may outlive the call: after
/// OnDone they find it finished and do nothing.
template <typename Event>
class ProgressStreamReactor final : public grpc::ServerWriteReactor<Event> {
 public:
  static std::shared_ptr<ProgressStreamReactor> start(CallRecord call) {
    auto reactor = std::shared_ptr<ProgressStreamReactor>(new ProgressStreamReactor(std::move(call)));
    reactor->self_ = reactor;
    return reactor;
  }

  std::stop_token stop_token() const { return stop_.get_token(); }

  /// A progress event (any thread); replaces a queued one of the same phase at the tail.
  void progress(Event event) {
    {
      const std::lock_guard lock(mutex_);
      if (result_ || is_finished_) return;
      if (!pending_.empty() && pending_.back().progress().phase() == event.progress().phase()) {
        pending_.back() = std::move(event);
      } else {
        pending_.push_back(std::move(event));
      }
    }
    pump();
  }

  /// The end of the work (any thread, once): `last` is written before an OK status.
  void finish(const Status& status, std::optional<Event> last) {
    {
      const std::lock_guard lock(mutex_);
      if (result_) return;
      result_ = status;
      last_ = std::move(last);
    }
    pump();
  }

  void OnWriteDone(bool ok) override {
    {
      const std::lock_guard lock(mutex_);
      is_writing_ = false;
      if (!ok) is_broken_ = true;  // the client is gone: write nothing more
    }
    if (!ok) stop_.request_stop();
    pump();
  }

  void OnCancel() override {
    {
      const std::lock_guard lock(mutex_);
      is_broken_ = true;
    }
    stop_.request_stop();
    pump();
  }

  void OnDone() override {
    std::shared_ptr<ProgressStreamReactor> keep;
    {
      const std::lock_guard lock(mutex_);
      is_finished_ = true;
      keep = std::move(self_);
    }
    // `keep` releases this object, unless the work's callbacks still hold it.
  }

 private:
  explicit ProgressStreamReactor(CallRecord call) : call_(std::move(call)) {}

  /// Starts the next write or the finish if no write is in flight; gRPC calls outside the lock.
  /// The response is an ordinary write and Finish follows its OnWriteDone, as Watch does: with
  /// StartWriteAndFinish the response did not reach clients of the gRPC-Web gateway (the viewer
  /// saw the stream end without it; GrpcWebTest.ProgressStreamsCarryEveryPhaseAndEndWithTheResponse
  /// hung), while native clients got it.
  void pump() {
    enum class Next { Nothing, Write, Finish } next = Next::Nothing;
    grpc::Status status;
    {
      const std::lock_guard lock(mutex_);
      if (is_finished_ || is_writing_) return;
      if (!pending_.empty() && !is_broken_) {
        message_ = std::move(pending_.front());
        pending_.pop_front();
        next = Next::Write;
      } else if (result_ && result_->ok() && last_ && !is_broken_) {
        message_ = std::move(*last_);
        last_.reset();
        next = Next::Write;
      } else if (result_) {
        status = call_.finish(*result_);
        next = Next::Finish;
        is_finished_ = true;
      }
      if (next == Next::Write) is_writing_ = true;
    }
    switch (next) {
      case Next::Nothing:
        break;
      case Next::Write:
        this->StartWrite(&message_);
        break;
      case Next::Finish:
        this->Finish(status);
        break;
    }
  }

  std::mutex mutex_;
  std::stop_source stop_;
  std::deque<Event> pending_;
  std::optional<Status> result_;
  std::optional<Event> last_;
  Event message_;  // owned by gRPC while a write is in flight
  bool is_writing_ = false;
  bool is_broken_ = false;
  bool is_finished_ = false;
  CallRecord call_;
  std::shared_ptr<ProgressStreamReactor> self_;
};

/// The completion of a *WithProgress call's work: `fill(value, event)` writes the response into
/// the last event (or the result's error passes on), then the reactor finishes.
template <typename Event, typename T, typename Fill>
auto finish_stream_with(std::shared_ptr<ProgressStreamReactor<Event>> reactor,
                        std::string_view rpc, Fill fill) {
  return [reactor = std::move(reactor), rpc, fill = std::move(fill)](Result<T> result) {
    std::optional<Event> last;
    const Status status = service::run_guarded(rpc, [&]() -> Status {
      if (!result.ok()) return result.status();
      last.emplace();
      fill(result.value(), *last);
      return Status::success();
    });
    reactor->finish(status, std::move(last));
  };
}

/// The progress callback of a ProgressStreamReactor<Event> (Event has a `progress` field).
template <typename Event>
service::ProgressFn stream_progress(const std::shared_ptr<ProgressStreamReactor<Event>>& reactor) {
  return [reactor](const service::ProgressEvent& progress) {
    Event event;
    progress_to_proto(progress, event.mutable_progress());
    reactor->progress(std::move(event));
  };
}

}  // namespace

std::string client_identity(const grpc::CallbackServerContext& context,
                            const ClientIdentityOptions& options) {
  const std::string peer = context.peer();
  if (options.trust_forwarded_for) {
    // Behind a proxy that sets the header (the gateway passes the browser's on).
    std::string forwarded = metadata_value(context, "x-forwarded-for");
    forwarded = forwarded.substr(0, forwarded.find(','));
    if (std::string name = sanitize_client(forwarded); !name.empty()) return "fwd:" + name;
  }
  if (options.resolve_peer) {
    // Relayed by the front door: the client's own address, not the relay's loopback one.
    if (std::optional<std::string> client = options.resolve_peer(peer)) {
      return sanitize_client(*client);
    }
  }
  if (peer.rfind("ipv4:", 0) != 0 && peer.rfind("ipv6:", 0) != 0 && peer.rfind("unix:", 0) != 0) {
    // In-process: the gateway forwarding a browser's call names the browser.
    if (std::string browser = metadata_value(context, "x-meshdeform-peer"); !browser.empty()) {
      return sanitize_client(browser);
    }
    return sanitize_client(peer);
  }
  if (peer.rfind("unix:", 0) == 0) return sanitize_client(peer);
  // Strip the port: "ipv4:1.2.3.4:5678" -> "ipv4:1.2.3.4", "ipv6:[::1]:5678" -> "ipv6:[::1]".
  const std::size_t colon = peer.rfind(':');
  return sanitize_client(colon > 5 ? std::string_view(peer).substr(0, colon) : peer);
}

/// Refuses a call over its client's rate limit (ResourceExhausted, with the wait in the message
/// and in the `retry-after-ms` trailer). @return the refusal, or success.
Status admit_call(service::DeformationService& service, grpc::CallbackServerContext* context,
                  const ClientIdentityOptions& identity, service::RateLimitedCall kind) {
  std::chrono::milliseconds retry_after{0};
  Status admitted = service.admit(client_identity(*context, identity), kind, &retry_after);
  if (!admitted.ok()) {
    context->AddTrailingMetadata("retry-after-ms", std::to_string(retry_after.count()));
  }
  return admitted;
}

grpc::ServerUnaryReactor* DeformServiceImpl::CreateSession(grpc::CallbackServerContext* context,
                                                           const v1::CreateSessionRequest* request,
                                                           v1::CreateSessionResponse* response) {
  // Parsing and cleaning an upload run on the service's workers, not on this gRPC thread.
  const CallRecord call(service_, "CreateSession", {});
  if (Status admitted = admit_call(service_, context, identity_,
                                   service::RateLimitedCall::CreateSession);
      !admitted.ok()) {
    return finish_now(context, call, admitted);
  }
  return start_async(call, [&](StoppableUnaryReactor* reactor) -> Status {
    MD_ASSIGN_OR_RETURN(service::CreateSessionRequest converted,
                        create_request_from_proto(*request));
    converted.client = client_identity(*context, identity_);  // uploads are admitted per client
    service_.create_session_async(
        std::move(converted), reactor->stop_token(),
        finish_with<service::CreatedSession>(
            reactor, call,
            [response](service::CreatedSession created) { created_to_proto(created, response); }));
    return Status::success();
  });
}

grpc::ServerUnaryReactor* DeformServiceImpl::SetHandles(grpc::CallbackServerContext* context,
                                                        const v1::SetHandlesRequest* request,
                                                        v1::SetHandlesResponse* response) {
  const CallRecord call(service_, "SetHandles", request->session_id());
  return start_async(call, [&](StoppableUnaryReactor* reactor) -> Status {
    MD_ASSIGN_OR_RETURN(service::SetHandlesRequest converted, set_handles_from_proto(*request));
    converted.client = client_identity(*context, identity_);  // precomputes are admitted per client
    service_.set_handles_async(
        service::SessionId{request->session_id()}, service::Token{request->token()},
        std::move(converted), reactor->stop_token(),
        finish_with<service::SessionInfo>(reactor, call, [response](service::SessionInfo info) {
          session_info_to_proto(info, response->mutable_info());
        }));
    return Status::success();
  });
}

grpc::ServerWriteReactor<v1::CreateSessionEvent>* DeformServiceImpl::CreateSessionWithProgress(
    grpc::CallbackServerContext* context, const v1::CreateSessionRequest* request) {
  const CallRecord call(service_, "CreateSessionWithProgress", {});
  if (Status admitted = admit_call(service_, context, identity_,
                                   service::RateLimitedCall::CreateSession);
      !admitted.ok()) {
    return new FailedWriteReactor<v1::CreateSessionEvent>(call.finish(admitted));
  }
  using Reactor = ProgressStreamReactor<v1::CreateSessionEvent>;
  const std::shared_ptr<Reactor> reactor = Reactor::start(call);
  const Status started = service::run_guarded(call.rpc(), [&]() -> Status {
    MD_ASSIGN_OR_RETURN(service::CreateSessionRequest converted,
                        create_request_from_proto(*request));
    converted.client = client_identity(*context, identity_);
    service_.create_session_async(
        std::move(converted), reactor->stop_token(),
        finish_stream_with<v1::CreateSessionEvent, service::CreatedSession>(
            reactor, call.rpc(),
            [](const service::CreatedSession& created, v1::CreateSessionEvent& event) {
              created_to_proto(created, event.mutable_response());
            }),
        stream_progress(reactor));
    return Status::success();
  });
  if (!started.ok()) reactor->finish(started, std::nullopt);
  return reactor.get();
}

grpc::ServerWriteReactor<v1::SetHandlesEvent>* DeformServiceImpl::SetHandlesWithProgress(
    grpc::CallbackServerContext* context, const v1::SetHandlesRequest* request) {
  const CallRecord call(service_, "SetHandlesWithProgress", request->session_id());
  using Reactor = ProgressStreamReactor<v1::SetHandlesEvent>;
  const std::shared_ptr<Reactor> reactor = Reactor::start(call);
  const Status started = service::run_guarded(call.rpc(), [&]() -> Status {
    MD_ASSIGN_OR_RETURN(service::SetHandlesRequest converted, set_handles_from_proto(*request));
    converted.client = client_identity(*context, identity_);
    service_.set_handles_async(
        service::SessionId{request->session_id()}, service::Token{request->token()},
        std::move(converted), reactor->stop_token(),
        finish_stream_with<v1::SetHandlesEvent, service::SessionInfo>(
            reactor, call.rpc(),
            [](const service::SessionInfo& info, v1::SetHandlesEvent& event) {
              session_info_to_proto(info, event.mutable_response()->mutable_info());
            }),
        stream_progress(reactor));
    return Status::success();
  });
  if (!started.ok()) reactor->finish(started, std::nullopt);
  return reactor.get();
}

grpc::ServerUnaryReactor* DeformServiceImpl::MoveHandles(grpc::CallbackServerContext* context,
                                                         const v1::MoveHandlesRequest* request,
                                                         v1::MoveHandlesResponse* response) {
  const CallRecord call(service_, "MoveHandles", request->session_id());
  if (Status admitted = admit_call(service_, context, identity_,
                                   service::RateLimitedCall::MoveHandles);
      !admitted.ok()) {
    return finish_now(context, call, admitted);
  }
  return start_async(call, [&](StoppableUnaryReactor* reactor) -> Status {
    MD_ASSIGN_OR_RETURN(service::MoveRequest converted, move_from_proto(*request));
    converted.deadline = steady_deadline(*context);
    MD_ASSIGN_OR_RETURN(v1::PositionEncoding encoding, encoding_from_proto(request->encoding()));
    const bool full_positions = request->full_positions();
    const bool omit_positions = request->omit_positions();
    service_.move_handles_async(
        service::SessionId{request->session_id()}, service::Token{request->token()},
        std::move(converted), reactor->stop_token(),
        finish_with<service::DeformResult>(
            reactor, call,
            [response, full_positions, omit_positions, encoding](service::DeformResult result) {
              if (omit_positions) {
                result_figures_to_proto(result, response->mutable_result());
              } else {
                result_to_proto(result, full_positions, encoding, response->mutable_result());
              }
            }));
    return Status::success();
  });
}

grpc::ServerWriteReactor<v1::DeformUpdate>* DeformServiceImpl::Watch(
    grpc::CallbackServerContext* context, const v1::WatchRequest* request) {
  (void)context;
  CallRecord call(service_, "Watch", request->session_id());
  const Result<v1::PositionEncoding> encoding = encoding_from_proto(request->encoding());
  if (!encoding.ok()) {
    return new FailedWriteReactor<v1::DeformUpdate>(call.finish(encoding.status()));
  }
  Result<service::Subscription> subscription = service::run_guarded("Watch", [&] {
    return service_.watch(service::SessionId{request->session_id()},
                          service::Token{request->token()});
  });
  if (!subscription.ok()) {
    return new FailedWriteReactor<v1::DeformUpdate>(call.finish(subscription.status()));
  }
  std::optional<codec::StreamSettings> deltas;
  if (request->has_updates() && request->updates().mode() != v1::DELTA_MODE_UNSPECIFIED) {
    // The grid is the rest mesh's bounding box (its corner, and the diagonal a relative
    // tolerance is taken of).
    const Result<std::optional<codec::StreamSettings>> settings =
        service::run_guarded("Watch", [&]() -> Result<std::optional<codec::StreamSettings>> {
          MD_ASSIGN_OR_RETURN(service::SessionInfo info,
                              service_.session_info(service::SessionId{request->session_id()},
                                                    service::Token{request->token()}));
          return wire::stream_settings_from_proto(request->updates(), info.bbox_min,
                                                  info.bbox_max);
        });
    if (!settings.ok()) {
      return new FailedWriteReactor<v1::DeformUpdate>(call.finish(settings.status()));
    }
    deltas = *settings;
  }
  return WatchReactor::start(std::move(subscription).value(), *encoding, std::move(call),
                             std::move(deltas), deltas ? &encode_executor() : nullptr,
                             request->coarse_preview());
}

SerialExecutor& DeformServiceImpl::encode_executor() {
  const std::lock_guard lock(executor_mutex_);
  if (!encode_executor_) encode_executor_ = std::make_unique<SerialExecutor>();
  return *encode_executor_;
}

DeformServiceImpl::~DeformServiceImpl() = default;

grpc::ServerUnaryReactor* DeformServiceImpl::GetMesh(grpc::CallbackServerContext* context,
                                                     const v1::GetMeshRequest* request,
                                                     v1::GetMeshResponse* response) {
  (void)context;
  // Serialising (GLB/OBJ/...) runs on the service's workers.
  const CallRecord call(service_, "GetMesh", request->session_id());
  return start_async(call, [&](StoppableUnaryReactor* reactor) -> Status {
    MD_ASSIGN_OR_RETURN(io::MeshFormat format, format_from_proto(request->format(), true));
    std::optional<std::uint64_t> revision;
    if (request->has_revision()) revision = request->revision();
    service_.get_mesh_async(
        service::SessionId{request->session_id()}, service::Token{request->token()}, format,
        revision, reactor->stop_token(),
        finish_with<std::string>(reactor, call, [response, format](std::string bytes) {
          response->set_mesh_bytes(std::move(bytes));
          response->set_format(wire::format_to_proto(format));
        }));
    return Status::success();
  });
}

grpc::ServerUnaryReactor* DeformServiceImpl::GetSessionInfo(
    grpc::CallbackServerContext* context, const v1::GetSessionInfoRequest* request,
    v1::GetSessionInfoResponse* response) {
  const CallRecord call(service_, "GetSessionInfo", request->session_id());
  return finish_now(context, call, service::run_guarded("GetSessionInfo", [&]() -> Status {
    MD_ASSIGN_OR_RETURN(service::SessionInfo info,
                        service_.session_info(service::SessionId{request->session_id()},
                                              service::Token{request->token()}));
    session_info_to_proto(info, response->mutable_info());
    response->set_can_edit(info.token_can_edit);
    response->set_view_token(info.view_token);
    return Status::success();
  }));
}

grpc::ServerUnaryReactor* DeformServiceImpl::CloseSession(grpc::CallbackServerContext* context,
                                                          const v1::CloseSessionRequest* request,
                                                          v1::CloseSessionResponse* response) {
  (void)response;
  const CallRecord call(service_, "CloseSession", request->session_id());
  return finish_now(context, call, service::run_guarded("CloseSession", [&]() -> Status {
    return service_.close_session(service::SessionId{request->session_id()},
                                  service::Token{request->token()});
  }));
}

grpc::ServerUnaryReactor* DeformServiceImpl::GetServerStats(
    grpc::CallbackServerContext* context, const v1::GetServerStatsRequest* request,
    v1::GetServerStatsResponse* response) {
  (void)request;
  const CallRecord call(service_, "GetServerStats", {});
  return finish_now(context, call, service::run_guarded("GetServerStats", [&]() -> Status {
    server_stats_to_proto(service_.stats(), uptime_seconds(), response);
    return Status::success();
  }));
}

double DeformServiceImpl::uptime_seconds() const {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - started_).count();
}

}  // namespace meshdeform::transport
