#pragma once
/// @file median_split.h
/// Internal to core: the geometric split behind the work done in two halves (the hierarchy's
/// decimation, core/multires/multires.cpp, and the prolongation's factorization, core/linalg/split_cholesky.h).

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "core/mesh/mesh_data.h"

namespace meshdeform::core {

/// Side 0 or 1 of every row of `points`: 0 below the median of the `candidates` rows along the
/// longest axis of the bounding box of all the points, 1 from it on (ties by index, so the
/// split is deterministic and the median row itself is on side 1). No candidates: all on 0.
inline std::vector<std::uint8_t> median_sides(const Positions& points,
                                              std::vector<int> candidates) {
  std::vector<std::uint8_t> side(static_cast<std::size_t>(points.rows()), 0);
  if (candidates.empty()) return side;
  Eigen::Index axis = 0;
  (points.colwise().maxCoeff() - points.colwise().minCoeff()).maxCoeff(&axis);
  const auto key = [&](int v) { return std::pair(points(v, axis), v); };
  const auto middle = candidates.begin() + static_cast<std::ptrdiff_t>(candidates.size() / 2);
  std::nth_element(candidates.begin(), middle, candidates.end(),
                   [&](int a, int b) { return key(a) < key(b); });
  const auto pivot = key(*middle);
  for (Eigen::Index v = 0; v < points.rows(); ++v) {
    side[static_cast<std::size_t>(v)] = key(static_cast<int>(v)) < pivot ? 0 : 1;
  }
  return side;
}

}  // namespace meshdeform::core
