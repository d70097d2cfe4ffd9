#include "core/methods/constraints.h"

#include <cmath>
#include <string>
#include <vector>

namespace meshdeform::core {

Status check_constrained(const Eigen::VectorXi& constrained, const MeshTopology& topology,
                         int min_per_component) {
  const int n = topology.vertex_count;
  std::vector<int> seen(n, -1);
  std::vector<int> per_component(topology.component_count, 0);
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    const int v = constrained(j);
    if (v < 0 || v >= n) {
      return Error(ErrorCode::InvalidArgument, "constrained vertex " + std::to_string(j) + " is " +
                                                   std::to_string(v) + " (#V=" +
                                                   std::to_string(n) + ")");
    }
    if (seen[v] >= 0) {
      return Error(ErrorCode::InvalidArgument,
                   "vertex " + std::to_string(v) + " is constrained twice (entries " +
                       std::to_string(seen[v]) + " and " + std::to_string(j) + ")");
    }
    seen[v] = static_cast<int>(j);
    ++per_component[topology.component(v)];
  }
  for (int c = 0; c < topology.component_count; ++c) {
    if (per_component[c] < min_per_component) {
      int example = 0;
      while (topology.component(example) != c) ++example;
      return Error(ErrorCode::InvalidArgument,
                   "connected component " + std::to_string(c) + " (containing vertex " +
                       std::to_string(example) + ") has " + std::to_string(per_component[c]) +
                       " constrained vertices; at least " + std::to_string(min_per_component) +
                       " are needed to pin it (the energy is invariant to translation and scale)");
    }
  }
  return Status::success();
}

Status check_targets(const Positions& targets, const Eigen::VectorXi& constrained,
                     const MeshTopology& topology, double length_scale, bool require_distinct) {
  if (targets.rows() != constrained.size()) {
    return Error(ErrorCode::InvalidArgument,
                 "expected " + std::to_string(constrained.size()) + " target rows (one per " +
                     "constrained vertex), got " + std::to_string(targets.rows()));
  }
  for (Eigen::Index j = 0; j < targets.rows(); ++j) {
    if (!targets.row(j).allFinite()) {
      return Error(ErrorCode::InvalidArgument, "target " + std::to_string(j) + " (vertex " +
                                                   std::to_string(constrained(j)) +
                                                   ") is not finite");
    }
  }
  if (!require_distinct) return Status::success();
  // First target of each component, then look for one that differs from it.
  std::vector<int> first(topology.component_count, -1);
  std::vector<char> spread(topology.component_count, 0);
  const double eps = 1e-12 * std::max(length_scale, 1e-300);
  for (Eigen::Index j = 0; j < targets.rows(); ++j) {
    const int c = topology.component(constrained(j));
    if (first[c] < 0) {
      first[c] = static_cast<int>(j);
    } else if ((targets.row(j) - targets.row(first[c])).norm() > eps) {
      spread[c] = 1;
    }
  }
  for (int c = 0; c < topology.component_count; ++c) {
    if (first[c] >= 0 && !spread[c]) {
      return Error(ErrorCode::InvalidArgument,
                   "all targets of connected component " + std::to_string(c) +
                       " coincide (vertex " + std::to_string(constrained(first[c])) +
                       "): the component would collapse to a point; give two distinct targets");
    }
  }
  return Status::success();
}

}  // namespace meshdeform::core
