#pragma once
/// @file status.h
/// Error values for core and service: `Status` and `Result<T>`, shaped like `std::expected` so that
/// `Result<T>` can become an alias later. Messages name the offending value.

#include <cassert>
#include <exception>
#include <new>
#include <string>
#include <utility>
#include <variant>

namespace meshdeform {

/// The error taxonomy shared by every layer; transport maps it with one switch.
enum class ErrorCode {
  Ok,
  InvalidArgument,
  NotFound,
  PermissionDenied,
  FailedPrecondition,
  ResourceExhausted,
  Cancelled,
  DeadlineExceeded,
  NumericalFailure,
  Internal,
  /// A concurrent change won (e.g. another replica edited the session): retrying may succeed.
  Aborted,
  /// Something the request needs cannot be reached now (e.g. the shared session store): not the
  /// caller's input and not a fault of this code; retrying later may succeed.
  Unavailable,
};

/// Human-readable name of an error code ("InvalidArgument").
const char* error_code_name(ErrorCode code);

/// A success or an error code with a message.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(ErrorCode code, std::string message) : code_(code), message_(std::move(message)) {}
  static Status success() { return {}; }

  bool ok() const { return code_ == ErrorCode::Ok; }
  ErrorCode code() const { return code_; }
  const std::string& message() const { return message_; }
  /// "InvalidArgument: face 17 references vertex 902 (#V=900)".
  std::string to_string() const;

 private:
  ErrorCode code_ = ErrorCode::Ok;
  std::string message_;
};

/// Shorthand for an error status.
inline Status Error(ErrorCode code, std::string message) { return {code, std::move(message)}; }

/// A value or an error status.
template <typename T>
class [[nodiscard]] Result {
 public:
  Result(T value) : data_(std::move(value)) {}  // NOLINT(google-explicit-constructor)
  Result(Status status) : data_(std::move(status)) {  // NOLINT(google-explicit-constructor)
    assert(!std::get<Status>(data_).ok() && "Result built from an ok Status has no value");
  }

  bool ok() const { return std::holds_alternative<T>(data_); }
  explicit operator bool() const { return ok(); }
  /// The error; success() when a value is held.
  Status status() const { return ok() ? Status::success() : std::get<Status>(data_); }

  T& value() & { return std::get<T>(data_); }
  const T& value() const& { return std::get<T>(data_); }
  T&& value() && { return std::get<T>(std::move(data_)); }
  T& operator*() & { return value(); }
  const T& operator*() const& { return value(); }
  T* operator->() { return &value(); }
  const T* operator->() const { return &value(); }

 private:
  std::variant<T, Status> data_;
};

/// Runs `body` (returning a Status or Result) so that no exception escapes: std::bad_alloc
/// becomes ResourceExhausted "<what>: out of memory", any other std::exception becomes
/// `on_exception` "<what>: <e.what()>".
template <typename F>
auto guard_exceptions(const char* what, ErrorCode on_exception, F&& body) -> decltype(body()) {
  try {
    return body();
  } catch (const std::bad_alloc&) {
    return Error(ErrorCode::ResourceExhausted, std::string(what) + ": out of memory");
  } catch (const std::exception& e) {
    return Error(on_exception, std::string(what) + ": " + e.what());
  }
}

}  // namespace meshdeform

#define MD_STATUS_CONCAT_INNER_(a, b) a##b
#define MD_STATUS_CONCAT_(a, b) MD_STATUS_CONCAT_INNER_(a, b)

/// Returns the status from the enclosing function when `expr` is an error.
#define MD_RETURN_IF_ERROR(expr)                          \
  do {                                                    \
    ::meshdeform::Status md_status_ = (expr);             \
    if (!md_status_.ok()) return md_status_;              \
  } while (false)

#define MD_ASSIGN_OR_RETURN_IMPL_(tmp, lhs, expr) \
  auto tmp = (expr);                              \
  if (!tmp.ok()) return tmp.status();             \
  lhs = std::move(tmp).value()

/// `MD_ASSIGN_OR_RETURN(auto x, f())`: binds the value or returns the error.
#define MD_ASSIGN_OR_RETURN(lhs, expr) \
  MD_ASSIGN_OR_RETURN_IMPL_(MD_STATUS_CONCAT_(md_result_, __LINE__), lhs, expr)

/// Internal invariant (never request data): aborts in every build type.
#define MD_ASSERT(cond)                                                                     \
  do {                                                                                      \
    if (!(cond)) ::meshdeform::detail::assert_fail(#cond, __FILE__, __LINE__);              \
  } while (false)

namespace meshdeform::detail {
[[noreturn]] void assert_fail(const char* cond, const char* file, int line);
}
