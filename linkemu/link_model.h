#pragma once
/// @file link_model.h
/// The timing model of one direction of an emulated network link, free of sockets and clocks so
/// that its arithmetic can be tested exactly (link_emulator.h drives it with steady_clock).
///
/// A direction is a bottleneck of `rate_bits_per_second` behind a queue of `queue_bytes`,
/// followed by a one-way propagation `delay` plus up to `jitter` more:
///  - bytes enter when the queue has room (the emulator stops reading its source otherwise, so
///    TCP's own flow control pushes back on the sender, as a full router queue would);
///  - the link serialises them in order: a chunk of n bytes that arrives at t leaves the
///    bottleneck at max(t, when the link is free) + 8 n / rate;
///  - it is delivered `delay` (+ a uniform draw in [0, jitter]) after that, never before the
///    chunk ahead of it (TCP delivers in order: jitter delays, it never reorders);
///  - loss is modelled as TCP sees it on a stream, as a stall: each full packet of
///    kPacketBytes a chunk spans is lost with probability `loss`, and a loss holds the link for
///    `stall` (a retransmission timeout) before the chunk goes on (head-of-line blocking).
/// Queue occupancy counts bytes from entry until delivery, so the queue also bounds the bytes
/// in flight on the emulated wire (rate x delay).

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <random>

namespace meshdeform::linkemu {

using Duration = std::chrono::nanoseconds;
using TimePoint = std::chrono::steady_clock::time_point;

/// The packet size losses are drawn per (an Ethernet MTU's TCP payload).
inline constexpr std::size_t kPacketBytes = 1448;

/// One direction's settings.
struct DirectionSettings {
  double rate_bits_per_second = 0;  ///< bottleneck rate; 0 = unlimited
  Duration delay{0};                ///< one-way propagation delay
  Duration jitter{0};               ///< extra delay drawn uniformly from [0, jitter] per chunk
  double loss = 0;                  ///< probability a packet is lost, in [0, 1)
  Duration stall{std::chrono::milliseconds(200)};  ///< how long a loss holds the link
  /// Bytes the direction holds at most (queued, on the wire, waiting for the receiver). 0: the
  /// default, the bandwidth-delay product plus 64 KiB (at least 256 KiB).
  std::size_t queue_bytes = 0;

  /// queue_bytes, or its default when 0.
  std::size_t effective_queue_bytes() const;
};

/// Counters of one direction; every field only grows.
struct DirectionCounters {
  std::uint64_t bytes_in = 0;         ///< taken from the source
  std::uint64_t bytes_delivered = 0;  ///< written to the destination
  std::uint64_t chunks = 0;           ///< chunks taken (one per read)
  std::uint64_t losses = 0;           ///< packets lost (stalls)
  std::uint64_t full_queue_waits = 0; ///< times the source was not read because the queue was full
  /// Sum over delivered chunks of (delivery time - arrival time), in nanoseconds, and its max.
  std::uint64_t queue_delay_ns_sum = 0;
  std::uint64_t queue_delay_ns_max = 0;
};

/// The schedule of one direction. Not thread-safe.
class DirectionModel {
 public:
  explicit DirectionModel(DirectionSettings settings, std::uint64_t seed = 1);

  /// Bytes that may enter now (the queue's free room).
  std::size_t room() const;
  /// Accepts `bytes` (<= room()) arriving at `now`. @return when they become deliverable.
  TimePoint push(std::size_t bytes, TimePoint now);
  /// Bytes deliverable at `now` (the chunks whose time has come, front first, partly delivered
  /// ones included), without taking them.
  std::size_t deliverable(TimePoint now) const;
  /// Marks `bytes` (<= deliverable(now)) as written to the destination.
  void delivered(std::size_t bytes, TimePoint now);
  /// When the next undelivered byte becomes deliverable; nullopt-like max() when none waits.
  TimePoint next_due() const;
  /// Bytes accepted and not yet delivered.
  std::size_t queued() const { return queued_; }

  const DirectionSettings& settings() const { return settings_; }
  const DirectionCounters& counters() const { return counters_; }
  /// The source was not read for lack of room (counted by the driver).
  void note_full_queue() { ++counters_.full_queue_waits; }

 private:
  struct Chunk {
    std::size_t bytes = 0;      ///< left to deliver
    TimePoint arrived;
    TimePoint due;
  };
  DirectionSettings settings_;
  std::size_t capacity_;
  std::deque<Chunk> chunks_;
  std::size_t queued_ = 0;
  TimePoint link_free_{};     ///< when the bottleneck finishes what it has
  TimePoint last_due_{};      ///< delivery time of the newest chunk (in-order delivery)
  std::mt19937_64 random_;
  DirectionCounters counters_;
};

}  // namespace meshdeform::linkemu
