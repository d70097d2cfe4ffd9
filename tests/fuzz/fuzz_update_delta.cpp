// libFuzzer target: link-sized updates (codec/update_codec.h), which a client decodes from the
// server's Watch stream. The input's first four bytes choose the header (mode, shift, vertex
// count), the rest is the payload before compression: the target compresses it (so the fuzzer
// explores the payload's fields, not zstd's) and sets vertices_sent from the payload's own count
// (else every input would stop at that check). Every input must be refused with
// InvalidArgument / FailedPrecondition or decode to finite positions of the header's count; a
// refused update leaves the decoder's state as it was.
#include <zstd.h>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "codec/update_codec.h"

using namespace meshdeform;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 4) return 0;
  codec::UpdateHeader h;
  h.mode = (data[0] & 1) != 0 ? codec::DeltaMode::Lossless : codec::DeltaMode::Quantized;
  h.shift = data[1] % (codec::kMaxShift + 2);  // one past the largest: refused
  h.vertex_count = 1u + ((static_cast<unsigned>(data[2]) | (static_cast<unsigned>(data[3]) << 8)) % 2048u);
  h.step = 1e-3;
  h.sequence = 1;
  const std::string raw(reinterpret_cast<const char*>(data + 4), size - 4);
  // The payload's count: byte 0 version, byte 1 flags, then a varint.
  std::uint64_t count = 0;
  for (std::size_t i = 2, shift = 0; i < raw.size() && shift < 64; ++i, shift += 7) {
    count |= static_cast<std::uint64_t>(static_cast<unsigned char>(raw[i]) & 0x7f) << shift;
    if ((static_cast<unsigned char>(raw[i]) & 0x80) == 0) break;
  }
  h.vertices_sent = static_cast<std::uint32_t>(count);
  std::string payload(ZSTD_compressBound(raw.size()), '\0');
  const std::size_t n = ZSTD_compress(payload.data(), payload.size(), raw.data(), raw.size(), 1);
  if (ZSTD_isError(n)) std::abort();
  payload.resize(n);

  codec::StreamDecoder decoder;
  for (int round = 0; round < 2; ++round) {
    const Positions before = decoder.positions();
    const std::uint64_t sequence = decoder.sequence();
    const Status status = decoder.apply(h, payload);
    if (!status.ok()) {
      if (status.code() != ErrorCode::InvalidArgument &&
          status.code() != ErrorCode::FailedPrecondition) {
        std::abort();
      }
      if (decoder.sequence() != sequence || !(decoder.positions() == before)) std::abort();
      return 0;
    }
    if (decoder.positions().rows() != static_cast<Eigen::Index>(h.vertex_count)) std::abort();
    if (h.mode == codec::DeltaMode::Quantized && !decoder.positions().allFinite()) std::abort();
    h.sequence += 1;  // the same delta again, on top of the first
  }
  return 0;
}
