// The link-sized update codec: quantized streams reconstruct every revision within the stated
// tolerance (and the encoder knows exactly what the client holds), lossless streams bit for bit,
// only vertices that moved are sent, a byte budget is met and the pending remainder converges,
// and the decoder refuses what does not decode without changing its state.
#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>

#include "codec/update_codec.h"

namespace meshdeform::codec {
namespace {

Positions grid_mesh(int n, std::uint64_t seed) {
  // Points on a wavy sheet, in index order along rows (as meshes usually are).
  Positions out(n, 3);
  std::mt19937_64 random(seed);
  std::uniform_real_distribution<double> noise(-1e-3, 1e-3);
  const int side = static_cast<int>(std::ceil(std::sqrt(n)));
  for (int i = 0; i < n; ++i) {
    const double x = (i % side) / static_cast<double>(side);
    const double y = (i / side) / static_cast<double>(side);
    out.row(i) << x, y, 0.05 * std::sin(6 * x) * std::cos(4 * y) + noise(random);
  }
  return out;
}

/// A smooth bend growing with `t` (as a drag does: every vertex moves, far ones little).
Positions bend(const Positions& rest, double t) {
  Positions out = rest;
  for (int i = 0; i < rest.rows(); ++i) {
    const double x = rest(i, 0);
    out(i, 2) += t * x * x;
    out(i, 0) += 0.1 * t * x * rest(i, 1);
  }
  return out;
}

double max_distance(const Positions& a, const Positions& b) {
  return (a - b).rowwise().norm().maxCoeff();
}

StreamSettings quantized(double tolerance, std::size_t budget = 0) {
  StreamSettings s;
  s.mode = DeltaMode::Quantized;
  s.tolerance = tolerance;
  s.origin = Eigen::Vector3d(0, 0, -0.1);
  s.max_update_bytes = budget;
  return s;
}

TEST(UpdateCodec, QuantizedReconstructsEveryRevisionWithinTheTolerance) {
  const Positions rest = grid_mesh(3000, 1);
  constexpr double kTolerance = 1e-4;
  auto encoder = StreamEncoder::create(quantized(kTolerance), 3000);
  ASSERT_TRUE(encoder.ok()) << encoder.status().message();
  StreamDecoder decoder;
  for (int r = 0; r <= 20; ++r) {
    const Positions target = bend(rest, 0.02 * r);
    auto update = encoder->encode(target, static_cast<std::uint64_t>(r));
    ASSERT_TRUE(update.ok()) << update.status().message();
    ASSERT_TRUE(decoder.apply(update->header, update->payload).ok()) << "revision " << r;
    EXPECT_TRUE(update->header.complete());
    EXPECT_EQ(decoder.revision(), static_cast<std::uint64_t>(r));
    const double error = max_distance(decoder.positions(), target);
    EXPECT_LE(error, kTolerance) << "revision " << r;
    EXPECT_DOUBLE_EQ(update->header.max_error, error);
    // The encoder's model of the client is the client's state, bit for bit.
    EXPECT_TRUE(encoder->client_positions() == decoder.positions()) << "revision " << r;
  }
}

TEST(UpdateCodec, LosslessIsBitExactEvenForAwkwardDoubles) {
  Positions rest = grid_mesh(500, 2);
  rest(0, 0) = -0.0;
  rest(1, 1) = std::numeric_limits<double>::denorm_min();
  rest(2, 2) = 1e300;
  auto encoder = StreamEncoder::create(StreamSettings{DeltaMode::Lossless}, 500);
  ASSERT_TRUE(encoder.ok());
  StreamDecoder decoder;
  for (int r = 0; r < 6; ++r) {
    Positions target = bend(rest, 0.1 * r);
    target(3, 0) = std::nextafter(target(3, 0), 10.0);  // one ulp apart from the bend
    auto update = encoder->encode(target, static_cast<std::uint64_t>(r));
    ASSERT_TRUE(update.ok());
    ASSERT_TRUE(decoder.apply(update->header, update->payload).ok());
    ASSERT_EQ(decoder.positions().rows(), 500);
    EXPECT_EQ(std::memcmp(decoder.positions().data(), target.data(), sizeof(double) * 1500), 0)
        << "revision " << r;
    EXPECT_TRUE(update->header.complete());
  }
  // -0.0 stays -0.0 (its sign bit travelled).
  EXPECT_TRUE(std::signbit(decoder.positions()(0, 0)));
}

TEST(UpdateCodec, OnlyVerticesThatMovedMoreThanTheToleranceAreSent) {
  const Positions rest = grid_mesh(1000, 3);
  constexpr double kTolerance = 1e-3;
  auto encoder = StreamEncoder::create(quantized(kTolerance), 1000);
  ASSERT_TRUE(encoder.ok());
  StreamDecoder decoder;
  auto first = encoder->encode(rest, 0);
  ASSERT_TRUE(first.ok());
  EXPECT_EQ(first->header.vertices_sent, 1000u);
  ASSERT_TRUE(decoder.apply(first->header, first->payload).ok());
  Positions moved = rest;
  for (int i = 0; i < 10; ++i) moved(100 + i, 2) += 0.01;           // far beyond the tolerance
  for (int i = 0; i < 10; ++i) moved(500 + i, 2) += 0.2 * kTolerance;  // within it
  auto second = encoder->encode(moved, 1);
  ASSERT_TRUE(second.ok());
  EXPECT_LE(second->header.vertices_sent, 20u);
  EXPECT_GE(second->header.vertices_sent, 10u);
  ASSERT_TRUE(decoder.apply(second->header, second->payload).ok());
  EXPECT_LE(max_distance(decoder.positions(), moved), kTolerance);
  for (int i = 0; i < 10; ++i) {
    EXPECT_NEAR(decoder.positions()(100 + i, 2), moved(100 + i, 2), kTolerance);
  }
}

TEST(UpdateCodec, ABudgetIsMetAndTheRemainderConverges) {
  const int n = 40'000;
  const Positions rest = grid_mesh(n, 4);
  constexpr double kTolerance = 1e-5;
  constexpr std::size_t kBudget = 8'000;
  auto encoder = StreamEncoder::create(quantized(kTolerance, kBudget), n);
  ASSERT_TRUE(encoder.ok());
  StreamDecoder decoder;
  const Positions target = bend(rest, 0.3);
  auto apply = [&](const EncodedUpdate& u) {
    EXPECT_LE(u.payload.size(), kBudget);
    ASSERT_TRUE(decoder.apply(u.header, u.payload).ok());
    // What the update says is left is what the client really is from the revision.
    EXPECT_DOUBLE_EQ(u.header.max_error, max_distance(decoder.positions(), target));
  };
  auto update = encoder->encode(target, 7);
  ASSERT_TRUE(update.ok());
  apply(*update);
  EXPECT_FALSE(update->header.complete()) << "40k vertices cannot fit 8 kB at 1e-5";
  EXPECT_GT(update->header.shift + (update->header.vertices_sent < static_cast<std::uint32_t>(n)), 0u);
  double previous_error = update->header.max_error;
  int steps = 0;
  while (encoder->pending() && steps < 200) {
    auto more = encoder->encode_pending();
    ASSERT_TRUE(more.ok());
    EXPECT_EQ(more->header.revision, 7u);
    apply(*more);
    EXPECT_LE(more->header.max_error, previous_error * (1 + 1e-12) + kTolerance);
    previous_error = more->header.max_error;
    ++steps;
  }
  EXPECT_FALSE(encoder->pending()) << "still pending after " << steps << " updates";
  EXPECT_TRUE(decoder.complete());
  EXPECT_LE(max_distance(decoder.positions(), target), kTolerance);
}

TEST(UpdateCodec, ASkippedRevisionIsStillADeltaAgainstWhatTheStreamSent) {
  const Positions rest = grid_mesh(2000, 5);
  auto encoder = StreamEncoder::create(quantized(1e-4), 2000);
  ASSERT_TRUE(encoder.ok());
  StreamDecoder decoder;
  auto first = encoder->encode(rest, 0);
  ASSERT_TRUE(decoder.apply(first->header, first->payload).ok());
  // Revisions 1-4 were never encoded for this stream (a slow watcher skipped them).
  const Positions fifth = bend(rest, 0.05);
  auto next = encoder->encode(fifth, 5);
  ASSERT_TRUE(next.ok());
  EXPECT_LT(next->payload.size(), first->payload.size());
  ASSERT_TRUE(decoder.apply(next->header, next->payload).ok());
  EXPECT_EQ(decoder.revision(), 5u);
  EXPECT_LE(max_distance(decoder.positions(), fifth), 1e-4);
}

TEST(UpdateCodec, TheDecoderRefusesWhatDoesNotDecodeAndKeepsItsState) {
  const Positions rest = grid_mesh(800, 6);
  auto encoder = StreamEncoder::create(quantized(1e-4), 800);
  ASSERT_TRUE(encoder.ok());
  StreamDecoder decoder;
  auto first = encoder->encode(rest, 0);
  ASSERT_TRUE(decoder.apply(first->header, first->payload).ok());
  const Positions before = decoder.positions();
  auto second = encoder->encode(bend(rest, 0.1), 1);
  ASSERT_TRUE(second.ok());

  UpdateHeader replay = first->header;  // out of sequence
  EXPECT_EQ(decoder.apply(replay, first->payload).code(), ErrorCode::FailedPrecondition);
  std::string truncated = second->payload.substr(0, second->payload.size() / 2);
  EXPECT_FALSE(decoder.apply(second->header, truncated).ok());
  UpdateHeader wrong_count = second->header;
  wrong_count.vertices_sent += 1;
  EXPECT_FALSE(decoder.apply(wrong_count, second->payload).ok());
  UpdateHeader other_grid = second->header;
  other_grid.step *= 2;
  EXPECT_EQ(decoder.apply(other_grid, second->payload).code(), ErrorCode::FailedPrecondition);
  EXPECT_FALSE(decoder.apply(second->header, "not zstd at all").ok());
  // Every single flipped byte is refused or decodes to something; it never crashes.
  for (std::size_t i = 0; i < second->payload.size(); i += 7) {
    std::string flipped = second->payload;
    flipped[i] = static_cast<char>(flipped[i] ^ 0x5a);
    StreamDecoder copy = decoder;
    (void)copy.apply(second->header, flipped);
  }
  EXPECT_TRUE(decoder.positions() == before);
  EXPECT_EQ(decoder.sequence(), 1u);
  ASSERT_TRUE(decoder.apply(second->header, second->payload).ok());
  EXPECT_EQ(decoder.sequence(), 2u);
}

// UpdateOptions.lossless_settled: a quantized stream sends a settled revision lossless (exact),
// then goes on quantized; every update keeps the encoder's model of the client exact.
TEST(UpdateCodec, AQuantizedStreamCarriesExactSettledRevisionsAndGoesOn) {
  const Positions rest = grid_mesh(3000, 7);
  constexpr double kTolerance = 1e-4;
  for (const std::size_t budget : {std::size_t{0}, std::size_t{4000}}) {
    SCOPED_TRACE(budget == 0 ? "no budget" : "a byte budget");
    auto encoder = StreamEncoder::create(quantized(kTolerance, budget), 3000);
    ASSERT_TRUE(encoder.ok()) << encoder.status().message();
    StreamDecoder decoder;
    const auto deliver = [&](const Positions& target, std::uint64_t revision, bool lossless) {
      auto update = encoder->encode(target, revision, lossless);
      ASSERT_TRUE(update.ok()) << update.status().message();
      EXPECT_EQ(update->header.mode, lossless ? DeltaMode::Lossless : DeltaMode::Quantized);
      EXPECT_EQ(update->header.step, kTolerance) << "the stream's grid, in every update";
      ASSERT_TRUE(decoder.apply(update->header, update->payload).ok()) << "revision " << revision;
      while (encoder->pending()) {  // a budget's continuations
        auto more = encoder->encode_pending();
        ASSERT_TRUE(more.ok());
        ASSERT_TRUE(decoder.apply(more->header, more->payload).ok());
      }
      EXPECT_TRUE(encoder->client_positions() == decoder.positions()) << "revision " << revision;
    };
    // A drag, quantized; the settled revision exact; the next drag quantized again.
    for (int r = 0; r < 5; ++r) {
      deliver(bend(rest, 0.02 * r), static_cast<std::uint64_t>(r), false);
      EXPECT_LE(max_distance(decoder.positions(), bend(rest, 0.02 * r)), kTolerance);
    }
    Positions settled = bend(rest, 0.08);
    settled(7, 1) = std::nextafter(settled(7, 1), 10.0);  // off any grid
    deliver(settled, 5, true);
    EXPECT_EQ(std::memcmp(decoder.positions().data(), settled.data(), sizeof(double) * 9000), 0)
        << "the settled revision, bit for bit";
    // A vertex whose grid coordinate the next revision leaves where it was is still sent back
    // onto the grid when it is farther than the tolerance.
    for (int r = 6; r < 10; ++r) {
      const Positions target = bend(rest, 0.08 - 0.01 * (r - 5));
      deliver(target, static_cast<std::uint64_t>(r), false);
      EXPECT_LE(max_distance(decoder.positions(), target), kTolerance) << "revision " << r;
    }
    // A settled revision again, equal to the last quantized target: exact again.
    const Positions again = bend(rest, 0.04);
    deliver(again, 10, true);
    EXPECT_TRUE(decoder.positions() == again);
    // And back to a revision it had shown: only what is off by more than the tolerance travels.
    deliver(again, 11, false);
    EXPECT_TRUE(decoder.positions() == again) << "nothing farther than the tolerance: nothing sent";
  }

  // A settled revision as the stream's first update (a watcher joining a settled session).
  auto encoder = StreamEncoder::create(quantized(kTolerance), 3000);
  ASSERT_TRUE(encoder.ok());
  StreamDecoder decoder;
  const Positions target = bend(rest, 0.05);
  auto first = encoder->encode(target, 3, true);
  ASSERT_TRUE(first.ok());
  ASSERT_TRUE(decoder.apply(first->header, first->payload).ok());
  EXPECT_TRUE(decoder.positions() == target);
  auto next = encoder->encode(bend(rest, 0.06), 4);
  ASSERT_TRUE(next.ok());
  ASSERT_TRUE(decoder.apply(next->header, next->payload).ok());
  EXPECT_LE(max_distance(decoder.positions(), bend(rest, 0.06)), kTolerance);

  // A lossless stream stays one: a quantized header there is another stream's.
  auto lossless = StreamEncoder::create(StreamSettings{DeltaMode::Lossless}, 3000);
  ASSERT_TRUE(lossless.ok());
  StreamDecoder exact;
  auto l1 = lossless->encode(rest, 0);
  ASSERT_TRUE(l1.ok() && exact.apply(l1->header, l1->payload).ok());
  UpdateHeader quantized_header = next->header;
  quantized_header.sequence = 2;
  EXPECT_EQ(exact.apply(quantized_header, next->payload).code(), ErrorCode::FailedPrecondition);
}

TEST(UpdateCodec, SettingsAreChecked) {
  EXPECT_FALSE(StreamEncoder::create(quantized(0), 10).ok());
  EXPECT_FALSE(StreamEncoder::create(quantized(std::nan("")), 10).ok());
  EXPECT_FALSE(StreamEncoder::create(quantized(1e-3, 100), 10).ok());
  EXPECT_TRUE(StreamEncoder::create(quantized(1e-3, kMinUpdateBytes), 10).ok());
  auto encoder = StreamEncoder::create(quantized(1e-3), 10);
  ASSERT_TRUE(encoder.ok());
  EXPECT_FALSE(encoder->encode(Positions::Zero(11, 3), 1).ok());
  Positions far = Positions::Zero(10, 3);
  far(3, 1) = 1e20;
  EXPECT_FALSE(encoder->encode(far, 1).ok());
}

}  // namespace
}  // namespace meshdeform::codec
