#include "server/service/session_store.h"

#include <chrono>
#include <memory>
#include <string>

#include <gtest/gtest.h>

#include "server/service/session.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::service {
namespace {

using namespace std::chrono_literals;

// A clock the test moves by hand: expiry never depends on how fast the machine is.
struct ManualClock {
  std::shared_ptr<std::chrono::steady_clock::time_point> now =
      std::make_shared<std::chrono::steady_clock::time_point>(std::chrono::steady_clock::time_point{} +
                                                             1h);
  Clock clock() const {
    return [now = now] { return *now; };
  }
  void advance(std::chrono::seconds by) { *now += by; }
};

std::shared_ptr<Session> make_session(const std::string& id, const ServiceOptions& options) {
  auto created = Session::create(SessionId{id}, Token{"edit-" + id}, Token{"view-" + id},
                                 test::make_grid(6, 0.05), core::DeformerSettings{}, options,
                                 std::make_shared<ServiceCounters>(), nullptr);
  EXPECT_TRUE(created.ok()) << created.status().to_string();
  return created.ok() ? *created : nullptr;
}

ServiceOptions options_with(const ManualClock& clock) {
  ServiceOptions options;
  options.clock = clock.clock();
  options.idle_ttl = 60s;
  return options;
}

TEST(SessionStore, FindsWhatItHoldsAndEraseClosesTheSession) {
  ManualClock clock;
  const ServiceOptions options = options_with(clock);
  SessionStore store(options);
  auto a = make_session("a", options);
  ASSERT_NE(a, nullptr);
  ASSERT_TRUE(store.insert(a).ok());
  EXPECT_EQ(store.size(), 1u);
  EXPECT_EQ(store.find(SessionId{"a"}), a);
  EXPECT_EQ(store.find(SessionId{"nope"}), nullptr);
  EXPECT_EQ(store.total_bytes(), a->estimated_bytes());
  EXPECT_TRUE(store.erase(SessionId{"a"}));
  EXPECT_TRUE(a->is_closed());
  EXPECT_FALSE(store.erase(SessionId{"a"}));
  EXPECT_EQ(store.find(SessionId{"a"}), nullptr);
  EXPECT_EQ(store.size(), 0u);
}

TEST(SessionStore, RefusesASessionOverTheCountLimit) {
  ManualClock clock;
  ServiceOptions options = options_with(clock);
  options.max_sessions = 2;
  SessionStore store(options);
  ASSERT_TRUE(store.insert(make_session("a", options)).ok());
  ASSERT_TRUE(store.insert(make_session("b", options)).ok());
  const Status third = store.insert(make_session("c", options));
  ASSERT_FALSE(third.ok());
  EXPECT_EQ(third.code(), ErrorCode::ResourceExhausted);
  EXPECT_NE(third.message().find("too many sessions: 2 open, the limit is 2"), std::string::npos)
      << third.message();
  EXPECT_EQ(store.size(), 2u);
}

// Idle past the TTL (by the injected clock) ends a session, on lookup or on a sweep; use
// refreshes it; a session with an edit in flight does not expire.
TEST(SessionStore, IdleSessionsExpireByTheClockNotByWaiting) {
  ManualClock clock;
  const ServiceOptions options = options_with(clock);
  SessionStore store(options);
  auto a = make_session("a", options), b = make_session("b", options),
       busy = make_session("busy", options);
  ASSERT_TRUE(store.insert(a).ok());
  ASSERT_TRUE(store.insert(b).ok());
  ASSERT_TRUE(store.insert(busy).ok());
  busy->inflight().fetch_add(1);

  clock.advance(40s);
  ASSERT_EQ(store.find(SessionId{"b"}), b);  // used at 40 s: its TTL restarts
  clock.advance(30s);                        // a idle 70 s, b idle 30 s
  EXPECT_EQ(store.find(SessionId{"a"}), nullptr);
  EXPECT_TRUE(a->is_closed());
  EXPECT_EQ(store.evicted_idle(), 1u);
  EXPECT_EQ(store.find(SessionId{"b"}), b);

  clock.advance(61s);
  EXPECT_EQ(store.evict_expired(store.now()), 1u);  // b; busy stays while its edit runs
  EXPECT_TRUE(b->is_closed());
  EXPECT_FALSE(busy->is_closed());
  EXPECT_EQ(store.size(), 1u);
  busy->inflight().fetch_sub(1);
  EXPECT_EQ(store.evict_expired(store.now()), 1u);
  EXPECT_EQ(store.evicted_idle(), 3u);
}

// Over the memory budget the least recently used idle sessions go first, and only as many as
// needed; if evicting every idle session would not make room, nothing is evicted.
TEST(SessionStore, MemoryBudgetEvictsLeastRecentlyUsedFirst) {
  ManualClock clock;
  ServiceOptions options = options_with(clock);
  auto probe = make_session("probe", options);
  ASSERT_NE(probe, nullptr);
  const std::size_t bytes = probe->estimated_bytes();
  ASSERT_GT(bytes, 0u);
  options.memory_budget_bytes = 3 * bytes;  // three sessions fit
  SessionStore store(options);
  auto a = make_session("a", options), b = make_session("b", options),
       c = make_session("c", options);
  ASSERT_TRUE(store.insert(a).ok());
  clock.advance(1s);
  ASSERT_TRUE(store.insert(b).ok());
  clock.advance(1s);
  ASSERT_TRUE(store.insert(c).ok());
  clock.advance(1s);
  ASSERT_EQ(store.find(SessionId{"a"}), a);  // a is now the most recently used
  clock.advance(1s);

  ASSERT_TRUE(store.insert(make_session("d", options)).ok());
  EXPECT_TRUE(b->is_closed());  // the least recently used
  EXPECT_FALSE(a->is_closed());
  EXPECT_FALSE(c->is_closed());
  EXPECT_EQ(store.evicted_lru(), 1u);
  EXPECT_EQ(store.size(), 3u);

  // Every other session busy: no room can be made, and none is evicted for nothing.
  for (const char* id : {"a", "c", "d"}) store.find(SessionId{id})->inflight().fetch_add(1);
  const Status refused = store.insert(make_session("e", options));
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.code(), ErrorCode::ResourceExhausted);
  EXPECT_NE(refused.message().find("memory budget exceeded"), std::string::npos)
      << refused.message();
  EXPECT_EQ(store.size(), 3u);
  EXPECT_EQ(store.evicted_lru(), 1u);
  const Status reserve = store.reserve(bytes, *a);
  EXPECT_EQ(reserve.code(), ErrorCode::ResourceExhausted);
}

TEST(SessionStore, ClearClosesEverySession) {
  ManualClock clock;
  const ServiceOptions options = options_with(clock);
  SessionStore store(options);
  auto a = make_session("a", options), b = make_session("b", options);
  ASSERT_TRUE(store.insert(a).ok());
  ASSERT_TRUE(store.insert(b).ok());
  store.clear();
  EXPECT_TRUE(a->is_closed());
  EXPECT_TRUE(b->is_closed());
  EXPECT_EQ(store.size(), 0u);
}

}  // namespace
}  // namespace meshdeform::service
