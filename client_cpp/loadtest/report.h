#pragma once
/// @file report.h
/// Turns a RunResult into the three reports: a human-readable summary (stdout), JSON (--json,
/// the complete record, per session and per watcher) and Markdown (--markdown, for
/// bench/results/). All three are computed from one Aggregate, so they always agree.

#include <cstdint>
#include <map>
#include <string>

#include "client_cpp/loadtest/run_result.h"
#include "client_cpp/loadtest/stats.h"

namespace meshdeform::loadtest {

/// Run-wide figures.
struct Aggregate {
  int sessions = 0;
  int sessions_set_up = 0;
  std::map<std::string, int> setup_failures;  ///< by "Call: CODE"
  Summary setup_ms;                           ///< CreateSession + SetHandles per set-up session
  Summary create_ms;
  Summary set_handles_ms;
  std::uint32_t vertices = 0;  ///< of the first set-up session

  std::int64_t ticks = 0;
  std::int64_t skipped_ticks = 0;
  std::int64_t moves_sent = 0;
  std::int64_t moves_ok = 0;
  std::int64_t moves_failed = 0;
  std::map<std::string, std::int64_t> errors_by_code;
  std::map<std::string, std::string> first_error;
  double moves_per_second = 0.0;     ///< OK moves / move-phase seconds, all sessions
  Summary moves_per_second_session;  ///< the same per set-up session
  Summary latency_ms;                ///< OK moves, client side
  Summary solve_ms;                  ///< OK moves, the server's solve_seconds
  Summary queue_ms;                  ///< OK moves, the server's queue_seconds
  double mean_iterations = 0.0;
  double mean_response_bytes = 0.0;  ///< serialized MoveHandles response, OK moves
  std::int64_t converged = 0;
  std::int64_t built_deformer = 0;
  std::int64_t revision_gaps = 0;  ///< revisions the editors did not commit (refinements)
  std::map<std::string, int> close_status;

  int watchers = 0;
  int watchers_with_join_snapshot = 0;
  std::int64_t watcher_updates = 0;
  std::int64_t watcher_snapshots = 0;
  std::int64_t watcher_deltas = 0;
  std::int64_t watcher_refinements = 0;
  std::int64_t watcher_skipped_revisions = 0;
  double mean_watcher_delta_bytes = 0.0;  ///< serialized non-snapshot Watch update
  std::int64_t watcher_seen_before_response = 0;
  double watcher_updates_per_second = 0.0;  ///< all watchers, join snapshots excluded
  double watcher_updates_per_second_each = 0.0;
  Summary watcher_delay_ms;             ///< receipt minus the editor's response, editors' revisions
  Summary watcher_delay_after_send_ms;  ///< receipt minus the editor's send, same revisions
  Summary watcher_join_ms;
  std::map<std::string, int> watcher_end_status;
  // --updates (link-sized updates):
  Summary watcher_applied_after_send_ms;  ///< own move sent -> first update at/past it applied
  Summary watcher_update_bytes;           ///< serialized update, after the join
  Summary watcher_max_error;              ///< VertexDelta.max_error after each update
  Summary watcher_decode_ms;              ///< applying one update at the client
  double watcher_join_bytes = 0;          ///< mean serialized join update
  std::int64_t watcher_revision_updates = 0;
  std::int64_t watcher_continuations = 0;
  std::int64_t watcher_complete_updates = 0;
  std::int64_t watcher_decode_failures = 0;
  std::int64_t watcher_coarse_updates = 0;    ///< --coarse-preview: updates with a coarse level
  std::int64_t watcher_coarse_malformed = 0;  ///< ... that broke the protocol
  Summary watcher_coarse_bytes;               ///< ... and the coarse part's serialized size
  int sessions_settled = 0;  ///< --settle-seconds: sessions that saw a converged revision
  Summary settle_ms;         ///< ... from their last move's response
  int sessions_with_settled = 0;  ///< --settle-seconds: sessions that saw a settled revision
  Summary settled_ms;             ///< ... from their last move's response
  int settled_lossless = 0;       ///< ... whose settled update came lossless
  std::int64_t watcher_lossless_updates = 0;  ///< link-sized updates in mode LOSSLESS
  double watcher_revision_updates_per_second_each = 0;  ///< newer revisions applied per second
};

Aggregate aggregate(const RunResult& run);

/// The stdout summary (a few aligned lines).
std::string summary_text(const RunResult& run, const Aggregate& totals);
/// The complete JSON report (pretty-printed, keys in a fixed order).
std::string report_json(const RunResult& run, const Aggregate& totals);
/// The Markdown summary.
std::string report_markdown(const RunResult& run, const Aggregate& totals);

}  // namespace meshdeform::loadtest
