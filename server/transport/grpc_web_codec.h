#pragma once
/// @file grpc_web_codec.h
/// The gRPC-Web wire format (github.com/grpc/grpc/blob/master/doc/PROTOCOL-WEB.md) as pure
/// functions on bytes: content types, length-prefixed frames (data 0x00, trailer 0x80), the
/// base64 of the -text content types, trailer text, grpc-timeout and grpc-message encoding.
/// No sockets and no gRPC: the gateway (grpc_web_gateway.h) moves the bytes.

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "core/base/status.h"

namespace meshdeform::transport {

/// "500m" -> 500 ms etc. (gRPC's TimeoutValue: 1-8 digits and one of H M S m u n).
/// @return the duration; InvalidArgument naming the value when malformed.
[[nodiscard]] Result<std::chrono::nanoseconds> parse_grpc_timeout(std::string_view value);

/// grpc-message percent-encoding: bytes outside 0x20..0x7E, and '%', as %XX (upper-case hex).
std::string percent_encode_grpc_message(std::string_view message);

namespace grpc_web {

inline constexpr unsigned char kDataFlag = 0x00;
inline constexpr unsigned char kTrailerFlag = 0x80;
inline constexpr std::size_t kFrameHeaderBytes = 5;  ///< the flag, then a big-endian uint32 length

/// Binary: application/grpc-web(+proto); Text: application/grpc-web-text(+proto), whose bodies
/// are base64 in both directions.
enum class Encoding { Binary, Text };

/// The encoding of a request's content type (media type compared case-insensitively, parameters
/// ignored); nullopt for anything that is not gRPC-Web.
std::optional<Encoding> parse_content_type(std::string_view value);

/// The content type of a response in `encoding`.
std::string_view response_content_type(Encoding encoding);

/// Standard base64 with padding.
std::string base64_encode(std::string_view bytes);

/// Standard base64 with padding; a concatenation of padded segments (how streaming
/// gRPC-Web-text peers write) decodes as their concatenation.
/// @return the bytes; nullopt for a length not a multiple of 4, a byte outside the alphabet or
///         misplaced padding.
std::optional<std::string> base64_decode(std::string_view text);

/// Appends one length-prefixed frame with `flag` to `out`.
void append_frame(std::string& out, unsigned char flag, std::string_view payload);

/// One length-prefixed frame with `flag`.
std::string frame(unsigned char flag, std::string_view payload);

/// The trailer frame "grpc-status: <code>\r\ngrpc-message: <percent-encoded message>\r\n".
/// @param[in] grpc_status  the numeric gRPC status code
std::string trailer_frame(int grpc_status, std::string_view message);

/// A response body (frames) as sent in `encoding`: as is, or base64.
std::string encode_body(Encoding encoding, std::string bytes);

/// The flag and declared payload length at the front of `bytes`; nullopt when fewer than
/// kFrameHeaderBytes bytes.
struct FrameHeader {
  unsigned char flag = kDataFlag;
  std::uint32_t length = 0;
};
std::optional<FrameHeader> read_frame_header(std::string_view bytes);

/// The message of a request body (already base64-decoded in text mode), which must be exactly
/// one uncompressed data frame.
/// @return a view into `body` of the message; ResourceExhausted when the frame declares more
///         than `max_message_bytes`; InvalidArgument for any other framing fault (empty body,
///         truncated header or message, a compressed or non-data flag, bytes after the frame),
///         the message naming it.
[[nodiscard]] Result<std::string_view> unframe_request(std::string_view body,
                                                       std::size_t max_message_bytes);

}  // namespace grpc_web
}  // namespace meshdeform::transport
