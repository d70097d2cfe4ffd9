#pragma once
/// @file run_result.h
/// What one load-test run observed: raw per-session and per-watcher measurements, the server's
/// own figures, and the facts about where it ran. Plain data; report.h turns it into text.

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "client_cpp/loadtest/options.h"

namespace meshdeform::loadtest {

/// One GetServerStats answer (or why there was none).
struct ServerStatsSample {
  bool is_available = false;  ///< false: not fetched, UNIMPLEMENTED or failed ("memory unknown")
  std::string status = "NOT_FETCHED";  ///< "OK" or the gRPC status code name
  std::string message;                 ///< the error message when not OK
  std::uint32_t sessions = 0;
  std::uint64_t estimated_bytes = 0;
  std::uint64_t resident_bytes = 0;  ///< 0: the server does not know
  std::uint64_t moves_committed = 0;
  std::uint64_t moves_cancelled = 0;
  std::uint64_t refinements_committed = 0;
  std::uint64_t deformer_constructions = 0;
  std::uint64_t evicted_lru = 0;
  std::uint64_t evicted_idle = 0;
  std::uint32_t workers = 0;
  double uptime_seconds = 0.0;
};

/// One Watch stream.
struct WatcherResult {
  int index = 0;                   ///< within its session
  bool has_join_snapshot = false;  ///< the first update was a full snapshot
  double join_ms = 0.0;            ///< Watch call to the join snapshot (client side)
  std::int64_t updates = 0;        ///< every message received, the join snapshot included
  std::int64_t snapshots = 0;      ///< is_snapshot (join, and after a gap)
  std::int64_t deltas = 0;
  std::int64_t refinements = 0;        ///< DeformResult.refinement (server background refinement)
  std::int64_t lossless_updates = 0;   ///< link-sized updates in mode LOSSLESS (join included)
  std::int64_t skipped_revisions = 0;  ///< sum of DeformUpdate.skipped_revisions
  std::uint64_t last_revision = 0;
  /// The errors of the newest revision received (after --settle-seconds: the result the
  /// session settled on, as far as this watcher saw).
  double last_e_theta = 0.0;
  double last_e_phi = 0.0;
  std::uint64_t delta_bytes = 0;  ///< serialized size of the non-snapshot updates, summed
  /// Watcher receipt minus the editor's MoveHandles response, for each revision the editor
  /// committed and this watcher saw (ms; negative when the watcher saw it first).
  std::vector<double> delays_ms;
  std::int64_t seen_before_response = 0;
  /// Watcher receipt minus the editor's MoveHandles send time, for the same revisions (ms).
  std::vector<double> delays_after_send_ms;
  // --updates (link-sized updates), after the join update:
  std::int64_t revision_updates = 0;  ///< updates that brought a newer revision
  std::int64_t continuations = 0;     ///< updates toward the same revision (a budget's remainder)
  std::int64_t complete_updates = 0;  ///< updates that left the client within the tolerance
  std::int64_t decode_failures = 0;   ///< updates the client could not apply (the stream ends)
  std::vector<double> update_bytes;   ///< serialized size of every update after the join
  std::vector<double> max_error;      ///< VertexDelta.max_error of every update after the join
  std::vector<double> decode_ms;      ///< time to apply each update (decompress + reconstruct)
  double join_bytes = 0;              ///< serialized size of the join update
  // --coarse-preview:
  std::int64_t coarse_updates = 0;    ///< updates carrying DeformUpdate.coarse
  std::int64_t coarse_malformed = 0;  ///< of those, positions not 12 bytes per coarse vertex,
                                      ///< or a first update of a level without its mesh
  std::vector<double> coarse_bytes;   ///< serialized size of DeformUpdate.coarse per update
  /// For each move the editor committed: its send time to the first update of this watcher
  /// with that revision or a newer one, applied (ms): what a user sees of their own drag.
  std::vector<double> applied_after_send_ms;
  std::string end_status = "NOT_STARTED";  ///< the stream's final status code name
  std::string end_message;
};

/// One session: its setup, its scripted drag, its watchers.
struct SessionResult {
  int index = 0;
  /// --settle-seconds: from the last own move's response to the first watcher's receipt of a
  /// converged revision at or past it (ms); empty when none came within the bound.
  std::optional<double> settle_ms;
  /// The same for a settled revision (DeformResult.settled: converged, or refinement's last),
  /// and whether that update came lossless.
  std::optional<double> settled_ms;
  bool settled_lossless = false;
  int channel = 0;
  bool is_set_up = false;  ///< CreateSession and SetHandles succeeded
  std::string
      setup_status;  ///< "OK" or the failing call and code, e.g. "CreateSession: UNAVAILABLE"
  std::string setup_error;  ///< its message
  double create_ms = 0.0;
  double set_handles_ms = 0.0;
  std::uint32_t vertices = 0;
  std::uint32_t faces = 0;
  std::size_t fixed_vertices = 0;
  std::size_t handle_vertices = 0;

  std::int64_t ticks = 0;          ///< rate > 0: ticks reached (moves sent + skipped)
  std::int64_t skipped_ticks = 0;  ///< ticks that came while the previous move was in flight
  std::int64_t sent_on_response = 0;  ///< --send-on-response: moves sent as a response came
  std::int64_t moves_sent = 0;
  std::int64_t moves_ok = 0;
  std::map<std::string, std::int64_t> errors_by_code;  ///< failed moves by status code name
  std::map<std::string, std::string> first_error;      ///< the first message per code
  std::vector<double> latencies_ms;                    ///< OK moves, send to response, client side
  std::vector<double> solve_ms;                        ///< OK moves, DeformResult.solve_seconds
  std::vector<double> queue_ms;                        ///< OK moves, DeformResult.queue_seconds
  std::uint64_t response_bytes = 0;                    ///< serialized size of OK responses, summed
  std::int64_t iterations = 0;                         ///< sum of DeformResult.iterations
  std::int64_t converged = 0;
  std::int64_t built_deformer = 0;
  /// Revisions committed between this editor's own moves (the server's refinements).
  std::int64_t revision_gaps = 0;
  std::uint64_t last_revision = 0;
  std::string close_status = "NOT_CLOSED";
  std::vector<WatcherResult> watchers;
};

/// Where and when the run happened.
struct MachineFacts {
  std::string date_utc;
  int hardware_threads = 0;
  std::string cpu_model = "unknown";
  std::string load_average_start = "unknown";
  std::string load_average_end = "unknown";
  std::string build_type = "unknown";  ///< of the load tester itself
};

/// The emulated link of --via-link (what it was, what it carried).
struct LinkResult {
  bool used = false;
  std::string spec;         ///< as given
  std::string description;  ///< describe_link()
  double down_mbit = 0, up_mbit = 0, rtt_ms = 0, jitter_ms = 0, loss = 0;
  std::uint64_t queue_bytes_down = 0, queue_bytes_up = 0;
  std::uint64_t bytes_down = 0, bytes_up = 0, losses = 0, full_queue_waits_down = 0;
  std::uint64_t connections = 0;
};

/// The whole run.
struct RunResult {
  LinkResult link;
  Options options;
  MachineFacts machine;
  std::string mesh_label;  ///< the sample name, or the uploaded file's name
  bool completed = false;  ///< every phase ran and every thread was joined
  int sessions_set_up = 0;
  double setup_phase_seconds = 0.0;  ///< start to the moment every session was set up
  double move_phase_seconds = 0.0;   ///< the measured phase: all set up -> last move returned
  double total_seconds = 0.0;
  std::vector<SessionResult> sessions;
  ServerStatsSample stats_before;  ///< before the first session was created
  ServerStatsSample stats_loaded;  ///< after the last move, sessions still open
  ServerStatsSample stats_after_close;
};

}  // namespace meshdeform::loadtest
