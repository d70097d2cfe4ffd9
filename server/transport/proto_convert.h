#pragma once
/// @file proto_convert.h
/// meshdeform.v1 messages <-> service domain types. Checks the wire shape only (finite numbers,
/// lengths, indices that fit an int, known enum values); the service checks the meaning (indices
/// < #V, roles, scale > 0, ...). Every error is InvalidArgument naming the field. The value and
/// enum maps themselves are meshdeform::wire's (proto/wire/wire_mapping.h), shared with the client.

#include "core/deformer.h"
#include "core/io/mesh_io.h"
#include "core/status.h"
#include "meshdeform/v1/deformation.pb.h"
#include "server/service/types.h"

namespace meshdeform::transport {

/// wire::format_from_proto with the server's reading of MESH_FORMAT_UNSPECIFIED.
/// @param[in] allow_unspecified  map MESH_FORMAT_UNSPECIFIED to GLB instead of rejecting it.
/// @return the format; InvalidArgument for UNSPECIFIED (unless allowed) or an unknown value.
[[nodiscard]] Result<io::MeshFormat> format_from_proto(v1::MeshFormat format,
                                                       bool allow_unspecified);

/// @return the request; InvalidArgument for neither bytes nor sample, a missing/unknown format
///         with bytes, or a non-finite / non-positive lambda.
[[nodiscard]] Result<service::CreateSessionRequest> create_request_from_proto(
    const v1::CreateSessionRequest& request);
/// @return the groups; InvalidArgument for an unspecified/unknown role or an index > INT_MAX.
[[nodiscard]] Result<service::SetHandlesRequest> set_handles_from_proto(
    const v1::SetHandlesRequest& request);
/// @return the move; InvalidArgument for non-finite numbers, an all-zero quaternion, targets whose
///         positions are not 3 per vertex, indices > INT_MAX, max_iterations > 1000, more than
///         kMaxMagnifyRegions regions or a non-finite magnify scale.
[[nodiscard]] Result<service::MoveRequest> move_from_proto(const v1::MoveHandlesRequest& request);

/// Compact deltas changing more than this fraction of the vertices are sent dense.
inline constexpr double kDenseFraction = 0.85;

/// At most this many magnify regions per move (each is resolved over every face).
inline constexpr int kMaxMagnifyRegions = 64;

/// @return the encoding; InvalidArgument for a value this server does not know.
[[nodiscard]] Result<v1::PositionEncoding> encoding_from_proto(int value);

/// Appends #rows x 3 positions to `out` in a compact encoding: FLOAT32 (little-endian float32
/// x, y, z per row) or MESHOPT (those float32 rows, 12 bytes each, through meshoptimizer's
/// lossless vertex codec). Rows beyond float's range become +-inf (FLOAT32 is the client's choice
/// of precision). No rows append nothing. @pre encoding is FLOAT32 or MESHOPT.
void pack_positions(const Positions& rows, v1::PositionEncoding encoding, std::string* out);

void session_info_to_proto(const service::SessionInfo& info, v1::SessionInfo* out);
void created_to_proto(const service::CreatedSession& created, v1::CreateSessionResponse* out);
/// @param[in] full_positions  also fill out->positions with all #V x 3 positions.
/// @param[in] encoding        UNSPECIFIED: doubles in the repeated fields; FLOAT32 / MESHOPT:
///                            the same positions in the packed_* bytes (see pack_positions),
///                            and a delta that changed more than kDenseFraction of the
///                            vertices dense (DeformResult.dense).
void result_to_proto(const service::DeformResult& result, bool full_positions,
                     v1::PositionEncoding encoding, v1::DeformResult* out);
/// Snapshots carry all positions and no changed lists; deltas the changed lists only.
void update_to_proto(const service::DeformUpdate& update, v1::PositionEncoding encoding,
                     v1::DeformUpdate* out);
void server_stats_to_proto(const service::ServiceStats& stats, double uptime_seconds,
                           v1::GetServerStatsResponse* out);

}  // namespace meshdeform::transport
