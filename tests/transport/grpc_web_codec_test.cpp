// The gRPC-Web wire format alone (grpc_web_codec.h): frames, trailers, base64 text mode and the
// request framing checks, without sockets or a gRPC server. The byte-level expectations are
// written out by hand (PROTOCOL-WEB.md, RFC 4648 test vectors), not derived from the codec.
#include "server/transport/grpc_web_codec.h"

#include <gtest/gtest.h>

#include <chrono>
#include <string>
#include <string_view>

namespace meshdeform::transport {
namespace {

using namespace std::string_literals;
using std::chrono::milliseconds;
using std::chrono::seconds;

/// Bytes that trip a codec mixing up signed chars, NULs or byte order: every value 0..255,
/// several times, so that the length needs three bytes (0x00 0x03 0x00 0x10 for 768 + 16).
std::string awkward_payload() {
  std::string bytes;
  for (int round = 0; round < 3; ++round) {
    for (int b = 0; b < 256; ++b) bytes += static_cast<char>(b);
  }
  bytes += "\x80\x00\xff tail\r\n"s;
  return bytes;
}

TEST(GrpcWebCodec, DataFrameRoundTrip) {
  const std::string payload = awkward_payload();
  ASSERT_EQ(payload.size(), 768U + 10U);
  const std::string framed = grpc_web::frame(grpc_web::kDataFlag, payload);
  // Flag 0x00, then the length big-endian (778 = 0x0000030A), then the payload as is.
  ASSERT_EQ(framed.size(), 5 + payload.size());
  EXPECT_EQ(framed.substr(0, 5), "\x00\x00\x00\x03\x0A"s);
  EXPECT_EQ(framed.substr(5), payload);

  const std::optional<grpc_web::FrameHeader> header = grpc_web::read_frame_header(framed);
  ASSERT_TRUE(header.has_value());
  EXPECT_EQ(header->flag, grpc_web::kDataFlag);
  EXPECT_EQ(header->length, payload.size());

  const Result<std::string_view> message = grpc_web::unframe_request(framed, 1 << 20);
  ASSERT_TRUE(message.ok()) << message.status().to_string();
  EXPECT_EQ(*message, payload);

  // append_frame adds to what is there: two frames back to back.
  std::string two = "x";
  grpc_web::append_frame(two, grpc_web::kDataFlag, "ab");
  grpc_web::append_frame(two, grpc_web::kTrailerFlag, "");
  EXPECT_EQ(two,
            "x\x00\x00\x00\x00\x02"
            "ab\x80\x00\x00\x00\x00"s);

  // An empty message is a valid frame too (a request with all fields at their defaults).
  const Result<std::string_view> empty =
      grpc_web::unframe_request(grpc_web::frame(grpc_web::kDataFlag, ""), 1 << 20);
  ASSERT_TRUE(empty.ok()) << empty.status().to_string();
  EXPECT_TRUE(empty->empty());
}

TEST(GrpcWebCodec, TrailerFrameRoundTrip) {
  const std::string framed = grpc_web::trailer_frame(5, "no session 'a%b'\n\xC3\xA9");
  const std::string text = "grpc-status: 5\r\ngrpc-message: no session 'a%25b'%0A%C3%A9\r\n";
  const std::optional<grpc_web::FrameHeader> header = grpc_web::read_frame_header(framed);
  ASSERT_TRUE(header.has_value());
  EXPECT_EQ(header->flag, grpc_web::kTrailerFlag);
  EXPECT_EQ(header->flag, 0x80);
  ASSERT_EQ(header->length, framed.size() - 5);
  EXPECT_EQ(framed.substr(5), text);
  EXPECT_EQ(framed.substr(0, 5), "\x80\x00\x00\x00"s + static_cast<char>(text.size()));

  EXPECT_EQ(grpc_web::trailer_frame(0, ""),
            "\x80\x00\x00\x00\x20"
            "grpc-status: 0\r\ngrpc-message: \r\n"s);

  // A trailer is never a request message.
  const Result<std::string_view> as_request = grpc_web::unframe_request(framed, 1 << 20);
  ASSERT_FALSE(as_request.ok());
  EXPECT_EQ(as_request.status().code(), ErrorCode::InvalidArgument);
  EXPECT_EQ(as_request.status().message(), "bad request frame flag 128 (want 0)");
}

TEST(GrpcWebCodec, Base64TextMode) {
  // RFC 4648 section 10.
  const std::pair<std::string_view, std::string_view> vectors[] = {{"", ""},
                                                                   {"f", "Zg=="},
                                                                   {"fo", "Zm8="},
                                                                   {"foo", "Zm9v"},
                                                                   {"foob", "Zm9vYg=="},
                                                                   {"fooba", "Zm9vYmE="},
                                                                   {"foobar", "Zm9vYmFy"}};
  for (const auto& [bytes, text] : vectors) {
    EXPECT_EQ(grpc_web::base64_encode(bytes), text) << bytes;
    const std::optional<std::string> decoded = grpc_web::base64_decode(text);
    ASSERT_TRUE(decoded.has_value()) << text;
    EXPECT_EQ(*decoded, bytes) << text;
  }
  EXPECT_EQ(grpc_web::base64_encode("\xfb\xff\x3e"s), "+/8+");
  EXPECT_EQ(grpc_web::base64_decode("+/8+"), "\xfb\xff\x3e"s);

  // Streaming -text peers send padded segments back to back.
  EXPECT_EQ(grpc_web::base64_decode("Zg==Zm8=Zm9v"), "ffofoo");
  for (const std::string_view bad : {"Zg=", "Z===", "Zg=a", "Zm9v!A==", "=Zm9", "Zm 9"}) {
    EXPECT_FALSE(grpc_web::base64_decode(bad).has_value()) << bad;
  }

  // A text-mode request and response: base64 of the frames, both directions.
  const std::string payload = awkward_payload();
  const std::string body = grpc_web::encode_body(grpc_web::Encoding::Text,
                                                 grpc_web::frame(grpc_web::kDataFlag, payload));
  EXPECT_EQ(body.size() % 4, 0U);
  EXPECT_EQ(
      body.find_first_not_of("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/="),
      std::string::npos);
  const std::optional<std::string> decoded = grpc_web::base64_decode(body);
  ASSERT_TRUE(decoded.has_value());
  const Result<std::string_view> message = grpc_web::unframe_request(*decoded, 1 << 20);
  ASSERT_TRUE(message.ok()) << message.status().to_string();
  EXPECT_EQ(*message, payload);
  EXPECT_EQ(grpc_web::encode_body(grpc_web::Encoding::Binary, "\x00\x01"s), "\x00\x01"s);

  // Which content types are text mode.
  EXPECT_EQ(grpc_web::parse_content_type("application/grpc-web-text"), grpc_web::Encoding::Text);
  EXPECT_EQ(grpc_web::parse_content_type(" Application/GRPC-Web-Text+proto ; charset=x"),
            grpc_web::Encoding::Text);
  EXPECT_EQ(grpc_web::parse_content_type("application/grpc-web"), grpc_web::Encoding::Binary);
  EXPECT_EQ(grpc_web::parse_content_type("application/grpc-web+proto"), grpc_web::Encoding::Binary);
  EXPECT_FALSE(grpc_web::parse_content_type("application/grpc").has_value());
  EXPECT_FALSE(grpc_web::parse_content_type("application/grpc-web+json").has_value());
  EXPECT_EQ(grpc_web::response_content_type(grpc_web::Encoding::Text),
            "application/grpc-web-text+proto");
  EXPECT_EQ(grpc_web::response_content_type(grpc_web::Encoding::Binary),
            "application/grpc-web+proto");
}

TEST(GrpcWebCodec, TruncatedAndMalformedFramesAreRejected) {
  const std::string framed = grpc_web::frame(grpc_web::kDataFlag, "hello");
  const auto expect_fault = [](std::string_view body, ErrorCode code, std::string_view message) {
    const Result<std::string_view> result = grpc_web::unframe_request(body, 16);
    ASSERT_FALSE(result.ok()) << "accepted: " << testing::PrintToString(std::string(body));
    EXPECT_EQ(result.status().code(), code);
    EXPECT_EQ(result.status().message(), message);
  };
  // The message cut short by one byte, and a header cut short.
  expect_fault(framed.substr(0, framed.size() - 1), ErrorCode::InvalidArgument,
               "truncated request message: the frame declares 5 bytes, the body holds 4");
  expect_fault(framed.substr(0, 3), ErrorCode::InvalidArgument,
               "truncated frame header: 3 of 5 bytes");
  EXPECT_FALSE(grpc_web::read_frame_header(framed.substr(0, 4)).has_value());
  expect_fault("", ErrorCode::InvalidArgument,
               "empty request body (want one length-prefixed message)");
  // One message per request, uncompressed, within the limit.
  expect_fault(framed + "!", ErrorCode::InvalidArgument,
               "1 bytes after the request message (one message per request)");
  expect_fault("\x01\x00\x00\x00\x01x"s, ErrorCode::InvalidArgument,
               "compressed request messages are not supported");
  expect_fault(grpc_web::frame(grpc_web::kDataFlag, std::string(17, 'x')),
               ErrorCode::ResourceExhausted,
               "request message of 17 bytes is over the limit of 16 bytes");
  // A declared length over the limit is refused before the body is looked at.
  expect_fault("\x00\xff\xff\xff\xff"s, ErrorCode::ResourceExhausted,
               "request message of 4294967295 bytes is over the limit of 16 bytes");
}

TEST(GrpcWebHelpers, ParseGrpcTimeout) {
  using std::chrono::nanoseconds;
  EXPECT_EQ(*parse_grpc_timeout("500m"), milliseconds(500));
  EXPECT_EQ(*parse_grpc_timeout("2S"), seconds(2));
  EXPECT_EQ(*parse_grpc_timeout("1H"), std::chrono::hours(1));
  EXPECT_EQ(*parse_grpc_timeout("3M"), std::chrono::minutes(3));
  EXPECT_EQ(*parse_grpc_timeout("10u"), std::chrono::microseconds(10));
  EXPECT_EQ(*parse_grpc_timeout("7n"), nanoseconds(7));
  EXPECT_EQ(*parse_grpc_timeout("99999999H"), std::chrono::hours(100'000));  // saturates
  for (const std::string_view bad : {"", "5", "m", "5x", "123456789S", "-5S", "5 S", "1.5S"}) {
    EXPECT_FALSE(parse_grpc_timeout(bad).ok()) << bad;
  }
  EXPECT_EQ(percent_encode_grpc_message("a%b\n\xC3\xA9 ok"), "a%25b%0A%C3%A9 ok");
}

}  // namespace
}  // namespace meshdeform::transport
