#pragma once
/// @file binary_codec.h
/// The little-endian binary fields of the service's stored bytes, shared by the state file
/// (persistence.cpp) and the Redis store (redis_store.cpp): fixed-size values, length-prefixed
/// strings and #rows x 3 matrices. Reads are bounded by the bytes present and by the caller's
/// limits, and fail with InvalidArgument naming the source, the field and the byte offset.
/// Little-endian hosts only (x86-64, arm64).

#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>

#include "core/mesh/mesh_data.h"
#include "core/base/status.h"

namespace meshdeform::service {

class BinaryWriter {
 public:
  template <typename T>
  void pod(T value) {
    char bytes[sizeof(T)];
    std::memcpy(bytes, &value, sizeof(T));
    out_.append(bytes, sizeof(T));
  }
  void str(std::string_view s) {
    pod(static_cast<std::uint32_t>(s.size()));
    out_.append(s);
  }
  void matrix(const Positions& P) {
    pod(static_cast<std::uint32_t>(P.rows()));
    for (Eigen::Index r = 0; r < P.rows(); ++r)
      for (int c = 0; c < 3; ++c) pod(P(r, c));
  }
  const std::string& bytes() const { return out_; }
  std::string take() { return std::move(out_); }

 private:
  std::string out_;
};

class BinaryReader {
 public:
  /// Counts above this are refused before anything is allocated (vertices, faces, groups).
  static constexpr std::uint32_t kMaxCount = 100'000'000;

  /// @param source  names the bytes in errors, e.g. "state file".
  BinaryReader(std::string_view in, std::string source) : in_(in), source_(std::move(source)) {}

  template <typename T>
  Status pod(T& value, const char* what) {
    if (in_.size() - at_ < sizeof(T)) return truncated(what);
    std::memcpy(&value, in_.data() + at_, sizeof(T));
    at_ += sizeof(T);
    return Status::success();
  }
  Status str(std::string& s, const char* what, std::size_t max) {
    std::uint32_t n = 0;
    MD_RETURN_IF_ERROR(pod(n, what));
    if (n > max || in_.size() - at_ < n) return truncated(what);
    s.assign(in_.data() + at_, n);
    at_ += n;
    return Status::success();
  }
  /// A count of items of `bytes_each` bytes that must all be present.
  Status count(std::uint32_t& n, const char* what, std::size_t bytes_each) {
    MD_RETURN_IF_ERROR(pod(n, what));
    if (n > kMaxCount || (in_.size() - at_) / bytes_each < n) return truncated(what);
    return Status::success();
  }
  /// A #rows x 3 matrix of finite values.
  Status matrix(Positions& P, const char* what) {
    std::uint32_t rows = 0;
    MD_RETURN_IF_ERROR(count(rows, what, 24));
    P.resize(rows, 3);
    for (Eigen::Index r = 0; r < P.rows(); ++r)
      for (int c = 0; c < 3; ++c) MD_RETURN_IF_ERROR(pod(P(r, c), what));
    if (!P.allFinite()) return corrupt(std::string(what) + " is not finite");
    return Status::success();
  }
  bool done() const { return at_ == in_.size(); }
  /// InvalidArgument "<source>: <message>".
  Status corrupt(const std::string& message) const {
    return Error(ErrorCode::InvalidArgument, source_ + ": " + message);
  }

 private:
  Status truncated(const char* what) const {
    return Error(ErrorCode::InvalidArgument, source_ + " truncated or corrupt at " + what +
                                                 " (byte " + std::to_string(at_) + ")");
  }
  std::string_view in_;
  std::string source_;
  std::size_t at_ = 0;
};

}  // namespace meshdeform::service
