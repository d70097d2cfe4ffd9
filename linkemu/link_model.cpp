#include "linkemu/link_model.h"

#include <algorithm>
#include <cmath>

namespace meshdeform::linkemu {

std::size_t DirectionSettings::effective_queue_bytes() const {
  if (queue_bytes > 0) return queue_bytes;
  constexpr std::size_t kExtra = 64 * 1024;
  constexpr std::size_t kMinimum = 256 * 1024;
  if (rate_bits_per_second <= 0) return std::max<std::size_t>(kMinimum, 4 * 1024 * 1024);
  const double seconds = std::chrono::duration<double>(delay + jitter).count();
  const auto bdp = static_cast<std::size_t>(rate_bits_per_second / 8.0 * seconds);
  return std::max(kMinimum, bdp + kExtra);
}

DirectionModel::DirectionModel(DirectionSettings settings, std::uint64_t seed)
    : settings_(settings), capacity_(settings.effective_queue_bytes()), random_(seed) {}

std::size_t DirectionModel::room() const {
  return queued_ >= capacity_ ? 0 : capacity_ - queued_;
}

TimePoint DirectionModel::push(std::size_t bytes, TimePoint now) {
  // Serialisation at the bottleneck, in order behind whatever it still transmits.
  TimePoint start = std::max(now, link_free_);
  if (settings_.loss > 0) {
    // Each packet the chunk spans may be lost; a loss stalls the link for a retransmission
    // timeout before the data goes on (a byte stream sees loss as head-of-line blocking).
    const std::size_t packets = (bytes + kPacketBytes - 1) / kPacketBytes;
    std::bernoulli_distribution lost(settings_.loss);
    for (std::size_t p = 0; p < packets; ++p) {
      if (lost(random_)) {
        start += settings_.stall;
        ++counters_.losses;
      }
    }
  }
  Duration transmit{0};
  if (settings_.rate_bits_per_second > 0) {
    transmit = std::chrono::duration_cast<Duration>(std::chrono::duration<double>(
        8.0 * static_cast<double>(bytes) / settings_.rate_bits_per_second));
  }
  link_free_ = start + transmit;
  Duration extra{0};
  if (settings_.jitter.count() > 0) {
    std::uniform_int_distribution<std::int64_t> draw(0, settings_.jitter.count());
    extra = Duration(draw(random_));
  }
  TimePoint due = link_free_ + settings_.delay + extra;
  due = std::max(due, last_due_);  // in order: never before the chunk ahead
  last_due_ = due;
  chunks_.push_back(Chunk{bytes, now, due});
  queued_ += bytes;
  counters_.bytes_in += bytes;
  ++counters_.chunks;
  return due;
}

std::size_t DirectionModel::deliverable(TimePoint now) const {
  std::size_t out = 0;
  for (const Chunk& chunk : chunks_) {
    if (chunk.due > now) break;
    out += chunk.bytes;
  }
  return out;
}

void DirectionModel::delivered(std::size_t bytes, TimePoint now) {
  bytes = std::min(bytes, queued_);
  queued_ -= bytes;
  counters_.bytes_delivered += bytes;
  while (bytes > 0 && !chunks_.empty()) {
    Chunk& front = chunks_.front();
    const std::size_t take = std::min(bytes, front.bytes);
    front.bytes -= take;
    bytes -= take;
    if (front.bytes == 0) {
      const auto waited = static_cast<std::uint64_t>(
          std::max<std::int64_t>(0, std::chrono::duration_cast<Duration>(now - front.arrived).count()));
      counters_.queue_delay_ns_sum += waited;
      counters_.queue_delay_ns_max = std::max(counters_.queue_delay_ns_max, waited);
      chunks_.pop_front();
    }
  }
}

TimePoint DirectionModel::next_due() const {
  return chunks_.empty() ? TimePoint::max() : chunks_.front().due;
}

}  // namespace meshdeform::linkemu
