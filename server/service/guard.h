#pragma once
/// @file guard.h
/// The one exception guard of the server: no exception leaves a service call, an RPC handler,
/// an HTTP handler or a worker task (gRPC would turn one into UNKNOWN; a worker thread would
/// die). Errors inside the server are statuses (core/base/status.h); this only catches the unexpected.

#include <exception>
#include <new>
#include <string>
#include <string_view>

#include "core/base/status.h"

namespace meshdeform::service {

/// Logs an exception caught by run_guarded (event "unexpected_exception", fields where and
/// message) at error level. Thread-safe.
void log_unexpected_exception(std::string_view where, std::string_view what);

/// Runs `fn` (returning Status or Result<T>), turning an escaped exception into a status:
/// std::bad_alloc -> ResourceExhausted ("out of memory"), any other -> Internal ("unexpected
/// exception"). The exception's text is logged (tagged with `where`), never returned: it may
/// name internals the caller should not see.
template <typename Fn>
auto run_guarded(std::string_view where, Fn&& fn) -> decltype(fn()) {
  try {
    return fn();
  } catch (const std::bad_alloc&) {
    log_unexpected_exception(where, "out of memory");
    return Error(ErrorCode::ResourceExhausted, "out of memory");
  } catch (const std::exception& e) {
    log_unexpected_exception(where, e.what());
    return Error(ErrorCode::Internal, "unexpected exception");
  } catch (...) {
    log_unexpected_exception(where, "non-standard exception");
    return Error(ErrorCode::Internal, "unexpected exception");
  }
}

}  // namespace meshdeform::service
