// meshdeform-bench-realistic (issue 13): the solvers on input that looks like real meshes, side
// by side with CGAL's ARAP in one run. Models: irregular variants of the Table 1 suite
// (core::make_irregular_suite) and Spot Loop-subdivided to ~47k / 187k / 750k vertices with
// bounding-box edits (core::make_spot_edit). Each method runs in its own forked child process, so
// its peak resident set is its own; timings are medians over --repeat rounds, interleaved (ours,
// CGAL, ours, CGAL...) so that load on the shared machine hits every method alike.
// Writes a Markdown report (stdout and <out-dir>/realistic.md), <out-dir>/realistic.json and a
// log-log plot <out-dir>/realistic_scaling.svg.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bench/bench_config.h"
#include "bench/cgal_arap.h"
#include "bench/bench_args.h"
#include "bench/bench_edits.h"
#include "bench/bench_process.h"
#include "bench/machine_info.h"
#include "core/methods/arap.h"
#include "core/methods/deform_types.h"
#include "core/methods/deformer.h"
#include "core/io/mesh_io.h"
#include "core/mesh/measures.h"
#include "core/samples/generators.h"
#include "core/methods/scale_aware.h"
#include "core/base/status.h"
#include "core/mesh/topology.h"

namespace meshdeform::bench {
namespace {

using nlohmann::json;

// Issue 13's targets: ours per outer iteration, precompute and peak memory against CGAL ARAP.
constexpr double kPerIterationRatioTarget = 1.5;
constexpr double kPrecomputeRatioTarget = 2.0;
constexpr double kMemoryRatioTarget = 2.0;

// ---- options ----------------------------------------------------------------------------------

struct Options {
  std::vector<std::string> models;  // empty: all
  long max_vertices = 1'000'000;
  std::vector<int> spot_levels = {2, 3, 4};
  std::vector<std::string> spot_edits = {"bend", "stretch", "twist"};  // all at the first level
  bool include_regular = false;
  int iterations = 15;
  int repeat = 3;
  long repeat_max_vertices = 200'000;  // larger models run one round (the 750k Spot: minutes)
  int anderson_window = 6;
  int cgal_max_iterations = 100;
  int threads = 1;
  // Start of the scale-aware runs: Auto (the default a user gets: converged ARAP at rigidity > 0,
  // or the Laplacian guess's or the paper start's result where that folds) or a named one
  // (--start laplacian: the paper's guess, as this bench ran before the rigid start became the
  // default).
  core::StartFrom start = core::StartFrom::Auto;
  std::uint64_t seed = 1;
  std::string out_dir = MESHDEFORM_BENCH_RESULTS_DIR;
  std::string stem = "realistic";
  std::string spot_path = std::string(MESHDEFORM_BENCH_SOURCE_DIR) + "/tests/data/spot.obj";
  std::vector<std::string> methods = {"scale_aware", "scale_aware_anderson",
                                      "scale_aware_threads", "arap", "arap_anderson", "cgal"};
};

void print_usage(std::ostream& out) {
  out << "usage: meshdeform-bench-realistic [options]\n"
         "  --models a,b          model names (default all; see the list printed on start)\n"
         "  --max-vertices N      skip models with more vertices (1000000)\n"
         "  --spot-levels a,b     Loop subdivision levels of Spot (2,3,4: ~47k, 187k, 750k)\n"
         "  --regular             also run the regular Table 1 models\n"
         "  --methods a,b         scale_aware, scale_aware_anderson, scale_aware_threads (the\n"
         "                        plain iteration on every core), arap, arap_anderson, cgal\n"
         "                        (default all)\n"
         "  --iterations N        outer-iteration budget of the timed runs (15)\n"
         "  --repeat N            rounds; timings are medians (3)\n"
         "  --repeat-max-vertices N  models above N vertices run one round (200000)\n"
         "  --anderson-window M   window of the accelerated runs, ARAP and scale-aware (6)\n"
         "  --cgal-max-iterations N  cap of the convergence runs (100)\n"
         "  --threads N           our solvers' OpenMP threads (1)\n"
         "  --start S             start of the scale-aware runs: auto (default, the library's)\n"
         "                        or laplacian, rigid, propagated\n"
         "  --seed S              irregular-mesh seed (1)\n"
         "  --out-dir DIR         (default "
      << MESHDEFORM_BENCH_RESULTS_DIR
      << ")\n"
         "  --stem NAME           output file stem (realistic)\n"
         "  --spot PATH           spot.obj (default tests/data/spot.obj)\n";
}

Result<Options> parse_options(int argc, char** argv) {
  Options o;
  BenchFlags flags;
  flags.list("--models", o.models);
  flags.integer("--max-vertices", o.max_vertices, 1L);
  flags.integer_list("--spot-levels", o.spot_levels, 0);
  flags.flag("--regular", [&] { o.include_regular = true; });
  flags.list("--methods", o.methods);
  flags.integer("--iterations", o.iterations, 1);
  flags.integer("--repeat", o.repeat, 1);
  flags.integer("--repeat-max-vertices", o.repeat_max_vertices, 1L);
  flags.integer("--anderson-window", o.anderson_window, 1);
  flags.integer("--cgal-max-iterations", o.cgal_max_iterations, 1);
  flags.integer("--threads", o.threads, 0);
  flags.value("--start", [&](const std::string& value) -> Status {
    MD_ASSIGN_OR_RETURN(o.start, core::parse_start(value));
    if (o.start == core::StartFrom::Previous) {
      return Error(ErrorCode::InvalidArgument, "--start previous has nothing to start from");
    }
    return Status::success();
  });
  flags.value("--seed", [&](const std::string& value) -> Status {
    MD_ASSIGN_OR_RETURN(const long seed, parse_integer<long>("--seed", value, 0));
    o.seed = static_cast<std::uint64_t>(seed);
    return Status::success();
  });
  flags.text("--out-dir", o.out_dir);
  flags.text("--stem", o.stem);
  flags.text("--spot", o.spot_path);
  MD_RETURN_IF_ERROR(flags.parse(argc, argv));
  for (const auto& m : o.methods) {
    if (m != "scale_aware" && m != "scale_aware_anderson" && m != "scale_aware_threads" &&
        m != "arap" && m != "arap_anderson" && m != "cgal") {
      return Error(ErrorCode::InvalidArgument, "unknown method '" + m + "'");
    }
  }
  return o;
}

struct Model {
  core::DeformationBenchmark bench;
  core::HandleSetup setup;
};

/// The peak of the timed part, read before the error metrics allocate their own measures.
long peak_now() { return peak_rss_kib(); }

json history_json(const std::vector<core::IterationInfo>& history) {
  json out = json::array();
  for (const auto& h : history) {
    out.push_back({{"energy", h.energy},
                   {"e_theta", h.e_theta},
                   {"e_phi", h.e_phi},
                   {"elapsed", h.elapsed_seconds},
                   {"pcg", h.pcg_iterations},
                   {"sweeps", h.normal_sweeps},
                   {"normals_s", h.normals_seconds},
                   {"assemble_s", h.assemble_seconds},
                   {"linear_s", h.linear_seconds}});
  }
  return out;
}

/// Both our solvers: create, a timed run without metrics (the timings), then reset and the same
/// run with metrics (per-iteration E_theta / E_phi; deterministic, so the same iterates), and for
/// ARAP a convergence run (tolerance 1e-4, the cap) timed the same way as CGAL's.
/// `threads` overrides --threads when > 0 (scale_aware_threads: every core).
template <typename Solver, typename Settings>
json run_ours(const Model& model, const Options& options, bool is_arap, int anderson_window,
              int threads = 0) {
  const Positions& V0 = model.bench.mesh.V;
  const Triangles& F = model.bench.mesh.F;
  Settings settings;
  settings.threads = threads > 0 ? threads : options.threads;
  json out;
  const auto start = std::chrono::steady_clock::now();
  auto created = Solver::create(V0, F, model.setup.constrained, settings);
  if (!created.ok()) throw std::runtime_error(created.status().to_string());
  Solver solver = std::move(created).value();
  if constexpr (requires { solver.prepare(core::SolveOptions{}.rigidity); }) {
    // Everything a default solve builds before its start: the scale term's system and the
    // preconditioner factor of the default rigidity (prepare), not only create().
    const Status prepared = solver.prepare(core::SolveOptions{}.rigidity);
    if (!prepared.ok()) throw std::runtime_error(prepared.to_string());
  }
  out["precompute_s"] = seconds_since(start);

  core::SolveOptions timed;
  timed.max_iterations = options.iterations;
  timed.track_metrics = false;
  timed.start = is_arap ? core::StartFrom::Laplacian : options.start;
  timed.anderson_window = anderson_window;
  if (is_arap) timed.tolerance = 0;  // exactly `iterations` iterations, like CGAL's fixed run
  auto report = solver.solve(model.setup.targets, timed);
  if (!report.ok()) throw std::runtime_error(report.status().to_string());
  out["peak_rss_kib"] = peak_now();
  out["solve_s"] = report->seconds;
  out["init_s"] = report->history.empty() ? 0.0 : report->history.front().elapsed_seconds;
  // The returned result's own iterations: when Auto ran two starts and kept the first, the
  // second's run comes after them and is neither start nor iteration time of the result.
  out["iterations_s"] = report->history.empty() ? 0.0
                                                : report->history.back().elapsed_seconds -
                                                      report->history.front().elapsed_seconds;
  out["start_used"] = core::start_name(report->start);
  out["start_candidates"] = report->start_candidates;
  out["iterations"] = report->iterations;
  out["converged"] = report->converged;
  out["pcg_iterations"] = report->pcg_iterations;
  out["factorizations"] = report->factorizations;
  out["history"] = history_json(report->history);
  const core::MeshTopology topology = core::build_topology(F, static_cast<int>(V0.rows())).value();
  const core::Measures rest = core::compute_measures(V0, F, topology);
  out["errors"] =
      errors_json(core::angle_errors(rest, core::compute_measures(report->V, F, topology)));

  core::SolveOptions converge = timed;
  if (is_arap) {
    converge.tolerance = 1e-4;
    converge.max_iterations = options.cgal_max_iterations;
    solver.reset();
    auto run = solver.solve(model.setup.targets, converge);
    if (!run.ok()) throw std::runtime_error(run.status().to_string());
    out["converge_s"] = run->seconds;
    out["converge_iterations"] = run->iterations;
    out["converge_history"] = history_json(run->history);
    out["converged_errors"] =
        errors_json(core::angle_errors(rest, core::compute_measures(run->V, F, topology)));
  }
  core::SolveOptions metrics = is_arap ? converge : timed;
  metrics.track_metrics = true;
  solver.reset();
  auto tracked = solver.solve(model.setup.targets, metrics);
  if (!tracked.ok()) throw std::runtime_error(tracked.status().to_string());
  out["metric_history"] = history_json(tracked->history);
  return out;
}

json run_cgal(const Model& model, const Options& options) {
  CgalArapOptions cgal;
  cgal.fixed_iterations = options.iterations;
  cgal.max_converge_iterations = options.cgal_max_iterations;
  cgal.run_convergence = true;
  auto result = run_cgal_arap(model.bench.mesh.V, model.bench.mesh.F, model.setup.constrained,
                              model.setup.targets, Positions(), cgal);
  if (!result.ok()) throw std::runtime_error(result.status().to_string());
  json out;
  out["peak_rss_kib"] = peak_now();
  out["precompute_s"] = result->preprocess_seconds;
  out["build_s"] = result->build_seconds;
  out["solve_s"] = result->fixed_seconds;
  out["iterations"] = result->fixed_iterations;
  out["converge_s"] = result->converge_seconds;
  out["converge_iterations"] = result->converge_iterations;
  const Positions& V0 = model.bench.mesh.V;
  const Triangles& F = model.bench.mesh.F;
  const core::MeshTopology topology = core::build_topology(F, static_cast<int>(V0.rows())).value();
  const core::Measures rest = core::compute_measures(V0, F, topology);
  out["errors"] =
      errors_json(core::angle_errors(rest, core::compute_measures(result->V_fixed, F, topology)));
  out["converged_errors"] = errors_json(
      core::angle_errors(rest, core::compute_measures(result->V_converged, F, topology)));
  return out;
}

// ---- aggregation ------------------------------------------------------------------------------

/// One method's figures over the rounds: medians of the timings, the first round's results
/// (identical across rounds: everything but the timings is deterministic).
struct MethodResult {
  std::string method;
  bool ok = false;
  std::string error;
  json first;
  double precompute_s = 0, per_iteration_s = 0, solve_s = 0, converge_s = 0;
  double peak_rss_mib = 0, baseline_rss_mib = 0;
  double pcg_per_iteration = 0, normals_ms = 0, assemble_ms = 0, linear_ms = 0;
  int iterations = 0, converge_iterations = 0;
  // Time to quality: first iterate with E_theta and E_phi both <= CGAL's converged ones.
  int quality_iteration = -1;
  double quality_s = -1;
  std::vector<double> precompute_all, per_iteration_all;
};

MethodResult aggregate(const std::string& method, const std::vector<json>& runs) {
  MethodResult r;
  r.method = method;
  if (runs.empty()) return r;
  r.ok = true;
  r.first = runs.front();
  std::vector<double> pre, per_it, solve, conv, rss, base, normals, assemble, linear;
  for (const json& run : runs) {
    const int its = run.value("iterations", 0);
    const double init = run.value("init_s", 0.0);
    pre.push_back(run.value("precompute_s", 0.0));
    solve.push_back(run.value("solve_s", 0.0));
    const double iterations_s = run.contains("iterations_s")
                                    ? run.value("iterations_s", 0.0)
                                    : run.value("solve_s", 0.0) - init;
    per_it.push_back(its > 0 ? iterations_s / its : 0.0);
    conv.push_back(run.value("converge_s", 0.0));
    rss.push_back(run.value("peak_rss_kib", 0L) / 1024.0);
    base.push_back(run.value("baseline_rss_kib", 0L) / 1024.0);
    if (run.contains("history") && its > 0) {
      double n = 0, a = 0, l = 0;
      for (size_t k = 1; k < run["history"].size(); ++k) {
        n += run["history"][k]["normals_s"].get<double>();
        a += run["history"][k]["assemble_s"].get<double>();
        l += run["history"][k]["linear_s"].get<double>();
      }
      normals.push_back(1e3 * n / its);
      assemble.push_back(1e3 * a / its);
      linear.push_back(1e3 * l / its);
    }
  }
  r.precompute_all = pre;
  r.per_iteration_all = per_it;
  r.precompute_s = median(pre);
  r.per_iteration_s = median(per_it);
  r.solve_s = median(solve);
  r.converge_s = median(conv);
  r.peak_rss_mib = median(rss);
  r.baseline_rss_mib = median(base);
  r.normals_ms = normals.empty() ? 0 : median(normals);
  r.assemble_ms = assemble.empty() ? 0 : median(assemble);
  r.linear_ms = linear.empty() ? 0 : median(linear);
  r.iterations = r.first.value("iterations", 0);
  r.converge_iterations = r.first.value("converge_iterations", 0);
  if (r.iterations > 0) {
    r.pcg_per_iteration = static_cast<double>(r.first.value("pcg_iterations", 0)) / r.iterations;
  }
  return r;
}

/// Fills quality_iteration / quality_s of an ours method against the bar: the metric run gives
/// the iteration, the timed run (same iterates, no metric cost) its median elapsed time.
void time_to_quality(MethodResult& r, const std::vector<json>& runs, double bar_theta,
                     double bar_phi) {
  if (!r.ok || !r.first.contains("metric_history")) return;
  const json& metric = r.first["metric_history"];
  int k = -1;
  for (size_t i = 0; i < metric.size(); ++i) {
    if (metric[i]["e_theta"].get<double>() <= bar_theta &&
        metric[i]["e_phi"].get<double>() <= bar_phi) {
      k = static_cast<int>(i);
      break;
    }
  }
  r.quality_iteration = k;
  if (k < 0) return;
  const char* timeline = r.first.contains("converge_history") ? "converge_history" : "history";
  std::vector<double> times;
  for (const json& run : runs) {
    if (run.contains(timeline) && static_cast<int>(run[timeline].size()) > k) {
      times.push_back(run[timeline][static_cast<size_t>(k)]["elapsed"].get<double>());
    }
  }
  r.quality_s = times.empty() ? -1 : median(times);
}

struct Row {
  std::string name;
  std::string family;  // "irregular", "spot", "regular"
  int vertices = 0, faces = 0, constrained = 0;
  std::map<std::string, MethodResult> methods;
  double bar_theta = -1, bar_phi = -1;
  std::string load_before, load_after;
  int rounds = 0;
  // Accelerated ARAP: iteration and time (median) at which it first reaches the energy plain ARAP
  // ended its convergence run with.
  int aa_equal_energy_iteration = -1;
  double aa_equal_energy_s = -1;
  // Accelerated scale-aware: iteration and time (median) at which it first reaches the energy of
  // the plain scale-aware timed run (the iteration budget).
  int sa_aa_equal_energy_iteration = -1;
  double sa_aa_equal_energy_s = -1;
};

// ---- models -----------------------------------------------------------------------------------

/// Generates the models lazily (the 750k Spot takes seconds and ~100 MB): name, vertex estimate
/// and a factory.
struct ModelSpec {
  std::string name, family;
  long vertices_estimate;
  std::function<Result<core::DeformationBenchmark>()> make;
};

Result<std::vector<ModelSpec>> model_specs(const Options& options) {
  std::vector<ModelSpec> specs;
  const auto regular = core::make_suite(core::SuiteScale::Paper);
  for (size_t k = 0; k < regular.size(); ++k) {
    const std::string name = regular[k].name;
    const long v = regular[k].mesh.V.rows();
    if (options.include_regular) {
      specs.push_back({name, "regular", v, [name]() -> Result<core::DeformationBenchmark> {
                         for (auto& b : core::make_suite(core::SuiteScale::Paper)) {
                           if (b.name == name) return b;
                         }
                         return Error(ErrorCode::NotFound, name);
                       }});
    }
    const std::uint64_t seed = options.seed;
    specs.push_back(
        {name + "_irregular", "irregular", v, [name, seed]() -> Result<core::DeformationBenchmark> {
           for (auto& b : core::make_suite(core::SuiteScale::Paper)) {
             if (b.name == name) return core::make_irregular(b, seed);
           }
           return Error(ErrorCode::NotFound, name);
         }});
  }
  bool first_level = true;
  for (const int level : options.spot_levels) {
    const long estimate = static_cast<long>(2930 * std::pow(4.0, level));
    const std::string tag = "spot" + std::to_string((estimate + 500) / 1000) + "k";
    std::vector<std::string> edits = {"bend"};
    if (first_level) edits = options.spot_edits;
    first_level = false;
    for (const std::string& edit_name : edits) {
      const core::SpotEdit edit = edit_name == "stretch" ? core::SpotEdit::Stretch
                                  : edit_name == "twist" ? core::SpotEdit::Twist
                                                         : core::SpotEdit::Bend;
      const std::string path = options.spot_path;
      specs.push_back({tag + "_" + edit_name, "spot", estimate,
                       [path, level, edit]() -> Result<core::DeformationBenchmark> {
                         return load_spot_edit(path, level, edit);
                       }});
    }
  }
  return specs;
}

// ---- output -----------------------------------------------------------------------------------

std::string fmt(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}
std::string ratio_cell(double ours, double cgal, double target) {
  if (!(ours > 0) || !(cgal > 0)) return "-";
  const double r = ours / cgal;
  return fmt("%.2f", r) + (r <= target ? " (met)" : " (NOT met)");
}

const MethodResult* find(const Row& row, const std::string& method) {
  const auto it = row.methods.find(method);
  return it != row.methods.end() && it->second.ok ? &it->second : nullptr;
}

std::string quality_cell(const MethodResult* m) {
  if (m == nullptr) return "-";
  if (m->quality_iteration < 0) return "not reached";
  return std::to_string(m->quality_iteration) + " its, " + fmt("%.3f", m->quality_s) + " s";
}

std::string markdown(const MachineInfo& machine, const std::string& load_end,
                     const Options& options, const std::vector<Row>& rows) {
  std::ostringstream out;
  out << "# Realistic meshes: our solvers vs CGAL ARAP (issue 13)\n\n";
  out << "- date: " << machine.date_utc << "\n";
  out << "- machine: nproc " << machine.hardware_threads << ", CPU " << machine.cpu_model
      << "; load average (1/5/15 min) " << machine.load_average << " at start, " << load_end
      << " at end (per model below)\n";
  out << "- BLAS: " << machine.blas << " (" << machine.blas_env << ")\n";
  out << "- compiler: " << machine.compiler << "; build type: " << machine.build_type << "\n";
  out << "- source: git " << machine.git_revision << "\n";
  out << "- runs: " << options.repeat << " rounds (one above " << options.repeat_max_vertices
      << " vertices), each method in its own forked process, "
      << "interleaved per round; timings are medians, peak RSS is VmHWM of the method's process "
         "(reset after fork; includes the input mesh and the libraries, baseline in the JSON)\n";
  out << "- ours: default settings, threads " << options.threads << ", " << options.iterations
      << " outer iterations; scale-aware from the start " << core::start_name(options.start)
      << (options.start == core::StartFrom::Auto
              ? " (the default: ARAP to convergence at rigidity > 0, or the Laplacian guess's "
                "result where that folds; the start's time is excluded from ms/it and "
                "included in time to quality)"
              : "")
      << ", ARAP from its Laplacian guess; the scale-aware precompute column is create() and "
         "prepare() at the default rigidity, everything a default solve builds before its start (validation, "
         "ARAP's factor for the default start, the scale term's system, the preconditioner "
         "factor; with two or more threads the first two factorizations run side by side), "
         "metrics off in the timed run (E_theta / "
         "E_phi per iteration come from a second, identical run with metrics on); ARAP timed run "
         "tolerance 0 (exactly "
      << options.iterations << " iterations, like CGAL's); scale_aware and arap: the plain "
         "iteration (Anderson window 0); scale_aware_anderson and arap_anderson: window "
      << options.anderson_window << "\n";
  out << "- CGAL: Surface_mesh_deformation, spokes-and-rims ARAP (CGAL default), Eigen SparseLU, "
         "deform("
      << options.iterations << ", 0) timed, then reset + deform(" << options.cgal_max_iterations
      << ", 1e-4) for its time to converge\n";
  out << "- time to quality: first iteration at which E_theta and E_phi are both <= those of CGAL "
         "ARAP run to convergence (the bar), and the time of that iteration in the timed run "
         "(solve only, precompute not included); CGAL's column is its time to converge\n\n";

  out << "## Per outer iteration, precompute and memory (ratios to CGAL; target per-it <= "
      << kPerIterationRatioTarget << "x, precompute <= " << kPrecomputeRatioTarget
      << "x, memory <= " << kMemoryRatioTarget << "x)\n\n";
  out << "| model | #V | load | SA ms/it | ARAP ms/it | CGAL ms/it | SA/CGAL per-it | ARAP/CGAL "
         "per-it | SA precompute s | ARAP precompute s | CGAL preprocess s | SA/CGAL precompute | "
         "SA MiB | ARAP MiB | CGAL MiB | SA/CGAL memory |\n";
  out << "|---|---:|---|---:|---:|---:|---|---|---:|---:|---:|---|---:|---:|---:|---|\n";
  for (const Row& row : rows) {
    const MethodResult* sa = find(row, "scale_aware");
    const MethodResult* arap = find(row, "arap");
    const MethodResult* cgal = find(row, "cgal");
    auto ms = [](const MethodResult* m) { return m ? fmt("%.1f", 1e3 * m->per_iteration_s) : "-"; };
    auto mib = [](const MethodResult* m) { return m ? fmt("%.0f", m->peak_rss_mib) : "-"; };
    out << "| " << row.name << " | " << row.vertices << " | " << row.load_before << " | " << ms(sa)
        << " | " << ms(arap) << " | " << ms(cgal) << " | "
        << (sa && cgal
                ? ratio_cell(sa->per_iteration_s, cgal->per_iteration_s, kPerIterationRatioTarget)
                : "-")
        << " | "
        << (arap && cgal
                ? ratio_cell(arap->per_iteration_s, cgal->per_iteration_s, kPerIterationRatioTarget)
                : "-")
        << " | " << (sa ? fmt("%.3f", sa->precompute_s) : "-") << " | "
        << (arap ? fmt("%.3f", arap->precompute_s) : "-") << " | "
        << (cgal ? fmt("%.3f", cgal->precompute_s) : "-") << " | "
        << (sa && cgal ? ratio_cell(sa->precompute_s, cgal->precompute_s, kPrecomputeRatioTarget)
                       : "-")
        << " | " << mib(sa) << " | " << mib(arap) << " | " << mib(cgal) << " | "
        << (sa && cgal ? ratio_cell(sa->peak_rss_mib, cgal->peak_rss_mib, kMemoryRatioTarget) : "-")
        << " |\n";
  }

  bool any_threads = false;
  for (const Row& row : rows) any_threads = any_threads || find(row, "scale_aware_threads");
  if (any_threads) {
    out << "\n## Both cores for one session (scale_aware_threads: the plain scale-aware run on "
        << std::max(1, static_cast<int>(std::thread::hardware_concurrency()))
        << " OpenMP threads, same run)\n\n";
    out << "| model | #V | SA ms/it, " << options.threads << " thread(s) | SA ms/it, all cores | "
           "speed-up | all cores / CGAL per-it | SA precompute s, " << options.threads
        << " / all cores | SA MiB, " << options.threads << " / all cores |\n";
    out << "|---|---:|---:|---:|---:|---|---|---|\n";
    for (const Row& row : rows) {
      const MethodResult* one = find(row, "scale_aware");
      const MethodResult* all = find(row, "scale_aware_threads");
      const MethodResult* cgal = find(row, "cgal");
      if (!all) continue;
      out << "| " << row.name << " | " << row.vertices << " | "
          << (one ? fmt("%.1f", 1e3 * one->per_iteration_s) : "-") << " | "
          << fmt("%.1f", 1e3 * all->per_iteration_s) << " | "
          << (one ? fmt("%.2f", one->per_iteration_s / all->per_iteration_s) : "-") << " | "
          << (cgal ? ratio_cell(all->per_iteration_s, cgal->per_iteration_s,
                                kPerIterationRatioTarget)
                   : "-")
          << " | " << (one ? fmt("%.3f", one->precompute_s) : "-") << " / "
          << fmt("%.3f", all->precompute_s) << " | "
          << (one ? fmt("%.0f", one->peak_rss_mib) : "-") << " / "
          << fmt("%.0f", all->peak_rss_mib) << " |\n";
    }
  }

  out << "\n## Scale-aware breakdown per outer iteration (timed run)\n\n";
  out << "| model | #V | ms/it | step one ms | assembly ms | linear (PCG) ms | PCG steps / it | "
         "ms / PCG step | sweeps / it | factorizations | E_theta | E_phi | area | start (of "
         "candidates) |\n";
  out << "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n";
  for (const Row& row : rows) {
    const MethodResult* sa = find(row, "scale_aware");
    if (!sa) continue;
    int sweeps = 0;
    for (size_t k = 1; k < sa->first["history"].size(); ++k) {
      sweeps += sa->first["history"][k]["sweeps"].get<int>();
    }
    const json& e = sa->first["errors"];
    out << "| " << row.name << " | " << row.vertices << " | "
        << fmt("%.1f", 1e3 * sa->per_iteration_s) << " | " << fmt("%.1f", sa->normals_ms) << " | "
        << fmt("%.1f", sa->assemble_ms) << " | " << fmt("%.1f", sa->linear_ms) << " | "
        << fmt("%.1f", sa->pcg_per_iteration) << " | "
        << (sa->pcg_per_iteration > 0 ? fmt("%.2f", sa->linear_ms / sa->pcg_per_iteration) : "-")
        << " | "
        << fmt("%.1f", sa->iterations > 0 ? static_cast<double>(sweeps) / sa->iterations : 0)
        << " | " << sa->first.value("factorizations", 0) << " | "
        << fmt("%.4f", e["e_theta"].get<double>()) << " | " << fmt("%.4f", e["e_phi"].get<double>())
        << " | " << fmt("%.4f", e["area"].get<double>()) << " | "
        << sa->first.value("start_used", std::string("-")) << " ("
        << sa->first.value("start_candidates", 1) << ") |\n";
  }

  out << "\n## Iterations and time to quality\n\n";
  out << "Bar = CGAL ARAP converged (tolerance 1e-4). Scale-aware and ARAP each with and without "
         "Anderson acceleration (SA+AA, ARAP+AA).\n\n";
  out << "| model | bar E_theta / E_phi | CGAL conv. its, s | SA to quality | SA+AA to quality | "
         "SA / SA+AA energy at "
      << options.iterations
      << " its | SA+AA reaches plain SA's final energy | ARAP conv. its, s | "
         "ARAP to quality | ARAP+AA conv. its, s | ARAP+AA to quality | ARAP / ARAP+AA final "
         "energy | ARAP+AA reaches plain ARAP's final energy |\n";
  out << "|---|---|---|---|---|---|---|---|---|---|---|---|---|\n";
  for (const Row& row : rows) {
    const MethodResult* sa = find(row, "scale_aware");
    const MethodResult* arap = find(row, "arap");
    const MethodResult* aa = find(row, "arap_anderson");
    const MethodResult* sa_aa = find(row, "scale_aware_anderson");
    const MethodResult* cgal = find(row, "cgal");
    auto timed_energy = [](const MethodResult* m) {
      if (!m || m->first["history"].empty()) return std::string("-");
      return fmt("%.4g", m->first["history"].back()["energy"].get<double>());
    };
    auto conv = [&](const MethodResult* m) {
      return m ? std::to_string(m->converge_iterations) +
                     (m->converge_iterations >= options.cgal_max_iterations ? " (cap)" : "") +
                     ", " + fmt("%.3f", m->converge_s)
               : std::string("-");
    };
    auto final_energy = [](const MethodResult* m) {
      if (!m || !m->first.contains("converge_history")) return std::string("-");
      return fmt("%.4g", m->first["converge_history"].back()["energy"].get<double>());
    };
    out << "| " << row.name << " | "
        << (row.bar_theta >= 0 ? fmt("%.4f", row.bar_theta) + " / " + fmt("%.4f", row.bar_phi)
                               : "-")
        << " | " << conv(cgal) << " | " << quality_cell(sa) << " | " << quality_cell(sa_aa)
        << " | " << timed_energy(sa) << " / " << timed_energy(sa_aa) << " | "
        << (row.sa_aa_equal_energy_iteration >= 0
                ? std::to_string(row.sa_aa_equal_energy_iteration) + " its, " +
                      fmt("%.3f", row.sa_aa_equal_energy_s) + " s (plain: " +
                      fmt("%.3f", sa ? sa->solve_s : 0.0) + " s)"
                : std::string("-"))
        << " | " << conv(arap) << " | "
        << quality_cell(arap) << " | " << conv(aa) << " | " << quality_cell(aa) << " | "
        << final_energy(arap) << " / " << final_energy(aa) << " | "
        << (row.aa_equal_energy_iteration >= 0
                ? std::to_string(row.aa_equal_energy_iteration) + " its, " +
                      fmt("%.3f", row.aa_equal_energy_s) + " s"
                : std::string("-"))
        << " |\n";
  }

  out << "\n## Errors of the timed runs (" << options.iterations << " iterations)\n\n";
  out << "| model | SA E_theta / E_phi / area | SA+AA | ARAP | ARAP+AA | CGAL |\n"
         "|---|---|---|---|---|---|\n";
  for (const Row& row : rows) {
    out << "| " << row.name;
    for (const char* method :
         {"scale_aware", "scale_aware_anderson", "arap", "arap_anderson", "cgal"}) {
      const MethodResult* m = find(row, method);
      if (!m) {
        out << " | -";
        continue;
      }
      const json& e = m->first["errors"];
      out << " | " << fmt("%.4f", e["e_theta"].get<double>()) << " / "
          << fmt("%.4f", e["e_phi"].get<double>()) << " / " << fmt("%.4f", e["area"].get<double>());
    }
    out << " |\n";
  }
  bool any_error = false;
  for (const Row& row : rows) {
    for (const auto& [name, m] : row.methods) {
      if (!m.ok) {
        if (!any_error) out << "\n## Failures\n\n";
        any_error = true;
        out << "- " << row.name << " / " << name << ": " << m.error << "\n";
      }
    }
  }
  return out.str();
}

/// Log-log plot, written directly as SVG (no plotting dependency): ms per iteration and peak RSS
/// against vertex count, one series per method.
std::string scaling_svg(const std::vector<Row>& rows) {
  struct Series {
    const char* method;
    const char* label;
    const char* color;
  };
  const Series series[] = {{"scale_aware", "ours scale-aware", "#d62728"},
                           {"arap", "ours ARAP", "#1f77b4"},
                           {"arap_anderson", "ours ARAP + Anderson", "#17becf"},
                           {"cgal", "CGAL ARAP", "#2ca02c"}};
  const int panel_w = 420, panel_h = 320, margin = 60;
  std::ostringstream svg;
  svg << "<svg xmlns='http://www.w3.org/2000/svg' width='" << 2 * panel_w + 3 * margin
      << "' height='" << panel_h + 2 * margin + 40
      << "' font-family='sans-serif' font-size='11'>\n";
  svg << "<rect width='100%' height='100%' fill='white'/>\n";
  for (int panel = 0; panel < 2; ++panel) {
    auto value = [panel](const MethodResult& m) {
      return panel == 0 ? 1e3 * m.per_iteration_s : m.peak_rss_mib;
    };
    double xmin = 1e300, xmax = 0, ymin = 1e300, ymax = 0;
    for (const Row& row : rows) {
      for (const auto& [name, m] : row.methods) {
        if (!m.ok || !(value(m) > 0)) continue;
        xmin = std::min(xmin, static_cast<double>(row.vertices));
        xmax = std::max(xmax, static_cast<double>(row.vertices));
        ymin = std::min(ymin, value(m));
        ymax = std::max(ymax, value(m));
      }
    }
    if (xmax <= 0) continue;
    const double lx0 = std::floor(std::log10(xmin)), lx1 = std::ceil(std::log10(xmax * 1.01));
    const double ly0 = std::floor(std::log10(ymin)), ly1 = std::ceil(std::log10(ymax * 1.01));
    const int ox = margin + panel * (panel_w + margin), oy = margin;
    auto px = [&](double x) {
      return ox + (std::log10(x) - lx0) / std::max(lx1 - lx0, 1.0) * panel_w;
    };
    auto py = [&](double y) {
      return oy + panel_h - (std::log10(y) - ly0) / std::max(ly1 - ly0, 1.0) * panel_h;
    };
    svg << "<rect x='" << ox << "' y='" << oy << "' width='" << panel_w << "' height='" << panel_h
        << "' fill='none' stroke='black'/>\n";
    for (double d = lx0; d <= lx1; ++d) {
      const double x = px(std::pow(10.0, d));
      svg << "<line x1='" << x << "' y1='" << oy << "' x2='" << x << "' y2='" << oy + panel_h
          << "' stroke='#ddd'/><text x='" << x << "' y='" << oy + panel_h + 15
          << "' text-anchor='middle'>1e" << d << "</text>\n";
    }
    for (double d = ly0; d <= ly1; ++d) {
      const double y = py(std::pow(10.0, d));
      svg << "<line x1='" << ox << "' y1='" << y << "' x2='" << ox + panel_w << "' y2='" << y
          << "' stroke='#ddd'/><text x='" << ox - 5 << "' y='" << y + 4 << "' text-anchor='end'>1e"
          << d << "</text>\n";
    }
    svg << "<text x='" << ox + panel_w / 2 << "' y='" << oy - 10 << "' text-anchor='middle' "
        << "font-size='13'>"
        << (panel == 0 ? "ms per (outer) iteration" : "peak RSS (MiB) of the method's process")
        << " vs vertices</text>\n";
    for (size_t s = 0; s < std::size(series); ++s) {
      std::vector<std::pair<double, double>> points;
      for (const Row& row : rows) {
        const MethodResult* m = find(row, series[s].method);
        if (m && value(*m) > 0) points.emplace_back(row.vertices, value(*m));
      }
      std::sort(points.begin(), points.end());
      for (const auto& [x, y] : points) {
        svg << "<circle cx='" << px(x) << "' cy='" << py(y) << "' r='3' fill='" << series[s].color
            << "'/>\n";
      }
      if (panel == 0) {
        const int lx = margin + static_cast<int>(s) * 200, ly = oy + panel_h + 45;
        svg << "<circle cx='" << lx << "' cy='" << ly - 4 << "' r='4' fill='" << series[s].color
            << "'/><text x='" << lx + 8 << "' y='" << ly << "'>" << series[s].label << "</text>\n";
      }
    }
  }
  svg << "</svg>\n";
  return svg.str();
}

json to_json(const MachineInfo& machine, const std::string& load_end, const Options& options,
             const std::vector<Row>& rows) {
  json out;
  out["machine"] = machine_json(machine, load_end);
  out["options"] = {{"iterations", options.iterations},
                    {"repeat", options.repeat},
                    {"threads", options.threads},
                    {"anderson_window", options.anderson_window},
                    {"cgal_max_iterations", options.cgal_max_iterations},
                    {"seed", options.seed}};
  out["targets"] = {{"per_iteration_ratio", kPerIterationRatioTarget},
                    {"precompute_ratio", kPrecomputeRatioTarget},
                    {"memory_ratio", kMemoryRatioTarget}};
  out["models"] = json::array();
  for (const Row& row : rows) {
    json model = {{"name", row.name},
                  {"family", row.family},
                  {"vertices", row.vertices},
                  {"faces", row.faces},
                  {"constrained", row.constrained},
                  {"load_before", row.load_before},
                  {"load_after", row.load_after},
                  {"rounds", row.rounds},
                  {"anderson_reaches_plain_arap_energy",
                   {{"iteration", row.aa_equal_energy_iteration},
                    {"seconds", row.aa_equal_energy_s}}},
                  {"bar", {{"e_theta", row.bar_theta}, {"e_phi", row.bar_phi}}}};
    for (const auto& [name, m] : row.methods) {
      json entry = {{"ok", m.ok}};
      if (!m.ok) {
        entry["error"] = m.error;
      } else {
        entry["median"] = {
            {"precompute_s", m.precompute_s}, {"per_iteration_s", m.per_iteration_s},
            {"solve_s", m.solve_s},           {"converge_s", m.converge_s},
            {"peak_rss_mib", m.peak_rss_mib}, {"baseline_rss_mib", m.baseline_rss_mib},
            {"step_one_ms", m.normals_ms},    {"assemble_ms", m.assemble_ms},
            {"linear_ms", m.linear_ms}};
        entry["all_rounds"] = {{"precompute_s", m.precompute_all},
                               {"per_iteration_s", m.per_iteration_all}};
        entry["iterations"] = m.iterations;
        entry["converge_iterations"] = m.converge_iterations;
        entry["pcg_per_iteration"] = m.pcg_per_iteration;
        entry["time_to_quality"] = {{"iteration", m.quality_iteration}, {"seconds", m.quality_s}};
        entry["errors"] = m.first["errors"];
        if (m.first.contains("converged_errors")) {
          entry["converged_errors"] = m.first["converged_errors"];
        }
        for (const char* key : {"history", "converge_history", "metric_history"}) {
          if (m.first.contains(key)) entry[key] = m.first[key];
        }
      }
      model["methods"][name] = entry;
    }
    const MethodResult* sa = find(row, "scale_aware");
    const MethodResult* cgal = find(row, "cgal");
    if (sa && cgal) {
      model["ratios"] = {{"per_iteration", sa->per_iteration_s / cgal->per_iteration_s},
                         {"precompute", sa->precompute_s / cgal->precompute_s},
                         {"memory", sa->peak_rss_mib / cgal->peak_rss_mib}};
    }
    out["models"].push_back(model);
  }
  return out;
}

Status run(int argc, char** argv) {
  MD_ASSIGN_OR_RETURN(const Options options, parse_options(argc, argv));
  MD_ASSIGN_OR_RETURN(const std::vector<ModelSpec> specs, model_specs(options));
  std::cerr << "models:";
  for (const auto& spec : specs) std::cerr << " " << spec.name;
  std::cerr << "\n";
  for (const std::string& name : options.models) {
    if (std::none_of(specs.begin(), specs.end(), [&](const auto& s) { return s.name == name; })) {
      return Error(ErrorCode::InvalidArgument, "unknown model '" + name + "'");
    }
  }
  const MachineInfo machine = collect_machine_info();
  std::vector<Row> rows;
  for (const ModelSpec& spec : specs) {
    if (!options.models.empty() && std::find(options.models.begin(), options.models.end(),
                                             spec.name) == options.models.end()) {
      continue;
    }
    if (spec.vertices_estimate > options.max_vertices) continue;
    Row row;
    row.name = spec.name;
    row.family = spec.family;
    std::cerr << "[" << spec.name << "] generating\n";
    MD_ASSIGN_OR_RETURN(core::DeformationBenchmark bench, spec.make());
    if (bench.mesh.V.rows() > options.max_vertices) continue;
    Model model;
    MD_ASSIGN_OR_RETURN(model.setup, core::constraints_from_selection(bench.mesh.V, bench.selection,
                                                                      bench.transform));
    model.bench = std::move(bench);
    row.vertices = static_cast<int>(model.bench.mesh.V.rows());
    row.faces = static_cast<int>(model.bench.mesh.F.rows());
    row.constrained = static_cast<int>(model.setup.constrained.size());
    row.load_before = read_load_average();
    std::map<std::string, std::vector<json>> runs;
    std::map<std::string, std::string> failures;
    const int rounds = row.vertices > options.repeat_max_vertices ? 1 : options.repeat;
    row.rounds = rounds;
    for (int round = 0; round < rounds; ++round) {
      for (const std::string& method : options.methods) {
        if (failures.count(method)) continue;
        std::cerr << "[" << spec.name << "] " << row.vertices << " vertices, round " << round + 1
                  << "/" << rounds << ": " << method << "\n";
        Result<json> result = run_in_child([&]() -> json {
          if (method == "scale_aware") {
            return run_ours<core::ScaleAwareSolver, core::ScaleAwareSettings>(model, options, false,
                                                                              0);
          }
          if (method == "scale_aware_threads") {
            return run_ours<core::ScaleAwareSolver, core::ScaleAwareSettings>(
                model, options, false, 0,
                std::max(1, static_cast<int>(std::thread::hardware_concurrency())));
          }
          if (method == "scale_aware_anderson") {
            return run_ours<core::ScaleAwareSolver, core::ScaleAwareSettings>(
                model, options, false, options.anderson_window);
          }
          if (method == "arap") {
            return run_ours<core::ArapSolver, core::ArapSettings>(model, options, true, 0);
          }
          if (method == "arap_anderson") {
            return run_ours<core::ArapSolver, core::ArapSettings>(model, options, true,
                                                                  options.anderson_window);
          }
          return run_cgal(model, options);
        });
        if (!result.ok()) {
          failures[method] = result.status().to_string();
          std::cerr << "[" << spec.name << "] " << method << " failed: " << failures[method]
                    << "\n";
          continue;
        }
        runs[method].push_back(std::move(result).value());
      }
    }
    row.load_after = read_load_average();
    for (const std::string& method : options.methods) {
      MethodResult r = aggregate(method, runs[method]);
      if (failures.count(method)) {
        r.ok = false;
        r.error = failures[method];
      }
      row.methods[method] = r;
    }
    // Accelerated against plain: the first iteration (and its median time over the rounds) at
    // which the accelerated run reaches the energy the plain run ended `timeline` with.
    auto reaches_plain_energy = [&](const char* plain_name, const char* fast_name,
                                    const char* timeline, int& iteration, double& seconds) {
      const MethodResult* plain = find(row, plain_name);
      const MethodResult* fast = find(row, fast_name);
      if (!plain || !fast || !plain->first.contains(timeline) || plain->first[timeline].empty()) {
        return;
      }
      const double target = plain->first[timeline].back()["energy"].get<double>();
      const json& history = fast->first[timeline];
      for (size_t k = 0; k < history.size(); ++k) {
        if (history[k]["energy"].get<double>() <= target) {
          iteration = static_cast<int>(k);
          std::vector<double> times;
          for (const json& run : runs[fast_name]) times.push_back(run[timeline][k]["elapsed"].get<double>());
          seconds = median(times);
          return;
        }
      }
    };
    // ARAP: against plain ARAP's convergence run; scale-aware: against the timed budget.
    reaches_plain_energy("arap", "arap_anderson", "converge_history", row.aa_equal_energy_iteration,
                         row.aa_equal_energy_s);
    reaches_plain_energy("scale_aware", "scale_aware_anderson", "history",
                         row.sa_aa_equal_energy_iteration, row.sa_aa_equal_energy_s);
    if (const MethodResult* cgal = find(row, "cgal")) {
      row.bar_theta = cgal->first["converged_errors"]["e_theta"].get<double>();
      row.bar_phi = cgal->first["converged_errors"]["e_phi"].get<double>();
      for (auto& [name, m] : row.methods) {
        if (name != "cgal") time_to_quality(m, runs[name], row.bar_theta, row.bar_phi);
      }
    }
    rows.push_back(std::move(row));
  }

  const std::string load_end = read_load_average();
  const std::string md = markdown(machine, load_end, options, rows);
  std::cout << md << std::flush;
  std::error_code error;
  std::filesystem::create_directories(options.out_dir, error);
  if (error) return Error(ErrorCode::Internal, "cannot create " + options.out_dir);
  const std::filesystem::path dir(options.out_dir);
  MD_RETURN_IF_ERROR(write_file(dir / (options.stem + ".md"), md));
  MD_RETURN_IF_ERROR(write_file(dir / (options.stem + ".json"),
                                to_json(machine, load_end, options, rows).dump() + "\n"));
  MD_RETURN_IF_ERROR(write_file(dir / (options.stem + "_scaling.svg"), scaling_svg(rows)));
  std::cerr << "wrote " << (dir / options.stem).string() << ".{md,json} and _scaling.svg\n";
  return Status::success();
}

}  // namespace
}  // namespace meshdeform::bench

int main(int argc, char** argv) {
  return meshdeform::bench::bench_main(argc, argv, "meshdeform-bench-realistic", meshdeform::bench::print_usage,
                                        meshdeform::bench::run);
}
