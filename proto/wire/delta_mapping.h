#pragma once
/// @file delta_mapping.h
/// meshdeform.v1 UpdateOptions / VertexDelta <-> the update codec's types (codec/update_codec.h),
/// shared by the server's transport, the C++ client and the load tester.

#include <optional>
#include <string>

#include "codec/update_codec.h"
#include "meshdeform/v1/deformation.pb.h"

namespace meshdeform::wire {

/// The relative tolerance UpdateOptions means by 0 (a fraction of the bounding-box diagonal).
inline constexpr double kDefaultRelativeTolerance = 1e-4;
/// The largest relative tolerance accepted.
inline constexpr double kMaxRelativeTolerance = 0.1;

/// The codec's settings for a stream of a session whose rest bounding box is [bbox_min,
/// bbox_max]. @return nullopt when the options are off (mode UNSPECIFIED); InvalidArgument
/// naming the field for an unknown mode, a negative or non-finite tolerance, a relative
/// tolerance outside (0, kMaxRelativeTolerance], or a budget in (0, 1024).
[[nodiscard]] Result<std::optional<codec::StreamSettings>> stream_settings_from_proto(
    const v1::UpdateOptions& options, const Eigen::Vector3d& bbox_min,
    const Eigen::Vector3d& bbox_max);

void delta_to_proto(const codec::EncodedUpdate& update, v1::VertexDelta* out);
/// @param[in] revision  the DeformResult's revision the delta belongs to.
/// @return the header; InvalidArgument for an unknown mode.
[[nodiscard]] Result<codec::UpdateHeader> delta_header_from_proto(const v1::VertexDelta& delta,
                                                                  std::uint64_t revision);

}  // namespace meshdeform::wire
