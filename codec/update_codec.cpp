#include "codec/update_codec.h"

#include <zstd.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>
#include <numeric>

namespace meshdeform::codec {
namespace {

Status invalid(std::string message) { return Error(ErrorCode::InvalidArgument, std::move(message)); }

void put_varint(std::string& out, std::uint64_t v) {
  while (v >= 0x80) {
    out.push_back(static_cast<char>((v & 0x7f) | 0x80));
    v >>= 7;
  }
  out.push_back(static_cast<char>(v));
}

std::uint64_t zigzag(std::int64_t v) {
  return (static_cast<std::uint64_t>(v) << 1) ^ static_cast<std::uint64_t>(v >> 63);
}
std::int64_t unzigzag(std::uint64_t v) {
  return static_cast<std::int64_t>(v >> 1) ^ -static_cast<std::int64_t>(v & 1);
}

/// Reads a payload; every read is bounded by the bytes left.
class Reader {
 public:
  explicit Reader(std::string_view bytes) : bytes_(bytes) {}
  bool byte(std::uint8_t& out) {
    if (at_ >= bytes_.size()) return false;
    out = static_cast<std::uint8_t>(bytes_[at_++]);
    return true;
  }
  bool varint(std::uint64_t& out) {
    out = 0;
    for (int shift = 0; shift < 64; shift += 7) {
      std::uint8_t b = 0;
      if (!byte(b)) return false;
      out |= static_cast<std::uint64_t>(b & 0x7f) << shift;
      if ((b & 0x80) == 0) return true;
    }
    return false;
  }
  std::size_t left() const { return bytes_.size() - at_; }
  const char* here() const { return bytes_.data() + at_; }
  void skip(std::size_t n) { at_ += n; }

 private:
  std::string_view bytes_;
  std::size_t at_ = 0;
};

std::uint64_t bits_of(double v) { return std::bit_cast<std::uint64_t>(v); }
double double_of(std::uint64_t v) { return std::bit_cast<double>(v); }

/// Grid coordinates farther than this from the origin are refused (doubles stay exact integers
/// well below 2^53, and zigzag differences cannot overflow).
constexpr double kMaxGrid = 4.0e15;

std::string compress(const std::string& raw, int level) {
  std::string out(ZSTD_compressBound(raw.size()), '\0');
  const std::size_t n = ZSTD_compress(out.data(), out.size(), raw.data(), raw.size(), level);
  out.resize(ZSTD_isError(n) ? 0 : n);
  return out;
}

/// One encoded candidate: a vertex and its per-axis values.
struct Sent {
  int vertex;
  std::int64_t d[3];
};

std::string serialize_quantized(const std::vector<Sent>& sent, int vertex_count) {
  std::string raw;
  raw.reserve(8 + sent.size() * 8);
  raw.push_back(static_cast<char>(kPayloadVersion));
  const bool all = static_cast<int>(sent.size()) == vertex_count;
  raw.push_back(static_cast<char>(all ? 1 : 0));
  put_varint(raw, sent.size());
  if (!all) {
    int previous = -1;
    for (const Sent& s : sent) {
      put_varint(raw, static_cast<std::uint64_t>(s.vertex - previous - 1));
      previous = s.vertex;
    }
  }
  for (int c = 0; c < 3; ++c) {
    std::int64_t previous = 0;
    for (const Sent& s : sent) {
      put_varint(raw, zigzag(s.d[c] - previous));
      previous = s.d[c];
    }
  }
  return raw;
}

/// A lossless payload: the vertices in `changed` (ascending), each coordinate's old ^ new bits.
std::string serialize_lossless(const std::vector<int>& changed, std::size_t vertex_count,
                               const std::vector<double>& old, const std::vector<double>& target) {
  std::string raw;
  raw.reserve(12 + changed.size() * 29);
  raw.push_back(static_cast<char>(kPayloadVersion));
  const bool all = changed.size() == vertex_count;
  raw.push_back(static_cast<char>(all ? 1 : 0));
  put_varint(raw, changed.size());
  if (!all) {
    int previous = -1;
    for (int v : changed) {
      put_varint(raw, static_cast<std::uint64_t>(v - previous - 1));
      previous = v;
    }
  }
  for (int c = 0; c < 3; ++c) {
    for (int b = 7; b >= 0; --b) {
      for (int v : changed) {
        const std::size_t i = 3 * static_cast<std::size_t>(v) + c;
        const std::uint64_t x = bits_of(old[i]) ^ bits_of(target[i]);
        raw.push_back(static_cast<char>((x >> (8 * b)) & 0xff));
      }
    }
  }
  return raw;
}

}  // namespace

std::size_t max_raw_payload_bytes(DeltaMode mode, std::uint32_t vertex_count) {
  const std::size_t n = vertex_count;
  // header + count + gaps (5 bytes each at most for 32-bit gaps) + values.
  return 2 + 10 + n * 5 + (mode == DeltaMode::Quantized ? n * 3 * 10 : n * 3 * 8);
}

Result<StreamEncoder> StreamEncoder::create(const StreamSettings& settings, int vertex_count) {
  if (vertex_count < 0) return invalid("vertex count must be >= 0");
  if (settings.mode == DeltaMode::Quantized) {
    if (!(settings.tolerance > 0) || !std::isfinite(settings.tolerance)) {
      return invalid("tolerance must be positive and finite");
    }
    if (!settings.origin.allFinite()) return invalid("grid origin must be finite");
    if (settings.max_update_bytes != 0 && settings.max_update_bytes < kMinUpdateBytes) {
      return invalid("max update bytes must be 0 (no limit) or at least " +
                     std::to_string(kMinUpdateBytes));
    }
  }
  StreamEncoder out;
  out.settings_ = settings;
  out.vertex_count_ = vertex_count;
  const auto n = static_cast<std::size_t>(vertex_count) * 3;
  // A quantized client starts with every vertex at grid point 0 (the origin), a lossless one
  // at the doubles of bit pattern 0.
  out.client_shown_.assign(n, 0.0);
  if (settings.mode == DeltaMode::Quantized) {
    out.client_q_.assign(n, 0);
    for (std::size_t i = 0; i < n; ++i) out.client_shown_[i] = settings.origin[static_cast<int>(i % 3)];
  }
  out.target_.assign(n, 0.0);
  return out;
}

Positions StreamEncoder::client_positions() const {
  Positions out(vertex_count_, 3);
  for (int v = 0; v < vertex_count_; ++v) {
    for (int c = 0; c < 3; ++c) {
      const auto i = static_cast<std::size_t>(3 * v + c);
      out(v, c) = client_shown_[i];
    }
  }
  return out;
}

std::size_t StreamEncoder::memory_bytes() const {
  return client_q_.capacity() * sizeof(std::int64_t) +
         (client_shown_.capacity() + target_.capacity()) * sizeof(double);
}

Result<EncodedUpdate> StreamEncoder::encode(const Positions& target, std::uint64_t revision,
                                            bool lossless) {
  if (target.rows() != vertex_count_) {
    return invalid("update of " + std::to_string(target.rows()) + " vertices on a stream of " +
                   std::to_string(vertex_count_));
  }
  if (!target.allFinite()) return invalid("non-finite position");
  if (settings_.mode == DeltaMode::Quantized) {
    const double limit = kMaxGrid * settings_.tolerance;
    for (int v = 0; v < vertex_count_; ++v) {
      for (int c = 0; c < 3; ++c) {
        if (!(std::abs(target(v, c) - settings_.origin[c]) < limit)) {
          return invalid("vertex " + std::to_string(v) +
                         " is too far from the grid origin for the stream's tolerance");
        }
      }
    }
  }
  for (int v = 0; v < vertex_count_; ++v) {
    for (int c = 0; c < 3; ++c) target_[static_cast<std::size_t>(3 * v + c)] = target(v, c);
  }
  revision_ = revision;
  return encode_current(lossless);
}

Result<EncodedUpdate> StreamEncoder::encode_pending() { return encode_current(false); }

Result<EncodedUpdate> StreamEncoder::encode_current(bool lossless) {
  EncodedUpdate out;
  UpdateHeader& h = out.header;
  h.mode = settings_.mode;
  h.sequence = ++sequence_;
  h.revision = revision_;
  h.vertex_count = static_cast<std::uint32_t>(vertex_count_);
  const auto n = static_cast<std::size_t>(vertex_count_);

  if (settings_.mode == DeltaMode::Lossless || lossless) {
    // A lossless update, against the positions the client shows, which it then shows exactly.
    // In a quantized stream (its settled revisions) the grid stays the stream's: the header
    // carries it, and the grid coordinates do not change (a later quantized update of a vertex
    // sends it back onto the grid).
    std::vector<int> changed;
    for (std::size_t v = 0; v < n; ++v) {
      for (int c = 0; c < 3; ++c) {
        if (bits_of(client_shown_[3 * v + c]) != bits_of(target_[3 * v + c])) {
          changed.push_back(static_cast<int>(v));
          break;
        }
      }
    }
    const std::string raw = serialize_lossless(changed, n, client_shown_, target_);
    for (int v : changed) {
      for (int c = 0; c < 3; ++c) {
        const std::size_t i = 3 * static_cast<std::size_t>(v) + c;
        client_shown_[i] = target_[i];
      }
    }
    h.mode = DeltaMode::Lossless;
    if (settings_.mode == DeltaMode::Quantized) {
      h.step = settings_.tolerance;
      h.origin = settings_.origin;
    }
    h.vertices_sent = static_cast<std::uint32_t>(changed.size());
    h.raw_bytes = raw.size();
    out.payload = compress(raw, settings_.zstd_level);
    pending_ = 0;
    return out;
  }

  // Quantized: the candidates are the vertices farther than the tolerance.
  const double step = settings_.tolerance;
  const Eigen::Vector3d& origin = settings_.origin;
  std::vector<int> candidates;
  std::vector<double> error(n, 0.0);
  for (std::size_t v = 0; v < n; ++v) {
    double e2 = 0;
    for (int c = 0; c < 3; ++c) {
      const double d = client_shown_[3 * v + c] - target_[3 * v + c];
      e2 += d * d;
    }
    error[v] = std::sqrt(e2);
    if (error[v] > settings_.tolerance) candidates.push_back(static_cast<int>(v));
  }
  // Whether a vertex shows a lossless update's position rather than its grid point: sent
  // again, it goes back onto the grid even when its grid coordinate does not change.
  auto off_grid = [&](std::size_t v) {
    for (int c = 0; c < 3; ++c) {
      if (client_shown_[3 * v + c] != origin[c] + static_cast<double>(client_q_[3 * v + c]) * step) {
        return true;
      }
    }
    return false;
  };
  auto values_at = [&](int shift, const std::vector<int>& vertices) {
    std::vector<Sent> sent;
    sent.reserve(vertices.size());
    const std::int64_t half = shift == 0 ? 0 : (std::int64_t{1} << (shift - 1));
    for (int v : vertices) {
      Sent s{v, {0, 0, 0}};
      bool any = false;
      for (int c = 0; c < 3; ++c) {
        const std::size_t i = 3 * static_cast<std::size_t>(v) + c;
        const auto q = static_cast<std::int64_t>(std::llround((target_[i] - origin[c]) / step));
        const std::int64_t delta = q - client_q_[i];
        s.d[c] = (delta + half) >> shift;  // round to the nearest multiple of 2^shift
        any = any || s.d[c] != 0;
      }
      if (any || off_grid(static_cast<std::size_t>(v))) sent.push_back(s);
    }
    return sent;
  };
  // The largest error the client would have after receiving `s` at `k`.
  auto error_after = [&](const std::vector<Sent>& s, int k) {
    std::vector<double> e = error;
    for (const Sent& x : s) {
      const auto v = static_cast<std::size_t>(x.vertex);
      double e2 = 0;
      for (int c = 0; c < 3; ++c) {
        const double shown =
            origin[c] + static_cast<double>(client_q_[3 * v + c] + x.d[c] * (std::int64_t{1} << k)) * step;
        const double d = shown - target_[3 * v + c];
        e2 += d * d;
      }
      e[v] = std::sqrt(e2);
    }
    return *std::max_element(e.begin(), e.end());
  };
  int shift = 0;
  std::vector<Sent> sent = values_at(0, candidates);
  std::string raw = serialize_quantized(sent, vertex_count_);
  std::string payload = compress(raw, settings_.zstd_level);
  const std::size_t budget = settings_.max_update_bytes;
  if (budget > 0 && payload.size() > budget) {
    const double error_before = n == 0 ? 0.0 : *std::max_element(error.begin(), error.end());
    // 1. Coarser values (every moved vertex moves, less exactly): the shift the size says.
    bool fits = false;
    while (shift < kMaxShift) {
      const double ratio = static_cast<double>(payload.size()) / static_cast<double>(budget);
      const int jump = std::max(1, static_cast<int>(std::ceil(std::log2(ratio))));
      const int next = std::min(kMaxShift, shift + jump);
      std::vector<Sent> s = values_at(next, candidates);
      std::string r = serialize_quantized(s, vertex_count_);
      std::string p = compress(r, settings_.zstd_level);
      shift = next;
      sent = std::move(s);
      raw = std::move(r);
      payload = std::move(p);
      if (payload.size() <= budget) {
        fits = true;
        if (jump > 1) {
          // The jump may have overshot: one step back is worth one more encode.
          std::vector<Sent> s2 = values_at(shift - 1, candidates);
          std::string r2 = serialize_quantized(s2, vertex_count_);
          std::string p2 = compress(r2, settings_.zstd_level);
          if (p2.size() <= budget) {
            shift -= 1;
            sent = std::move(s2);
            raw = std::move(r2);
            payload = std::move(p2);
          }
        }
        break;
      }
    }
    // 2. When coarse values do not fit, or would leave the largest error nearly where it was
    //    (the remainder after a drag is many small errors that round to nothing at that shift),
    //    the largest errors first, exactly, as many as fit: the stream always makes progress.
    if (!fits || error_after(sent, shift) > 0.75 * error_before) {
      std::vector<int> order = candidates;
      std::stable_sort(order.begin(), order.end(), [&](int a, int b) {
        return error[static_cast<std::size_t>(a)] > error[static_cast<std::size_t>(b)];
      });
      std::vector<Sent> all = values_at(0, candidates);
      const std::string all_payload = compress(serialize_quantized(all, vertex_count_),
                                               settings_.zstd_level);
      double fraction = 0.9 * static_cast<double>(budget) /
                        static_cast<double>(std::max<std::size_t>(all_payload.size(), 1));
      shift = 0;
      for (int attempt = 0; attempt < 16; ++attempt) {
        const auto take = std::min(order.size(),
                                   std::max<std::size_t>(1, static_cast<std::size_t>(
                                                                fraction * static_cast<double>(order.size()))));
        std::vector<int> subset(order.begin(), order.begin() + static_cast<std::ptrdiff_t>(take));
        std::sort(subset.begin(), subset.end());
        sent = values_at(0, subset);
        raw = serialize_quantized(sent, vertex_count_);
        payload = compress(raw, settings_.zstd_level);
        if (payload.size() <= budget || take == 1) break;
        fraction *= 0.7;
      }
    }
  }
  // Commit: the client will hold these values.
  for (const Sent& s : sent) {
    const auto v = static_cast<std::size_t>(s.vertex);
    double e2 = 0;
    for (int c = 0; c < 3; ++c) {
      client_q_[3 * v + c] += s.d[c] * (std::int64_t{1} << shift);
      const double shown = origin[c] + static_cast<double>(client_q_[3 * v + c]) * step;
      client_shown_[3 * v + c] = shown;
      const double d = shown - target_[3 * v + c];
      e2 += d * d;
    }
    error[v] = std::sqrt(e2);
  }
  std::size_t pending = 0;
  double max_error = 0;
  for (std::size_t v = 0; v < n; ++v) {
    max_error = std::max(max_error, error[v]);
    if (error[v] > settings_.tolerance) ++pending;
  }
  pending_ = pending;
  h.vertices_sent = static_cast<std::uint32_t>(sent.size());
  h.step = step;
  h.origin = origin;
  h.shift = static_cast<std::uint32_t>(shift);
  h.max_error = max_error;
  h.pending_vertices = static_cast<std::uint32_t>(pending);
  h.raw_bytes = raw.size();
  out.payload = std::move(payload);
  return out;
}

Status StreamDecoder::apply(const UpdateHeader& h, std::string_view payload) {
  if (h.sequence != sequence_ + 1) {
    return Error(ErrorCode::FailedPrecondition,
                 "update " + std::to_string(h.sequence) + " out of sequence (expected " +
                     std::to_string(sequence_ + 1) + ")");
  }
  // A stream is on a grid (quantized; its settled revisions may come lossless, on the same
  // grid) or lossless throughout (no grid: step 0), from its first update on.
  const bool grid = h.mode == DeltaMode::Quantized || h.step != 0;
  if (sequence_ > 0 && (grid != grid_ || h.vertex_count != vertex_count_ ||
                        (grid && (h.step != step_ || h.origin != origin_)))) {
    return Error(ErrorCode::FailedPrecondition, "update of another stream (count, mode or grid)");
  }
  if (grid && (!(h.step > 0) || !std::isfinite(h.step) || !h.origin.allFinite() ||
               h.shift > kMaxShift || (h.mode == DeltaMode::Lossless && h.shift != 0))) {
    return invalid("bad grid in update header");
  }
  const unsigned long long declared = ZSTD_getFrameContentSize(payload.data(), payload.size());
  if (declared == ZSTD_CONTENTSIZE_ERROR || declared == ZSTD_CONTENTSIZE_UNKNOWN) {
    return invalid("update payload is not a zstd frame with its size");
  }
  if (declared > max_raw_payload_bytes(h.mode, h.vertex_count)) {
    return invalid("update payload claims " + std::to_string(declared) +
                   " bytes, more than an update of " + std::to_string(h.vertex_count) +
                   " vertices can hold");
  }
  std::string raw(static_cast<std::size_t>(declared), '\0');
  const std::size_t got = ZSTD_decompress(raw.data(), raw.size(), payload.data(), payload.size());
  if (ZSTD_isError(got) || got != raw.size()) return invalid("update payload does not decompress");

  Reader in(raw);
  std::uint8_t version = 0, flags = 0;
  std::uint64_t count = 0;
  if (!in.byte(version) || version != kPayloadVersion) return invalid("unknown payload version");
  if (!in.byte(flags) || (flags & ~1u) != 0) return invalid("unknown payload flags");
  if (!in.varint(count) || count > h.vertex_count || count != h.vertices_sent) {
    return invalid("payload vertex count disagrees with its header");
  }
  const auto n = static_cast<std::size_t>(count);
  const bool all = (flags & 1u) != 0;
  if (all && n != h.vertex_count) return invalid("payload says every vertex but carries fewer");
  std::vector<std::uint32_t> index(n);
  if (all) {
    std::iota(index.begin(), index.end(), 0u);
  } else {
    std::int64_t previous = -1;
    for (std::size_t k = 0; k < n; ++k) {
      std::uint64_t gap = 0;
      if (!in.varint(gap)) return invalid("payload truncated in its index list");
      const std::int64_t v = previous + 1 + static_cast<std::int64_t>(std::min<std::uint64_t>(gap, 1ull << 40));
      if (v >= static_cast<std::int64_t>(h.vertex_count)) return invalid("vertex index out of range");
      index[k] = static_cast<std::uint32_t>(v);
      previous = v;
    }
  }
  const std::size_t total = static_cast<std::size_t>(h.vertex_count) * 3;
  // What the client shows: a grid stream starts with every vertex at grid point 0 (the origin),
  // a lossless one at the doubles of bit pattern 0.
  Positions shown = positions_;
  if (sequence_ == 0) {
    shown = grid ? Positions(h.origin.transpose().replicate(h.vertex_count, 1))
                 : Positions(Positions::Zero(h.vertex_count, 3));
  }
  if (h.mode == DeltaMode::Quantized) {
    std::vector<std::int64_t> q = sequence_ > 0 ? q_ : std::vector<std::int64_t>(total, 0);
    for (int c = 0; c < 3; ++c) {
      std::int64_t previous = 0;
      for (std::size_t k = 0; k < n; ++k) {
        std::uint64_t z = 0;
        if (!in.varint(z)) return invalid("payload truncated in its values");
        // Every intermediate stays far inside int64 (no overflow whatever the bytes say): a
        // difference, a value and its scaled form are each refused beyond the grid's range.
        const std::int64_t step_change = unzigzag(z);
        if (std::abs(static_cast<double>(step_change)) > 2 * kMaxGrid) {
          return invalid("grid value out of range");
        }
        const std::int64_t d = previous + step_change;
        const double scaled_value = static_cast<double>(d) * std::ldexp(1.0, static_cast<int>(h.shift));
        if (std::abs(static_cast<double>(d)) > kMaxGrid || std::abs(scaled_value) > kMaxGrid) {
          return invalid("grid value out of range");
        }
        previous = d;
        const std::int64_t scaled = d * (std::int64_t{1} << h.shift);
        const std::size_t i = 3 * static_cast<std::size_t>(index[k]) + static_cast<std::size_t>(c);
        q[i] += scaled;
        if (std::abs(static_cast<double>(q[i])) > kMaxGrid) return invalid("grid value out of range");
      }
    }
    if (in.left() != 0) return invalid("payload has trailing bytes");
    q_ = std::move(q);
    // The vertices sent show their grid points; the others keep what they showed (their grid
    // points, or a lossless update's positions).
    for (std::size_t k = 0; k < n; ++k) {
      const std::uint32_t v = index[k];
      for (int c = 0; c < 3; ++c) {
        shown(v, c) = h.origin[c] + static_cast<double>(q_[3 * static_cast<std::size_t>(v) + c]) * h.step;
      }
    }
    positions_ = std::move(shown);
  } else {
    // Lossless: against the positions shown; a grid stream's grid coordinates stay.
    if (in.left() != n * 24) return invalid("payload size disagrees with its vertex count");
    if (sequence_ == 0 && grid) q_.assign(total, 0);
    const char* base = in.here();
    for (int c = 0; c < 3; ++c) {
      for (int b = 7; b >= 0; --b) {
        const char* plane = base + (static_cast<std::size_t>(c) * 8 + static_cast<std::size_t>(7 - b)) * n;
        for (std::size_t k = 0; k < n; ++k) {
          double& value = shown(index[k], c);
          value = double_of(bits_of(value) ^
                            (static_cast<std::uint64_t>(static_cast<std::uint8_t>(plane[k])) << (8 * b)));
        }
      }
    }
    positions_ = std::move(shown);
  }
  sequence_ = h.sequence;
  revision_ = h.revision;
  complete_ = h.complete();
  grid_ = grid;
  vertex_count_ = h.vertex_count;
  step_ = h.step;
  origin_ = h.origin;
  return Status::success();
}

}  // namespace meshdeform::codec
