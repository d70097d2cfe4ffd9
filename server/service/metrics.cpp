#include "server/service/metrics.h"

#include <cmath>
#include <cstdio>
#include <memory>
#include <tuple>


namespace meshdeform::service {
namespace {

std::string number(double value) {
  if (std::isinf(value)) return value > 0 ? "+Inf" : "-Inf";
  if (std::isnan(value)) return "NaN";
  char buffer[40];
  std::snprintf(buffer, sizeof buffer, "%.9g", value);
  return buffer;
}

/// Label values: backslash, quote and newline escaped (exposition format).
std::string label_value(std::string_view text) {
  std::string out;
  for (const char c : text) {
    if (c == '\\') out += "\\\\";
    else if (c == '"') out += "\\\"";
    else if (c == '\n') out += "\\n";
    else out += c;
  }
  return out;
}

void header(std::string& out, std::string_view name, std::string_view type, std::string_view help) {
  out += "# HELP ";
  out += name;
  out += ' ';
  out += help;
  out += "\n# TYPE ";
  out += name;
  out += ' ';
  out += type;
  out += '\n';
}

void sample(std::string& out, std::string_view name, double value, std::string_view labels = {}) {
  out += name;
  if (!labels.empty()) {
    out += '{';
    out += labels;
    out += '}';
  }
  out += ' ';
  out += number(value);
  out += '\n';
}

}  // namespace

const std::vector<double>& Histogram::latency_bounds() {
  static const std::vector<double> bounds = {0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1,
                                             0.25,  0.5,    1.0,   2.5,  5.0,   10.0};
  return bounds;
}

Histogram::Histogram(std::vector<double> bounds)
    : bounds_(std::move(bounds)), counts_(bounds_.size() + 1, 0) {}

void Histogram::observe(double value) {
  if (!std::isfinite(value)) return;
  std::size_t bucket = 0;
  while (bucket < bounds_.size() && value > bounds_[bucket]) ++bucket;
  const std::lock_guard lock(mutex_);
  ++counts_[bucket];
  sum_ += value;
  ++count_;
}

std::uint64_t Histogram::count() const {
  const std::lock_guard lock(mutex_);
  return count_;
}

void Histogram::render(std::string_view name, std::string_view labels, std::string& out) const {
  const std::lock_guard lock(mutex_);
  const std::string prefix = labels.empty() ? std::string() : std::string(labels) + ",";
  std::uint64_t cumulative = 0;
  for (std::size_t b = 0; b <= bounds_.size(); ++b) {
    cumulative += counts_[b];
    const std::string le = b < bounds_.size() ? number(bounds_[b]) : "+Inf";
    sample(out, std::string(name) + "_bucket", static_cast<double>(cumulative),
           prefix + "le=\"" + le + "\"");
  }
  sample(out, std::string(name) + "_sum", sum_, labels);
  sample(out, std::string(name) + "_count", static_cast<double>(count_), labels);
}

void MetricsRegistry::record_rpc(std::string_view frontend, std::string_view method,
                                 std::string_view code, double seconds) {
  Histogram* histogram = nullptr;
  {
    const std::lock_guard lock(mutex_);
    ++rpc_counts_[{std::string(frontend), std::string(method), std::string(code)}];
    std::unique_ptr<Histogram>& h = rpc_latency_[{std::string(frontend), std::string(method)}];
    if (!h) h = std::make_unique<Histogram>();
    histogram = h.get();  // entries are never erased
  }
  histogram->observe(seconds);
}

void MetricsRegistry::record_solve(bool refinement, double seconds) {
  (refinement ? refinement_solve_ : move_solve_).observe(seconds);
}

void MetricsRegistry::record_move_queue_wait(double seconds) { move_queue_wait_.observe(seconds); }

std::string MetricsRegistry::render(const ServiceStats& stats) const {
  std::string out;
  header(out, "meshdeform_rpc_requests_total", "counter", "Finished calls by front end, method and status code.");
  {
    const std::lock_guard lock(mutex_);
    for (const auto& [key, count] : rpc_counts_) {
      const auto& [frontend, method, code] = key;
      sample(out, "meshdeform_rpc_requests_total", static_cast<double>(count),
             "frontend=\"" + label_value(frontend) + "\",method=\"" + label_value(method) +
                 "\",code=\"" + label_value(code) + "\"");
    }
    header(out, "meshdeform_rpc_latency_seconds", "histogram",
           "Wall time from a call's arrival to its status, by front end and method.");
    for (const auto& [key, histogram] : rpc_latency_) {
      histogram->render("meshdeform_rpc_latency_seconds",
                        "frontend=\"" + label_value(key.first) + "\",method=\"" +
                            label_value(key.second) + "\"",
                        out);
    }
  }
  header(out, "meshdeform_solve_seconds", "histogram",
         "Solver wall time of committed revisions (kind: move or refinement).");
  move_solve_.render("meshdeform_solve_seconds", "kind=\"move\"", out);
  refinement_solve_.render("meshdeform_solve_seconds", "kind=\"refinement\"", out);
  header(out, "meshdeform_move_queue_seconds", "histogram",
         "Wait of each move on the server before its solve began: the session's earlier edits, "
         "then a free worker.");
  move_queue_wait_.render("meshdeform_move_queue_seconds", "", out);

  auto gauge = [&](std::string_view name, std::string_view help, double value) {
    header(out, name, "gauge", help);
    sample(out, name, value);
  };
  auto counter = [&](std::string_view name, std::string_view help, double value) {
    header(out, name, "counter", help);
    sample(out, name, value);
  };
  gauge("meshdeform_sessions", "Open sessions.", static_cast<double>(stats.sessions));
  gauge("meshdeform_watchers", "Open Watch subscriptions.", static_cast<double>(stats.watchers));
  gauge("meshdeform_session_estimated_bytes", "What the memory budget charges all sessions.",
        static_cast<double>(stats.estimated_bytes));
  gauge("process_resident_memory_bytes", "Resident memory size in bytes.",
        static_cast<double>(stats.resident_bytes));
  gauge("meshdeform_workers", "Solver worker threads.", static_cast<double>(stats.workers));
  counter("meshdeform_factorizations_total",
          "Deformers built (sparse factorizations per method and handle set).",
          static_cast<double>(stats.deformer_constructions));
  counter("meshdeform_moves_committed_total", "Moves committed as revisions.",
          static_cast<double>(stats.moves_committed));
  counter("meshdeform_moves_cancelled_total", "Moves stopped by cancellation or deadline.",
          static_cast<double>(stats.moves_cancelled));
  counter("meshdeform_refinements_committed_total",
          "Revisions committed by background refinement.",
          static_cast<double>(stats.refinements_committed));
  counter("meshdeform_refinements_preempted_total",
          "Refinement slices stopped because an edit arrived.",
          static_cast<double>(stats.refinements_preempted));
  counter("meshdeform_background_builds_installed_total",
          "Full-resolution solvers of multiresolution sessions built off the strand and installed.",
          static_cast<double>(stats.background_builds_installed));
  counter("meshdeform_pcg_iterations_total", "Conjugate-gradient iterations of step two.",
          static_cast<double>(stats.pcg_iterations));
  counter("meshdeform_outer_iterations_total", "Outer (local/global) iterations of all solves.",
          static_cast<double>(stats.outer_iterations));
  header(out, "meshdeform_sessions_evicted_total", "counter", "Sessions evicted, by reason.");
  sample(out, "meshdeform_sessions_evicted_total", static_cast<double>(stats.evicted_lru),
         "reason=\"memory_budget\"");
  sample(out, "meshdeform_sessions_evicted_total", static_cast<double>(stats.evicted_idle),
         "reason=\"idle_ttl\"");
  counter("meshdeform_state_write_failures_total",
          "Session state writes that failed (state directory or shared store): each failed the "
          "edit it was for, which was not acknowledged.",
          static_cast<double>(stats.persist_failures));
  gauge("meshdeform_solves_running", "Moves and refinement slices solving now.",
        static_cast<double>(stats.solves_running));
  counter("meshdeform_yielded_tasks_total",
          "Short moves run by a long solve between two of its iterations (solver time shared "
          "between sessions).",
          static_cast<double>(stats.yielded_tasks));
  counter("meshdeform_stale_copies_dropped_total",
          "Cached sessions dropped because another replica changed their state file.",
          static_cast<double>(stats.stale_copies_dropped));
  header(out, "meshdeform_rate_limited_total", "counter",
         "Calls refused by the per-client rate limits, by call.");
  sample(out, "meshdeform_rate_limited_total", static_cast<double>(stats.rate_limited_creates),
         "call=\"CreateSession\"");
  sample(out, "meshdeform_rate_limited_total", static_cast<double>(stats.rate_limited_moves),
         "call=\"MoveHandles\"");
  header(out, "meshdeform_queue_depth", "gauge", "Worker-pool tasks waiting, by class.");
  sample(out, "meshdeform_queue_depth", static_cast<double>(stats.queued_normal),
         "class=\"normal\"");
  sample(out, "meshdeform_queue_depth", static_cast<double>(stats.queued_heavy),
         "class=\"heavy\"");
  sample(out, "meshdeform_queue_depth", static_cast<double>(stats.queued_background),
         "class=\"background\"");
  gauge("meshdeform_heavy_work_admitted",
        "Uploads and SetHandles precomputes admitted now (queued or running).",
        static_cast<double>(stats.heavy_admitted));
  gauge("meshdeform_heavy_work_running", "Uploads and SetHandles precomputes running now.",
        static_cast<double>(stats.heavy_running));
  counter("meshdeform_heavy_work_rejected_total",
          "Uploads and SetHandles refused by admission control (per client or in total).",
          static_cast<double>(stats.heavy_rejected));
  header(out, "meshdeform_work_cancelled_total", "counter",
         "Heavy work stopped mid-way by its call's deadline or cancellation, by kind.");
  sample(out, "meshdeform_work_cancelled_total", static_cast<double>(stats.uploads_cancelled),
         "kind=\"upload\"");
  sample(out, "meshdeform_work_cancelled_total", static_cast<double>(stats.precomputes_cancelled),
         "kind=\"precompute\"");
  std::vector<std::function<void(std::string&)>> sections;
  {
    std::lock_guard lock(mutex_);
    sections = sections_;
  }
  for (const auto& section : sections) section(out);
  return out;
}

void MetricsRegistry::add_section(std::function<void(std::string& out)> render) {
  std::lock_guard lock(mutex_);
  sections_.push_back(std::move(render));
}

}  // namespace meshdeform::service
