#include "server/service/guard.h"

#include <gtest/gtest.h>

#include <stdexcept>
#include <string>
#include <string_view>
#include <vector>

#include "server/service/log.h"

namespace meshdeform::service {
namespace {

/// Captures log lines for the test's lifetime.
class CapturedLog {
 public:
  CapturedLog() {
    set_log_sink([this](std::string_view line) { lines_.emplace_back(line); });
  }
  ~CapturedLog() { set_log_sink({}); }
  const std::vector<std::string>& lines() const { return lines_; }

 private:
  std::vector<std::string> lines_;
};

TEST(GuardTest, ExceptionsBecomeStatusesAndAreLogged) {
  const CapturedLog log;
  EXPECT_EQ(run_guarded("Test", []() -> Status { throw std::bad_alloc(); }).code(),
            ErrorCode::ResourceExhausted);
  const Status internal =
      run_guarded("Test", []() -> Status { throw std::runtime_error("secret detail"); });
  EXPECT_EQ(internal.code(), ErrorCode::Internal);
  // The text goes to the log, not to the caller.
  EXPECT_EQ(internal.message().find("secret detail"), std::string::npos) << internal.message();
  EXPECT_EQ(run_guarded("Test", []() -> Result<int> { throw 7; }).status().code(),
            ErrorCode::Internal);
  ASSERT_EQ(log.lines().size(), 3u);
  EXPECT_NE(log.lines()[1].find("secret detail"), std::string::npos) << log.lines()[1];
  EXPECT_NE(log.lines()[1].find("\"where\":\"Test\""), std::string::npos) << log.lines()[1];
}

TEST(GuardTest, ValuesPassThrough) {
  EXPECT_EQ(*run_guarded("Test", []() -> Result<int> { return 3; }), 3);
  EXPECT_TRUE(run_guarded("Test", [] { return Status::success(); }).ok());
  EXPECT_EQ(run_guarded("Test", [] { return Error(ErrorCode::NotFound, "x"); }).code(),
            ErrorCode::NotFound);
}

}  // namespace
}  // namespace meshdeform::service
