#include "proto/wire/delta_mapping.h"

#include <cmath>

#include "proto/wire/wire_mapping.h"

namespace meshdeform::wire {

Result<std::optional<codec::StreamSettings>> stream_settings_from_proto(
    const v1::UpdateOptions& options, const Eigen::Vector3d& bbox_min,
    const Eigen::Vector3d& bbox_max) {
  auto invalid = [](const std::string& message) {
    return Error(ErrorCode::InvalidArgument, "updates." + message);
  };
  codec::StreamSettings out;
  switch (options.mode()) {
    case v1::DELTA_MODE_UNSPECIFIED:
      return std::optional<codec::StreamSettings>();
    case v1::DELTA_MODE_QUANTIZED:
      out.mode = codec::DeltaMode::Quantized;
      break;
    case v1::DELTA_MODE_LOSSLESS:
      out.mode = codec::DeltaMode::Lossless;
      return std::optional<codec::StreamSettings>(out);
    default:
      return invalid("mode: unknown delta mode " + std::to_string(static_cast<int>(options.mode())));
  }
  if (!std::isfinite(options.tolerance()) || options.tolerance() < 0) {
    return invalid("tolerance must be >= 0 and finite, got " + std::to_string(options.tolerance()));
  }
  const double relative = options.relative_tolerance();
  if (!std::isfinite(relative) || relative < 0 || relative > kMaxRelativeTolerance) {
    return invalid("relative_tolerance must be in [0, " + std::to_string(kMaxRelativeTolerance) +
                   "], got " + std::to_string(relative));
  }
  if (options.max_update_bytes() != 0 && options.max_update_bytes() < codec::kMinUpdateBytes) {
    return invalid("max_update_bytes must be 0 (no limit) or at least " +
                   std::to_string(codec::kMinUpdateBytes) + ", got " +
                   std::to_string(options.max_update_bytes()));
  }
  double diagonal = (bbox_max - bbox_min).norm();
  if (!(diagonal > 0) || !std::isfinite(diagonal)) diagonal = 1.0;  // a degenerate box
  out.tolerance = options.tolerance() > 0
                      ? options.tolerance()
                      : (relative > 0 ? relative : kDefaultRelativeTolerance) * diagonal;
  out.origin = bbox_min.allFinite() ? bbox_min : Eigen::Vector3d::Zero();
  out.max_update_bytes = options.max_update_bytes();
  out.lossless_settled = options.lossless_settled();
  return std::optional<codec::StreamSettings>(out);
}

void delta_to_proto(const codec::EncodedUpdate& update, v1::VertexDelta* out) {
  const codec::UpdateHeader& h = update.header;
  out->set_mode(h.mode == codec::DeltaMode::Quantized ? v1::DELTA_MODE_QUANTIZED
                                                      : v1::DELTA_MODE_LOSSLESS);
  out->set_sequence(h.sequence);
  out->set_vertex_count(h.vertex_count);
  out->set_vertices_sent(h.vertices_sent);
  // A quantized stream's lossless updates (its settled revisions) carry its grid too.
  if (h.mode == codec::DeltaMode::Quantized || h.step != 0) {
    out->set_step(h.step);
    vec_to_proto(h.origin, out->mutable_origin());
    out->set_shift(h.shift);
    out->set_max_error(h.max_error);
  }
  out->set_pending_vertices(h.pending_vertices);
  out->set_payload(update.payload);
  out->set_raw_bytes(h.raw_bytes);
}

Result<codec::UpdateHeader> delta_header_from_proto(const v1::VertexDelta& delta,
                                                    std::uint64_t revision) {
  codec::UpdateHeader h;
  switch (delta.mode()) {
    case v1::DELTA_MODE_QUANTIZED:
      h.mode = codec::DeltaMode::Quantized;
      break;
    case v1::DELTA_MODE_LOSSLESS:
      h.mode = codec::DeltaMode::Lossless;
      break;
    default:
      return Error(ErrorCode::InvalidArgument,
                   "unknown delta mode " + std::to_string(static_cast<int>(delta.mode())));
  }
  h.sequence = delta.sequence();
  h.revision = revision;
  h.vertex_count = delta.vertex_count();
  h.vertices_sent = delta.vertices_sent();
  h.step = delta.step();
  h.origin = vec_from_proto(delta.origin());
  h.shift = delta.shift();
  h.max_error = delta.max_error();
  h.pending_vertices = delta.pending_vertices();
  h.raw_bytes = delta.raw_bytes();
  return h;
}

}  // namespace meshdeform::wire
