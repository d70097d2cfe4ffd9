#include "client_cpp/loadtest/stats.h"

#include <algorithm>
#include <cmath>
#include <numeric>

namespace meshdeform::loadtest {

double percentile_sorted(const std::vector<double>& sorted, double p) {
  const double n = static_cast<double>(sorted.size());
  const double rank = std::ceil(p / 100.0 * n);  // 1-based nearest rank
  const std::size_t index =
      static_cast<std::size_t>(std::clamp(rank, 1.0, n)) - 1;  // p = 0 gives the minimum
  return sorted[index];
}

Summary summarize(std::vector<double> values) {
  Summary summary;
  summary.count = values.size();
  if (values.empty()) return summary;
  std::sort(values.begin(), values.end());
  summary.min = values.front();
  summary.max = values.back();
  summary.mean =
      std::accumulate(values.begin(), values.end(), 0.0) / static_cast<double>(values.size());
  summary.p50 = percentile_sorted(values, 50);
  summary.p95 = percentile_sorted(values, 95);
  summary.p99 = percentile_sorted(values, 99);
  return summary;
}

}  // namespace meshdeform::loadtest
