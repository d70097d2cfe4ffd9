#include "server/transport/grpc_web_gateway.h"

#include <google/protobuf/descriptor.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/support/byte_buffer.h>
#include <grpcpp/support/client_callback.h>

#include <algorithm>
#include <array>
#include <climits>
#include <condition_variable>
#include <cstdint>
#include <fstream>
#include <map>
#include <mutex>
#include <optional>
#include <sstream>
#include <utility>

#include "meshdeform/v1/deformation.grpc.pb.h"
#include "server/service/log.h"
#include "server/service/metrics.h"
#include "server/transport/status_mapping.h"

namespace meshdeform::transport {
namespace {

constexpr std::string_view kFrontend = "grpc-web";
constexpr std::string_view kHealthCheckPath = "/grpc.health.v1.Health/Check";
constexpr unsigned char kDataFlag = 0x00;
constexpr unsigned char kTrailerFlag = 0x80;
constexpr std::size_t kFrameHeaderBytes = 5;
constexpr std::string_view kAllowHeaders =
    "content-type, x-grpc-web, x-user-agent, grpc-timeout, x-session-id";
constexpr std::string_view kExposeHeaders = "grpc-status, grpc-message";

enum class Encoding { Binary, Text };

struct MethodInfo {
  std::string name;  ///< the last path segment, the metrics label
  bool is_server_streaming = false;
};

char lower_ascii(char c) { return c >= 'A' && c <= 'Z' ? static_cast<char>(c - 'A' + 'a') : c; }

std::string_view trim(std::string_view text) {
  while (!text.empty() && (text.front() == ' ' || text.front() == '\t')) text.remove_prefix(1);
  while (!text.empty() && (text.back() == ' ' || text.back() == '\t')) text.remove_suffix(1);
  return text;
}

/// The gRPC-Web encoding of a content type; nullopt for anything else.
std::optional<Encoding> parse_content_type(std::string_view value) {
  std::string media(trim(value.substr(0, value.find(';'))));
  std::transform(media.begin(), media.end(), media.begin(), lower_ascii);
  if (media == "application/grpc-web" || media == "application/grpc-web+proto") {
    return Encoding::Binary;
  }
  if (media == "application/grpc-web-text" || media == "application/grpc-web-text+proto") {
    return Encoding::Text;
  }
  return std::nullopt;
}

std::string_view response_content_type(Encoding encoding) {
  return encoding == Encoding::Text ? "application/grpc-web-text+proto"
                                    : "application/grpc-web+proto";
}

constexpr std::string_view kBase64Alphabet =
    "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

std::string base64_encode(std::string_view bytes) {
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 3 <= bytes.size(); i += 3) {
    const auto n = (std::uint32_t{static_cast<unsigned char>(bytes[i])} << 16) |
                   (std::uint32_t{static_cast<unsigned char>(bytes[i + 1])} << 8) |
                   std::uint32_t{static_cast<unsigned char>(bytes[i + 2])};
    out += kBase64Alphabet[(n >> 18) & 63];
    out += kBase64Alphabet[(n >> 12) & 63];
    out += kBase64Alphabet[(n >> 6) & 63];
    out += kBase64Alphabet[n & 63];
  }
  if (const std::size_t rest = bytes.size() - i; rest > 0) {
    std::uint32_t n = std::uint32_t{static_cast<unsigned char>(bytes[i])} << 16;
    if (rest == 2) n |= std::uint32_t{static_cast<unsigned char>(bytes[i + 1])} << 8;
    out += kBase64Alphabet[(n >> 18) & 63];
    out += kBase64Alphabet[(n >> 12) & 63];
    out += rest == 2 ? kBase64Alphabet[(n >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

/// Standard base64 with padding; a concatenation of padded segments (how streaming gRPC-Web-text
/// peers write) decodes as their concatenation.
std::optional<std::string> base64_decode(std::string_view text) {
  if (text.size() % 4 != 0) return std::nullopt;
  std::array<int, 256> value{};
  value.fill(-1);
  for (std::size_t i = 0; i < kBase64Alphabet.size(); ++i) {
    value[static_cast<unsigned char>(kBase64Alphabet[i])] = static_cast<int>(i);
  }
  std::string out;
  out.reserve(text.size() / 4 * 3);
  for (std::size_t i = 0; i < text.size(); i += 4) {
    int pad = 0;
    std::uint32_t n = 0;
    for (std::size_t k = 0; k < 4; ++k) {
      const char c = text[i + k];
      if (c == '=') {
        if (k < 2) return std::nullopt;
        ++pad;
        n <<= 6;
        continue;
      }
      if (pad > 0) return std::nullopt;  // data after padding within a group
      const int v = value[static_cast<unsigned char>(c)];
      if (v < 0) return std::nullopt;
      n = (n << 6) | static_cast<std::uint32_t>(v);
    }
    out += static_cast<char>((n >> 16) & 0xFF);
    if (pad < 2) out += static_cast<char>((n >> 8) & 0xFF);
    if (pad < 1) out += static_cast<char>(n & 0xFF);
  }
  return out;
}

/// Appends one length-prefixed frame to `out`.
void append_frame(std::string& out, unsigned char flag, std::string_view payload) {
  const auto length = static_cast<std::uint32_t>(payload.size());
  out.reserve(out.size() + kFrameHeaderBytes + payload.size());
  out += static_cast<char>(flag);
  out += static_cast<char>((length >> 24) & 0xFF);
  out += static_cast<char>((length >> 16) & 0xFF);
  out += static_cast<char>((length >> 8) & 0xFF);
  out += static_cast<char>(length & 0xFF);
  out += payload;
}

std::string frame(unsigned char flag, std::string_view payload) {
  std::string out;
  append_frame(out, flag, payload);
  return out;
}

std::string trailer_frame(grpc::StatusCode code, std::string_view message) {
  return frame(kTrailerFlag, "grpc-status: " + std::to_string(static_cast<int>(code)) +
                                 "\r\ngrpc-message: " + percent_encode_grpc_message(message) +
                                 "\r\n");
}

std::string encode_body(Encoding encoding, std::string bytes) {
  return encoding == Encoding::Text ? base64_encode(bytes) : std::move(bytes);
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

/// The request path without query; empty when the target is not origin-form.
std::string_view target_path(std::string_view target) {
  return target.substr(0, target.find_first_of("?#"));
}

HttpResponse text_response(int status, std::string body, HttpHeaders headers = {}) {
  return HttpResponse{status, "text/plain; charset=utf-8", std::move(body), std::move(headers)};
}

class ForwardedCall;

}  // namespace

struct GrpcWebGateway::Shared {
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<grpc::GenericStub> stub;
  std::size_t max_message_bytes = 0;
  GrpcWebGatewayOptions options;
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

  /// The Access-Control-Allow-Origin value for `origin`; empty when not allowed.
  std::string allowed_origin(std::string_view origin) const {
    if (origin.empty()) return {};
    for (const std::string& allowed : options.allowed_origins) {
      if (allowed == "*") return "*";
      if (allowed == origin) return std::string(origin);
    }
    return {};
  }

  /// CORS headers of an actual (non-preflight) response.
  HttpHeaders cors_headers(std::string_view origin) const {
    HttpHeaders headers;
    const std::string allowed = allowed_origin(origin);
    if (!allowed.empty()) {
      headers.emplace_back("Access-Control-Allow-Origin", allowed);
      if (allowed != "*") headers.emplace_back("Vary", "Origin");
      headers.emplace_back("Access-Control-Expose-Headers", std::string(kExposeHeaders));
    }
    return headers;
  }

  HttpResponse preflight(std::string_view origin) const {
    HttpResponse response;
    response.status = 204;
    response.content_type.clear();
    response.headers.emplace_back("Allow", "POST, OPTIONS");
    if (origin.empty()) return response;  // not a browser's CORS preflight
    const std::string allowed = allowed_origin(origin);
    if (allowed.empty()) {
      return text_response(403, "origin not allowed: " + std::string(origin.substr(0, 200)) + "\n");
    }
    response.headers.emplace_back("Access-Control-Allow-Origin", allowed);
    if (allowed != "*") response.headers.emplace_back("Vary", "Origin");
    response.headers.emplace_back("Access-Control-Allow-Methods", "POST, OPTIONS");
    response.headers.emplace_back("Access-Control-Allow-Headers", std::string(kAllowHeaders));
    response.headers.emplace_back("Access-Control-Expose-Headers", std::string(kExposeHeaders));
    response.headers.emplace_back("Access-Control-Max-Age",
                                  std::to_string(options.cors_max_age_seconds));
    return response;
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
      append_frame(body_, kDataFlag, payload);  // unary: answered in one piece in OnDone
      StartRead(&response_);
      return;
    }
    std::string framed = frame(kDataFlag, payload);
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
  const std::size_t framed = shared_->max_message_bytes + kFrameHeaderBytes;
  return (framed + 2) / 3 * 4 + 4096;  // base64 (grpc-web-text) and slack
}

void GrpcWebGateway::handle(HttpRequest request, std::shared_ptr<HttpExchange> exchange) {
  const auto start = std::chrono::steady_clock::now();
  Shared& shared = *shared_;
  const std::string_view origin = request.find_header("origin");
  const std::string path(target_path(request.target));
  if (request.method == "OPTIONS") {
    exchange->respond(shared.preflight(origin));
    return;
  }
  if (request.method != "POST") {
    exchange->respond(text_response(405, "use POST\n", {{"Allow", "POST, OPTIONS"}}));
    return;
  }
  HttpHeaders headers = shared.cors_headers(origin);
  const std::optional<Encoding> encoding = parse_content_type(request.find_header("content-type"));
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
    std::optional<std::string> decoded = base64_decode(body);
    if (!decoded) {
      fail(grpc::StatusCode::INTERNAL, "bad base64 in the grpc-web-text request body");
      return;
    }
    body = std::move(*decoded);
  }
  // Framing: exactly one uncompressed data frame.
  if (body.size() < kFrameHeaderBytes) {
    fail(grpc::StatusCode::INTERNAL,
         body.empty() ? std::string("empty request body (want one length-prefixed message)")
                      : "truncated frame header: " + std::to_string(body.size()) + " of 5 bytes");
    return;
  }
  const auto flag = static_cast<unsigned char>(body[0]);
  if (flag != kDataFlag) {
    fail(grpc::StatusCode::INTERNAL,
         flag == 0x01 ? std::string("compressed request messages are not supported")
                      : "bad request frame flag " + std::to_string(flag) + " (want 0)");
    return;
  }
  const std::uint64_t length = (std::uint64_t{static_cast<unsigned char>(body[1])} << 24) |
                               (std::uint64_t{static_cast<unsigned char>(body[2])} << 16) |
                               (std::uint64_t{static_cast<unsigned char>(body[3])} << 8) |
                               std::uint64_t{static_cast<unsigned char>(body[4])};
  const std::size_t held = body.size() - kFrameHeaderBytes;
  if (length > shared.max_message_bytes) {
    fail(grpc::StatusCode::RESOURCE_EXHAUSTED,
         "request message of " + std::to_string(length) + " bytes is over the limit of " +
             std::to_string(shared.max_message_bytes) + " bytes");
    return;
  }
  if (length > held) {
    fail(grpc::StatusCode::INTERNAL, "truncated request message: the frame declares " +
                                         std::to_string(length) + " bytes, the body holds " +
                                         std::to_string(held));
    return;
  }
  if (length < held) {
    fail(grpc::StatusCode::INTERNAL,
         std::to_string(held - length) +
             " bytes after the request message (one message per request)");
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
      grpc::Slice slice(body.data() + kFrameHeaderBytes, length);
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

// ------------------------------------------------------------------------------------------------

namespace {

/// %XX-decoding of a URL path; nullopt for a malformed escape.
std::optional<std::string> percent_decode(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  const auto hex = [](char c) -> int {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
  };
  for (std::size_t i = 0; i < text.size(); ++i) {
    if (text[i] != '%') {
      out += text[i];
      continue;
    }
    if (i + 2 >= text.size()) return std::nullopt;
    const int high = hex(text[i + 1]), low = hex(text[i + 2]);
    if (high < 0 || low < 0) return std::nullopt;
    out += static_cast<char>(high * 16 + low);
    i += 2;
  }
  return out;
}

std::string_view content_type_of(const std::filesystem::path& file) {
  static const std::map<std::string, std::string_view, std::less<>> kTypes = {
      {".html", "text/html; charset=utf-8"},
      {".htm", "text/html; charset=utf-8"},
      {".js", "text/javascript; charset=utf-8"},
      {".mjs", "text/javascript; charset=utf-8"},
      {".css", "text/css; charset=utf-8"},
      {".wasm", "application/wasm"},
      {".svg", "image/svg+xml"},
      {".png", "image/png"},
      {".json", "application/json"},
      {".map", "application/json"},
      {".ico", "image/x-icon"},
      {".txt", "text/plain; charset=utf-8"},
  };
  std::string extension = file.extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(), lower_ascii);
  const auto found = kTypes.find(extension);
  return found == kTypes.end() ? std::string_view("application/octet-stream") : found->second;
}

/// True when `path` is `root` or below it (both canonical).
bool is_within(const std::filesystem::path& root, const std::filesystem::path& path) {
  auto r = root.begin();
  auto p = path.begin();
  for (; r != root.end(); ++r, ++p) {
    if (p == path.end() || *r != *p) return false;
  }
  return true;
}

}  // namespace

Result<StaticFileServer> StaticFileServer::open(const std::filesystem::path& root,
                                                std::size_t max_file_bytes) {
  std::error_code error;
  std::filesystem::path canonical = std::filesystem::canonical(root, error);
  if (error || !std::filesystem::is_directory(canonical, error)) {
    return Error(ErrorCode::InvalidArgument,
                 "static file root '" + root.string() + "' is not a directory");
  }
  return StaticFileServer(std::move(canonical), max_file_bytes);
}

HttpResponse StaticFileServer::serve(const HttpRequest& request) const {
  if (request.method != "GET") return text_response(405, "use GET\n", {{"Allow", "GET"}});
  const std::optional<std::string> decoded = percent_decode(target_path(request.target));
  if (!decoded || decoded->empty() || decoded->front() != '/') {
    return text_response(400, "bad path\n");
  }
  std::filesystem::path relative;
  std::size_t begin = 1;
  while (begin <= decoded->size()) {
    std::size_t end = decoded->find('/', begin);
    if (end == std::string::npos) end = decoded->size();
    const std::string_view segment = std::string_view(*decoded).substr(begin, end - begin);
    if (!segment.empty()) {
      if (segment.front() == '.' || segment.find('\0') != std::string_view::npos ||
          segment.find('\\') != std::string_view::npos) {
        return text_response(400, "bad path\n");
      }
      relative /= std::string(segment);
    }
    begin = end + 1;
  }
  const HttpResponse not_found = text_response(404, "not found\n");
  std::error_code error;
  std::filesystem::path file = root_ / relative;
  if (std::filesystem::is_directory(file, error)) file /= "index.html";
  // Resolve symlinks, then insist on staying under the root.
  const std::filesystem::path resolved = std::filesystem::canonical(file, error);
  if (error || !is_within(root_, resolved) || !std::filesystem::is_regular_file(resolved, error)) {
    return not_found;
  }
  const std::uintmax_t size = std::filesystem::file_size(resolved, error);
  if (error) return not_found;
  if (size > max_file_bytes_) {
    service::log_event(service::LogLevel::Warn, "static_file_too_large",
                       service::LogFields().add("path", resolved.string()));
    return not_found;
  }
  std::ifstream in(resolved, std::ios::binary);
  std::string body(static_cast<std::size_t>(size), '\0');
  if (!in.read(body.data(), static_cast<std::streamsize>(size))) return not_found;
  return HttpResponse{200,
                      std::string(content_type_of(file)),
                      std::move(body),
                      {{"X-Content-Type-Options", "nosniff"}, {"Cache-Control", "no-cache"}}};
}

AsyncHttpHandler make_http_router(GrpcWebGateway& gateway, const StaticFileServer* files,
                                  HttpHandler fallback) {
  return [&gateway, files, fallback = std::move(fallback)](HttpRequest request,
                                                           std::shared_ptr<HttpExchange> exchange) {
    if (gateway.handles(request.method, request.target)) {
      gateway.handle(std::move(request), std::move(exchange));
      return;
    }
    if (request.is_body_over_limit) {
      exchange->respond(text_response(413, "request body of " +
                                               std::to_string(request.declared_body_bytes) +
                                               " bytes over the limit\n"));
      return;
    }
    const std::string_view path = target_path(request.target);
    HttpResponse response;
    try {
      response = files != nullptr && request.method == "GET" && path != "/metrics" &&
                         path != "/healthz"
                     ? files->serve(request)
                     : fallback(request);
    } catch (const std::exception&) {
      response = text_response(500, "internal error\n");
    }
    exchange->respond(std::move(response));
  };
}

std::function<std::size_t(std::string_view, std::string_view)> make_body_limit(
    const GrpcWebGateway& gateway, std::size_t other_limit) {
  return [&gateway, other_limit](std::string_view method, std::string_view target) {
    return gateway.handles(method, target) ? gateway.max_request_bytes() : other_limit;
  };
}

Result<std::chrono::nanoseconds> parse_grpc_timeout(std::string_view value) {
  const auto bad = [&] {
    return Error(ErrorCode::InvalidArgument,
                 "bad grpc-timeout '" + std::string(value.substr(0, 40)) +
                     "' (want 1-8 digits and a unit H, M, S, m, u or n)");
  };
  if (value.size() < 2 || value.size() > 9) return bad();
  std::int64_t amount = 0;
  for (const char c : value.substr(0, value.size() - 1)) {
    if (c < '0' || c > '9') return bad();
    amount = amount * 10 + (c - '0');
  }
  std::int64_t unit_ns = 0;
  switch (value.back()) {
    case 'H': unit_ns = 3'600'000'000'000; break;
    case 'M': unit_ns = 60'000'000'000; break;
    case 'S': unit_ns = 1'000'000'000; break;
    case 'm': unit_ns = 1'000'000; break;
    case 'u': unit_ns = 1'000; break;
    case 'n': unit_ns = 1; break;
    default: return bad();
  }
  // 99999999H overflows nanoseconds: saturate at 100,000 hours (beyond any deadline we honour).
  constexpr std::int64_t kMaxNs = std::int64_t{100'000} * 3'600'000'000'000;
  if (amount > kMaxNs / unit_ns) return std::chrono::nanoseconds(kMaxNs);
  return std::chrono::nanoseconds(amount * unit_ns);
}

std::string percent_encode_grpc_message(std::string_view message) {
  static constexpr char kHex[] = "0123456789ABCDEF";
  std::string out;
  out.reserve(message.size());
  for (const char c : message) {
    const auto byte = static_cast<unsigned char>(c);
    if (byte >= 0x20 && byte <= 0x7E && byte != '%') {
      out += c;
    } else {
      out += '%';
      out += kHex[byte >> 4];
      out += kHex[byte & 0x0F];
    }
  }
  return out;
}

}  // namespace meshdeform::transport
