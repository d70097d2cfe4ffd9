#include "server/transport/grpc_web_codec.h"

#include <algorithm>
#include <array>

#include "server/transport/http_message.h"

namespace meshdeform::transport {

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

namespace grpc_web {
namespace {

constexpr std::string_view kBase64Alphabet =
    "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

std::string_view trim(std::string_view text) {
  while (!text.empty() && (text.front() == ' ' || text.front() == '\t')) text.remove_prefix(1);
  while (!text.empty() && (text.back() == ' ' || text.back() == '\t')) text.remove_suffix(1);
  return text;
}

}  // namespace

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

std::string trailer_frame(int grpc_status, std::string_view message) {
  return frame(kTrailerFlag, "grpc-status: " + std::to_string(grpc_status) + "\r\ngrpc-message: " +
                                 percent_encode_grpc_message(message) + "\r\n");
}

std::string encode_body(Encoding encoding, std::string bytes) {
  return encoding == Encoding::Text ? base64_encode(bytes) : std::move(bytes);
}

std::optional<FrameHeader> read_frame_header(std::string_view bytes) {
  if (bytes.size() < kFrameHeaderBytes) return std::nullopt;
  FrameHeader header;
  header.flag = static_cast<unsigned char>(bytes[0]);
  header.length = (std::uint32_t{static_cast<unsigned char>(bytes[1])} << 24) |
                  (std::uint32_t{static_cast<unsigned char>(bytes[2])} << 16) |
                  (std::uint32_t{static_cast<unsigned char>(bytes[3])} << 8) |
                  std::uint32_t{static_cast<unsigned char>(bytes[4])};
  return header;
}

Result<std::string_view> unframe_request(std::string_view body, std::size_t max_message_bytes) {
  const std::optional<FrameHeader> header = read_frame_header(body);
  if (!header) {
    return Error(ErrorCode::InvalidArgument,
                 body.empty()
                     ? std::string("empty request body (want one length-prefixed message)")
                     : "truncated frame header: " + std::to_string(body.size()) + " of 5 bytes");
  }
  if (header->flag != kDataFlag) {
    return Error(ErrorCode::InvalidArgument,
                 header->flag == 0x01
                     ? std::string("compressed request messages are not supported")
                     : "bad request frame flag " + std::to_string(header->flag) + " (want 0)");
  }
  const std::uint64_t length = header->length;
  const std::size_t held = body.size() - kFrameHeaderBytes;
  if (length > max_message_bytes) {
    return Error(ErrorCode::ResourceExhausted, "request message of " + std::to_string(length) +
                                                   " bytes is over the limit of " +
                                                   std::to_string(max_message_bytes) + " bytes");
  }
  if (length > held) {
    return Error(ErrorCode::InvalidArgument, "truncated request message: the frame declares " +
                                                 std::to_string(length) +
                                                 " bytes, the body holds " + std::to_string(held));
  }
  if (length < held) {
    return Error(ErrorCode::InvalidArgument,
                 std::to_string(held - length) +
                     " bytes after the request message (one message per request)");
  }
  return body.substr(kFrameHeaderBytes, static_cast<std::size_t>(length));
}

}  // namespace grpc_web
}  // namespace meshdeform::transport
