// Token buckets with an injected clock: exact admissions, waits and refills, no sleeping.
#include "server/service/rate_limiter.h"

#include <gtest/gtest.h>

#include <chrono>
#include <string>

namespace meshdeform::service {
namespace {

using std::chrono::milliseconds;

class FakeClock {
 public:
  Clock clock() {
    return [this] { return now_; };
  }
  void advance(milliseconds d) { now_ += d; }

 private:
  std::chrono::steady_clock::time_point now_{std::chrono::hours(1)};
};

TEST(RateLimiterTest, BurstThenSustainedRateWithExactWaits) {
  FakeClock time;
  RateLimiter limiter({/*per_second=*/2.0, /*burst=*/3.0}, {0, 1}, time.clock());
  for (int i = 0; i < 3; ++i) {
    EXPECT_FALSE(limiter.admit("ipv4:10.0.0.1", RateLimitedCall::CreateSession)) << i;
  }
  const auto wait = limiter.admit("ipv4:10.0.0.1", RateLimitedCall::CreateSession);
  ASSERT_TRUE(wait);
  EXPECT_EQ(*wait, milliseconds(500));  // one token at 2 per second
  time.advance(milliseconds(499));
  EXPECT_TRUE(limiter.admit("ipv4:10.0.0.1", RateLimitedCall::CreateSession));
  time.advance(milliseconds(1));
  EXPECT_FALSE(limiter.admit("ipv4:10.0.0.1", RateLimitedCall::CreateSession));
  // A long quiet spell refills to the burst, not beyond.
  time.advance(std::chrono::minutes(10));
  for (int i = 0; i < 3; ++i) {
    EXPECT_FALSE(limiter.admit("ipv4:10.0.0.1", RateLimitedCall::CreateSession)) << i;
  }
  EXPECT_TRUE(limiter.admit("ipv4:10.0.0.1", RateLimitedCall::CreateSession));
}

TEST(RateLimiterTest, ClientsAndCallsHaveSeparateBuckets) {
  FakeClock time;
  RateLimiter limiter({1.0, 1.0}, {1.0, 2.0}, time.clock());
  EXPECT_FALSE(limiter.admit("a", RateLimitedCall::CreateSession));
  EXPECT_TRUE(limiter.admit("a", RateLimitedCall::CreateSession));
  EXPECT_FALSE(limiter.admit("b", RateLimitedCall::CreateSession));  // another client
  EXPECT_FALSE(limiter.admit("a", RateLimitedCall::MoveHandles));    // another kind of call
  EXPECT_FALSE(limiter.admit("a", RateLimitedCall::MoveHandles));
  EXPECT_TRUE(limiter.admit("a", RateLimitedCall::MoveHandles));
}

TEST(RateLimiterTest, ZeroRateIsUnlimitedAndTracksNobody) {
  RateLimiter limiter({0, 1}, {0, 1});
  for (int i = 0; i < 10'000; ++i) {
    const std::string client = std::string("a").append(std::to_string(i % 7));
    ASSERT_FALSE(limiter.admit(client, RateLimitedCall::MoveHandles));
  }
  EXPECT_EQ(limiter.tracked_clients(), 0u);
}

TEST(RateLimiterTest, TableIsBoundedAndForgetsTheLongestIdle) {
  FakeClock time;
  RateLimiter limiter({1.0, 1.0}, {1.0, 1.0}, time.clock(), /*max_clients=*/3);
  for (const char* c : {"a", "b", "c"}) {
    EXPECT_FALSE(limiter.admit(c, RateLimitedCall::MoveHandles));
    time.advance(milliseconds(10));
  }
  EXPECT_TRUE(limiter.admit("b", RateLimitedCall::MoveHandles));  // refreshes b's touch
  EXPECT_FALSE(limiter.admit("d", RateLimitedCall::MoveHandles));  // evicts a, the longest idle
  EXPECT_EQ(limiter.tracked_clients(), 3u);
  EXPECT_TRUE(limiter.admit("c", RateLimitedCall::MoveHandles));  // c was kept: still empty
  EXPECT_FALSE(limiter.admit("a", RateLimitedCall::MoveHandles));  // a starts afresh
}

}  // namespace
}  // namespace meshdeform::service
