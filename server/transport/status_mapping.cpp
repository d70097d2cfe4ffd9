#include "server/transport/status_mapping.h"

#include "proto/wire/wire_mapping.h"
#include "server/service/log.h"

namespace meshdeform::transport {

grpc::StatusCode to_grpc_code(ErrorCode code) {
  // No default: -Wswitch flags a new ErrorCode here.
  switch (code) {
    case ErrorCode::Ok:
      return grpc::StatusCode::OK;
    case ErrorCode::InvalidArgument:
      return grpc::StatusCode::INVALID_ARGUMENT;
    case ErrorCode::NotFound:
      return grpc::StatusCode::NOT_FOUND;
    case ErrorCode::PermissionDenied:
      return grpc::StatusCode::PERMISSION_DENIED;
    case ErrorCode::FailedPrecondition:
      return grpc::StatusCode::FAILED_PRECONDITION;
    case ErrorCode::ResourceExhausted:
      return grpc::StatusCode::RESOURCE_EXHAUSTED;
    case ErrorCode::Cancelled:
      return grpc::StatusCode::CANCELLED;
    case ErrorCode::DeadlineExceeded:
      return grpc::StatusCode::DEADLINE_EXCEEDED;
    case ErrorCode::NumericalFailure:
      return grpc::StatusCode::INTERNAL;  // solver breakdown
    case ErrorCode::Internal:
      return grpc::StatusCode::INTERNAL;
    case ErrorCode::Aborted:
      return grpc::StatusCode::ABORTED;
    case ErrorCode::Unavailable:
      return grpc::StatusCode::UNAVAILABLE;
  }
  return grpc::StatusCode::UNKNOWN;  // an out-of-range enum value
}

std::string truncate_message(std::string_view message) {
  if (message.size() <= kMaxClientMessageBytes) return std::string(message);
  constexpr std::string_view kEllipsis = "...";
  std::size_t cut = kMaxClientMessageBytes - kEllipsis.size();
  // Back up over UTF-8 continuation bytes (10xxxxxx) so a multi-byte character is not split.
  while (cut > 0 && (static_cast<unsigned char>(message[cut]) & 0xC0) == 0x80) --cut;
  std::string out(message.substr(0, cut));
  out += kEllipsis;
  return out;
}

std::string_view grpc_code_name(grpc::StatusCode code) {
  // DO_NOT_USE and values outside gRPC's codes have no name of their own.
  return wire::grpc_code_name(static_cast<int>(code)).value_or("UNKNOWN");
}

void log_line(std::string_view rpc, std::string_view text) {
  service::log_event(service::LogLevel::Error, "rpc_error",
                     service::LogFields().add("rpc", rpc).add("message", text));
}

grpc::Status to_grpc_status(const Status& status, std::string_view rpc) {
  if (status.ok()) return grpc::Status::OK;
  const bool is_internal =
      status.code() == ErrorCode::Internal || status.code() == ErrorCode::NumericalFailure;
  if (is_internal || status.message().size() > kMaxClientMessageBytes) {
    log_line(rpc, status.to_string());
  }
  return grpc::Status(to_grpc_code(status.code()), truncate_message(status.message()));
}

}  // namespace meshdeform::transport
