#pragma once
/// @file metrics.h
/// Process metrics in the Prometheus text exposition format (version 0.0.4): RPC counts by method
/// and status code, latency histograms, solve-time histograms, and the service's gauges and
/// counters (sessions, memory, factorizations, PCG iterations, refinements, evictions). Front ends
/// (gRPC, the browser gateway) record their calls here; the service records its solves.
/// Thread-safe.

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <tuple>
#include <mutex>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "server/service/types.h"

namespace meshdeform::service {

/// A cumulative histogram with fixed upper bounds (seconds).
class Histogram {
 public:
  /// Bounds of the latency buckets: 1 ms .. 10 s (+Inf implied).
  static const std::vector<double>& latency_bounds();

  explicit Histogram(std::vector<double> bounds = latency_bounds());
  void observe(double value);
  /// Appends `name_bucket{labels,le="..."}`, `name_sum{labels}`, `name_count{labels}` lines.
  /// @param[in] labels  `key="value"` pairs joined by commas, or empty.
  void render(std::string_view name, std::string_view labels, std::string& out) const;
  std::uint64_t count() const;

 private:
  std::vector<double> bounds_;
  mutable std::mutex mutex_;
  std::vector<std::uint64_t> counts_;  ///< per bucket (not cumulative), last = +Inf
  double sum_ = 0;
  std::uint64_t count_ = 0;
};

/// Everything /metrics shows besides ServiceStats.
class MetricsRegistry {
 public:
  /// One finished call: `method` ("MoveHandles"), `code` ("OK", "NOT_FOUND"), wall seconds, and
  /// the front end ("grpc" or "grpc-web").
  void record_rpc(std::string_view frontend, std::string_view method, std::string_view code,
                  double seconds);
  /// One committed solve: a move or a background refinement slice.
  void record_solve(bool refinement, double seconds);
  /// One move's wait on the server before its solve began (DeformResult::queue_seconds).
  void record_move_queue_wait(double seconds);

  /// The whole exposition: RPC and solve metrics plus `stats` as gauges and counters, then the
  /// added sections.
  std::string render(const ServiceStats& stats) const;
  /// Adds a section rendered after the service's own (complete `# HELP`/`# TYPE` blocks): the
  /// transport's connection counters. Called at render time, on the scraping thread.
  void add_section(std::function<void(std::string& out)> render);

 private:
  mutable std::mutex mutex_;
  std::map<std::tuple<std::string, std::string, std::string>, std::uint64_t> rpc_counts_;
  std::map<std::pair<std::string, std::string>, std::unique_ptr<Histogram>> rpc_latency_;
  std::vector<std::function<void(std::string&)>> sections_;
  Histogram move_solve_;
  Histogram refinement_solve_;
  Histogram move_queue_wait_;
};

}  // namespace meshdeform::service
