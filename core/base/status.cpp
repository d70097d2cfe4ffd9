#include "core/base/status.h"

#include <cstdio>
#include <cstdlib>

namespace meshdeform {

const char* error_code_name(ErrorCode code) {
  switch (code) {
    case ErrorCode::Ok: return "Ok";
    case ErrorCode::InvalidArgument: return "InvalidArgument";
    case ErrorCode::NotFound: return "NotFound";
    case ErrorCode::PermissionDenied: return "PermissionDenied";
    case ErrorCode::FailedPrecondition: return "FailedPrecondition";
    case ErrorCode::ResourceExhausted: return "ResourceExhausted";
    case ErrorCode::Cancelled: return "Cancelled";
    case ErrorCode::DeadlineExceeded: return "DeadlineExceeded";
    case ErrorCode::NumericalFailure: return "NumericalFailure";
    case ErrorCode::Internal: return "Internal";
    case ErrorCode::Aborted: return "Aborted";
    case ErrorCode::Unavailable: return "Unavailable";
  }
  return "Unknown";
}

std::string Status::to_string() const {
  if (ok()) return "Ok";
  return std::string(error_code_name(code_)) + ": " + message_;
}

namespace detail {
void assert_fail(const char* cond, const char* file, int line) {
  std::fprintf(stderr, "meshdeform internal invariant failed: %s (%s:%d)\n", cond, file, line);
  std::abort();
}
}  // namespace detail

}  // namespace meshdeform
