#include "server/transport/status_mapping.h"

#include <gtest/gtest.h>

#include <string>

namespace meshdeform::transport {
namespace {

TEST(StatusMappingTest, EveryCodeMaps) {
  EXPECT_EQ(to_grpc_code(ErrorCode::Ok), grpc::StatusCode::OK);
  EXPECT_EQ(to_grpc_code(ErrorCode::InvalidArgument), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_EQ(to_grpc_code(ErrorCode::NotFound), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(to_grpc_code(ErrorCode::PermissionDenied), grpc::StatusCode::PERMISSION_DENIED);
  EXPECT_EQ(to_grpc_code(ErrorCode::FailedPrecondition), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_EQ(to_grpc_code(ErrorCode::ResourceExhausted), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_EQ(to_grpc_code(ErrorCode::Cancelled), grpc::StatusCode::CANCELLED);
  EXPECT_EQ(to_grpc_code(ErrorCode::DeadlineExceeded), grpc::StatusCode::DEADLINE_EXCEEDED);
  EXPECT_EQ(to_grpc_code(ErrorCode::NumericalFailure), grpc::StatusCode::INTERNAL);
  EXPECT_EQ(to_grpc_code(ErrorCode::Internal), grpc::StatusCode::INTERNAL);
}

TEST(StatusMappingTest, MessagesAreTruncatedTo1KiB) {
  const grpc::Status short_status =
      to_grpc_status(Error(ErrorCode::NotFound, "no session 'x'"), "Test");
  EXPECT_EQ(short_status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(short_status.error_message(), "no session 'x'");

  const grpc::Status long_status =
      to_grpc_status(Error(ErrorCode::InvalidArgument, std::string(1500, 'a')), "Test");
  EXPECT_EQ(long_status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_LE(long_status.error_message().size(), kMaxClientMessageBytes);
  EXPECT_EQ(long_status.error_message().substr(long_status.error_message().size() - 3), "...");

  // A multi-byte UTF-8 character straddling the cut is dropped whole.
  std::string utf8(kMaxClientMessageBytes - 4, 'a');
  for (int i = 0; i < 10; ++i) utf8 += "\xc3\xa9";  // U+00E9
  const std::string cut = truncate_message(utf8);
  EXPECT_LE(cut.size(), kMaxClientMessageBytes);
  const std::string body = cut.substr(0, cut.size() - 3);
  EXPECT_NE(static_cast<unsigned char>(body.back()), 0xc3);
  EXPECT_TRUE(to_grpc_status(Status::success()).ok());
}

}  // namespace
}  // namespace meshdeform::transport
