#include "server/transport/grpc_web_gateway.h"

#include <google/protobuf/descriptor.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/support/byte_buffer.h>
#include <grpcpp/support/client_callback.h>

#include <algorithm>
#include <climits>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <utility>

#include "meshdeform/v1/deformation.grpc.pb.h"
#include "server/service/log.h"
#include "server/service/metrics.h"
#include "server/transport/grpc_web_codec.h"
#include "server/transport/grpc_web_cors.h"
#include "server/transport/status_mapping.h"

namespace meshdeform::transport {
namespace {

using grpc_web::encode_body;
using grpc_web::Encoding;
using grpc_web::response_content_type;

constexpr std::string_view kFrontend = "grpc-web";
constexpr std::string_view kHealthCheckPath = "/grpc.health.v1.Health/Check";

struct MethodInfo {
  std::string name;  ///< the last path segment, the metrics label
  bool is_server_streaming = false;
};

/// The trailer frame of a call ending with `code`.
std::string trailer_frame(grpc::StatusCode code, std::string_view message) {
  return grpc_web::trailer_frame(static_cast<int>(code), message);
}

std::string byte_buffer_to_string(const grpc::ByteBuffer& buffer) {
  std::vector<grpc::Slice> slices;
  std::string out;
  if (!buffer.Dump(&slices).ok()) return out;
  out.reserve(buffer.Length());
  for (const grpc::Slice& slice : slices) {
    out.append(reinterpret_cast<const char*>(slice.begin()), slice.size());
  }
  return out;
}

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

/// Metadata values must be printable ASCII (gRPC refuses others).
bool is_printable_ascii(std::string_view value) {
  return std::all_of(value.begin(), value.end(), [](char c) { return c >= 0x20 && c <= 0x7E; });
}

class ForwardedCall;

}  // namespace

struct GrpcWebGateway::Shared {
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<grpc::GenericStub> stub;
  std::size_t max_message_bytes = 0;
  GrpcWebGatewayOptions options;
  GrpcWebCors cors;  ///< from options.allowed_origins and options.cors_max_age_seconds
  service::MetricsRegistry* metrics = nullptr;
  std::map<std::string, MethodInfo, std::less<>> methods;  ///< by path

  mutable std::mutex mutex;
  std::condition_variable ended;
  bool is_stopping = false;
  std::size_t unary_calls = 0;
  std::size_t streams = 0;
  std::map<const ForwardedCall*, std::weak_ptr<ForwardedCall>> calls;  ///< before OnDone
  std::size_t live_calls = 0;  ///< ForwardedCall objects not yet destroyed

  void record(std::string_view method, grpc::StatusCode code,
              std::chrono::steady_clock::time_point start) const {
    if (metrics != nullptr) {
      metrics->record_rpc(kFrontend, method, grpc_code_name(code), seconds_since(start));
    }
  }

  /// A call that ends without messages: HTTP 200, the trailer frame as the body, and the status
  /// as headers too.
  static HttpResponse trailers_only(Encoding encoding, HttpHeaders headers, grpc::StatusCode code,
                                    std::string_view message) {
    headers.emplace_back("grpc-status", std::to_string(static_cast<int>(code)));
    headers.emplace_back("grpc-message", percent_encode_grpc_message(message));
    return HttpResponse{200, std::string(response_content_type(encoding)),
                        encode_body(encoding, trailer_frame(code, message)), std::move(headers)};
  }
};

namespace {

/// One forwarded call: a generic bidi-streaming call (one request message, then half-close),
/// which serves unary and server-streaming methods alike on the wire. Owns itself (self_) until
/// OnDone. A hold keeps OnDone from running while the read loop waits for a chunk to be written
/// (the next StartRead comes from the HTTP side, outside a reaction).
class ForwardedCall final : public grpc::ClientBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer> {
 public:
  struct Setup {
    std::string path;
    MethodInfo method;
    Encoding encoding = Encoding::Binary;
    HttpHeaders headers;  ///< CORS headers of the response
    std::optional<std::chrono::nanoseconds> timeout;
    std::string session_id;
    std::string peer;  ///< the browser's address, for the service's per-client rate limits
    std::string forwarded_for;  ///< X-Forwarded-For of a proxy in front (used only if trusted)
    std::chrono::steady_clock::time_point start;
  };

  /// Starts the call; the caller has counted it in `shared` already.
  static void start(GrpcWebGateway::Shared& shared, Setup setup,
                    grpc::ByteBuffer request, std::shared_ptr<HttpExchange> exchange) {
    auto call = std::shared_ptr<ForwardedCall>(
        new ForwardedCall(shared, std::move(setup), std::move(request), exchange));
    call->self_ = call;
    bool is_stopping = false;
    {
      const std::lock_guard lock(call->shared_->mutex);
      call->shared_->calls.emplace(call.get(), call);
      // Admitted just before stop() collected the open calls: cancel it here instead.
      is_stopping = call->shared_->is_stopping;
    }
    if (call->setup_.timeout) {
      call->context_.set_deadline(
          std::chrono::system_clock::now() +
          std::chrono::duration_cast<std::chrono::system_clock::duration>(*call->setup_.timeout));
    }
    if (!call->setup_.session_id.empty()) {
      call->context_.AddMetadata("x-session-id", call->setup_.session_id);
    }
    // The service names in-process callers by this (client_identity in deform_service_impl.h);
    // over the network it is ignored, so a browser cannot pick its own name.
    if (!call->setup_.peer.empty()) call->context_.AddMetadata("x-meshdeform-peer", call->setup_.peer);
    // A proxy's X-Forwarded-For, which the service honours only with --trust-forwarded-for.
    if (!call->setup_.forwarded_for.empty()) {
      call->context_.AddMetadata("x-forwarded-for", call->setup_.forwarded_for);
    }
    call->shared_->stub->PrepareBidiStreamingCall(&call->context_, call->setup_.path,
                                                  grpc::StubOptions(), call.get());
    call->StartWriteLast(&call->request_, grpc::WriteOptions());
    call->AddHold();
    call->StartRead(&call->response_);
    call->StartCall();
    if (is_stopping) call->cancel();
    // The browser leaving (or the listener stopping) cancels the call.
    std::weak_ptr<ForwardedCall> weak = call;
    exchange->on_close([weak] {
      if (const std::shared_ptr<ForwardedCall> strong = weak.lock()) strong->cancel();
    });
  }

  void cancel() { context_.TryCancel(); }

  void OnReadDone(bool ok) override {
    if (!ok) {
      RemoveHold();  // the stream ended; OnDone follows with the status
      return;
    }
    const std::string payload = byte_buffer_to_string(response_);
    response_.Clear();
    ++messages_;
    if (!setup_.method.is_server_streaming) {
      // Unary: answered in one piece in OnDone.
      grpc_web::append_frame(body_, grpc_web::kDataFlag, payload);
      StartRead(&response_);
      return;
    }
    std::string framed = grpc_web::frame(grpc_web::kDataFlag, payload);
    if (messages_ == 1) {
      exchange_->start_stream(200, std::string(response_content_type(setup_.encoding)),
                              setup_.headers);
    }
    std::shared_ptr<ForwardedCall> self = self_;  // alive: OnDone waits for the hold
    exchange_->write_chunk(encode_body(setup_.encoding, std::move(framed)), [self](bool written) {
      if (written) {
        self->StartRead(&self->response_);
      } else {
        self->cancel();  // the browser is gone
        self->RemoveHold();
      }
    });
  }

  void OnDone(const grpc::Status& status) override {
    const grpc::StatusCode code = status.error_code();
    shared_->record(setup_.method.name, code, setup_.start);
    if (messages_ == 0) {
      exchange_->respond(GrpcWebGateway::Shared::trailers_only(setup_.encoding, setup_.headers, code,
                                                               status.error_message()));
    } else if (!setup_.method.is_server_streaming) {
      body_ += trailer_frame(code, status.error_message());
      exchange_->respond(HttpResponse{200, std::string(response_content_type(setup_.encoding)),
                                      encode_body(setup_.encoding, std::move(body_)),
                                      setup_.headers});
    } else {
      exchange_->write_chunk(
          encode_body(setup_.encoding, trailer_frame(code, status.error_message())), nullptr);
      exchange_->end_stream();
    }
    exchange_.reset();
    {
      const std::lock_guard lock(shared_->mutex);
      shared_->calls.erase(this);
      if (setup_.method.is_server_streaming) {
        --shared_->streams;
      } else {
        --shared_->unary_calls;
      }
    }
    shared_->ended.notify_all();
    // Last: may destroy this object (unless a callback of the HTTP side holds it for a moment).
    std::shared_ptr<ForwardedCall> keep = std::move(self_);
  }

 private:
  /// Counts this object in Shared::live_calls. The first member, so destroyed last: after
  /// context_, which holds a reference to the channel too. The count drops (and waiters are
  /// notified) under the lock; once it is released the gateway may destroy Shared and the
  /// channel, and this thread touches neither again. So the channel is never destroyed on one
  /// of its own callback threads (as the last owner dropping it in OnDone would: a double free
  /// in gRPC 1.51's callback completion queue).
  class LiveToken {
   public:
    explicit LiveToken(GrpcWebGateway::Shared& shared) : shared_(&shared) {
      const std::lock_guard lock(shared_->mutex);
      ++shared_->live_calls;
    }
    ~LiveToken() {
      const std::lock_guard lock(shared_->mutex);
      --shared_->live_calls;
      shared_->ended.notify_all();
    }
    LiveToken(const LiveToken&) = delete;
    LiveToken& operator=(const LiveToken&) = delete;

   private:
    GrpcWebGateway::Shared* shared_;
  };

  ForwardedCall(GrpcWebGateway::Shared& shared, Setup setup, grpc::ByteBuffer request,
                std::shared_ptr<HttpExchange> exchange)
      : live_(shared), shared_(&shared), setup_(std::move(setup)), request_(std::move(request)),
        exchange_(std::move(exchange)) {}

  LiveToken live_;
  GrpcWebGateway::Shared* shared_;  ///< owned by the gateway, which outlives this (see live_)
  Setup setup_;
  grpc::ClientContext context_;
  grpc::ByteBuffer request_;
  grpc::ByteBuffer response_;  // owned by gRPC while a read is pending
  std::shared_ptr<HttpExchange> exchange_;
  std::string body_;         // unary: the data frames so far
  std::size_t messages_ = 0;
  std::shared_ptr<ForwardedCall> self_;
};

}  // namespace

GrpcWebGateway::GrpcWebGateway(grpc::Server& server, std::size_t max_message_bytes,
                               GrpcWebGatewayOptions options, service::MetricsRegistry* metrics)
    : shared_(std::make_unique<Shared>()) {
  const int limit = max_message_bytes > static_cast<std::size_t>(INT_MAX)
                        ? INT_MAX
                        : static_cast<int>(max_message_bytes);
  grpc::ChannelArguments arguments;
  arguments.SetMaxReceiveMessageSize(limit);
  arguments.SetMaxSendMessageSize(limit);
  shared_->channel = server.InProcessChannel(arguments);
  shared_->stub = std::make_unique<grpc::GenericStub>(shared_->channel);
  shared_->max_message_bytes = max_message_bytes;
  shared_->cors = GrpcWebCors{options.allowed_origins, options.cors_max_age_seconds};
  shared_->options = std::move(options);
  shared_->metrics = metrics;
  // The allowed methods come from the service's descriptor, so new RPCs need no gateway change.
  const google::protobuf::ServiceDescriptor* service =
      v1::CreateSessionRequest::descriptor()->file()->FindServiceByName("DeformationService");
  for (int i = 0; service != nullptr && i < service->method_count(); ++i) {
    const google::protobuf::MethodDescriptor* method = service->method(i);
    if (method->client_streaming()) continue;  // gRPC-Web has no client streaming
    shared_->methods.emplace("/" + service->full_name() + "/" + method->name(),
                             MethodInfo{method->name(), method->server_streaming()});
  }
  shared_->methods.emplace(std::string(kHealthCheckPath), MethodInfo{"Check", false});
}

GrpcWebGateway::~GrpcWebGateway() {
  stop();
  // The calls' objects can outlive OnDone briefly (a callback of the HTTP side holding one).
  std::unique_lock lock(shared_->mutex);
  if (!shared_->ended.wait_for(lock, std::chrono::seconds(10),
                               [this] { return shared_->live_calls == 0; })) {
    service::log_event(service::LogLevel::Error, "grpc_web_leak",
                       service::LogFields().add("live_calls", shared_->live_calls));
    lock.unlock();
    (void)shared_.release();  // calls still point at it: leak rather than crash
    return;
  }
  lock.unlock();
}

bool GrpcWebGateway::handles(std::string_view method, std::string_view target) const {
  if (method != "POST" && method != "OPTIONS") return false;
  const std::string_view path = target_path(target);
  if (path.size() < 4 || path.front() != '/') return false;
  const std::size_t slash = path.find('/', 1);
  if (slash == std::string_view::npos || slash == 1 || slash + 1 == path.size()) return false;
  if (path.find('/', slash + 1) != std::string_view::npos) return false;
  return path.substr(1, slash - 1).find('.') != std::string_view::npos;
}

std::size_t GrpcWebGateway::max_request_bytes() const {
  const std::size_t framed = shared_->max_message_bytes + grpc_web::kFrameHeaderBytes;
  return (framed + 2) / 3 * 4 + 4096;  // base64 (grpc-web-text) and slack
}

void GrpcWebGateway::handle(HttpRequest request, std::shared_ptr<HttpExchange> exchange) {
  const auto start = std::chrono::steady_clock::now();
  Shared& shared = *shared_;
  const std::string_view origin = request.find_header("origin");
  const std::string path(target_path(request.target));
  if (request.method == "OPTIONS") {
    exchange->respond(shared.cors.preflight(origin));
    return;
  }
  if (request.method != "POST") {
    exchange->respond(text_response(405, "use POST\n", {{"Allow", "POST, OPTIONS"}}));
    return;
  }
  HttpHeaders headers = shared.cors.response_headers(origin);
  const std::optional<Encoding> encoding =
      grpc_web::parse_content_type(request.find_header("content-type"));
  if (!encoding) {
    HttpResponse response = text_response(
        415, "gRPC-Web wants content-type application/grpc-web+proto (or application/grpc-web, "
             "application/grpc-web-text)\n",
        headers);
    response.headers.emplace_back("Accept", "application/grpc-web+proto");
    exchange->respond(std::move(response));
    return;
  }
  const auto found = shared.methods.find(path);
  const std::string_view label = found == shared.methods.end()
                                     ? std::string_view("unknown")
                                     : std::string_view(found->second.name);
  const auto fail = [&](grpc::StatusCode code, const std::string& message) {
    shared.record(label, code, start);
    exchange->respond(Shared::trailers_only(*encoding, headers, code, message));
  };
  if (found == shared.methods.end()) {
    fail(grpc::StatusCode::UNIMPLEMENTED,
         "unknown method " + path.substr(0, 200) + " (the gateway serves " +
             std::string(v1::DeformationService::service_full_name()) + " and " +
             std::string(kHealthCheckPath.substr(1)) + ")");
    return;
  }
  const MethodInfo& method = found->second;
  if (request.is_body_over_limit) {
    fail(grpc::StatusCode::RESOURCE_EXHAUSTED,
         "request body of " + std::to_string(request.declared_body_bytes) +
             " bytes is over the limit (messages up to " +
             std::to_string(shared.max_message_bytes) + " bytes)");
    return;
  }
  std::string body = std::move(request.body);
  if (*encoding == Encoding::Text) {
    std::optional<std::string> decoded = grpc_web::base64_decode(body);
    if (!decoded) {
      fail(grpc::StatusCode::INTERNAL, "bad base64 in the grpc-web-text request body");
      return;
    }
    body = std::move(*decoded);
  }
  // Framing: exactly one uncompressed data frame (a fault is INTERNAL, as gRPC answers it).
  const Result<std::string_view> payload =
      grpc_web::unframe_request(body, shared.max_message_bytes);
  if (!payload.ok()) {
    fail(payload.status().code() == ErrorCode::ResourceExhausted
             ? grpc::StatusCode::RESOURCE_EXHAUSTED
             : grpc::StatusCode::INTERNAL,
         payload.status().message());
    return;
  }
  ForwardedCall::Setup setup;
  setup.path = path;
  setup.method = method;
  setup.encoding = *encoding;
  setup.start = start;
  const std::chrono::milliseconds limit =
      method.is_server_streaming ? shared.options.stream_timeout : shared.options.unary_timeout;
  if (const std::string_view timeout = request.find_header("grpc-timeout"); !timeout.empty()) {
    Result<std::chrono::nanoseconds> parsed = parse_grpc_timeout(timeout);
    if (!parsed.ok()) {
      fail(grpc::StatusCode::INVALID_ARGUMENT, parsed.status().message());
      return;
    }
    setup.timeout = limit.count() > 0 ? std::min<std::chrono::nanoseconds>(*parsed, limit) : *parsed;
  } else if (limit.count() > 0) {
    setup.timeout = limit;
  }
  if (const std::string_view session = request.find_header("x-session-id"); !session.empty()) {
    if (session.size() > 256 || !is_printable_ascii(session)) {
      fail(grpc::StatusCode::INVALID_ARGUMENT,
           "bad x-session-id header (want at most 256 printable ASCII characters)");
      return;
    }
    setup.session_id = std::string(session);
  }
  setup.peer = request.peer;
  if (const std::string_view forwarded = request.find_header("x-forwarded-for");
      !forwarded.empty() && forwarded.size() <= 256 && is_printable_ascii(forwarded)) {
    setup.forwarded_for = std::string(forwarded);
  }
  enum class Admission { Admitted, Stopping, Full } admission = Admission::Admitted;
  {
    const std::lock_guard lock(shared.mutex);
    std::size_t& open = method.is_server_streaming ? shared.streams : shared.unary_calls;
    const std::size_t cap =
        method.is_server_streaming ? shared.options.max_streams : shared.options.max_unary_calls;
    if (shared.is_stopping) {
      admission = Admission::Stopping;
    } else if (open >= cap) {
      admission = Admission::Full;
    } else {
      ++open;
    }
  }
  switch (admission) {
    case Admission::Admitted: {
      setup.headers = std::move(headers);
      grpc::Slice slice(payload->data(), payload->size());
      ForwardedCall::start(shared, std::move(setup), grpc::ByteBuffer(&slice, 1),
                           std::move(exchange));
      break;
    }
    case Admission::Stopping:
      fail(grpc::StatusCode::UNAVAILABLE, "the gateway is stopping");
      break;
    case Admission::Full:
      fail(grpc::StatusCode::RESOURCE_EXHAUSTED,
           method.is_server_streaming
               ? "too many open streams (" + std::to_string(shared.options.max_streams) + ")"
               : "too many calls in flight (" + std::to_string(shared.options.max_unary_calls) +
                     ")");
      break;
  }
}

bool GrpcWebGateway::stop(std::chrono::milliseconds wait) {
  std::vector<std::shared_ptr<ForwardedCall>> open;
  {
    const std::lock_guard lock(shared_->mutex);
    shared_->is_stopping = true;
    for (const auto& [raw, weak] : shared_->calls) {
      if (std::shared_ptr<ForwardedCall> call = weak.lock()) open.push_back(std::move(call));
    }
  }
  // Outside the lock: gRPC may run the calls' reactions inline.
  for (const auto& call : open) call->cancel();
  open.clear();
  std::unique_lock lock(shared_->mutex);
  const bool ended =
      shared_->ended.wait_for(lock, wait, [this] { return shared_->calls.empty(); });
  if (!ended) {
    service::log_event(service::LogLevel::Warn, "grpc_web_stop_timeout",
                       service::LogFields().add("open_calls", shared_->calls.size()));
  }
  return ended;
}

std::size_t GrpcWebGateway::open_calls() const {
  const std::lock_guard lock(shared_->mutex);
  return shared_->unary_calls + shared_->streams;
}

std::size_t GrpcWebGateway::open_streams() const {
  const std::lock_guard lock(shared_->mutex);
  return shared_->streams;
}

}  // namespace meshdeform::transport
