#include "server/service/call_stop.h"

#include <gtest/gtest.h>

#include <chrono>
#include <future>
#include <memory>
#include <stop_token>

namespace meshdeform::service {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;

/// A generous bound for something that should happen at once (loaded CI machines).
constexpr seconds kBound{30};

/// True once `token` is stopped, waiting at most kBound (a condition, not a sleep).
bool stops_within_bound(const std::stop_token& token) {
  auto stopped = std::make_shared<std::promise<void>>();
  std::future<void> done = stopped->get_future();
  const std::stop_callback notify(token, [stopped] { stopped->set_value(); });
  return done.wait_for(kBound) == std::future_status::ready;
}

TEST(CallStopTest, StopsWithTheCallOrTheShutdown) {
  std::stop_source call, shutdown;
  const CallStop first(call.get_token(), shutdown.get_token());
  EXPECT_FALSE(first.token().stop_requested());
  call.request_stop();
  EXPECT_TRUE(first.token().stop_requested());

  std::stop_source other_call;
  const CallStop second(other_call.get_token(), shutdown.get_token());
  EXPECT_FALSE(second.token().stop_requested());
  shutdown.request_stop();
  EXPECT_TRUE(second.token().stop_requested());
  EXPECT_FALSE(other_call.stop_requested());  // the call's own token is not touched

  // Already stopped when made: stopped at once.
  const CallStop late(other_call.get_token(), shutdown.get_token());
  EXPECT_TRUE(late.token().stop_requested());
}

TEST(CallStopTest, WithoutTokensOnlyItsSourceStopsIt) {
  const CallStop stop({}, {});
  EXPECT_FALSE(stop.token().stop_requested());
  stop.source().request_stop();  // what refinement preemption does
  EXPECT_TRUE(stop.token().stop_requested());
}

TEST(CallStopTest, StopsAtTheDeadline) {
  DelayQueue timers;
  const CallStop none({}, {}, std::nullopt, timers);
  const CallStop passed({}, {}, std::chrono::steady_clock::now() - milliseconds(1), timers);
  EXPECT_TRUE(passed.token().stop_requested());  // at once, no timer
  const CallStop soon({}, {}, std::chrono::steady_clock::now() + milliseconds(20), timers);
  EXPECT_TRUE(stops_within_bound(soon.token()));
  EXPECT_FALSE(none.token().stop_requested());
}

TEST(CallStopTest, ATimerFiringAfterTheCallEndedIsHarmless) {
  DelayQueue timers;
  std::stop_token token;
  {
    const CallStop ended({}, {}, std::chrono::steady_clock::now() + milliseconds(20), timers);
    token = ended.token();
  }
  // The timer still holds the stop state; it fires into nobody's call.
  EXPECT_TRUE(stops_within_bound(token));
}

}  // namespace
}  // namespace meshdeform::service
