// BytesMemo: bytes made once per key and shared, also by threads asking at once; clear forgets.

#include "server/service/bytes_memo.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <future>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace meshdeform::service {
namespace {

TEST(BytesMemo, MakesEachKeyOnceAndForgetsOnClear) {
  BytesMemo memo;
  int made = 0;
  auto make = [&made](char c) {
    return [&made, c] {
      ++made;
      return std::string(10, c);
    };
  };
  const auto a = memo.get(1, make('a'));
  EXPECT_EQ(*a, std::string(10, 'a'));
  EXPECT_EQ(memo.get(1, make('z')), a);  // the same bytes, not made again
  EXPECT_EQ(*memo.get(2, make('b')), std::string(10, 'b'));
  EXPECT_EQ(made, 2);
  EXPECT_EQ(memo.bytes(), 20u);
  memo.clear();
  EXPECT_EQ(memo.bytes(), 0u);
  EXPECT_EQ(*a, std::string(10, 'a'));  // a reader's copy outlives the clear
  EXPECT_EQ(*memo.get(1, make('c')), std::string(10, 'c'));
  EXPECT_EQ(made, 3);
}

TEST(BytesMemo, ThreadsAskingAtOnceShareOneMake) {
  BytesMemo memo;
  std::atomic<int> made{0};
  std::vector<std::thread> threads;
  std::vector<const std::string*> got(4, nullptr);
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      got[static_cast<std::size_t>(t)] = memo.get(5, [&made] {
        made.fetch_add(1);
        std::this_thread::sleep_for(std::chrono::milliseconds(20));  // overlap the others
        return std::string("bytes");
      }).get();
    });
  }
  for (std::thread& thread : threads) thread.join();
  EXPECT_EQ(made.load(), 1);
  for (const std::string* bytes : got) EXPECT_EQ(bytes, got[0]);
}

TEST(BytesMemo, AFailedMakeLeavesNothingBehind) {
  BytesMemo memo;
  EXPECT_THROW(memo.get(1, []() -> std::string { throw std::runtime_error("no"); }),
               std::runtime_error);
  EXPECT_EQ(memo.bytes(), 0u);
  EXPECT_EQ(*memo.get(1, [] { return std::string("ok"); }), "ok");
}

TEST(BytesMemo, ClearDoesNotWaitForAMakeAndItsBytesStayOut) {
  // A watcher encoding revision r must not hold up the commit of r + 1, which clears r's memo.
  BytesMemo memo;
  std::promise<void> inside, release;
  std::shared_future<void> released = release.get_future().share();
  auto maker = std::async(std::launch::async, [&] {
    return memo.get(1, [&] {
      inside.set_value();
      released.wait();
      return std::string("old");
    });
  });
  inside.get_future().wait();
  // Bounded: a clear (or another key) that waited for the make would still be blocked when this
  // gives up; the make is released either way, so nothing hangs.
  auto cleared = std::async(std::launch::async, [&] { memo.clear(); });
  EXPECT_EQ(cleared.wait_for(std::chrono::seconds(30)), std::future_status::ready);
  auto other = std::async(std::launch::async,
                          [&] { return memo.get(2, [] { return std::string("other"); }); });
  EXPECT_EQ(other.wait_for(std::chrono::seconds(30)), std::future_status::ready);
  release.set_value();
  EXPECT_EQ(*other.get(), "other");
  EXPECT_EQ(*maker.get(), "old");  // its reader gets the bytes...
  EXPECT_EQ(memo.bytes(), 5u);     // ...but only key 2's are kept: the clear came after key 1's make began
  int made = 0;
  EXPECT_EQ(*memo.get(1, [&] { ++made; return std::string("new"); }), "new");
  EXPECT_EQ(made, 1);
}

TEST(BytesMemo, AReaderWaitingOnAFailedMakeMakesItItself) {
  BytesMemo memo;
  std::promise<void> inside, release;
  std::shared_future<void> released = release.get_future().share();
  auto failing = std::async(std::launch::async, [&] {
    return memo.get(1, [&]() -> std::string {
      inside.set_value();
      released.wait();
      throw std::runtime_error("encoder failed");
    });
  });
  inside.get_future().wait();
  auto waiting = std::async(std::launch::async, [&] {
    return memo.get(1, [] { return std::string("second"); });
  });
  release.set_value();
  EXPECT_THROW(failing.get(), std::runtime_error);
  EXPECT_EQ(*waiting.get(), "second");
  EXPECT_EQ(memo.bytes(), 6u);
}

}  // namespace
}  // namespace meshdeform::service
