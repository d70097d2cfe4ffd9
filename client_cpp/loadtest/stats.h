#pragma once
/// @file stats.h
/// Order statistics of a sample (latencies, delays), nearest-rank percentiles.

#include <cstddef>
#include <optional>
#include <vector>

namespace meshdeform::loadtest {

/// Summary of a sample; every field is empty for an empty sample.
struct Summary {
  std::size_t count = 0;
  std::optional<double> min;
  std::optional<double> mean;
  std::optional<double> p50;
  std::optional<double> p95;
  std::optional<double> p99;
  std::optional<double> max;
};

/// Nearest-rank percentiles (the smallest value with at least p% of the sample at or below it),
/// so p50 <= p95 <= p99 <= max always and every value reported was observed.
/// @param[in] values  the sample, any order (copied and sorted).
Summary summarize(std::vector<double> values);

/// Nearest-rank percentile `p` in [0, 100] of an ascending, non-empty sample.
double percentile_sorted(const std::vector<double>& sorted, double p);

}  // namespace meshdeform::loadtest
