#pragma once
/// @file status_mapping.h
/// meshdeform::Status -> grpc::Status (one switch) and message truncation. Handlers keep
/// exceptions in with service::run_guarded (server/service/guard.h), the server's one guard.

#include <cstddef>
#include <string>
#include <string_view>

#include <grpcpp/support/status.h>

#include "core/base/status.h"

namespace meshdeform::transport {

/// Longest message sent to a client; longer ones are cut and logged in full (TF Serving).
inline constexpr std::size_t kMaxClientMessageBytes = 1024;

/// The gRPC code of an error code (Ok -> OK).
grpc::StatusCode to_grpc_code(ErrorCode code);

/// The canonical upper-case name of a gRPC code ("OK", "NOT_FOUND", ...), for metrics and logs
/// (wire::grpc_code_name); "UNKNOWN" for DO_NOT_USE or a value outside gRPC's codes.
std::string_view grpc_code_name(grpc::StatusCode code);

/// `message` cut to at most kMaxClientMessageBytes bytes (ending in "..." when cut, never splitting
/// a UTF-8 sequence).
std::string truncate_message(std::string_view message);

/// The client-facing status: code mapped by to_grpc_code, message truncated. Logs the full text
/// of truncated messages and of Internal errors to stderr, tagged with `rpc`.
grpc::Status to_grpc_status(const Status& status, std::string_view rpc = {});

/// Writes one structured error line (event "rpc_error", fields rpc and message); thread-safe.
void log_line(std::string_view rpc, std::string_view text);

}  // namespace meshdeform::transport
