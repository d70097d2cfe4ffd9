// meshdeform-bench-converge (issue 41): time to a result at the defaults, against CGAL's ARAP run
// for 100 iterations and to its own convergence, in one run, with E_theta / E_phi / area and
// folds beside every time. Also the single-level solve (the multilevel path off) at the same
// defaults, and both run to the same stopping rule with a large budget (the multilevel result's
// agreement with the single-level one). `--variants` adds the study of docs/multilevel.md: the
// multilevel cascade's alternatives (plain prolongation, coarse-grid corrections in the fine
// iteration, level counts and tolerances). Each run is a forked child (its own peak RSS).
// Writes <out-dir>/<stem>.md and .json (stem "multilevel_time_to_result").

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <iostream>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bench/bench_args.h"
#include "bench/bench_config.h"
#include "bench/bench_edits.h"
#include "bench/bench_process.h"
#include "bench/cgal_arap.h"
#include "bench/machine_info.h"
#include "core/base/status.h"
#include "core/mesh/measures.h"
#include "core/mesh/topology.h"
#include "core/methods/convergence.h"
#include "core/methods/deform_types.h"
#include "core/methods/deformer.h"
#include "core/multires/multilevel.h"
#include "core/samples/generators.h"
#include "core/samples/samples.h"

namespace meshdeform::bench {
namespace {

using nlohmann::json;
using Clock = std::chrono::steady_clock;

// Issue 41's targets.
constexpr double kTimeRatioTarget = 0.5;        // default result / CGAL's 100 iterations
constexpr double kAreaRatioTarget = 1.5;        // default area / converged ARAP's
constexpr double kAgreementTarget = 0.02;       // multilevel vs single level, both converged
constexpr double k187kSecondsTarget = 10.0;     // CLI default result at 187k
constexpr double k750kSecondsTarget = 40.0;     // and at 750k
constexpr double k750kMemoryMiBTarget = 8192.0;

struct Options {
  std::vector<std::string> models;  // empty: all
  long max_vertices = 1'000'000;
  std::vector<int> spot_levels = {2, 3, 4};
  int threads = 1;
  /// The default run's DeformerSettings::multilevel_above and multilevel_coarsest_vertices
  /// (the library's defaults unless given: the study of the cascade below 20,000 vertices).
  int multilevel_above = core::kDefaultMultilevelAbove;
  int multilevel_coarsest = core::kDefaultMultilevelCoarsest;
  int converge_iterations = 300;             // budget of the "run to the rule" solves
  long single_converge_max_vertices = 250'000;
  int cgal_iterations = 100;
  int cgal_max_iterations = 1000;            // cap of CGAL's own convergence run
  long cgal_converge_max_vertices = 250'000;
  /// Runs per model (default, cgal, single, multilevel_converged, single_converged); empty: all.
  std::vector<std::string> methods;
  bool variants = false;
  std::vector<std::string> variant_models = {"bumpy_plane_irregular", "cactus_irregular",
                                             "spot47k_bend", "spot47k_twist", "spot188k_bend"};
  /// Only the study's variants whose name contains this (and the default); empty: all.
  std::string variant_filter;
  std::string out_dir = MESHDEFORM_BENCH_RESULTS_DIR;
  std::string stem = "multilevel_time_to_result";
  std::string spot_path = std::string(MESHDEFORM_BENCH_SOURCE_DIR) + "/tests/data/spot.obj";
  std::uint64_t seed = 1;
};

void print_usage(std::ostream& out) {
  out << "usage: meshdeform-bench-converge [options]\n"
         "  --models a,b          model names (default all; see the list printed on start)\n"
         "  --max-vertices N      skip models with more vertices (1000000)\n"
         "  --spot-levels a,b     Loop subdivision levels of Spot (2,3,4: ~47k, 187k, 750k)\n"
         "  --threads N           our solvers' OpenMP threads (1, as the CLI's default)\n"
         "  --multilevel-above N  the default run's multilevel threshold (20000; the `single`\n"
         "                        run stays single-level)\n"
         "  --multilevel-coarsest N  the default run's coarsest level target (1000)\n"
         "  --converge-iterations N  budget of the runs to the stopping rule (300)\n"
         "  --single-converge-max-vertices N  run the single level to the rule up to N (250000)\n"
         "  --cgal-iterations N   CGAL's timed run (100)\n"
         "  --cgal-max-iterations N  cap of CGAL's own convergence run (1000)\n"
         "  --cgal-converge-max-vertices N  CGAL's convergence run up to N vertices (250000)\n"
         "  --methods a,b         only these runs: default, cgal, single, multilevel_converged,\n"
         "                        single_converged (default all; bounds a run at 750k)\n"
         "  --variants            also the multilevel study (docs/multilevel.md)\n"
         "  --variant-models a,b  models of the study (bumpy_plane_irregular, cactus_irregular,\n"
         "                        spot47k_bend, spot47k_twist, spot188k_bend)\n"
         "  --variant-filter TEXT only the variants whose name contains TEXT, and the default\n"
         "  --out-dir DIR         (default "
      << MESHDEFORM_BENCH_RESULTS_DIR
      << ")\n"
         "  --stem NAME           output file stem (multilevel_time_to_result)\n"
         "  --spot PATH           spot.obj (default tests/data/spot.obj)\n";
}

Result<Options> parse_options(int argc, char** argv) {
  Options o;
  BenchFlags flags;
  flags.list("--models", o.models);
  flags.integer("--max-vertices", o.max_vertices, 1L);
  flags.integer_list("--spot-levels", o.spot_levels, 0);
  flags.integer("--threads", o.threads, 0);
  flags.integer("--multilevel-above", o.multilevel_above, 0);
  flags.integer("--multilevel-coarsest", o.multilevel_coarsest, 100);
  flags.integer("--converge-iterations", o.converge_iterations, 1);
  flags.integer("--single-converge-max-vertices", o.single_converge_max_vertices, 0L);
  flags.integer("--cgal-iterations", o.cgal_iterations, 1);
  flags.integer("--cgal-max-iterations", o.cgal_max_iterations, 1);
  flags.integer("--cgal-converge-max-vertices", o.cgal_converge_max_vertices, 0L);
  flags.value("--methods", [&](const std::string& value) -> Status {
    o.methods = split_commas(value);
    for (const std::string& m : o.methods) {
      if (m != "default" && m != "cgal" && m != "single" && m != "multilevel_converged" &&
          m != "single_converged") {
        return Error(ErrorCode::InvalidArgument, "--methods: unknown run '" + m + "'");
      }
    }
    return Status::success();
  });
  flags.flag("--variants", [&] { o.variants = true; });
  flags.list("--variant-models", o.variant_models);
  flags.text("--variant-filter", o.variant_filter);
  flags.text("--out-dir", o.out_dir);
  flags.text("--stem", o.stem);
  flags.text("--spot", o.spot_path);
  MD_RETURN_IF_ERROR(flags.parse(argc, argv));
  return o;
}

struct Model {
  core::DeformationBenchmark bench;
  core::HandleSetup setup;
};

struct ModelSpec {
  std::string name, family;
  long vertices_estimate;
  std::function<Result<core::DeformationBenchmark>()> make;
};

std::vector<ModelSpec> model_specs(const Options& options) {
  std::vector<ModelSpec> specs;
  for (const auto& regular : core::make_suite(core::SuiteScale::Paper)) {
    const std::string name = regular.name;
    const std::uint64_t seed = options.seed;
    specs.push_back({name + "_irregular", "irregular", static_cast<long>(regular.mesh.V.rows()),
                     [name, seed]() -> Result<core::DeformationBenchmark> {
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
    std::vector<core::SpotEdit> edits = {core::SpotEdit::Bend};
    if (first_level) edits = {core::SpotEdit::Bend, core::SpotEdit::Stretch, core::SpotEdit::Twist};
    for (const core::SpotEdit edit : edits) {
      const std::string path = options.spot_path;
      specs.push_back({tag + "_" + core::spot_edit_name(edit), "spot", estimate,
                       [path, level, edit]() -> Result<core::DeformationBenchmark> {
                         return load_spot_edit(path, level, edit);
                       }});
    }
    if (first_level) {
      // Spot remeshed like a scan (irregular density, slivers, flips, jitter): a mesh no
      // generator of ours made the connectivity of, with the bend's slab regions.
      const std::string path = options.spot_path;
      const std::uint64_t seed = options.seed;
      specs.push_back({tag + "_bend_remeshed", "spot", estimate,
                       [path, level, seed]() -> Result<core::DeformationBenchmark> {
                         MD_ASSIGN_OR_RETURN(core::DeformationBenchmark b,
                                             load_spot_edit(path, level, core::SpotEdit::Bend));
                         MD_ASSIGN_OR_RETURN(core::DeformationBenchmark r,
                                             core::make_irregular(b, seed));
                         r.name = b.name + "_remeshed";
                         return r;
                       }});
    }
    first_level = false;
  }
  return specs;
}

// ---- measurement ------------------------------------------------------------------------------

/// Errors, folds and peak of a result.
json quality_json(const Model& model, const core::Measures& rest, const core::MeshTopology& topology,
                  const Positions& V) {
  const core::AngleErrors e = core::angle_errors(rest, V, model.bench.mesh.F, topology);
  const int folds = core::count_folds(rest.phi, core::dihedral_angles(V, model.bench.mesh.F, topology));
  double handle_error = 0;
  for (Eigen::Index j = 0; j < model.setup.constrained.size(); ++j) {
    handle_error = std::max(handle_error,
                            (V.row(model.setup.constrained(j)) - model.setup.targets.row(j)).norm());
  }
  const double diagonal =
      (model.bench.mesh.V.colwise().maxCoeff() - model.bench.mesh.V.colwise().minCoeff()).norm();
  return {{"e_theta", e.e_theta},
          {"e_phi", e.e_phi},
          {"area", e.area_log_rms},
          {"folds", folds},
          {"handle_error", handle_error / diagonal}};
}

/// Ours through make_deformer, as the CLI runs it: precompute, one solve, the result's errors.
json run_ours(const Model& model, const Options& options, bool multilevel, int max_iterations) {
  core::DeformerSettings settings;
  settings.threads = options.threads;
  settings.multilevel_above = multilevel ? options.multilevel_above : 0;
  settings.multilevel_coarsest_vertices = options.multilevel_coarsest;
  core::SolveOptions solve_options;
  solve_options.track_metrics = false;
  if (max_iterations > 0) solve_options.max_iterations = max_iterations;
  const auto t0 = Clock::now();
  auto made = core::make_deformer(core::Method::ScaleAware, model.bench.mesh.V, model.bench.mesh.F,
                                  model.setup.constrained, settings);
  if (!made.ok()) throw std::runtime_error(made.status().to_string());
  const double precompute = seconds_since(t0);
  const auto t1 = Clock::now();
  auto solved = (*made)->solve(model.setup.targets, solve_options);
  if (!solved.ok()) throw std::runtime_error(solved.status().to_string());
  const double solve = seconds_since(t1);
  const long peak = peak_rss_kib();
  const core::SolveReport& r = *solved;
  json out;
  out["precompute_s"] = precompute;
  out["solve_s"] = solve;
  out["total_s"] = precompute + solve;
  out["phases"] = {{"start", r.phases.start}, {"levels", r.phases.levels}, {"fine", r.phases.fine}};
  out["iterations"] = r.iterations;
  out["converged"] = r.converged;
  out["estimated_remaining"] =
      std::isfinite(r.estimated_remaining) ? json(r.estimated_remaining) : json(nullptr);
  out["energy"] = r.history.empty() ? 0.0 : r.history.back().energy;
  out["start"] = core::start_name(r.start);
  out["start_candidates"] = r.start_candidates;
  out["peak_rss_mib"] = static_cast<double>(peak) / 1024.0;
  json levels = json::array();
  for (const core::LevelReport& l : r.levels) {
    levels.push_back({{"level", l.level},
                      {"vertices", l.vertices},
                      {"start_iterations", l.start_iterations},
                      {"start_s", l.start_seconds},
                      {"iterations", l.iterations},
                      {"converged", l.converged},
                      {"seconds", l.seconds}});
  }
  out["levels"] = levels;
  const core::MeshTopology topology =
      core::build_topology(model.bench.mesh.F, static_cast<int>(model.bench.mesh.V.rows())).value();
  const core::Measures rest = core::compute_measures(model.bench.mesh.V, model.bench.mesh.F, topology);
  out["quality"] = quality_json(model, rest, topology, r.V);
  return out;
}

/// One variant of the study: MultilevelSolver with `settings`, default solve options.
json run_variant(const Model& model, const Options& options, core::MultilevelSettings settings) {
  settings.solver.threads = options.threads;
  const auto t0 = Clock::now();
  auto made = core::MultilevelSolver::create(model.bench.mesh.V, model.bench.mesh.F,
                                             model.setup.constrained, settings);
  if (!made.ok()) throw std::runtime_error(made.status().to_string());
  const double precompute = seconds_since(t0);
  core::SolveOptions solve_options;
  solve_options.track_metrics = false;
  const auto t1 = Clock::now();
  auto solved = made->solve(model.setup.targets, solve_options);
  if (!solved.ok()) throw std::runtime_error(solved.status().to_string());
  json out;
  out["precompute_s"] = precompute;
  out["solve_s"] = seconds_since(t1);
  out["total_s"] = precompute + seconds_since(t1);
  out["phases"] = {{"start", solved->phases.start},
                   {"levels", solved->phases.levels},
                   {"fine", solved->phases.fine}};
  out["iterations"] = solved->iterations;
  out["converged"] = solved->converged;
  out["energy"] = solved->history.empty() ? 0.0 : solved->history.back().energy;
  std::string levels;
  for (const core::LevelReport& l : solved->levels) {
    if (!levels.empty()) levels += " > ";
    levels += std::to_string(l.vertices);
  }
  out["levels"] = levels.empty() ? std::to_string(model.bench.mesh.V.rows()) : levels;
  const core::MeshTopology topology =
      core::build_topology(model.bench.mesh.F, static_cast<int>(model.bench.mesh.V.rows())).value();
  const core::Measures rest = core::compute_measures(model.bench.mesh.V, model.bench.mesh.F, topology);
  out["quality"] = quality_json(model, rest, topology, solved->V);
  return out;
}

json run_cgal(const Model& model, const Options& options) {
  CgalArapOptions cgal;
  cgal.fixed_iterations = options.cgal_iterations;
  cgal.max_converge_iterations = options.cgal_max_iterations;
  cgal.run_convergence = model.bench.mesh.V.rows() <= options.cgal_converge_max_vertices;
  auto r = run_cgal_arap(model.bench.mesh.V, model.bench.mesh.F, model.setup.constrained,
                         model.setup.targets, Positions(), cgal);
  if (!r.ok()) throw std::runtime_error(r.status().to_string());
  const core::MeshTopology topology =
      core::build_topology(model.bench.mesh.F, static_cast<int>(model.bench.mesh.V.rows())).value();
  const core::Measures rest = core::compute_measures(model.bench.mesh.V, model.bench.mesh.F, topology);
  json out;
  out["preprocess_s"] = r->preprocess_seconds;
  out["fixed_s"] = r->fixed_seconds;
  out["fixed_total_s"] = r->preprocess_seconds + r->fixed_seconds;
  out["fixed_iterations"] = r->fixed_iterations;
  out["fixed_quality"] = quality_json(model, rest, topology, r->V_fixed);
  if (cgal.run_convergence) {
    out["converge_s"] = r->converge_seconds;
    out["converge_total_s"] = r->preprocess_seconds + r->converge_seconds;
    out["converge_iterations"] = r->converge_iterations;
    out["converge_capped"] = r->converge_iterations >= options.cgal_max_iterations;
    out["converged_quality"] = quality_json(model, rest, topology, r->V_converged);
  }
  out["peak_rss_mib"] = static_cast<double>(peak_rss_kib()) / 1024.0;
  return out;
}

// ---- output -----------------------------------------------------------------------------------

std::string fmt(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

std::string errors_cell(const json& q) {
  if (!q.is_object()) return "-";
  return fmt("%.4f", q["e_theta"].get<double>()) + " / " + fmt("%.4f", q["e_phi"].get<double>()) +
         " / " + fmt("%.4f", q["area"].get<double>()) + " / " + std::to_string(q["folds"].get<int>());
}

struct Row {
  std::string name;
  int vertices = 0, constrained = 0;
  std::string load_before, load_after;
  std::map<std::string, json> runs;         // method -> result (missing: not run)
  std::map<std::string, std::string> failed;  // method -> error
  std::vector<std::pair<std::string, json>> variants;
};

const json* get(const Row& row, const std::string& method) {
  const auto it = row.runs.find(method);
  return it == row.runs.end() ? nullptr : &it->second;
}

double relative(double a, double b) { return std::abs(a - b) / std::max(std::abs(b), 1e-300); }

/// Target lines for one model (met / NOT met / not measured).
std::vector<std::string> targets_of(const Row& row) {
  std::vector<std::string> lines;
  const json* ours = get(row, "default");
  const json* cgal = get(row, "cgal");
  const auto verdict = [](bool met) { return met ? std::string("met") : std::string("**NOT met**"); };
  if (ours && cgal) {
    const double ratio = (*ours)["total_s"].get<double>() / (*cgal)["fixed_total_s"].get<double>();
    std::string line = row.name + ": default result " + fmt("%.2f", (*ours)["total_s"].get<double>()) +
                       " s = " + fmt("%.2f", ratio) + "x CGAL's " +
                       std::to_string((*cgal)["fixed_iterations"].get<int>()) + " iterations (" +
                       fmt("%.2f", (*cgal)["fixed_total_s"].get<double>()) + " s) <= " +
                       fmt("%.1f", kTimeRatioTarget) + "x: " + verdict(ratio <= kTimeRatioTarget);
    lines.push_back(line);
    if (cgal->contains("converged_quality")) {
      const json& q = (*ours)["quality"];
      const json& bar = (*cgal)["converged_quality"];
      const bool theta = q["e_theta"].get<double>() < bar["e_theta"].get<double>();
      const bool phi = q["e_phi"].get<double>() < bar["e_phi"].get<double>();
      const double area_ratio = q["area"].get<double>() / bar["area"].get<double>();
      const bool folds = q["folds"].get<int>() <= bar["folds"].get<int>();
      lines.push_back(row.name + ": E_theta " + fmt("%.4f", q["e_theta"].get<double>()) + " < " +
                      fmt("%.4f", bar["e_theta"].get<double>()) + " (converged ARAP): " +
                      verdict(theta) + "; E_phi " + fmt("%.4f", q["e_phi"].get<double>()) + " < " +
                      fmt("%.4f", bar["e_phi"].get<double>()) + ": " + verdict(phi) + "; area " +
                      fmt("%.2f", area_ratio) + "x <= 1.5x: " +
                      verdict(area_ratio <= kAreaRatioTarget) + "; folds " +
                      std::to_string(q["folds"].get<int>()) + " (converged ARAP " +
                      std::to_string(bar["folds"].get<int>()) + "), no new ones: " +
                      verdict(folds));
    } else {
      lines.push_back(row.name + ": quality against converged ARAP: not measured (CGAL's "
                                 "convergence run skipped at this size)");
    }
  }
  if (ours && row.vertices > 150'000 && row.vertices < 300'000) {
    lines.push_back(row.name + ": CLI default result " + fmt("%.2f", (*ours)["total_s"].get<double>()) +
                    " s <= " + fmt("%.0f", k187kSecondsTarget) + " s: " +
                    verdict((*ours)["total_s"].get<double>() <= k187kSecondsTarget));
  }
  if (ours && row.vertices > 600'000) {
    const double t = (*ours)["total_s"].get<double>();
    const double mib = (*ours)["peak_rss_mib"].get<double>();
    lines.push_back(row.name + ": default result " + fmt("%.1f", t) + " s <= " +
                    fmt("%.0f", k750kSecondsTarget) + " s: " + verdict(t <= k750kSecondsTarget) +
                    "; peak " + fmt("%.0f", mib) + " MiB <= 8 GiB: " +
                    verdict(mib <= k750kMemoryMiBTarget));
  }
  const json* ml = get(row, "multilevel_converged");
  const json* single = get(row, "single_converged");
  if (ml && single) {
    const double dt = relative((*ml)["quality"]["e_theta"].get<double>(),
                               (*single)["quality"]["e_theta"].get<double>());
    const double dp = relative((*ml)["quality"]["e_phi"].get<double>(),
                               (*single)["quality"]["e_phi"].get<double>());
    const double de = relative((*ml)["energy"].get<double>(), (*single)["energy"].get<double>());
    const double worst = std::max({dt, dp, de});
    lines.push_back(row.name + ": converged multilevel vs single level (same rule): E_theta " +
                    fmt("%.1f", 100 * dt) + "%, E_phi " + fmt("%.1f", 100 * dp) + "%, energy " +
                    fmt("%.1f", 100 * de) + "% apart <= 2%: " + verdict(worst <= kAgreementTarget) +
                    ((*single)["converged"].get<bool>() ? "" : " (single level hit the budget)"));
  } else if (ml) {
    lines.push_back(row.name + ": agreement with the single level: not measured (single-level "
                               "convergence run skipped at this size)");
  }
  return lines;
}

std::string markdown(const MachineInfo& machine, const std::string& load_end,
                     const Options& options, const std::vector<Row>& rows) {
  std::ostringstream out;
  out << "# Time to a result at the defaults, against CGAL's ARAP (issue 41)\n\n";
  out << "- date: " << machine.date_utc << "\n";
  out << "- machine: nproc " << machine.hardware_threads << ", CPU " << machine.cpu_model
      << "; load average (1/5/15 min) " << machine.load_average << " at start, " << load_end
      << " at end (per model below; the machine is shared: read times as ratios within a row)\n";
  out << "- BLAS: " << machine.blas << " (" << machine.blas_env << ")\n";
  out << "- compiler: " << machine.compiler << "; build type: " << machine.build_type << "\n";
  out << "- source: git " << machine.git_revision << "\n";
  out << "- ours (`default`): what `meshdeform-cli deform` runs at its defaults, threads "
      << options.threads
      << ": core::make_deformer (the precompute) and one solve with the default SolveOptions "
         "(budget 15 full-resolution iterations, stopping rule `remaining` at tolerance 1e-3: "
      << core::stopping_rule_description(core::StoppingRule::Remaining)
      << "); multilevel above " << options.multilevel_above << " vertices (coarsest level ~"
      << options.multilevel_coarsest << ")"
      << (options.multilevel_above != core::kDefaultMultilevelAbove ||
                  options.multilevel_coarsest != core::kDefaultMultilevelCoarsest
              ? " (not the library's defaults: --multilevel-above / --multilevel-coarsest)"
              : "")
      << ". Time = precompute + solve, wall clock. `single`: the same with the "
         "multilevel path off (DeformerSettings::multilevel_above 0). `*_converged`: the same "
         "two run to the same rule with a budget of "
      << options.converge_iterations << " iterations\n";
  out << "- CGAL: Surface_mesh_deformation, spokes-and-rims ARAP (its default), Eigen SparseLU, one "
         "thread; preprocess + deform("
      << options.cgal_iterations << ", 0) timed (the 100-iteration time), then reset + deform("
      << options.cgal_max_iterations
      << ", 1e-4), its own convergence test (relative energy change 1e-4), for its time to "
         "converge and the quality bar (converged ARAP)\n";
  out << "- errors: E_theta / E_phi (RMS radians) / area (RMS log area ratio) / folds (interior "
         "edges whose dihedral angle moved by more than 90 degrees), by core::angle_errors and "
         "core::count_folds for every method alike; each run in its own forked process (peak "
         "RSS its own)\n\n";

  out << "## Time to result\n\n";
  out << "| model | #V | load before | default s (setup + solve) | start / levels / fine s | its "
         "| CGAL 100 its s | default / CGAL 100 | CGAL converged its, s | single (ML off) s, its | "
         "default / single | peak MiB default / CGAL |\n";
  out << "|---|---:|---|---:|---|---|---:|---:|---|---|---:|---|\n";
  for (const Row& row : rows) {
    const json* ours = get(row, "default");
    const json* cgal = get(row, "cgal");
    const json* single = get(row, "single");
    out << "| " << row.name << " | " << row.vertices << " | " << row.load_before << " | ";
    if (ours) {
      out << fmt("%.2f", (*ours)["total_s"].get<double>()) << " ("
          << fmt("%.2f", (*ours)["precompute_s"].get<double>()) << " + "
          << fmt("%.2f", (*ours)["solve_s"].get<double>()) << ") | "
          << fmt("%.2f", (*ours)["phases"]["start"].get<double>()) << " / "
          << fmt("%.2f", (*ours)["phases"]["levels"].get<double>()) << " / "
          << fmt("%.2f", (*ours)["phases"]["fine"].get<double>()) << " | "
          << (*ours)["iterations"].get<int>()
          << ((*ours)["converged"].get<bool>() ? " (conv.)" : "") << " | ";
    } else {
      out << (row.failed.count("default") ? "failed" : "-") << " | - | - | ";
    }
    if (cgal) {
      out << fmt("%.2f", (*cgal)["fixed_total_s"].get<double>()) << " | ";
      out << (ours ? fmt("%.2f", (*ours)["total_s"].get<double>() /
                                     (*cgal)["fixed_total_s"].get<double>())
                   : std::string("-"))
          << " | ";
      if (cgal->contains("converge_total_s")) {
        out << (*cgal)["converge_iterations"].get<int>()
            << ((*cgal)["converge_capped"].get<bool>() ? " (cap)" : "") << ", "
            << fmt("%.2f", (*cgal)["converge_total_s"].get<double>()) << " | ";
      } else {
        out << "not run | ";
      }
    } else {
      out << "- | - | - | ";
    }
    if (single) {
      out << fmt("%.2f", (*single)["total_s"].get<double>()) << ", "
          << (*single)["iterations"].get<int>()
          << ((*single)["converged"].get<bool>() ? " (conv.)" : "") << " | "
          << (ours ? fmt("%.2f", (*ours)["total_s"].get<double>() / (*single)["total_s"].get<double>())
                   : std::string("-"))
          << " | ";
    } else {
      out << "- | - | ";
    }
    out << (ours ? fmt("%.0f", (*ours)["peak_rss_mib"].get<double>()) : std::string("-")) << " / "
        << (cgal ? fmt("%.0f", (*cgal)["peak_rss_mib"].get<double>()) : std::string("-")) << " |\n";
  }

  out << "\n## Quality beside each time\n\nE_theta / E_phi / area / folds.\n\n";
  out << "| model | default | single (ML off) | CGAL 100 its | CGAL converged (the bar) | "
         "default: handle error / diagonal |\n";
  out << "|---|---|---|---|---|---:|\n";
  for (const Row& row : rows) {
    const json* ours = get(row, "default");
    const json* single = get(row, "single");
    const json* cgal = get(row, "cgal");
    out << "| " << row.name << " | " << (ours ? errors_cell((*ours)["quality"]) : "-") << " | "
        << (single ? errors_cell((*single)["quality"]) : "-") << " | "
        << (cgal ? errors_cell((*cgal)["fixed_quality"]) : "-") << " | "
        << (cgal && cgal->contains("converged_quality") ? errors_cell((*cgal)["converged_quality"])
                                                         : std::string("-"))
        << " | "
        << (ours ? fmt("%.1e", (*ours)["quality"]["handle_error"].get<double>()) : std::string("-"))
        << " |\n";
  }

  out << "\n## Run to the stopping rule: multilevel against single level\n\n";
  out << "Both with the default rule and tolerance and a budget of " << options.converge_iterations
      << " full-resolution iterations.\n\n";
  out << "| model | multilevel s, its | single level s, its | multilevel E_theta / E_phi / "
         "area / folds | single level | energy multilevel / single |\n";
  out << "|---|---|---|---|---|---|\n";
  for (const Row& row : rows) {
    const json* ml = get(row, "multilevel_converged");
    const json* single = get(row, "single_converged");
    if (!ml && !single) continue;
    const auto cell = [](const json* r) -> std::string {
      if (!r) return "-";
      return fmt("%.2f", (*r)["total_s"].get<double>()) + ", " +
             std::to_string((*r)["iterations"].get<int>()) +
             ((*r)["converged"].get<bool>() ? " (conv.)" : " (budget)");
    };
    out << "| " << row.name << " | " << cell(ml) << " | " << cell(single) << " | "
        << (ml ? errors_cell((*ml)["quality"]) : "-") << " | "
        << (single ? errors_cell((*single)["quality"]) : "-") << " | "
        << (ml ? fmt("%.5g", (*ml)["energy"].get<double>()) : std::string("-")) << " / "
        << (single ? fmt("%.5g", (*single)["energy"].get<double>()) : std::string("-")) << " |\n";
  }

  bool any_variants = false;
  for (const Row& row : rows) any_variants = any_variants || !row.variants.empty();
  if (any_variants) {
    out << "\n## Study: alternatives of the multilevel solve\n\n";
    out << "core::MultilevelSolver with one setting changed from the default, default solve "
           "options, time = create + solve (docs/multilevel.md).\n\n";
    out << "| model | variant | levels | s (setup + solve) | start / levels / fine s | fine its | "
           "E_theta / E_phi / area / folds | energy |\n";
    out << "|---|---|---|---|---|---|---|---|\n";
    for (const Row& row : rows) {
      for (const auto& [name, r] : row.variants) {
        if (r.contains("error")) {
          out << "| " << row.name << " | " << name << " | failed: " << r["error"].get<std::string>()
              << " | | | | | |\n";
          continue;
        }
        out << "| " << row.name << " | " << name << " | " << r["levels"].get<std::string>() << " | "
            << fmt("%.2f", r["total_s"].get<double>()) << " ("
            << fmt("%.2f", r["precompute_s"].get<double>()) << " + "
            << fmt("%.2f", r["solve_s"].get<double>()) << ") | "
            << fmt("%.2f", r["phases"]["start"].get<double>()) << " / "
            << fmt("%.2f", r["phases"]["levels"].get<double>()) << " / "
            << fmt("%.2f", r["phases"]["fine"].get<double>()) << " | "
            << r["iterations"].get<int>() << (r["converged"].get<bool>() ? " (conv.)" : "")
            << " | " << errors_cell(r["quality"]) << " | " << fmt("%.5g", r["energy"].get<double>())
            << " |\n";
      }
    }
  }

  out << "\n## Targets\n\n";
  out << "Machine: nproc " << machine.hardware_threads << ", " << machine.cpu_model
      << ", load at start " << machine.load_average << ". The server's 187k target (a converged "
         "full-resolution revision within 3 s of the release) is measured by "
         "bench/run_multires_server.sh, not here.\n\n";
  for (const Row& row : rows) {
    for (const std::string& line : targets_of(row)) out << "- " << line << "\n";
    for (const auto& [method, error] : row.failed) {
      out << "- " << row.name << ": " << method << " failed: " << error << "\n";
    }
  }
  return out.str();
}

Status run(int argc, char** argv) {
  MD_ASSIGN_OR_RETURN(const Options options, parse_options(argc, argv));
  const std::vector<ModelSpec> specs = model_specs(options);
  std::cerr << "models:";
  for (const ModelSpec& spec : specs) std::cerr << " " << spec.name;
  std::cerr << "\n";
  for (const std::string& name : options.models) {
    if (std::none_of(specs.begin(), specs.end(), [&](const ModelSpec& s) { return s.name == name; })) {
      return Error(ErrorCode::InvalidArgument, "unknown model '" + name + "'");
    }
  }
  const MachineInfo machine = collect_machine_info();
  std::vector<Row> rows;
  json rows_json = json::array();
  for (const ModelSpec& spec : specs) {
    if (!options.models.empty() &&
        std::find(options.models.begin(), options.models.end(), spec.name) == options.models.end()) {
      continue;
    }
    if (spec.vertices_estimate > options.max_vertices) continue;
    std::cerr << "[" << spec.name << "] generating\n";
    MD_ASSIGN_OR_RETURN(core::DeformationBenchmark bench, spec.make());
    Model model;
    MD_ASSIGN_OR_RETURN(model.setup, core::constraints_from_selection(bench.mesh.V, bench.selection,
                                                                      bench.transform));
    model.bench = std::move(bench);
    Row row;
    row.name = spec.name;
    row.vertices = static_cast<int>(model.bench.mesh.V.rows());
    row.constrained = static_cast<int>(model.setup.constrained.size());
    row.load_before = read_load_average();
    std::vector<std::pair<std::string, std::function<json()>>> methods = {
        {"default", [&] { return run_ours(model, options, true, 0); }},
        {"cgal", [&] { return run_cgal(model, options); }},
        {"single", [&] { return run_ours(model, options, false, 0); }},
        {"multilevel_converged",
         [&] { return run_ours(model, options, true, options.converge_iterations); }},
    };
    if (row.vertices <= options.single_converge_max_vertices) {
      methods.push_back({"single_converged", [&] {
                           return run_ours(model, options, false, options.converge_iterations);
                         }});
    }
    for (auto& [method, body] : methods) {
      if (!options.methods.empty() && std::find(options.methods.begin(), options.methods.end(),
                                                method) == options.methods.end()) {
        continue;
      }
      std::cerr << "[" << spec.name << "] " << row.vertices << " vertices: " << method << " (load "
                << read_load_average() << ")\n";
      Result<json> result = run_in_child(body);
      if (!result.ok()) {
        row.failed[method] = result.status().to_string();
        std::cerr << "[" << spec.name << "] " << method << " failed: " << row.failed[method] << "\n";
        continue;
      }
      row.runs[method] = std::move(result).value();
    }
    if (options.variants &&
        std::find(options.variant_models.begin(), options.variant_models.end(), spec.name) !=
            options.variant_models.end()) {
      std::vector<std::pair<std::string, core::MultilevelSettings>> variants;
      core::MultilevelSettings base;
      base.coarsest_vertices = core::kDefaultMultilevelCoarsest;
      variants.push_back({"default (correction transfer, level tol 1e-2)", base});
      {
        core::MultilevelSettings v = base;
        v.transfer = core::LevelTransfer::Prolong;
        variants.push_back({"cascade only: plain prolongation", v});
      }
      {
        core::MultilevelSettings v = base;
        v.level_tolerance = 1e-3;
        variants.push_back({"levels to tol 1e-3", v});
      }
      {
        core::MultilevelSettings v = base;
        v.fine_corrections = 2;
        variants.push_back({"+ 2 coarse-grid corrections in the fine iteration", v});
      }
      for (const auto& [tolerance, name] :
           {std::pair{3e-4, "3e-4"}, std::pair{1e-3, "1e-3"}}) {
        core::MultilevelSettings v = base;
        v.start_level_tolerance = tolerance;
        variants.push_back({std::string("start above the coarsest level to the rule at ") + name, v});
      }
      for (const int its : {5, 15, 40}) {
        core::MultilevelSettings v = base;
        v.fine_start_max_iterations = its;
        variants.push_back({"full-resolution start: at most " + std::to_string(its) + " ARAP its", v});
      }
      {
        core::MultilevelSettings v = base;
        v.transfer = core::LevelTransfer::Detail;
        variants.push_back({"detail transfer", v});
        for (const int its : {15, 40}) {
          v.start_max_iterations = its;
          v.fine_start_max_iterations = its;
          variants.push_back({"detail transfer, starts above the coarsest at most " +
                                  std::to_string(its) + " ARAP its", v});
        }
      }
      {
        core::MultilevelSettings v = base;
        v.coarsest_vertices = 4000;
        variants.push_back({"fewer levels: coarsest 4000", v});
      }
      {
        core::MultilevelSettings v = base;
        v.coarsest_vertices = 250;
        variants.push_back({"more levels: coarsest 250", v});
      }
      {
        core::MultilevelSettings v = base;
        v.level_ratio = 16;
        variants.push_back({"two levels apart: ratio 16", v});
      }
      for (const auto& [name, settings] : variants) {
        if (!options.variant_filter.empty() && &name != &variants.front().first &&
            name.find(options.variant_filter) == std::string::npos) {
          continue;
        }
        std::cerr << "[" << spec.name << "] variant: " << name << "\n";
        Result<json> result = run_in_child([&] { return run_variant(model, options, settings); });
        row.variants.push_back(
            {name, result.ok() ? std::move(result).value()
                               : json{{"error", result.status().to_string()}}});
      }
    }
    row.load_after = read_load_average();
    json row_json = {{"model", row.name},
                     {"vertices", row.vertices},
                     {"constrained", row.constrained},
                     {"load_before", row.load_before},
                     {"load_after", row.load_after},
                     {"runs", row.runs},
                     {"failed", row.failed}};
    json variants = json::array();
    for (const auto& [name, r] : row.variants) variants.push_back({{"variant", name}, {"result", r}});
    row_json["variants"] = variants;
    row_json["targets"] = targets_of(row);
    rows_json.push_back(row_json);
    rows.push_back(std::move(row));
    // Write after every model: a long run leaves its results so far.
    const std::string load_now = read_load_average();
    std::error_code error;
    std::filesystem::create_directories(options.out_dir, error);
    const std::filesystem::path dir(options.out_dir);
    MD_RETURN_IF_ERROR(write_file(dir / (options.stem + ".md"), markdown(machine, load_now, options, rows)));
    MD_RETURN_IF_ERROR(write_file(
        dir / (options.stem + ".json"),
        json{{"machine", machine_json(machine, load_now)}, {"rows", rows_json}}.dump() + "\n"));
  }
  const std::string load_end = read_load_average();
  const std::string md = markdown(machine, load_end, options, rows);
  std::cout << md << std::flush;
  const std::filesystem::path dir(options.out_dir);
  MD_RETURN_IF_ERROR(write_file(dir / (options.stem + ".md"), md));
  MD_RETURN_IF_ERROR(write_file(
      dir / (options.stem + ".json"),
      json{{"machine", machine_json(machine, load_end)}, {"rows", rows_json}}.dump() + "\n"));
  std::cerr << "wrote " << (dir / options.stem).string() << ".{md,json}\n";
  return Status::success();
}

}  // namespace
}  // namespace meshdeform::bench

int main(int argc, char** argv) {
  return meshdeform::bench::bench_main(argc, argv, "meshdeform-bench-converge",
                                       meshdeform::bench::print_usage, meshdeform::bench::run);
}
