#include "server/service/watcher.h"

#include <chrono>
#include <memory>
#include <stop_token>

#include <gtest/gtest.h>

namespace meshdeform::service {
namespace {

using namespace std::chrono_literals;

std::shared_ptr<const DeformResult> revision(std::uint64_t r) {
  auto result = std::make_shared<DeformResult>();
  result->revision = r;
  return result;
}

TEST(Watcher, DeliversEachRevisionTakenInTime) {
  Watcher watcher;
  EXPECT_FALSE(watcher.try_take().has_value());
  watcher.publish_snapshot(revision(3));
  auto first = watcher.try_take();
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->result->revision, 3u);
  EXPECT_TRUE(first->is_snapshot);
  watcher.publish(revision(4));
  auto second = watcher.try_take();
  ASSERT_TRUE(second.has_value());
  EXPECT_EQ(second->result->revision, 4u);
  EXPECT_FALSE(second->is_snapshot);
  EXPECT_EQ(second->skipped_revisions, 0u);
  EXPECT_FALSE(watcher.try_take().has_value());
}

// A slow watcher skips to the newest revision: one pending update, a snapshot, counting what it
// skipped; memory stays one result however far behind it is.
TEST(Watcher, ASlowWatcherSkipsToTheNewestAsASnapshot) {
  Watcher watcher;
  for (std::uint64_t r = 1; r <= 5; ++r) watcher.publish(revision(r));
  auto update = watcher.try_take();
  ASSERT_TRUE(update.has_value());
  EXPECT_EQ(update->result->revision, 5u);
  EXPECT_TRUE(update->is_snapshot);
  EXPECT_EQ(update->skipped_revisions, 4u);
  EXPECT_FALSE(watcher.try_take().has_value());
}

// The join snapshot and a concurrent commit race: the watcher never goes back in revisions.
TEST(Watcher, NeverGoesBackInRevisions) {
  Watcher watcher;
  watcher.publish(revision(7));
  watcher.publish_snapshot(revision(6));
  watcher.publish(revision(7));
  auto update = watcher.try_take();
  ASSERT_TRUE(update.has_value());
  EXPECT_EQ(update->result->revision, 7u);
  EXPECT_EQ(update->skipped_revisions, 0u);
  watcher.publish(revision(5));
  EXPECT_FALSE(watcher.try_take().has_value());
}

// notify fires when an update becomes pending (not again while one is), at once when set while
// one is pending, and on close.
TEST(Watcher, NotifiesWhenAnUpdateBecomesPendingAndOnClose) {
  Watcher watcher;
  int calls = 0;
  watcher.set_notify([&] { ++calls; });
  EXPECT_EQ(calls, 0);
  watcher.publish(revision(1));
  EXPECT_EQ(calls, 1);
  watcher.publish(revision(2));  // replaces the pending one: no new notification
  EXPECT_EQ(calls, 1);
  ASSERT_TRUE(watcher.try_take().has_value());
  watcher.publish(revision(3));
  EXPECT_EQ(calls, 2);
  int late_calls = 0;
  watcher.set_notify([&] { ++late_calls; });  // an update is pending: called at once
  EXPECT_EQ(late_calls, 1);
  watcher.close();
  EXPECT_EQ(late_calls, 2);
  watcher.close();  // idempotent
  EXPECT_EQ(late_calls, 2);
}

// After close: nothing new is accepted, a pending update can still be taken, then waits end at
// once with nothing.
TEST(Watcher, CloseEndsTheWatchAfterThePendingUpdate) {
  Watcher watcher;
  watcher.publish(revision(1));
  watcher.close();
  EXPECT_TRUE(watcher.closed());
  watcher.publish(revision(2));
  auto last = watcher.wait_take(24h);
  ASSERT_TRUE(last.has_value());
  EXPECT_EQ(last->result->revision, 1u);
  EXPECT_FALSE(watcher.wait_take(24h).has_value());  // returns at once: closed, nothing pending
}

TEST(Watcher, WaitTakeEndsOnTimeoutOrStopWithNothing) {
  Watcher watcher;
  EXPECT_FALSE(watcher.wait_take(0ms).has_value());
  std::stop_source stop;
  stop.request_stop();
  EXPECT_FALSE(watcher.wait_take(24h, stop.get_token()).has_value());  // at once
  watcher.publish(revision(9));
  auto update = watcher.wait_take(24h);
  ASSERT_TRUE(update.has_value());
  EXPECT_EQ(update->result->revision, 9u);
}

}  // namespace
}  // namespace meshdeform::service
