#pragma once
/// @file constraints.h
/// Internal to core: checks shared by every solver on a set of constrained vertices.

#include <Eigen/Core>

#include "core/mesh/mesh_data.h"
#include "core/base/status.h"
#include "core/mesh/topology.h"

namespace meshdeform::core {

/// Indices in range and distinct, and every connected component holding at least
/// `min_per_component` of them. Messages name the index or the component and one of its vertices.
[[nodiscard]] Status check_constrained(const Eigen::VectorXi& constrained,
                                       const MeshTopology& topology, int min_per_component);

/// Targets of the right shape, finite, and (when `require_distinct`) spanning two distinct points
/// in every component that holds constrained vertices.
[[nodiscard]] Status check_targets(const Positions& targets, const Eigen::VectorXi& constrained,
                                   const MeshTopology& topology, double length_scale,
                                   bool require_distinct);

}  // namespace meshdeform::core
