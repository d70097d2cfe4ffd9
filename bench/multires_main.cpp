// meshdeform-bench-multires (issue 15): the two-level scale-aware deformation of core/multires/multires.h
// on Spot Loop-subdivided to ~187k and ~750k vertices, against the single-level solver.
// Per model, two forked children (each with its own peak resident set):
//  - multires: MultiresDeformer::create (hierarchy, prolongation factor, coarse precompute); a
//    drag of the handles from rest to the edit in --moves steps, each a warm move of
//    --move-iterations coarse outer iterations plus the prolongation (the interactive answer);
//    the coarse level converged at the final targets and prolonged (or, with --refine-from
//    drag-end, nothing: the drag's last prolonged move as the server has it after a release);
//    then the full-resolution solver built and run from the prolonged positions to convergence
//    (background refinement), as one solve or, with --refine-slice N, as solves of N
//    iterations in a row, each continuing the last (the server's slices);
//  - single: ScaleAwareSolver at full resolution to convergence from the Laplacian guess, or
//    with --single-start auto from the solver's default start.
// Writes a Markdown report (stdout and <out-dir>/<stem>.md) and <out-dir>/<stem>.json.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bench/bench_args.h"
#include "bench/bench_config.h"
#include "bench/bench_edits.h"
#include "bench/bench_process.h"
#include "bench/machine_info.h"
#include "core/methods/deform_types.h"
#include "core/methods/deformer.h"
#include "core/mesh/measures.h"
#include "core/multires/multires.h"
#include "core/samples/generators.h"
#include "core/methods/scale_aware.h"
#include "core/base/status.h"
#include "core/mesh/topology.h"

namespace meshdeform::bench {
namespace {

using nlohmann::json;

// Issue 15's targets.
constexpr double kMoveP50TargetMs = 100.0;        // warm move (coarse solve + prolongation), 187k
constexpr double kSetupTargetSeconds = 2.0;       // hierarchy + coarse precompute, 187k
constexpr double kMemory187kTargetMiB = 1536.0;   // peak RSS, 187k
constexpr double kMemory750kTargetMiB = 8192.0;   // peak RSS end to end, 750k
constexpr double kErrorAgreement = 0.02;          // converged errors, multires vs single level

struct Options {
  std::vector<int> spot_levels = {3, 4};
  std::string edit = "bend";
  int coarse_vertices = 10000;
  std::string constraints = "borders";
  int moves = 20;
  int move_iterations = 1;
  int max_iterations = 60;
  double tolerance = 1e-4;
  int threads = 1;
  int split_above = core::MultiresSettings{}.split_above_vertices;
  bool single = true;
  core::StartFrom single_start = core::StartFrom::Laplacian;
  bool refine = true;
  // The refinement's start: the prolonged converged coarse result, or the drag's end (what the
  // server refines from after a release).
  bool refine_from_drag_end = false;
  // Refinement as solves of this many iterations in a row (the server's background slices: 2);
  // 0 = one solve.
  int refine_slice = 0;
  // The full-resolution solver is a MultilevelSolver and the first refinement runs its cascade
  // (MultiresDeformerSettings::refine_cascade, the server's default above 20,000 vertices).
  bool refine_cascade = false;
  std::string out_dir = MESHDEFORM_BENCH_RESULTS_DIR;
  std::string stem = "multires";
  std::string spot_path = std::string(MESHDEFORM_BENCH_SOURCE_DIR) + "/tests/data/spot.obj";
};

void print_usage(std::ostream& out) {
  out << "usage: meshdeform-bench-multires [options]\n"
         "  --spot-levels a,b       Loop subdivision levels of Spot (3,4: ~187k, ~750k vertices)\n"
         "  --edit NAME             bend, stretch or twist (bend)\n"
         "  --coarse-vertices N     target vertex count of the coarse level (10000)\n"
         "  --constraints MODE      borders (lock region borders) or all (lock every\n"
         "                          constrained vertex) (borders)\n"
         "  --moves N               drag steps from rest to the edit (20)\n"
         "  --move-iterations N     coarse outer iterations per move (1)\n"
         "  --max-iterations N      cap of the converging solves (60)\n"
         "  --tolerance-exp N       the stopping rule's tolerance, 10^-N (4)\n"
         "  --threads N             solver OpenMP threads, and the hierarchy's (1)\n"
         "  --split-above N         decimate meshes above N vertices in two halves (50000;\n"
         "                          0 never)\n"
         "  --no-single             skip the single-level reference\n"
         "  --single-start NAME     start of the single-level reference: laplacian (the\n"
         "                          Laplacian guess) or auto (the solver's default: converged\n"
         "                          ARAP at rigidity > 0) (laplacian)\n"
         "  --no-refine             skip the coarse convergence and the full-resolution\n"
         "                          refinement (interactive part only)\n"
         "  --refine-from WHERE     converged-coarse (the coarse level converged at the edit,\n"
         "                          prolonged) or drag-end (the drag's last prolonged move, as\n"
         "                          the server refines after a release) (converged-coarse)\n"
         "  --refine-slice N        run the refinement as solves of N iterations in a row,\n"
         "                          each continuing the last (the server's background slices\n"
         "                          are 2); 0: one solve (0)\n"
         "  --refine-cascade        the first refinement runs the multilevel cascade toward\n"
         "                          the edit instead of iterating from the refinement's start\n"
         "                          (as make_deformer's multiresolution deformer does above\n"
         "                          20000 vertices)\n"
         "  --out-dir DIR           (default "
      << MESHDEFORM_BENCH_RESULTS_DIR
      << ")\n"
         "  --stem NAME             output file stem (multires)\n"
         "  --spot PATH             spot.obj (default tests/data/spot.obj)\n";
}

Result<Options> parse_options(int argc, char** argv) {
  Options o;
  BenchFlags flags;
  flags.integer_list("--spot-levels", o.spot_levels, 0);
  flags.value("--edit", [&](const std::string& value) -> Status {
    o.edit = value;
    if (o.edit != "bend" && o.edit != "stretch" && o.edit != "twist") {
      return Error(ErrorCode::InvalidArgument, "unknown edit '" + o.edit + "'");
    }
    return Status::success();
  });
  flags.integer("--coarse-vertices", o.coarse_vertices, 4);
  flags.value("--constraints", [&](const std::string& value) -> Status {
    o.constraints = value;
    if (o.constraints != "borders" && o.constraints != "all") {
      return Error(ErrorCode::InvalidArgument, "--constraints wants borders or all");
    }
    return Status::success();
  });
  flags.integer("--moves", o.moves, 2);
  flags.integer("--move-iterations", o.move_iterations, 1);
  flags.integer("--max-iterations", o.max_iterations, 1);
  flags.value("--tolerance-exp", [&](const std::string& value) -> Status {
    MD_ASSIGN_OR_RETURN(const int exponent, parse_integer<int>("--tolerance-exp", value, 0));
    o.tolerance = std::pow(10.0, -exponent);
    return Status::success();
  });
  flags.integer("--threads", o.threads, 0);
  flags.integer("--split-above", o.split_above, 0);
  flags.flag("--no-single", [&] { o.single = false; });
  flags.value("--single-start", [&](const std::string& value) -> Status {
    MD_ASSIGN_OR_RETURN(o.single_start, core::parse_start(value));
    if (o.single_start != core::StartFrom::Laplacian && o.single_start != core::StartFrom::Auto) {
      return Error(ErrorCode::InvalidArgument, "--single-start wants laplacian or auto");
    }
    return Status::success();
  });
  flags.flag("--no-refine", [&] { o.refine = false; });
  flags.value("--refine-from", [&](const std::string& value) -> Status {
    if (value != "converged-coarse" && value != "drag-end") {
      return Error(ErrorCode::InvalidArgument, "--refine-from wants converged-coarse or drag-end");
    }
    o.refine_from_drag_end = value == "drag-end";
    return Status::success();
  });
  flags.integer("--refine-slice", o.refine_slice, 0);
  flags.flag("--refine-cascade", [&] { o.refine_cascade = true; });
  flags.text("--out-dir", o.out_dir);
  flags.text("--stem", o.stem);
  flags.text("--spot", o.spot_path);
  MD_RETURN_IF_ERROR(flags.parse(argc, argv));
  return o;
}

template <typename T>
T value_or_throw(Result<T> result) {
  if (!result.ok()) throw std::runtime_error(result.status().to_string());
  return std::move(result).value();
}

double mib(long kib) { return static_cast<double>(kib) / 1024.0; }

/// Energy and elapsed seconds of each outer iteration (iteration 0: the start).
json energy_history(const core::SolveReport& report) {
  json out = json::array();
  for (const auto& h : report.history) {
    out.push_back({{"energy", h.energy}, {"elapsed", h.elapsed_seconds}});
  }
  return out;
}

struct Model {
  std::string name;
  core::DeformationBenchmark bench;
  core::HandleSetup setup;
  std::vector<Positions> drag;  // targets of each drag step, the last one the edit itself
};

/// Errors of fine positions against the rest mesh.
struct Metrics {
  core::MeshTopology topology;
  core::Measures rest;
  Metrics(const Positions& V0, const Triangles& F)
      : topology(core::build_topology(F, static_cast<int>(V0.rows())).value()),
        rest(core::compute_measures(V0, F, topology)) {}
  json of(const Positions& V, const Triangles& F) const {
    return errors_json(core::angle_errors(rest, core::compute_measures(V, F, topology)));
  }
};

core::SolveOptions converge_options(const Options& options) {
  core::SolveOptions converge;
  converge.max_iterations = options.max_iterations;
  converge.tolerance = options.tolerance;
  converge.track_metrics = false;
  return converge;
}

json run_multires(const Model& model, const Options& options) {
  const Positions& V0 = model.bench.mesh.V;
  const Triangles& F = model.bench.mesh.F;
  json out;
  core::MultiresDeformerSettings settings;
  settings.hierarchy.level_vertices = {options.coarse_vertices};
  settings.hierarchy.constraint_levels = options.constraints == "all"
                                             ? core::ConstraintLevels::KeepAll
                                             : core::ConstraintLevels::KeepBorders;
  settings.solver.threads = options.threads;
  settings.hierarchy.threads =
      options.threads > 0 ? options.threads
                          : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  settings.hierarchy.split_above_vertices = options.split_above;
  if (options.refine_cascade) {
    settings.refine_cascade = true;
    settings.cascade.solver = settings.solver;
    settings.cascade.coarsest_vertices = core::kDefaultMultilevelCoarsest;
    settings.cascade.threads = settings.hierarchy.threads;
    settings.cascade.keep_fine_start = true;  // as make_deformer's
  }
  auto start = std::chrono::steady_clock::now();
  core::MultiresDeformer deformer = value_or_throw(
      core::MultiresDeformer::create(V0, F, model.setup.constrained, settings));
  out["setup_s"] = seconds_since(start);
  const core::MultiresBuildReport& build = deformer.build_report();
  out["hierarchy_s"] = build.hierarchy_seconds;
  out["prolongation_setup_s"] = build.prolongation_seconds;
  out["coarse_precompute_s"] = build.coarse_solver_seconds;
  out["coarse_vertices"] = build.coarse_vertices;
  out["coarse_faces"] = deformer.hierarchy().level(deformer.coarse_level()).F.rows();
  out["coarse_constrained"] = build.coarse_constrained;

  // The drag: move 0 is cold (the coarse solver's Laplacian guess), the others warm.
  core::SolveOptions move_options;
  move_options.max_iterations = options.move_iterations;
  move_options.track_metrics = false;
  json moves = json::array();
  for (const Positions& targets : model.drag) {
    start = std::chrono::steady_clock::now();
    const core::MultiresMove move = value_or_throw(deformer.move(targets, move_options));
    const double total = seconds_since(start);
    moves.push_back({{"total_s", total},
                     {"coarse_s", move.coarse.seconds},
                     {"prolong_s", move.prolong_seconds},
                     {"iterations", move.coarse.iterations}});
  }
  out["moves"] = moves;
  out["interactive_peak_rss_kib"] = peak_rss_kib();
  const Metrics metrics(V0, F);
  out["drag_end_errors"] = metrics.of(deformer.positions(), F);
  if (!options.refine) return out;

  // The coarse level settled at the edit, prolonged (unless the refinement starts at the drag's
  // end).
  const core::SolveOptions converge = converge_options(options);
  if (!options.refine_from_drag_end) {
    start = std::chrono::steady_clock::now();
    const core::MultiresMove settled =
        value_or_throw(deformer.move(model.setup.targets, converge));
    out["coarse_converge_s"] = seconds_since(start);
    out["coarse_converge_iterations"] = settled.coarse.iterations;
    out["coarse_converged"] = settled.coarse.converged;
    out["settled_prolong_s"] = settled.prolong_seconds;
    out["prolonged_errors"] = metrics.of(settled.V, F);
  }

  // Background refinement at full resolution from the prolonged positions: one solve, or solves
  // of --refine-slice iterations in a row, each continuing the last (as the server's slices do),
  // until the rule holds or --max-iterations are spent.
  start = std::chrono::steady_clock::now();
  const Status prepared = deformer.prepare_refinement();
  if (!prepared.ok()) throw std::runtime_error(prepared.to_string());
  out["fine_precompute_s"] = seconds_since(start);
  core::SolveReport refined;
  int iterations = 0;
  int solves = 0;
  double seconds = 0;
  std::vector<core::IterationInfo> history;
  while (iterations < options.max_iterations) {
    core::SolveOptions slice = converge;
    if (options.refine_slice > 0) {
      slice.max_iterations = std::min(options.refine_slice, options.max_iterations - iterations);
    }
    refined = value_or_throw(deformer.refine(model.setup.targets, slice));
    if (solves == 0 && !refined.levels.empty()) {
      out["refine_cascade_phases_s"] = {{"start", refined.phases.start},
                                        {"levels", refined.phases.levels},
                                        {"fine", refined.phases.fine}};
    }
    // One history across the solves: each solve's iteration 0 is the last one's result.
    const double offset = seconds;
    for (std::size_t k = history.empty() ? 0 : 1; k < refined.history.size(); ++k) {
      history.push_back(refined.history[k]);
      history.back().elapsed_seconds += offset;
    }
    iterations += refined.iterations;
    seconds += refined.seconds;
    ++solves;
    if (refined.converged || refined.iterations == 0) break;
  }
  refined.history = std::move(history);
  out["peak_rss_kib"] = peak_rss_kib();
  out["refine_s"] = seconds;
  out["refine_iterations"] = iterations;
  out["refine_solves"] = solves;
  out["refine_converged"] = refined.converged;
  out["refined_errors"] = metrics.of(refined.V, F);
  out["refine_history"] = energy_history(refined);
  return out;
}

json run_single(const Model& model, const Options& options) {
  const Positions& V0 = model.bench.mesh.V;
  const Triangles& F = model.bench.mesh.F;
  json out;
  core::ScaleAwareSettings settings;
  settings.threads = options.threads;
  const auto start = std::chrono::steady_clock::now();
  core::ScaleAwareSolver solver = value_or_throw(
      core::ScaleAwareSolver::create(V0, F, model.setup.constrained, settings));
  out["precompute_s"] = seconds_since(start);
  core::SolveOptions converge = converge_options(options);
  converge.start = options.single_start;
  const core::SolveReport report = value_or_throw(solver.solve(model.setup.targets, converge));
  out["peak_rss_kib"] = peak_rss_kib();
  out["solve_s"] = report.seconds;
  out["init_s"] = report.history.empty() ? 0.0 : report.history.front().elapsed_seconds;
  out["start_used"] = core::start_name(report.start);
  out["iterations"] = report.iterations;
  out["converged"] = report.converged;
  out["errors"] = Metrics(V0, F).of(report.V, F);
  out["history"] = energy_history(report);
  return out;
}

// ---- report -------------------------------------------------------------------------------------

std::string fmt(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

std::string verdict(bool met) { return met ? "met" : "NOT met"; }

struct Row {
  std::string name;
  int vertices = 0, constrained = 0;
  json multires, single;
  std::string multires_error, single_error;
  std::string load_before, load_after;
  double generate_s = 0;
};

/// Warm-move statistics of a multires run (moves after the first).
struct MoveStats {
  double p50_ms = 0, p90_ms = 0, max_ms = 0, coarse_p50_ms = 0, prolong_p50_ms = 0, cold_ms = 0;
};

MoveStats move_stats(const json& multires) {
  std::vector<double> total, coarse, prolong;
  const json& moves = multires["moves"];
  for (size_t k = 1; k < moves.size(); ++k) {
    total.push_back(1e3 * moves[k]["total_s"].get<double>());
    coarse.push_back(1e3 * moves[k]["coarse_s"].get<double>());
    prolong.push_back(1e3 * moves[k]["prolong_s"].get<double>());
  }
  MoveStats s;
  s.p50_ms = median(total);
  s.p90_ms = quantile(total, 0.9);
  s.max_ms = total.empty() ? 0 : *std::max_element(total.begin(), total.end());
  s.coarse_p50_ms = median(coarse);
  s.prolong_p50_ms = median(prolong);
  s.cold_ms = moves.empty() ? 0 : 1e3 * moves[0]["total_s"].get<double>();
  return s;
}

double relative_difference(const json& a, const json& b, const char* key) {
  const double x = a[key].get<double>(), y = b[key].get<double>();
  return std::abs(x - y) / std::max(std::abs(y), 1e-300);
}

std::string errors_cell(const json& e) {
  return fmt("%.4f", e["e_theta"].get<double>()) + " / " + fmt("%.4f", e["e_phi"].get<double>()) +
         " / " + fmt("%.4f", e["area"].get<double>());
}

bool is_near(int vertices, int reference) {
  return std::abs(vertices - reference) < reference / 10;
}

/// A row of the energy table: start and final energies, and when the refinement first reaches
/// the single-level solve's final energy.
std::string energy_row(const std::string& name, const json& multires, const json& single) {
  const json& refine = multires["refine_history"];
  const json& alone = single["history"];
  if (refine.empty() || alone.empty()) return "";
  const double target = alone.back()["energy"].get<double>();
  std::string reach = "not reached";
  for (size_t k = 0; k < refine.size(); ++k) {
    if (refine[k]["energy"].get<double>() <= target) {
      reach = std::to_string(k) + " its, " + fmt("%.1f", refine[k]["elapsed"].get<double>()) + " s";
      break;
    }
  }
  return "| " + name + " | " + fmt("%.4g", refine.front()["energy"].get<double>()) + " / " +
         fmt("%.4g", alone.front()["energy"].get<double>()) + " | " +
         fmt("%.4g", refine.back()["energy"].get<double>()) + " / " + fmt("%.4g", target) +
         " | " + reach + " | " + std::to_string(alone.size() - 1) + " its, " +
         fmt("%.1f", alone.back()["elapsed"].get<double>()) + " s |\n";
}

/// How the report names the single-level reference's start.
std::string start_phrase(core::StartFrom start) {
  return start == core::StartFrom::Laplacian
             ? "the Laplacian guess"
             : "the solver's default start (auto: converged ARAP at rigidity > 0)";
}
std::string start_label(core::StartFrom start) {
  return start == core::StartFrom::Laplacian ? "Laplacian" : "auto start";
}

std::string markdown(const MachineInfo& machine, const std::string& load_end,
                     const Options& options, const std::vector<Row>& rows) {
  std::ostringstream out;
  out << "# Multiresolution scale-aware deformation on large meshes (issue 15)\n\n";
  out << "- date: " << machine.date_utc << "\n";
  out << "- machine: nproc " << machine.hardware_threads << ", CPU " << machine.cpu_model
      << "; load average (1/5/15 min) " << machine.load_average << " at start, " << load_end
      << " at end (per model below)\n";
  out << "- BLAS: " << machine.blas << " (" << machine.blas_env << ")\n";
  out << "- compiler: " << machine.compiler << "; build type: " << machine.build_type << "\n";
  out << "- source: git " << machine.git_revision << "\n";
  out << "- edit: Spot " << options.edit << " (core::make_spot_edit); coarse level target "
      << options.coarse_vertices << " vertices, constrained vertices locked: "
      << (options.constraints == "all" ? "all (KeepAll)" : "region borders (KeepBorders)")
      << "; solver and hierarchy threads " << options.threads
      << ", the first level decimated in two halves above " << options.split_above
      << " vertices (0: never), default settings (rigidity "
      << core::kDefaultRigidity << ", Anderson window " << core::SolveOptions{}.anderson_window
      << ")\n";
  out << "- drag: " << options.moves << " moves from rest to the edit along T^s (s = k/"
      << options.moves << "), each " << options.move_iterations
      << " coarse outer iteration(s) warm-started from the previous move, then the prolongation; "
         "move 1 is cold (coarse Laplacian guess) and left out of the percentiles\n";
  out << "- converged: the stopping rule (core/methods/convergence.h: estimated remaining "
         "relative energy change <= "
      << fmt("%.0e", options.tolerance) << " at two consecutive iterations) or "
      << options.max_iterations
      << " outer iterations; single level from " << start_phrase(options.single_start)
      << ", multires refinement from the "
      << (options.refine_from_drag_end ? "drag's last prolonged move"
                                       : "prolonged converged coarse solution")
      << (options.refine_cascade
              ? " (the first refinement by the multilevel cascade toward the edit, "
                "MultiresDeformerSettings::refine_cascade), "
              : " (same full-resolution solver, ScaleAwareSolver::set_positions), ")
      << (options.refine_slice > 0
              ? "as solves of " + std::to_string(options.refine_slice) +
                    " iterations in a row, each continuing the last (the server's background "
                    "refinement slices)"
              : std::string("as one solve"))
      << "\n";
  out << "- each of multires / single in its own forked process; peak RSS is VmHWM of that process "
         "(reset after fork; includes the input mesh); interactive peak = before the full-"
         "resolution solver is built\n\n";

  out << "## Interactive path\n\n";
  out << "| model | #V | coarse #V (constrained) | hierarchy s | prolongation setup s | coarse "
         "precompute s | setup total s | cold move ms | warm move p50 / p90 / max ms | coarse "
         "solve p50 ms | prolongation p50 ms | interactive peak MiB |\n";
  out << "|---|---:|---|---:|---:|---:|---:|---:|---|---:|---:|---:|\n";
  for (const Row& row : rows) {
    if (row.multires.is_null()) continue;
    const json& m = row.multires;
    const MoveStats s = move_stats(m);
    out << "| " << row.name << " | " << row.vertices << " | " << m["coarse_vertices"].get<int>()
        << " (" << m["coarse_constrained"].get<int>() << ") | "
        << fmt("%.2f", m["hierarchy_s"].get<double>()) << " | "
        << fmt("%.2f", m["prolongation_setup_s"].get<double>()) << " | "
        << fmt("%.2f", m["coarse_precompute_s"].get<double>()) << " | "
        << fmt("%.2f", m["setup_s"].get<double>()) << " | " << fmt("%.0f", s.cold_ms) << " | "
        << fmt("%.0f", s.p50_ms) << " / " << fmt("%.0f", s.p90_ms) << " / "
        << fmt("%.0f", s.max_ms) << " | " << fmt("%.0f", s.coarse_p50_ms) << " | "
        << fmt("%.0f", s.prolong_p50_ms) << " | "
        << fmt("%.0f", mib(m["interactive_peak_rss_kib"].get<long>())) << " |\n";
  }

  out << "\n## Full-resolution refinement and quality\n\n";
  out << "E_theta / E_phi / area (RMS radians, radians, RMS log area ratio; "
         "core::angle_errors).\n\n";
  out << "| model | drag end (prolonged, 1 it/move) | coarse converged, prolonged | coarse "
         "converge s (its) | fine precompute s | refine from prolonged s (its) | single: "
         "precompute s | single: solve from " << start_label(options.single_start)
      << " s (its) | multires converged | single "
         "converged | max rel. difference | multires peak MiB | single peak MiB |\n";
  out << "|---|---|---|---|---:|---|---:|---|---|---|---:|---:|---:|\n";
  std::vector<std::string> energy_rows;
  for (const Row& row : rows) {
    if (row.multires.is_null() || !row.multires.contains("refined_errors")) continue;
    const json& m = row.multires;
    const json& s = row.single;
    auto its = [](const json& j, const char* key, const char* converged) {
      return std::to_string(j[key].get<int>()) + (j[converged].get<bool>() ? "" : ", cap");
    };
    out << "| " << row.name << " | " << errors_cell(m["drag_end_errors"]) << " | "
        << (m.contains("prolonged_errors") ? errors_cell(m["prolonged_errors"]) : "-") << " | "
        << (m.contains("coarse_converge_s")
                ? fmt("%.2f", m["coarse_converge_s"].get<double>()) + " (" +
                      its(m, "coarse_converge_iterations", "coarse_converged") + ")"
                : "-")
        << " | "
        << fmt("%.1f", m["fine_precompute_s"].get<double>()) << " | "
        << fmt("%.1f", m["refine_s"].get<double>()) << " ("
        << its(m, "refine_iterations", "refine_converged") << ") | ";
    if (s.is_null()) {
      out << "- | - | " << errors_cell(m["refined_errors"]) << " | - | - | "
          << fmt("%.0f", mib(m["peak_rss_kib"].get<long>())) << " | - |\n";
      continue;
    }
    double worst = 0;
    for (const char* key : {"e_theta", "e_phi", "area"}) {
      worst = std::max(worst, relative_difference(m["refined_errors"], s["errors"], key));
    }
    energy_rows.push_back(energy_row(row.name, m, s));
    out << fmt("%.1f", s["precompute_s"].get<double>()) << " | "
        << fmt("%.1f", s["solve_s"].get<double>()) << " (" << its(s, "iterations", "converged")
        << ") | " << errors_cell(m["refined_errors"]) << " | " << errors_cell(s["errors"]) << " | "
        << fmt("%.1f", 100 * worst) << "% (" << verdict(worst <= kErrorAgreement) << " at "
        << fmt("%.0f", 100 * kErrorAgreement) << "%) | "
        << fmt("%.0f", mib(m["peak_rss_kib"].get<long>())) << " | "
        << fmt("%.0f", mib(s["peak_rss_kib"].get<long>())) << " |\n";
  }

  if (!energy_rows.empty()) {
    out << "\n## Energy (Eq. 12 + rigidity x scale term) of the full-resolution solves\n\n";
    out << "Both solves stop on a relative energy change; the refinement from the prolonged start "
           "and the single-level solve from "
        << start_phrase(options.single_start)
        << " need not stop at the same energy. "
           "*reaches single's final energy*: the first refinement iteration at or below the energy "
           "the single-level solve ended with, and its time.\n\n";
    out << "| model | start energy: prolonged / " << start_label(options.single_start)
        << " | final energy: multires / single | "
           "refinement reaches single's final energy | single-level solve |\n";
    out << "|---|---|---|---|---|\n";
    for (const std::string& line : energy_rows) out << line;
  }
  out << "\n## Targets\n\n";
  for (const Row& row : rows) {
    if (row.multires.is_null()) continue;
    const json& m = row.multires;
    const MoveStats s = move_stats(m);
    const double peak = mib(m.value("peak_rss_kib", m["interactive_peak_rss_kib"].get<long>()));
    if (is_near(row.vertices, 187'000)) {
      out << "- " << row.name << ": warm move p50 " << fmt("%.0f", s.p50_ms) << " ms <= "
          << kMoveP50TargetMs << " ms: **" << verdict(s.p50_ms <= kMoveP50TargetMs) << "**\n";
      const double setup = m["setup_s"].get<double>();
      out << "- " << row.name << ": hierarchy + coarse precompute " << fmt("%.2f", setup)
          << " s <= " << kSetupTargetSeconds << " s: **" << verdict(setup <= kSetupTargetSeconds)
          << "**\n";
      out << "- " << row.name << ": peak memory " << fmt("%.0f", peak)
          << " MiB with the full-resolution refinement (interactive part alone "
          << fmt("%.0f", mib(m["interactive_peak_rss_kib"].get<long>())) << " MiB) <= "
          << kMemory187kTargetMiB << " MiB: **" << verdict(peak <= kMemory187kTargetMiB)
          << "**\n";
    } else if (is_near(row.vertices, 750'000)) {
      out << "- " << row.name << ": end to end (hierarchy, drag, coarse convergence, full-"
          << "resolution refinement) peak memory " << fmt("%.0f", peak) << " MiB <= "
          << kMemory750kTargetMiB << " MiB: **" << verdict(peak <= kMemory750kTargetMiB)
          << "**\n";
    }
  }
  bool any_error = false;
  for (const Row& row : rows) {
    for (const auto& [what, error] :
         {std::pair{"multires", row.multires_error}, std::pair{"single", row.single_error}}) {
      if (error.empty()) continue;
      if (!any_error) out << "\n## Failures\n\n";
      any_error = true;
      out << "- " << row.name << " / " << what << ": " << error << "\n";
    }
  }
  return out.str();
}

json to_json(const MachineInfo& machine, const std::string& load_end, const Options& options,
             const std::vector<Row>& rows) {
  json out;
  out["machine"] = machine_json(machine, load_end);
  out["options"] = {{"edit", options.edit},
                    {"coarse_vertices", options.coarse_vertices},
                    {"constraints", options.constraints},
                    {"moves", options.moves},
                    {"move_iterations", options.move_iterations},
                    {"max_iterations", options.max_iterations},
                    {"tolerance", options.tolerance},
                    {"threads", options.threads},
                    {"split_above", options.split_above},
                    {"single_start", core::start_name(options.single_start)},
                    {"refine_from", options.refine_from_drag_end ? "drag-end" : "converged-coarse"},
                    {"refine_slice", options.refine_slice},
                    {"refine_cascade", options.refine_cascade}};
  out["targets"] = {{"warm_move_p50_ms_187k", kMoveP50TargetMs},
                    {"setup_s_187k", kSetupTargetSeconds},
                    {"peak_mib_187k", kMemory187kTargetMiB},
                    {"peak_mib_750k", kMemory750kTargetMiB},
                    {"error_agreement", kErrorAgreement}};
  out["models"] = json::array();
  for (const Row& row : rows) {
    json model = {{"name", row.name},
                  {"vertices", row.vertices},
                  {"constrained", row.constrained},
                  {"generate_s", row.generate_s},
                  {"load_before", row.load_before},
                  {"load_after", row.load_after},
                  {"multires", row.multires},
                  {"single", row.single}};
    if (!row.multires.is_null()) {
      const MoveStats s = move_stats(row.multires);
      model["warm_move_ms"] = {{"p50", s.p50_ms},
                               {"p90", s.p90_ms},
                               {"max", s.max_ms},
                               {"coarse_p50", s.coarse_p50_ms},
                               {"prolong_p50", s.prolong_p50_ms},
                               {"cold", s.cold_ms}};
    }
    if (!row.multires_error.empty()) model["multires_error"] = row.multires_error;
    if (!row.single_error.empty()) model["single_error"] = row.single_error;
    out["models"].push_back(model);
  }
  return out;
}

core::SpotEdit spot_edit_of(const std::string& name) {
  return name == "stretch" ? core::SpotEdit::Stretch
         : name == "twist" ? core::SpotEdit::Twist
                           : core::SpotEdit::Bend;
}

Status run(int argc, char** argv) {
  MD_ASSIGN_OR_RETURN(const Options options, parse_options(argc, argv));
  const MachineInfo machine = collect_machine_info();
  std::vector<Row> rows;
  for (const int level : options.spot_levels) {
    Row row;
    std::cerr << "[spot level " << level << "] generating\n";
    const auto start = std::chrono::steady_clock::now();
    Model model;
    MD_ASSIGN_OR_RETURN(model.bench,
                        load_spot_edit(options.spot_path, level, spot_edit_of(options.edit)));
    MD_ASSIGN_OR_RETURN(model.setup,
                        core::constraints_from_selection(model.bench.mesh.V, model.bench.selection,
                                                         model.bench.transform));
    for (int k = 1; k <= options.moves; ++k) {
      const Eigen::Matrix4d T =
          affine_power(model.bench.transform, static_cast<double>(k) / options.moves);
      MD_ASSIGN_OR_RETURN(
          core::HandleSetup step,
          core::constraints_from_selection(model.bench.mesh.V, model.bench.selection, T));
      model.drag.push_back(std::move(step.targets));
    }
    model.drag.back() = model.setup.targets;
    row.generate_s = seconds_since(start);
    row.name = model.bench.name;
    row.vertices = static_cast<int>(model.bench.mesh.V.rows());
    row.constrained = static_cast<int>(model.setup.constrained.size());
    row.load_before = read_load_average();
    std::cerr << "[" << row.name << "] " << row.vertices << " vertices, " << row.constrained
              << " constrained: multires\n";
    Result<json> multires = run_in_child([&]() { return run_multires(model, options); });
    if (multires.ok()) {
      row.multires = std::move(multires).value();
    } else {
      row.multires_error = multires.status().to_string();
      std::cerr << "[" << row.name << "] multires failed: " << row.multires_error << "\n";
    }
    if (options.single) {
      std::cerr << "[" << row.name << "] single level\n";
      Result<json> single = run_in_child([&]() { return run_single(model, options); });
      if (single.ok()) {
        row.single = std::move(single).value();
      } else {
        row.single_error = single.status().to_string();
        std::cerr << "[" << row.name << "] single failed: " << row.single_error << "\n";
      }
    }
    row.load_after = read_load_average();
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
                                to_json(machine, load_end, options, rows).dump(1) + "\n"));
  std::cerr << "wrote " << (dir / options.stem).string() << ".{md,json}\n";
  return Status::success();
}

}  // namespace
}  // namespace meshdeform::bench

int main(int argc, char** argv) {
  return meshdeform::bench::bench_main(argc, argv, "meshdeform-bench-multires",
                                       meshdeform::bench::print_usage, meshdeform::bench::run);
}
