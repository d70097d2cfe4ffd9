// The link model's schedule, driven by explicit time points (no clock, no sockets): rate,
// delay, in-order jitter, loss as a stall and the bounded queue, checked by exact arithmetic.
#include <gtest/gtest.h>

#include <chrono>

#include "linkemu/link_emulator.h"
#include "linkemu/link_model.h"

namespace meshdeform::linkemu {
namespace {

using namespace std::chrono_literals;

TimePoint at(Duration d) { return TimePoint{} + d; }

TEST(LinkModel, SerialisesChunksAtTheRate) {
  DirectionSettings s;
  s.rate_bits_per_second = 1e6;  // 1250 bytes take 10 ms
  DirectionModel model(s);
  const TimePoint t0 = at(1s);
  EXPECT_EQ(model.push(1250, t0), t0 + 10ms);
  EXPECT_EQ(model.push(1250, t0), t0 + 20ms);  // behind the first
  EXPECT_EQ(model.push(2500, t0 + 5ms), t0 + 40ms);
  EXPECT_EQ(model.queued(), 5000u);
  EXPECT_EQ(model.deliverable(t0 + 19ms), 1250u);
  EXPECT_EQ(model.deliverable(t0 + 20ms), 2500u);
  EXPECT_EQ(model.deliverable(t0 + 40ms), 5000u);
}

TEST(LinkModel, AnIdleLinkStartsAtArrivalWithoutCredit) {
  DirectionSettings s;
  s.rate_bits_per_second = 8e6;  // 1000 bytes per ms
  DirectionModel model(s);
  EXPECT_EQ(model.push(1000, at(0ms)), at(1ms));
  // The link was idle from 1 ms to 100 ms: that time is not banked for the next chunk.
  EXPECT_EQ(model.push(5000, at(100ms)), at(105ms));
}

TEST(LinkModel, AddsTheOneWayDelayAfterTransmission) {
  DirectionSettings s;
  s.rate_bits_per_second = 8e6;
  s.delay = 20ms;
  DirectionModel model(s);
  EXPECT_EQ(model.push(2000, at(0ms)), at(22ms));
  EXPECT_EQ(model.next_due(), at(22ms));
  EXPECT_EQ(model.deliverable(at(21ms)), 0u);
  EXPECT_EQ(model.deliverable(at(22ms)), 2000u);
}

TEST(LinkModel, JitterNeverReorders) {
  DirectionSettings s;
  s.rate_bits_per_second = 80e6;
  s.delay = 5ms;
  s.jitter = 10ms;
  DirectionModel model(s, 7);
  TimePoint previous{};
  bool any_jitter = false;
  for (int i = 0; i < 500; ++i) {
    const TimePoint now = at(i * 100us);
    const TimePoint due = model.push(100, now);
    EXPECT_GE(due, previous) << "chunk " << i;
    // Never earlier than transmission plus the base delay.
    EXPECT_GE(due, now + 5ms);
    if (due > now + 5ms + 10us) any_jitter = true;
    previous = due;
  }
  EXPECT_TRUE(any_jitter);
  // Delivering in order takes every byte once.
  std::size_t total = 0;
  for (int step = 0; step < 400; ++step) {
    const TimePoint now = at(step * 1ms);
    const std::size_t due = model.deliverable(now);
    model.delivered(due, now);
    total += due;
  }
  EXPECT_EQ(total, 50'000u);
  EXPECT_EQ(model.queued(), 0u);
  EXPECT_EQ(model.counters().bytes_delivered, 50'000u);
}

TEST(LinkModel, LossStallsTheLinkByTheStallPerLostPacket) {
  DirectionSettings s;
  s.rate_bits_per_second = 8e6;  // 1000 bytes per ms
  s.loss = 0.2;
  s.stall = 50ms;
  DirectionModel model(s, 3);
  TimePoint due{};
  for (int i = 0; i < 100; ++i) due = model.push(kPacketBytes, at(0ms));
  const std::uint64_t losses = model.counters().losses;
  EXPECT_GT(losses, 5u);
  EXPECT_LT(losses, 50u);
  // Head-of-line blocking: every loss adds exactly one stall to the stream's schedule.
  const Duration transmit = std::chrono::duration_cast<Duration>(
      std::chrono::duration<double>(8.0 * kPacketBytes / 8e6));
  const Duration expected = static_cast<std::int64_t>(losses) * 50ms + 100 * transmit;
  EXPECT_LE((due - at(0ms) - expected).count(), 100) << "rounding only";
  EXPECT_GE((due - at(0ms) - expected).count(), -100);
}

TEST(LinkModel, TheQueueBoundsWhatEntersUntilBytesAreDelivered) {
  DirectionSettings s;
  s.rate_bits_per_second = 1e6;
  s.queue_bytes = 10'000;
  DirectionModel model(s);
  EXPECT_EQ(model.room(), 10'000u);
  model.push(6'000, at(0ms));
  EXPECT_EQ(model.room(), 4'000u);
  model.push(4'000, at(0ms));
  EXPECT_EQ(model.room(), 0u);
  // Bytes that were transmitted but not yet taken by the receiver still occupy the queue.
  EXPECT_EQ(model.deliverable(at(1s)), 10'000u);
  EXPECT_EQ(model.room(), 0u);
  model.delivered(7'000, at(1s));
  EXPECT_EQ(model.room(), 7'000u);
  EXPECT_EQ(model.queued(), 3'000u);
}

TEST(LinkModel, DefaultQueueHoldsTheBandwidthDelayProduct) {
  DirectionSettings s;
  s.rate_bits_per_second = 100e6;
  s.delay = 50ms;  // BDP 625,000 bytes
  EXPECT_EQ(s.effective_queue_bytes(), 625'000u + 64 * 1024);
  DirectionSettings small;
  small.rate_bits_per_second = 1e6;
  small.delay = 1ms;
  EXPECT_EQ(small.effective_queue_bytes(), 256u * 1024);
}

TEST(LinkSpec, ParsesRateRttAndOptions) {
  std::string error;
  const std::optional<LinkSettings> s =
      parse_link_spec("20mbit,40ms,jitter=2ms,loss=1%,stall=300ms,queue=512kb", error);
  ASSERT_TRUE(s) << error;
  EXPECT_DOUBLE_EQ(s->down.rate_bits_per_second, 20e6);
  EXPECT_DOUBLE_EQ(s->up.rate_bits_per_second, 20e6);
  EXPECT_EQ(s->down.delay, 20ms);
  EXPECT_EQ(s->up.delay, 20ms);
  EXPECT_EQ(s->down.jitter, 2ms);
  EXPECT_DOUBLE_EQ(s->up.loss, 0.01);
  EXPECT_EQ(s->up.stall, 300ms);
  EXPECT_EQ(s->down.queue_bytes, 512u * 1024);
  const LinkSummary m = summarize_link(*s);
  EXPECT_DOUBLE_EQ(m.rtt_ms, 40.0);
  EXPECT_DOUBLE_EQ(m.down_mbit, 20.0);
}

TEST(LinkSpec, PerDirectionItemsOverrideTheShorthand) {
  std::string error;
  const std::optional<LinkSettings> s =
      parse_link_spec("100mbit,up=5mbit,rtt=30ms,delay-up=25ms", error);
  ASSERT_TRUE(s) << error;
  EXPECT_DOUBLE_EQ(s->down.rate_bits_per_second, 100e6);
  EXPECT_DOUBLE_EQ(s->up.rate_bits_per_second, 5e6);
  EXPECT_EQ(s->down.delay, 15ms);
  EXPECT_EQ(s->up.delay, 25ms);
}

TEST(LinkSpec, RefusesBadItemsNamingThem) {
  for (const char* bad : {"", "20furlongs", "loss=1.5", "jitter=fast", "queue=0", "colour=red",
                          "20mbit,-5ms"}) {
    std::string error;
    EXPECT_FALSE(parse_link_spec(bad, error)) << bad;
    EXPECT_FALSE(error.empty()) << bad;
  }
  std::string error;
  EXPECT_FALSE(parse_link_spec("20mbit,colour=red", error));
  EXPECT_NE(error.find("colour=red"), std::string::npos) << error;
}

}  // namespace
}  // namespace meshdeform::linkemu
