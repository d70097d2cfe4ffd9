#include "server/service/worker_pool.h"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <future>
#include <memory>
#include <mutex>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <gtest/gtest.h>

namespace meshdeform::service {
namespace {

// Generous bound for "this eventually happens": only a broken pool waits this long.
constexpr auto kBound = std::chrono::seconds(60);

// Waits (bounded) until depths() satisfies `ready`.
template <typename Ready>
bool wait_for_depths(const WorkerPool& pool, Ready ready) {
  const auto deadline = std::chrono::steady_clock::now() + kBound;
  while (std::chrono::steady_clock::now() < deadline) {
    if (ready(pool.depths())) return true;
    std::this_thread::yield();
  }
  return false;
}

// A gate tasks wait at; open() is idempotent. Tests hold it open-on-exit guards declared after
// the pool (so destroyed first): an early ASSERT opens it and the pool's drain cannot hang.
class Gate {
 public:
  void wait() {
    std::unique_lock lock(mutex_);
    cv_.wait(lock, [this] { return open_; });
  }
  void open() {
    {
      std::lock_guard lock(mutex_);
      open_ = true;
    }
    cv_.notify_all();
  }

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  bool open_ = false;
};

struct OpenOnExit {
  Gate& gate;
  ~OpenOnExit() { gate.open(); }
};

// Records the order in which tasks ran.
struct Journal {
  std::mutex mutex;
  std::vector<std::string> order;
  void add(std::string name) {
    std::lock_guard lock(mutex);
    order.push_back(std::move(name));
  }
};

TEST(WorkerPool, SizeAndHeavyLanesFollowTheirRules) {
  EXPECT_EQ(WorkerPool(1).size(), 1);
  EXPECT_EQ(WorkerPool(1).heavy_lanes(), 1);
  EXPECT_EQ(WorkerPool(3).heavy_lanes(), 2);       // default: size - 1
  EXPECT_EQ(WorkerPool(3, 1).heavy_lanes(), 1);
  EXPECT_EQ(WorkerPool(3, 7).heavy_lanes(), 2);    // clamped: one worker stays light
  EXPECT_GE(WorkerPool(0).size(), 2);              // one per core, at least 2
}

// A normal task waiting behind a blocked worker runs before a background task queued earlier.
TEST(WorkerPool, NormalTasksGoBeforeBackgroundOnes) {
  Journal journal;
  Gate release;
  {
    WorkerPool pool(1);
    OpenOnExit open_on_exit{release};
    pool.submit([&] { release.wait(); });
    ASSERT_TRUE(wait_for_depths(pool, [](const QueueDepths& d) { return d.normal == 0; }));
    std::promise<void> background_ran;
    pool.submit_background([&] {
      journal.add("background");
      background_ran.set_value();
    });
    pool.submit([&] { journal.add("normal"); });
    const QueueDepths queued = pool.depths();
    EXPECT_EQ(queued.normal, 1u);
    EXPECT_EQ(queued.background, 1u);
    release.open();
    ASSERT_EQ(background_ran.get_future().wait_for(kBound), std::future_status::ready);
  }
  EXPECT_EQ(journal.order, (std::vector<std::string>{"normal", "background"}));
}

// Heavy tasks are fair between clients: tasks queued while the lane is busy alternate between
// clients (a1, b1, a2) instead of running first in, first out (a1, a2, b1). The pool forgets
// who was served whenever its heavy queue empties, so the blocker a0 does not count.
TEST(WorkerPool, HeavyTasksAlternateBetweenClients) {
  Journal journal;
  Gate release;
  std::promise<void> blocker_started;
  {
    WorkerPool pool(2, 1);
    OpenOnExit open_on_exit{release};
    pool.submit(
        [&] {
          blocker_started.set_value();
          release.wait();
          journal.add("a0");
        },
        TaskClass::Heavy, "a");
    ASSERT_EQ(blocker_started.get_future().wait_for(kBound), std::future_status::ready);
    pool.submit([&] { journal.add("a1"); }, TaskClass::Heavy, "a");
    pool.submit([&] { journal.add("a2"); }, TaskClass::Heavy, "a");
    pool.submit([&] { journal.add("b1"); }, TaskClass::Heavy, "b");
    ASSERT_EQ(pool.depths().heavy, 3u);
    release.open();
  }  // the destructor runs every queued heavy task
  EXPECT_EQ(journal.order, (std::vector<std::string>{"a0", "a1", "b1", "a2"}));
}

// A throwing task is swallowed; the worker goes on with the next one.
TEST(WorkerPool, AThrowingTaskDoesNotStopTheWorker) {
  std::promise<void> next_ran;
  WorkerPool pool(1);
  pool.submit([] { throw std::runtime_error("task failed"); });
  pool.submit([&] { next_ran.set_value(); });
  EXPECT_EQ(next_ran.get_future().wait_for(kBound), std::future_status::ready);
}

// Shutdown runs every normal and heavy task still queued.
TEST(WorkerPool, ShutdownRunsQueuedNormalAndHeavyTasks) {
  std::atomic<int> ran{0};
  Gate release;
  auto pool = std::make_unique<WorkerPool>(2, 1);
  pool->submit([&] { release.wait(); });
  pool->submit([&] { release.wait(); }, TaskClass::Heavy, "c");
  for (int i = 0; i < 5; ++i) pool->submit([&] { ++ran; });
  for (int i = 0; i < 3; ++i) pool->submit([&] { ++ran; }, TaskClass::Heavy, "c");
  std::jthread releaser([&] { release.open(); });
  pool.reset();
  EXPECT_EQ(ran.load(), 8);
}

}  // namespace
}  // namespace meshdeform::service
