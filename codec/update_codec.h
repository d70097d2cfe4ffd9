#pragma once
/// @file update_codec.h
/// Link-sized vertex updates (issue 45): a stream's updates are deltas against what that stream
/// has already delivered (its *base*), not against the previous revision, so a stream that
/// skips revisions (a slow watcher) still gets a delta, and an update may carry only part of
/// the way to a revision (a byte budget) with the rest following in later updates.
///
/// Two modes:
///  - Quantized: positions live on a grid of `step` = `tolerance` per axis (fixed-point against
///    the rest mesh's bounding-box corner). The client's state is the integer grid coordinate of
///    every vertex, its position origin + q * step (the same double arithmetic on both sides, so
///    the server knows exactly what the client shows). A vertex is sent when its client position
///    is farther than `tolerance` (Euclidean) from the revision's; once sent at full precision
///    it is within step * sqrt(3) / 2 < tolerance. An update is *complete* when no vertex is
///    farther than `tolerance`: every delivered position is then within the stated tolerance of
///    the solver's.
///  - Lossless: the client's state is the 64-bit pattern of every double; a vertex is sent when
///    any coordinate's bits differ, as the XOR of old and new bits. Every update is complete and
///    reproduces the revision bit for bit (the byte budget does not apply).
///  - Both: a quantized stream may send single updates lossless (StreamEncoder::encode's
///    `lossless`: the server does so for settled revisions when a watcher asks,
///    UpdateOptions.lossless_settled). Such an update carries the stream's grid in its header
///    and XORs the bits of the positions the client shows; the client then shows the revision
///    exactly, and a later quantized update puts a vertex it sends back on the grid (its grid
///    coordinate never changed), even when that coordinate's delta is 0.
///
/// Byte budget (quantized): an update whose payload would exceed `max_update_bytes` is sent at
/// a coarser precision (values rounded to multiples of 2^shift grid steps: every moved vertex
/// moves, less exactly), and if even the coarsest shift does not fit, only the vertices with
/// the largest errors are sent. Either way the update says how far the client still is
/// (max_error, pending_vertices), and StreamEncoder::pending() / encode_pending() continue
/// toward the same revision until it is complete: a progressive stream after a drag ends.
///
/// Payload (then compressed as one zstd frame), little-endian, varints LEB128:
///   byte    version (1)
///   byte    flags: bit 0 = every vertex in index order (no index list)
///   varint  n, vertices sent
///   n varints (unless bit 0): index gaps (first index, then index - previous - 1)
///   quantized: for x, y, z in turn, n zigzag varints: d_i - d_{i-1} (d_{-1} = 0), where d_i is
///              the vertex's grid delta divided by 2^shift (exactly: the encoder rounds it);
///   lossless:  for x, y, z in turn, for byte 7 down to 0: n bytes, that byte of old ^ new bits.
/// The web viewer decodes the same format (web_viewer/src/update_codec.ts).

#include <Eigen/Core>
#include <cstddef>
#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

#include "core/mesh/mesh_data.h"
#include "core/base/status.h"

namespace meshdeform::codec {

enum class DeltaMode { Quantized, Lossless };

/// The payload format version written and accepted.
inline constexpr int kPayloadVersion = 1;
/// The largest shift (values rounded to 2^kMaxShift grid steps).
inline constexpr int kMaxShift = 24;

/// What a stream was asked for.
struct StreamSettings {
  DeltaMode mode = DeltaMode::Quantized;
  /// Quantized: the largest distance a complete update leaves between a client position and the
  /// solver's (absolute, in model units); > 0 and finite. Also the grid step.
  double tolerance = 0;
  /// Quantized: the grid's origin (the rest mesh's bounding-box minimum).
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  /// Quantized: the most payload bytes an update may carry (after compression); 0 = no limit.
  /// At least kMinUpdateBytes when set.
  std::size_t max_update_bytes = 0;
  int zstd_level = 1;
  /// Quantized: the stream's owner sends settled revisions lossless (encode's `lossless`;
  /// UpdateOptions.lossless_settled). The encoder itself does not read it.
  bool lossless_settled = false;
};

/// The smallest byte budget accepted (an update must be able to carry something).
inline constexpr std::size_t kMinUpdateBytes = 1024;

/// What travels beside the payload (meshdeform.v1.VertexDelta).
struct UpdateHeader {
  DeltaMode mode = DeltaMode::Quantized;
  std::uint64_t sequence = 0;    ///< 1 for a stream's first update, then +1 each
  std::uint64_t revision = 0;    ///< the revision this update moves the client toward
  std::uint32_t vertex_count = 0;
  std::uint32_t vertices_sent = 0;
  double step = 0;               ///< quantized: the grid step (= the stream's tolerance)
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  ///< quantized: the grid origin
  std::uint32_t shift = 0;       ///< quantized: values are in units of 2^shift steps
  /// After this update: the largest distance between a client position and the revision's
  /// (quantized; 0 when lossless), and how many vertices are still farther than the tolerance.
  double max_error = 0;
  std::uint32_t pending_vertices = 0;
  std::uint64_t raw_bytes = 0;   ///< payload size before compression (for reports)
  bool complete() const { return pending_vertices == 0; }
};

struct EncodedUpdate {
  UpdateHeader header;
  std::string payload;  ///< one zstd frame
};

/// The server side of one stream. Not thread-safe.
class StreamEncoder {
 public:
  /// @return the encoder; InvalidArgument for a tolerance that is not positive and finite, a
  ///         non-finite origin, a budget below kMinUpdateBytes, or vertex_count < 0.
  [[nodiscard]] static Result<StreamEncoder> create(const StreamSettings& settings,
                                                    int vertex_count);

  /// The next update toward `target` (#V x 3, the revision's positions).
  /// @param lossless  in a quantized stream: send this update lossless (every position exact,
  ///                  complete; the byte budget does not apply), e.g. a settled revision
  ///                  (UpdateOptions.lossless_settled). Its header keeps the stream's grid, and
  ///                  the client keeps showing those exact positions until a later quantized
  ///                  update sends a vertex again. Lossless streams ignore it.
  /// @return the update; InvalidArgument for a row count other than the stream's or a
  ///         non-finite position.
  [[nodiscard]] Result<EncodedUpdate> encode(const Positions& target, std::uint64_t revision,
                                             bool lossless = false);
  /// Whether the client is not yet within tolerance of the last target (quantized with a
  /// budget): encode_pending() makes the next step.
  bool pending() const { return pending_ > 0; }
  /// Another update toward the last target. @pre pending().
  [[nodiscard]] Result<EncodedUpdate> encode_pending();

  /// What the client holds (for tests and for reports): origin + q * step, or the doubles.
  Positions client_positions() const;
  /// Bytes this encoder keeps (its model of the client and the last target).
  std::size_t memory_bytes() const;
  const StreamSettings& settings() const { return settings_; }

 private:
  StreamEncoder() = default;
  Result<EncodedUpdate> encode_current(bool lossless);

  StreamSettings settings_;
  int vertex_count_ = 0;
  std::uint64_t sequence_ = 0;
  std::uint64_t revision_ = 0;
  std::vector<std::int64_t> client_q_;     // quantized: 3 per vertex
  std::vector<double> client_shown_;       // what the client shows (grid or exact), 3 per vertex
  std::vector<double> target_;             // the last target, 3 per vertex (row-major)
  std::size_t pending_ = 0;
};

/// The client side of one stream. Not thread-safe.
class StreamDecoder {
 public:
  /// Applies an update.
  /// @return success; FailedPrecondition for an update out of sequence or of another stream
  ///         (vertex count or grid changed, a quantized update in a lossless stream; a
  ///         lossless update in a quantized stream carries the stream's grid and is accepted);
  ///         InvalidArgument for a payload that does not
  ///         decode (truncated, wrong version, index out of range, a count that disagrees with
  ///         the header, more bytes than such an update can hold). The state is unchanged on
  ///         error.
  [[nodiscard]] Status apply(const UpdateHeader& header, std::string_view payload);

  bool has_state() const { return sequence_ > 0; }
  std::uint64_t sequence() const { return sequence_; }
  /// The revision the last update moved toward (complete or not).
  std::uint64_t revision() const { return revision_; }
  /// Whether the last update was complete (within tolerance, or exact).
  bool complete() const { return complete_; }
  /// #V x 3 reconstructed positions (empty before the first update).
  const Positions& positions() const { return positions_; }

 private:
  std::uint64_t sequence_ = 0;
  std::uint64_t revision_ = 0;
  bool complete_ = false;
  bool grid_ = false;  // a quantized stream (its lossless updates carry the grid too)
  std::uint32_t vertex_count_ = 0;
  double step_ = 0;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  std::vector<std::int64_t> q_;
  Positions positions_;
};

/// The largest payload, before compression, an update of `vertex_count` vertices can have in
/// `mode` (decoders refuse frames that claim more: no decompression bombs).
std::size_t max_raw_payload_bytes(DeltaMode mode, std::uint32_t vertex_count);

}  // namespace meshdeform::codec
