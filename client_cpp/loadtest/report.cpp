#include "client_cpp/loadtest/report.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

namespace meshdeform::loadtest {
namespace {

using Json = nlohmann::ordered_json;

std::string format(const char* pattern, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof buffer, pattern, value);
  return buffer;
}

// "12.3" (one decimal below 100, none above), or "n/a".
std::string ms_text(const std::optional<double>& value) {
  if (!value) return "n/a";
  return format(std::abs(*value) < 100.0 ? "%.1f" : "%.0f", *value);
}

std::string rate_text(double value) { return format(value < 100.0 ? "%.2f" : "%.1f", value); }

std::string mib_text(std::uint64_t bytes) {
  return format("%.1f MiB", static_cast<double>(bytes) / (1024.0 * 1024.0));
}

// Rounds to microsecond resolution (values in ms) so that the JSON stays readable.
Json rounded(const std::optional<double>& value) {
  if (!value || !std::isfinite(*value)) return nullptr;
  return std::round(*value * 1000.0) / 1000.0;
}

Json rounded(double value) { return rounded(std::optional<double>(value)); }

Json summary_json(const Summary& summary) {
  return Json{{"count", summary.count},        {"min", rounded(summary.min)},
              {"mean", rounded(summary.mean)}, {"p50", rounded(summary.p50)},
              {"p95", rounded(summary.p95)},   {"p99", rounded(summary.p99)},
              {"max", rounded(summary.max)}};
}

Json stats_json(const ServerStatsSample& stats) {
  Json json{{"available", stats.is_available}, {"status", stats.status}};
  if (!stats.is_available) {
    json["message"] = stats.message;
    return json;
  }
  json["sessions"] = stats.sessions;
  json["estimated_bytes"] = stats.estimated_bytes;
  // 0 means the server does not know its resident set.
  json["resident_bytes"] = stats.resident_bytes == 0 ? Json(nullptr) : Json(stats.resident_bytes);
  json["moves_committed"] = stats.moves_committed;
  json["moves_cancelled"] = stats.moves_cancelled;
  json["refinements_committed"] = stats.refinements_committed;
  json["deformer_constructions"] = stats.deformer_constructions;
  json["evicted_lru"] = stats.evicted_lru;
  json["evicted_idle"] = stats.evicted_idle;
  json["workers"] = stats.workers;
  json["uptime_seconds"] = rounded(stats.uptime_seconds);
  return json;
}

Json resident_json(const ServerStatsSample& stats) {
  if (!stats.is_available || stats.resident_bytes == 0) return nullptr;
  return stats.resident_bytes;
}

std::string resident_text(const ServerStatsSample& stats) {
  if (!stats.is_available) return "unknown (" + stats.status + ")";
  if (stats.resident_bytes == 0) return "unknown (0)";
  return mib_text(stats.resident_bytes);
}

std::string rate_label(const Options& options) {
  if (options.rate_hz <= 0.0) return "back to back (rate 0)";
  return format("%g Hz", options.rate_hz) + " per session";
}

std::string moves_label(const Options& options) {
  return options.moves == 0 ? "until the duration ends" : std::to_string(options.moves);
}

// "4 connections (one per session)".
std::string connections_label(const Options& options) {
  return std::to_string(options.channel_count()) +
         (options.channel_count() == 1 ? " connection" : " connections") +
         (options.connections == 0 ? " (one per session)" : "");
}

std::string error_list(const Aggregate& totals) {
  if (totals.errors_by_code.empty()) return "none";
  std::string text;
  for (const auto& [code, count] : totals.errors_by_code) {
    if (!text.empty()) text += ", ";
    text += code + " " + std::to_string(count);
  }
  return text;
}

std::string count_list(const std::map<std::string, int>& counts) {
  std::string text;
  for (const auto& [name, count] : counts) {
    if (!text.empty()) text += ", ";
    text += name + " " + std::to_string(count);
  }
  return text.empty() ? "none" : text;
}

std::string title(const RunResult& run) {
  const Options& o = run.options;
  return std::to_string(o.sessions) + " sessions x " + run.mesh_label + ", " +
         std::string(method_name(o.method)) + ", " + std::to_string(o.iterations) +
         " iterations, " + rate_label(o) + ", " + std::to_string(o.watchers) + " watchers/session";
}

}  // namespace

Aggregate aggregate(const RunResult& run) {
  Aggregate totals;
  totals.sessions = static_cast<int>(run.sessions.size());
  std::vector<double> setup, create, set_handles, latency, solve, queue, per_session, delays, joins;
  std::vector<double> delays_after_send, applied, update_bytes, max_error, decode_ms, coarse_bytes;
  double join_bytes = 0;
  std::int64_t iterations = 0;
  std::uint64_t response_bytes = 0, delta_bytes = 0;
  const double phase = run.move_phase_seconds;
  for (const SessionResult& session : run.sessions) {
    if (session.is_set_up) {
      ++totals.sessions_set_up;
      if (totals.vertices == 0) totals.vertices = session.vertices;
      setup.push_back(session.create_ms + session.set_handles_ms);
      create.push_back(session.create_ms);
      set_handles.push_back(session.set_handles_ms);
      per_session.push_back(phase > 0.0 ? static_cast<double>(session.moves_ok) / phase : 0.0);
    } else {
      ++totals.setup_failures[session.setup_status.empty() ? "unknown" : session.setup_status];
    }
    totals.ticks += session.ticks;
    totals.skipped_ticks += session.skipped_ticks;
    totals.moves_sent += session.moves_sent;
    totals.moves_ok += session.moves_ok;
    for (const auto& [code, count] : session.errors_by_code) {
      totals.errors_by_code[code] += count;
      totals.moves_failed += count;
    }
    for (const auto& [code, message] : session.first_error) {
      totals.first_error.try_emplace(code, message);
    }
    latency.insert(latency.end(), session.latencies_ms.begin(), session.latencies_ms.end());
    solve.insert(solve.end(), session.solve_ms.begin(), session.solve_ms.end());
    queue.insert(queue.end(), session.queue_ms.begin(), session.queue_ms.end());
    iterations += session.iterations;
    response_bytes += session.response_bytes;
    totals.converged += session.converged;
    totals.built_deformer += session.built_deformer;
    totals.revision_gaps += session.revision_gaps;
    ++totals.close_status[session.close_status];
    for (const WatcherResult& watcher : session.watchers) {
      ++totals.watchers;
      if (watcher.has_join_snapshot) {
        ++totals.watchers_with_join_snapshot;
        joins.push_back(watcher.join_ms);
      }
      totals.watcher_updates += watcher.updates;
      totals.watcher_snapshots += watcher.snapshots;
      totals.watcher_deltas += watcher.deltas;
      delta_bytes += watcher.delta_bytes;
      totals.watcher_refinements += watcher.refinements;
      totals.watcher_lossless_updates += watcher.lossless_updates;
      totals.watcher_skipped_revisions += watcher.skipped_revisions;
      totals.watcher_seen_before_response += watcher.seen_before_response;
      delays.insert(delays.end(), watcher.delays_ms.begin(), watcher.delays_ms.end());
      delays_after_send.insert(delays_after_send.end(), watcher.delays_after_send_ms.begin(),
                               watcher.delays_after_send_ms.end());
      ++totals.watcher_end_status[watcher.end_status];
      applied.insert(applied.end(), watcher.applied_after_send_ms.begin(),
                     watcher.applied_after_send_ms.end());
      update_bytes.insert(update_bytes.end(), watcher.update_bytes.begin(),
                          watcher.update_bytes.end());
      max_error.insert(max_error.end(), watcher.max_error.begin(), watcher.max_error.end());
      decode_ms.insert(decode_ms.end(), watcher.decode_ms.begin(), watcher.decode_ms.end());
      join_bytes += watcher.join_bytes;
      totals.watcher_revision_updates += watcher.revision_updates;
      totals.watcher_continuations += watcher.continuations;
      totals.watcher_complete_updates += watcher.complete_updates;
      totals.watcher_decode_failures += watcher.decode_failures;
      totals.watcher_coarse_updates += watcher.coarse_updates;
      totals.watcher_coarse_malformed += watcher.coarse_malformed;
      coarse_bytes.insert(coarse_bytes.end(), watcher.coarse_bytes.begin(),
                          watcher.coarse_bytes.end());
    }
  }
  totals.setup_ms = summarize(std::move(setup));
  totals.create_ms = summarize(std::move(create));
  totals.set_handles_ms = summarize(std::move(set_handles));
  totals.latency_ms = summarize(std::move(latency));
  totals.solve_ms = summarize(std::move(solve));
  totals.queue_ms = summarize(std::move(queue));
  totals.moves_per_second_session = summarize(std::move(per_session));
  totals.watcher_delay_ms = summarize(std::move(delays));
  totals.watcher_delay_after_send_ms = summarize(std::move(delays_after_send));
  totals.watcher_join_ms = summarize(std::move(joins));
  totals.watcher_applied_after_send_ms = summarize(std::move(applied));
  totals.watcher_update_bytes = summarize(std::move(update_bytes));
  totals.watcher_max_error = summarize(std::move(max_error));
  totals.watcher_decode_ms = summarize(std::move(decode_ms));
  totals.watcher_coarse_bytes = summarize(std::move(coarse_bytes));
  std::vector<double> settle;
  for (const SessionResult& s : run.sessions) {
    if (s.settle_ms) settle.push_back(*s.settle_ms);
  }
  totals.sessions_settled = static_cast<int>(settle.size());
  totals.settle_ms = summarize(std::move(settle));
  std::vector<double> settled;
  for (const SessionResult& s : run.sessions) {
    if (!s.settled_ms) continue;
    settled.push_back(*s.settled_ms);
    if (s.settled_lossless) ++totals.settled_lossless;
  }
  totals.sessions_with_settled = static_cast<int>(settled.size());
  totals.settled_ms = summarize(std::move(settled));
  if (totals.watchers > 0) totals.watcher_join_bytes = join_bytes / totals.watchers;
  if (phase > 0.0 && totals.watchers > 0) {
    totals.watcher_revision_updates_per_second_each =
        static_cast<double>(totals.watcher_revision_updates) / phase / totals.watchers;
  }
  if (phase > 0.0) {
    totals.moves_per_second = static_cast<double>(totals.moves_ok) / phase;
    const std::int64_t after_join = totals.watcher_updates - totals.watchers_with_join_snapshot;
    totals.watcher_updates_per_second = static_cast<double>(after_join) / phase;
    if (totals.watchers > 0) {
      totals.watcher_updates_per_second_each = totals.watcher_updates_per_second / totals.watchers;
    }
  }
  if (totals.moves_ok > 0) {
    totals.mean_iterations = static_cast<double>(iterations) / static_cast<double>(totals.moves_ok);
    totals.mean_response_bytes =
        static_cast<double>(response_bytes) / static_cast<double>(totals.moves_ok);
  }
  if (totals.watcher_deltas > 0) {
    totals.mean_watcher_delta_bytes =
        static_cast<double>(delta_bytes) / static_cast<double>(totals.watcher_deltas);
  }
  return totals;
}

std::string summary_text(const RunResult& run, const Aggregate& t) {
  const Options& o = run.options;
  std::ostringstream out;
  out << "meshdeform-loadtest: " << title(run) << "\n";
  out << "  target      " << o.server << ", " << connections_label(o) << ", duration "
      << format("%g", o.duration_seconds) << " s, moves/session " << moves_label(o)
      << ", move deadline " << o.move_deadline_ms << " ms\n";
  out << "  setup       " << t.sessions_set_up << "/" << t.sessions << " sessions set up ("
      << t.vertices << " vertices each) in " << format("%.2f", run.setup_phase_seconds)
      << " s; create + set handles p50 " << ms_text(t.setup_ms.p50) << " ms, max "
      << ms_text(t.setup_ms.max) << " ms";
  if (!t.setup_failures.empty()) out << "; failures: " << count_list(t.setup_failures);
  out << "\n";
  out << "  moves       " << t.moves_ok << " ok, " << t.moves_failed << " failed in "
      << format("%.2f", run.move_phase_seconds) << " s: " << rate_text(t.moves_per_second)
      << " moves/s total, " << rate_text(t.moves_per_second_session.mean.value_or(0.0))
      << "/s per session (min " << rate_text(t.moves_per_second_session.min.value_or(0.0))
      << ", max " << rate_text(t.moves_per_second_session.max.value_or(0.0)) << ")\n";
  out << "  latency     p50 " << ms_text(t.latency_ms.p50) << " ms, p95 "
      << ms_text(t.latency_ms.p95) << " ms, p99 " << ms_text(t.latency_ms.p99) << " ms, max "
      << ms_text(t.latency_ms.max) << " ms (OK moves, send to response); server solve p50 "
      << ms_text(t.solve_ms.p50) << " ms, p99 " << ms_text(t.solve_ms.p99)
      << " ms; server queue p50 " << ms_text(t.queue_ms.p50) << " ms, p99 "
      << ms_text(t.queue_ms.p99) << " ms\n";
  if (o.rate_hz > 0.0) {
    out << "  ticks       " << t.ticks << " ticks, " << t.skipped_ticks
        << " skipped (previous move still in flight; one move in flight per session)\n";
  }
  out << "  errors      " << error_list(t) << "\n";
  for (const auto& [code, message] : t.first_error) {
    out << "              first " << code << ": " << message << "\n";
  }
  out << "  refinement  " << t.revision_gaps
      << " revisions committed between the editors' own moves (background refinement)\n";
  if (t.watchers > 0) {
    out << "  watchers    " << t.watchers << " streams (" << t.watchers_with_join_snapshot
        << " with join snapshot), " << t.watcher_updates << " updates ("
        << rate_text(t.watcher_updates_per_second) << "/s total, "
        << rate_text(t.watcher_updates_per_second_each) << "/s each), " << t.watcher_snapshots
        << " snapshots, " << t.watcher_refinements << " refinements, "
        << t.watcher_skipped_revisions << " skipped revisions\n";
    if (o.settle_seconds > 0) {
      out << "  settle      converged revision seen by " << t.sessions_settled << " of "
          << t.sessions << " sessions (p50 " << ms_text(t.settle_ms.p50)
          << " ms after the last move's response); settled by " << t.sessions_with_settled
          << " (p50 " << ms_text(t.settled_ms.p50) << " ms, " << t.settled_lossless
          << " lossless); " << t.watcher_lossless_updates << " lossless updates\n";
    }
    out << "  propagation after the move response: p50 " << ms_text(t.watcher_delay_ms.p50)
        << " ms, p95 " << ms_text(t.watcher_delay_ms.p95) << " ms, p99 "
        << ms_text(t.watcher_delay_ms.p99) << " ms, max " << ms_text(t.watcher_delay_ms.max)
        << " ms (" << t.watcher_delay_ms.count << " revisions, " << t.watcher_seen_before_response
        << " seen before the response)\n";
    out << "  propagation after the move was sent: p50 "
        << ms_text(t.watcher_delay_after_send_ms.p50) << " ms, p99 "
        << ms_text(t.watcher_delay_after_send_ms.p99) << " ms, max "
        << ms_text(t.watcher_delay_after_send_ms.max)
        << " ms; streams ended: " << count_list(t.watcher_end_status) << "\n";
  }
  out << "  server      resident " << resident_text(run.stats_before) << " before, "
      << resident_text(run.stats_loaded) << " loaded, " << resident_text(run.stats_after_close)
      << " after close";
  if (run.stats_loaded.is_available) {
    const ServerStatsSample& s = run.stats_loaded;
    out << "; loaded: " << s.sessions << " sessions, " << s.moves_committed << " moves committed, "
        << s.refinements_committed << " refinements, " << s.deformer_constructions
        << " factorizations, " << s.moves_cancelled << " cancelled, " << s.workers << " workers";
  }
  out << "\n";
  out << "  closed      " << count_list(t.close_status) << "; total "
      << format("%.2f", run.total_seconds) << " s\n";
  return out.str();
}

std::string report_json(const RunResult& run, const Aggregate& t) {
  const Options& o = run.options;
  Json json;
  json["tool"] = "meshdeform-loadtest";
  json["format_version"] = 1;
  json["completed"] = run.completed;
  json["machine"] = Json{{"date_utc", run.machine.date_utc},
                         {"hardware_threads", run.machine.hardware_threads},
                         {"cpu_model", run.machine.cpu_model},
                         {"load_average_start", run.machine.load_average_start},
                         {"load_average_end", run.machine.load_average_end},
                         {"loadtest_build_type", run.machine.build_type}};
  json["config"] = Json{{"server", o.server},
                        {"sessions", o.sessions},
                        {"mesh", run.mesh_label},
                        {"mesh_source", o.mesh_path.empty() ? "sample" : "upload"},
                        {"moves_per_session", o.moves},
                        {"rate_hz", o.rate_hz},
                        {"duration_seconds", o.duration_seconds},
                        {"watchers_per_session", o.watchers},
                        {"max_iterations", o.iterations},
                        {"method", std::string(method_name(o.method))},
                        {"encoding", std::string(encoding_name(o.encoding))},
                        {"connections", o.channel_count()},
                        {"updates", std::string(updates_name(o.updates))},
                        {"tolerance", o.tolerance},
                        {"relative_tolerance", o.relative_tolerance},
                        {"max_update_bytes", o.max_update_bytes},
                        {"via_link", o.via_link},
                        {"fixed_receive_window", o.fixed_receive_window},
                        {"send_on_response", o.send_on_response},
                        {"coarse_preview", o.coarse_preview},
                        {"settle_seconds", o.settle_seconds},
                        {"move_deadline_ms", o.move_deadline_ms},
                        {"one_move_in_flight", true}};
  if (run.link.used) {
    const LinkResult& l = run.link;
    json["link"] = Json{{"spec", l.spec},
                        {"description", l.description},
                        {"down_mbit", l.down_mbit},
                        {"up_mbit", l.up_mbit},
                        {"rtt_ms", l.rtt_ms},
                        {"jitter_ms", l.jitter_ms},
                        {"loss", l.loss},
                        {"queue_bytes_down", l.queue_bytes_down},
                        {"queue_bytes_up", l.queue_bytes_up},
                        {"connections", l.connections},
                        {"bytes_down", l.bytes_down},
                        {"bytes_up", l.bytes_up},
                        {"losses", l.losses},
                        {"full_queue_waits_down", l.full_queue_waits_down}};
  }
  json["phases"] = Json{{"setup_seconds", rounded(run.setup_phase_seconds)},
                        {"move_seconds", rounded(run.move_phase_seconds)},
                        {"total_seconds", rounded(run.total_seconds)}};
  Json failures = Json::object();
  for (const auto& [name, count] : t.setup_failures) failures[name] = count;
  json["setup"] = Json{{"sessions", t.sessions},
                       {"sessions_ok", t.sessions_set_up},
                       {"failures", failures},
                       {"vertices", t.vertices},
                       {"setup_ms", summary_json(t.setup_ms)},
                       {"create_ms", summary_json(t.create_ms)},
                       {"set_handles_ms", summary_json(t.set_handles_ms)}};
  Json errors = Json::object();
  for (const auto& [code, count] : t.errors_by_code) errors[code] = count;
  Json first_errors = Json::object();
  for (const auto& [code, message] : t.first_error) first_errors[code] = message;
  json["moves"] = Json{{"sent", t.moves_sent},
                       {"ok", t.moves_ok},
                       {"failed", t.moves_failed},
                       {"errors_by_code", errors},
                       {"first_error_by_code", first_errors},
                       {"ticks", t.ticks},
                       {"skipped_ticks", t.skipped_ticks},
                       {"per_second_total", rounded(t.moves_per_second)},
                       {"per_second_per_session", summary_json(t.moves_per_second_session)},
                       {"latency_ms", summary_json(t.latency_ms)},
                       {"server_solve_ms", summary_json(t.solve_ms)},
                       {"server_queue_ms", summary_json(t.queue_ms)},
                       {"mean_iterations", rounded(t.mean_iterations)},
                       {"mean_response_bytes", rounded(t.mean_response_bytes)},
                       {"converged", t.converged},
                       {"built_deformer", t.built_deformer},
                       {"revision_gaps", t.revision_gaps}};
  Json end_status = Json::object();
  for (const auto& [name, count] : t.watcher_end_status) end_status[name] = count;
  json["settle"] = Json{{"seconds", o.settle_seconds},
                        {"sessions_settled", t.sessions_settled},
                        {"ms_after_last_response", summary_json(t.settle_ms)},
                        {"sessions_with_settled_revision", t.sessions_with_settled},
                        {"settled_ms_after_last_response", summary_json(t.settled_ms)},
                        {"settled_lossless", t.settled_lossless}};
  json["watchers"] =
      Json{{"streams", t.watchers},
           {"with_join_snapshot", t.watchers_with_join_snapshot},
           {"updates", t.watcher_updates},
           {"snapshots", t.watcher_snapshots},
           {"mean_delta_bytes", rounded(t.mean_watcher_delta_bytes)},
           {"deltas", t.watcher_deltas},
           {"refinements", t.watcher_refinements},
           {"lossless_updates", t.watcher_lossless_updates},
           {"skipped_revisions", t.watcher_skipped_revisions},
           {"updates_per_second_total", rounded(t.watcher_updates_per_second)},
           {"updates_per_second_per_watcher", rounded(t.watcher_updates_per_second_each)},
           {"propagation_delay_ms", summary_json(t.watcher_delay_ms)},
           {"seen_before_response", t.watcher_seen_before_response},
           {"delay_after_send_ms", summary_json(t.watcher_delay_after_send_ms)},
           {"join_ms", summary_json(t.watcher_join_ms)},
           {"end_status", end_status},
           {"link_sized",
            Json{{"revision_updates", t.watcher_revision_updates},
                 {"revision_updates_per_second_per_watcher",
                  rounded(t.watcher_revision_updates_per_second_each)},
                 {"continuations", t.watcher_continuations},
                 {"complete_updates", t.watcher_complete_updates},
                 {"decode_failures", t.watcher_decode_failures},
                 {"join_bytes_mean", rounded(t.watcher_join_bytes)},
                 {"update_bytes", summary_json(t.watcher_update_bytes)},
                 {"max_error", summary_json(t.watcher_max_error)},
                 {"decode_ms", summary_json(t.watcher_decode_ms)},
                 {"applied_after_send_ms", summary_json(t.watcher_applied_after_send_ms)}}},
           {"coarse_preview",
            Json{{"updates", t.watcher_coarse_updates},
                 {"malformed", t.watcher_coarse_malformed},
                 {"coarse_bytes", summary_json(t.watcher_coarse_bytes)}}}};
  json["server"] = Json{{"stats_available", run.stats_loaded.is_available},
                        {"resident_bytes_before", resident_json(run.stats_before)},
                        {"resident_bytes_loaded", resident_json(run.stats_loaded)},
                        {"resident_bytes_after_close", resident_json(run.stats_after_close)},
                        {"before", stats_json(run.stats_before)},
                        {"loaded", stats_json(run.stats_loaded)},
                        {"after_close", stats_json(run.stats_after_close)}};
  Json sessions = Json::array();
  for (const SessionResult& s : run.sessions) {
    Json session_errors = Json::object();
    for (const auto& [code, count] : s.errors_by_code) session_errors[code] = count;
    Json watchers = Json::array();
    for (const WatcherResult& w : s.watchers) {
      watchers.push_back(
          Json{{"index", w.index},
               {"join_snapshot", w.has_join_snapshot},
               {"join_ms", rounded(w.join_ms)},
               {"updates", w.updates},
               {"snapshots", w.snapshots},
               {"deltas", w.deltas},
               {"refinements", w.refinements},
               {"skipped_revisions", w.skipped_revisions},
               {"last_revision", w.last_revision},
               {"last_e_theta", w.last_e_theta},
               {"last_e_phi", w.last_e_phi},
               {"propagation_delay_ms", summary_json(summarize(w.delays_ms))},
               {"seen_before_response", w.seen_before_response},
               {"delay_after_send_ms", summary_json(summarize(w.delays_after_send_ms))},
               {"end_status", w.end_status},
               {"end_message", w.end_message}});
    }
    const double phase = run.move_phase_seconds;
    sessions.push_back(Json{
        {"index", s.index},
        {"channel", s.channel},
        {"set_up", s.is_set_up},
        {"setup_status", s.setup_status},
        {"setup_error", s.setup_error},
        {"create_ms", rounded(s.create_ms)},
        {"set_handles_ms", rounded(s.set_handles_ms)},
        {"vertices", s.vertices},
        {"faces", s.faces},
        {"fixed_vertices", s.fixed_vertices},
        {"handle_vertices", s.handle_vertices},
        {"ticks", s.ticks},
        {"skipped_ticks", s.skipped_ticks},
        {"sent_on_response", s.sent_on_response},
        {"moves_sent", s.moves_sent},
        {"moves_ok", s.moves_ok},
        {"errors_by_code", session_errors},
        {"moves_per_second", rounded(phase > 0.0 ? static_cast<double>(s.moves_ok) / phase : 0.0)},
        {"latency_ms", summary_json(summarize(s.latencies_ms))},
        {"server_solve_ms", summary_json(summarize(s.solve_ms))},
        {"server_queue_ms", summary_json(summarize(s.queue_ms))},
        {"revision_gaps", s.revision_gaps},
        {"last_revision", s.last_revision},
        {"close_status", s.close_status},
        {"settle_ms", s.settle_ms ? Json(rounded(*s.settle_ms)) : Json(nullptr)},
        {"settled_ms", s.settled_ms ? Json(rounded(*s.settled_ms)) : Json(nullptr)},
        {"settled_lossless", s.settled_lossless},
        {"watchers", watchers}});
  }
  json["sessions"] = sessions;
  return json.dump(2) + "\n";
}

std::string report_markdown(const RunResult& run, const Aggregate& t) {
  const Options& o = run.options;
  const MachineFacts& m = run.machine;
  std::ostringstream out;
  out << "# Load test: " << title(run) << "\n\n";
  out << "- date: " << m.date_utc << "\n";
  out << "- machine: nproc " << m.hardware_threads << ", CPU " << m.cpu_model
      << "; load average (1/5/15 min) " << m.load_average_start << " at start, "
      << m.load_average_end << " at end\n";
  out << "- load tester: meshdeform-loadtest (" << m.build_type
      << "), generated gRPC stubs, synchronous API, one thread per session and per watcher, "
         "on the same machine as the server\n";
  out << "- target: " << o.server << "; " << connections_label(o) << " (gRPC channels)\n";
  out << "- sessions: " << o.sessions << " x " << run.mesh_label << " (" << t.vertices
      << " vertices), method " << method_name(o.method) << ", max_iterations " << o.iterations
      << "\n";
  out << "- drag: moves per session " << moves_label(o) << ", " << rate_label(o)
      << "; one move in flight per session (a tick that comes while the previous move is in "
         "flight is skipped and the next move aims at the newest target"
      << (o.send_on_response ? ", sent as soon as the response arrives (--send-on-response)"
                             : "")
      << "); move deadline " << o.move_deadline_ms << " ms\n";
  out << "- watchers: " << o.watchers << " per session (view token)"
      << (o.coarse_preview ? "; they ask for the coarse level of multiresolution moves "
                             "(--coarse-preview: WatchRequest.coarse_preview, float32 positions "
                             "beside the full ones)"
                           : "")
      << "\n";
  if (run.link.used) {
    out << "- link (--via-link " << run.link.spec << "): " << run.link.description
        << "; each gRPC channel its own line through the emulator (linkemu); carried "
        << mib_text(run.link.bytes_down) << " down, " << mib_text(run.link.bytes_up) << " up, "
        << run.link.losses << " losses; receive window "
        << (o.fixed_receive_window ? "fixed 64 KiB" : "adaptive (BDP probing)") << "\n";
  }
  if (o.updates != Updates::Off) {
    out << "- updates: " << updates_name(o.updates) << " (link-sized Watch updates); tolerance "
        << (o.tolerance > 0 ? format("%g", o.tolerance) + " model units"
                            : format("%g", o.relative_tolerance > 0 ? o.relative_tolerance : 1e-4) +
                                  " of the bounding-box diagonal")
        << ", budget " << (o.max_update_bytes > 0 ? std::to_string(o.max_update_bytes) + " bytes"
                                                  : std::string("none"))
        << " per update; moves ask for no positions (omit_positions)\n";
  }
  out << "- duration: " << format("%g", o.duration_seconds) << " s bound; setup "
      << format("%.2f", run.setup_phase_seconds) << " s, measured move phase "
      << format("%.2f", run.move_phase_seconds) << " s, total " << format("%.2f", run.total_seconds)
      << " s\n\n";

  out << "## Results\n\n";
  out << "| metric | value |\n|---|---:|\n";
  out << "| sessions set up | " << t.sessions_set_up << " / " << t.sessions << " |\n";
  out << "| moves OK | " << t.moves_ok << " |\n";
  out << "| moves failed | " << t.moves_failed << " |\n";
  out << "| moves/s, total | " << rate_text(t.moves_per_second) << " |\n";
  out << "| moves/s per session, mean (min, max) | "
      << rate_text(t.moves_per_second_session.mean.value_or(0.0)) << " ("
      << rate_text(t.moves_per_second_session.min.value_or(0.0)) << ", "
      << rate_text(t.moves_per_second_session.max.value_or(0.0)) << ") |\n";
  if (o.rate_hz > 0.0) {
    out << "| ticks / skipped ticks | " << t.ticks << " / " << t.skipped_ticks << " |\n";
  }
  out << "| mean outer iterations per move | " << format("%.2f", t.mean_iterations) << " |\n";
  out << "| positions encoding | " << encoding_name(o.encoding) << " |\n";
  out << "| mean bytes per move response | " << format("%.0f", t.mean_response_bytes) << " |\n";
  out << "| revisions between own moves (refinement) | " << t.revision_gaps << " |\n";
  if (o.settle_seconds > 0) {
    out << "| converged revision seen after the last move's response (--settle-seconds "
        << format("%g", o.settle_seconds) << "): sessions, p50 / max ms | "
        << t.sessions_settled << " of " << t.sessions << ", " << ms_text(t.settle_ms.p50)
        << " / " << ms_text(t.settle_ms.max) << " |\n";
    out << "| settled revision seen (no refinement follows; lossless with --lossless-settled): "
           "sessions, lossless, p50 / max ms | "
        << t.sessions_with_settled << " of " << t.sessions << ", " << t.settled_lossless << ", "
        << ms_text(t.settled_ms.p50) << " / " << ms_text(t.settled_ms.max) << " |\n";
  }
  if (t.watchers > 0) {
    out << "| watcher streams (with join snapshot) | " << t.watchers << " ("
        << t.watchers_with_join_snapshot << ") |\n";
    out << "| watcher updates (snapshots, refinements) | " << t.watcher_updates << " ("
        << t.watcher_snapshots << ", " << t.watcher_refinements << ") |\n";
    out << "| watcher updates/s, total (per watcher) | " << rate_text(t.watcher_updates_per_second)
        << " (" << rate_text(t.watcher_updates_per_second_each) << ") |\n";
    out << "| watcher skipped revisions | " << t.watcher_skipped_revisions << " |\n";
    out << "| mean bytes per watcher delta update | "
        << format("%.0f", t.mean_watcher_delta_bytes) << " |\n";
  }
  if (o.updates != Updates::Off && t.watchers > 0) {
    out << "| link-sized: newer revisions applied per second, per watcher | "
        << rate_text(t.watcher_revision_updates_per_second_each) << " |\n";
    out << "| link-sized: updates (newer revision / continuation / complete) | "
        << t.watcher_revision_updates << " / " << t.watcher_continuations << " / "
        << t.watcher_complete_updates << " |\n";
    out << "| link-sized: bytes per update p50 / p95 / max | "
        << format("%.0f", t.watcher_update_bytes.p50.value_or(0)) << " / "
        << format("%.0f", t.watcher_update_bytes.p95.value_or(0)) << " / "
        << format("%.0f", t.watcher_update_bytes.max.value_or(0)) << " |\n";
    out << "| link-sized: join update bytes (mean) | " << format("%.0f", t.watcher_join_bytes)
        << " |\n";
    out << "| link-sized: max error after an update p50 / max (model units) | "
        << format("%.3g", t.watcher_max_error.p50.value_or(0)) << " / "
        << format("%.3g", t.watcher_max_error.max.value_or(0)) << " |\n";
    out << "| link-sized: client decode ms p50 / max | " << ms_text(t.watcher_decode_ms.p50)
        << " / " << ms_text(t.watcher_decode_ms.max) << " |\n";
    out << "| link-sized: decode failures | " << t.watcher_decode_failures << " |\n";
  }
  if (o.coarse_preview && t.watchers > 0) {
    out << "| coarse preview: updates with a coarse level (malformed) | "
        << t.watcher_coarse_updates << " (" << t.watcher_coarse_malformed << ") |\n";
    out << "| coarse preview: coarse bytes per update p50 / max | "
        << format("%.0f", t.watcher_coarse_bytes.p50.value_or(0)) << " / "
        << format("%.0f", t.watcher_coarse_bytes.max.value_or(0)) << " |\n";
  }
  out << "\n## Latency (ms)\n\n";
  out << "| | count | p50 | p95 | p99 | max |\n|---|---:|---:|---:|---:|---:|\n";
  const auto row = [&](const std::string& name, const Summary& s) {
    out << "| " << name << " | " << s.count << " | " << ms_text(s.p50) << " | " << ms_text(s.p95)
        << " | " << ms_text(s.p99) << " | " << ms_text(s.max) << " |\n";
  };
  row("move, client side (OK moves, send to response)", t.latency_ms);
  row("move, server solve_seconds", t.solve_ms);
  row("move, server queue_seconds (arrival to solve)", t.queue_ms);
  if (t.watchers > 0) {
    row("watcher receipt after the move response", t.watcher_delay_ms);
    row("watcher receipt after the move was sent", t.watcher_delay_after_send_ms);
    if (o.updates != Updates::Off) {
      row("move sent to an update at or past it applied (every move)",
          t.watcher_applied_after_send_ms);
    }
  }
  row("setup: create + set handles", t.setup_ms);
  out << "\n## Errors\n\n";
  if (t.errors_by_code.empty() && t.setup_failures.empty()) {
    out << "None.\n";
  } else {
    out << "| status | count | first message |\n|---|---:|---|\n";
    for (const auto& [code, count] : t.errors_by_code) {
      const auto found = t.first_error.find(code);
      out << "| move " << code << " | " << count << " | "
          << (found == t.first_error.end() ? "" : found->second) << " |\n";
    }
    for (const auto& [name, count] : t.setup_failures) {
      out << "| setup " << name << " | " << count << " | |\n";
    }
  }
  out << "\n## Server (GetServerStats)\n\n";
  if (!run.stats_before.is_available && !run.stats_loaded.is_available) {
    out << "Unavailable (" << run.stats_loaded.status << "): memory unknown.\n";
  } else {
    out << "| | before | loaded | after close |\n|---|---:|---:|---:|\n";
    const auto stat_row = [&](const std::string& name, auto field) {
      out << "| " << name;
      for (const ServerStatsSample* s :
           {&run.stats_before, &run.stats_loaded, &run.stats_after_close}) {
        out << " | " << (s->is_available ? field(*s) : std::string("n/a"));
      }
      out << " |\n";
    };
    stat_row("resident", [](const ServerStatsSample& s) {
      return s.resident_bytes == 0 ? std::string("unknown") : mib_text(s.resident_bytes);
    });
    stat_row("estimated (budget)",
             [](const ServerStatsSample& s) { return mib_text(s.estimated_bytes); });
    stat_row("sessions", [](const ServerStatsSample& s) { return std::to_string(s.sessions); });
    stat_row("moves committed",
             [](const ServerStatsSample& s) { return std::to_string(s.moves_committed); });
    stat_row("moves cancelled",
             [](const ServerStatsSample& s) { return std::to_string(s.moves_cancelled); });
    stat_row("refinements committed",
             [](const ServerStatsSample& s) { return std::to_string(s.refinements_committed); });
    stat_row("factorizations",
             [](const ServerStatsSample& s) { return std::to_string(s.deformer_constructions); });
    stat_row("workers", [](const ServerStatsSample& s) { return std::to_string(s.workers); });
  }
  out << "\n## Per session\n\n";
  out << "| session | setup ms | moves OK | failed | skipped ticks | moves/s | p50 ms | p99 ms | "
         "max ms | watcher updates | refinements seen |\n"
         "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const SessionResult& s : run.sessions) {
    std::int64_t failed = 0;
    for (const auto& [code, count] : s.errors_by_code) failed += count;
    std::int64_t updates = 0, refinements = 0;
    for (const WatcherResult& w : s.watchers) {
      updates += w.updates;
      refinements += w.refinements;
    }
    const Summary latency = summarize(s.latencies_ms);
    const double phase = run.move_phase_seconds;
    out << "| " << s.index << " | "
        << (s.is_set_up ? ms_text(s.create_ms + s.set_handles_ms) : s.setup_status) << " | "
        << s.moves_ok << " | " << failed << " | " << s.skipped_ticks << " | "
        << rate_text(phase > 0.0 ? static_cast<double>(s.moves_ok) / phase : 0.0) << " | "
        << ms_text(latency.p50) << " | " << ms_text(latency.p99) << " | " << ms_text(latency.max)
        << " | " << updates << " | " << refinements << " |\n";
  }
  out << "\nLatency is client side, from sending MoveHandles to its response, over OK moves "
         "only. The server's queue_seconds is a move's wait from its arrival to the start of "
         "its solve (earlier edits of the session, then a free worker), solve_seconds the solve "
         "itself. Propagation is a watcher's receipt of a revision minus the editor's receipt of "
         "the response that committed it (same process, steady clock; negative when the "
         "watcher was first), and the same receipt minus the time the move was sent. "
         "Refinement revisions have no move and are only counted. Watcher updates/s exclude the "
         "join snapshots. Percentiles are "
         "nearest-rank.\n";
  return out.str();
}

}  // namespace meshdeform::loadtest
