#pragma once
/// @file proto_convert.h
/// meshdeform.v1 messages <-> service domain types. Checks the wire shape only: what cannot be
/// represented in the service's types (the oneof given, lengths such as 3 positions per target,
/// indices and counts that fit an int, known enum values). The service checks the meaning, once:
/// finite numbers, ranges (max_iterations, tolerance, lambda, rigidity, scales), non-zero
/// quaternions, indices < #V, roles. Every error here is InvalidArgument naming the field. The
/// value and enum maps themselves are meshdeform::wire's (proto/wire/wire_mapping.h), shared with
/// the client.

#include "core/methods/deformer.h"
#include "core/io/mesh_io.h"
#include "core/base/status.h"
#include "meshdeform/v1/deformation.pb.h"
#include "server/service/types.h"

namespace meshdeform::transport {

/// wire::format_from_proto with the server's reading of MESH_FORMAT_UNSPECIFIED.
/// @param[in] allow_unspecified  map MESH_FORMAT_UNSPECIFIED to GLB instead of rejecting it.
/// @return the format; InvalidArgument for UNSPECIFIED (unless allowed) or an unknown value.
[[nodiscard]] Result<io::MeshFormat> format_from_proto(v1::MeshFormat format,
                                                       bool allow_unspecified);

/// @return the request; InvalidArgument for neither bytes nor sample (or an empty one), or a
///         missing/unknown format with bytes.
[[nodiscard]] Result<service::CreateSessionRequest> create_request_from_proto(
    const v1::CreateSessionRequest& request);
/// @return the groups; InvalidArgument for an unspecified/unknown role or an index > INT_MAX.
[[nodiscard]] Result<service::SetHandlesRequest> set_handles_from_proto(
    const v1::SetHandlesRequest& request);
/// @return the move; InvalidArgument for targets whose positions are not 3 per vertex, indices or
///         max_iterations > INT_MAX, or an unknown history action.
[[nodiscard]] Result<service::MoveRequest> move_from_proto(const v1::MoveHandlesRequest& request);

/// Compact deltas changing more than this fraction of the vertices are sent dense.
inline constexpr double kDenseFraction = 0.85;

/// @return the encoding; InvalidArgument for a value this server does not know.
[[nodiscard]] Result<v1::PositionEncoding> encoding_from_proto(int value);

/// Appends #rows x 3 positions to `out` in a compact encoding: FLOAT32 (little-endian float32
/// x, y, z per row) or MESHOPT (those float32 rows, 12 bytes each, through meshoptimizer's
/// lossless vertex codec). Rows beyond float's range become +-inf (FLOAT32 is the client's choice
/// of precision). No rows append nothing. @pre encoding is FLOAT32 or MESHOPT.
void pack_positions(const Positions& rows, v1::PositionEncoding encoding, std::string* out);

void session_info_to_proto(const service::SessionInfo& info, v1::SessionInfo* out);
void created_to_proto(const service::CreatedSession& created, v1::CreateSessionResponse* out);
void progress_to_proto(const service::ProgressEvent& event, v1::Progress* out);
/// @param[in] full_positions  also fill out->positions with all #V x 3 positions.
/// @param[in] encoding        UNSPECIFIED: doubles in the repeated fields; FLOAT32 / MESHOPT:
///                            the same positions in the packed_* bytes (see pack_positions),
///                            and a delta that changed more than kDenseFraction of the
///                            vertices dense (DeformResult.dense). Packed bytes are made once
///                            per result and encoding, in the result's memo
///                            (service::DeformResult::encoded), and shared with every other
///                            response or watch update of that result.
void result_to_proto(const service::DeformResult& result, bool full_positions,
                     v1::PositionEncoding encoding, v1::DeformResult* out);
/// The result's figures only (revision, method, errors, iterations, ...): no positions, no
/// changed lists (MoveHandlesRequest.omit_positions; the figures of a link-sized Watch update).
void result_figures_to_proto(const service::DeformResult& result, v1::DeformResult* out);
/// Snapshots carry all positions and no changed lists; deltas the changed lists only.
void update_to_proto(const service::DeformUpdate& update, v1::PositionEncoding encoding,
                     v1::DeformUpdate* out);
/// DeformUpdate.coarse for a result solved on a coarse level (WatchRequest.coarse_preview):
/// its float32 positions, and its triangles and to_fine when the level's key differs from
/// `*sent_key` (what the stream sent last), which then becomes that key. Nothing for a result
/// without a coarse level.
void coarse_to_proto(const service::DeformResult& result, std::optional<std::uint64_t>* sent_key,
                     v1::DeformUpdate* out);
void server_stats_to_proto(const service::ServiceStats& stats, double uptime_seconds,
                           v1::GetServerStatsResponse* out);

}  // namespace meshdeform::transport
