// meshdeform-bench-table1: the paper's Table 1 suite (Liu et al., "Scale-aware shape
// manipulation") run with our scale-aware solver and, on the same mesh and edit, with CGAL's
// Surface_mesh_deformation (ARAP). Writes a Markdown table (stdout and <out-dir>/table1.md) and
// <out-dir>/table1.json. Everything except the timings is deterministic.

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <optional>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <nlohmann/json.hpp>

#include "bench/bench_config.h"
#include "bench/cgal_arap.h"
#include "bench/bench_args.h"
#include "bench/bench_edits.h"
#include "bench/machine_info.h"
#include "core/methods/deform_types.h"
#include "core/methods/deformer.h"
#include "core/io/report_json.h"
#include "core/mesh/measures.h"
#include "core/samples/samples.h"
#include "core/methods/scale_aware.h"
#include "core/base/status.h"
#include "core/mesh/topology.h"

namespace meshdeform::bench {
namespace {

using core::AngleErrors;

// Targets the project set itself (see bench/README.md).
constexpr double kPlaneSolveTargetSeconds = 3.0;       // 40,401-vertex plane, init to convergence
constexpr double kPerIterationRatioTarget = 2.0;       // ours per outer iteration / CGAL per iteration
constexpr double kMidSizePerIterationTarget = 0.015;   // ~5,000-vertex models, seconds per outer it.
constexpr int kPlaneTargetMinVertices = 40000;         // the plane target applies at paper size only
constexpr int kMidSizeMinVertices = 1000;              // "~5,000 vertices": the paper's 2.6k-5.3k models
constexpr int kMidSizeMaxVertices = 10000;

// The paper's Table 1 (runtime on the authors' laptop, E_theta, E_phi), for reference only: its
// meshes are not ours, so the error columns are comparable in magnitude, not value.
struct PaperRow {
  const char* name;
  int vertices;
  double seconds, e_theta, e_phi;
};
constexpr PaperRow kPaperTable1[] = {
    {"bumpy_plane", 40401, 76, 0.021, 0.113},
    {"cylinder", 4802, 8, 0.013, 0.238},
    {"bar", 2602, 6, 0.086, 1.289},
    {"cactus", 5261, 11, 0.036, 0.140},
};

const PaperRow* paper_row(const std::string& name) {
  for (const PaperRow& row : kPaperTable1) {
    if (name == row.name) return &row;
  }
  return nullptr;
}

struct Options {
  std::vector<std::string> models;  // empty: all
  bool small = false;
  std::string out_dir = MESHDEFORM_BENCH_RESULTS_DIR;
  int iterations = 15;
  int threads = 0;
  double rigidity = core::kDefaultRigidity;
  double move_fraction = 0.05;
  int move_iterations = 2;
  bool track_metrics = true;
  bool run_cgal = true;
  CgalArapVariant cgal_variant = CgalArapVariant::SpokesAndRims;
  int cgal_max_converge_iterations = 100;
};

void print_usage(std::ostream& out) {
  out << "usage: meshdeform-bench-table1 [options]\n"
         "  --models a,b          models to run (bumpy_plane, cylinder, bar, cactus; default all)\n"
         "  --small               SuiteScale::Small (quick check; writes table1_small.{md,json})\n"
         "  --out-dir DIR         where table1.md / table1.json go (default "
      << MESHDEFORM_BENCH_RESULTS_DIR
      << ")\n"
         "  --iterations N        outer-iteration budget of our solve and CGAL's fixed run (15)\n"
         "  --threads N           our solver's OpenMP threads (0: all hardware threads; default 0)\n"
         "  --rigidity X          scale control of our scale-aware runs (default: the library's;\n"
         "                        0 = the paper's method, as in the paper's Table 1)\n"
         "  --move-fraction F     warm move: continue the edit by this fraction (0.05)\n"
         "  --move-iterations N   warm move: outer-iteration budget (2)\n"
         "  --no-track-metrics    solve with SolveOptions::track_metrics = false\n"
         "  --cgal-arap V         spokes_and_rims (CGAL default) | original | sre\n"
         "  --cgal-max-iterations N  cap of CGAL's convergence run (100)\n"
         "  --no-cgal             skip CGAL\n";
}

Result<Options> parse_options(int argc, char** argv) {
  Options options;
  BenchFlags flags;
  flags.list("--models", options.models);
  flags.flag("--small", [&] { options.small = true; });
  flags.text("--out-dir", options.out_dir);
  flags.integer("--iterations", options.iterations, 1);
  flags.value("--rigidity", [&](const std::string& value) -> Status {
    char* end = nullptr;
    options.rigidity = std::strtod(value.c_str(), &end);
    if (end == value.c_str() || *end != '\0' || !(options.rigidity >= 0) ||
        !std::isfinite(options.rigidity)) {
      return Error(ErrorCode::InvalidArgument, "--rigidity wants a number >= 0, got '" + value + "'");
    }
    return Status::success();
  });
  flags.integer("--threads", options.threads, 0);
  flags.value("--move-fraction", [&](const std::string& value) -> Status {
    char* end = nullptr;
    options.move_fraction = std::strtod(value.c_str(), &end);
    if (end == value.c_str() || *end != '\0' || !std::isfinite(options.move_fraction)) {
      return Error(ErrorCode::InvalidArgument, "--move-fraction wants a number, got '" + value + "'");
    }
    return Status::success();
  });
  flags.integer("--move-iterations", options.move_iterations, 1);
  flags.flag("--no-track-metrics", [&] { options.track_metrics = false; });
  flags.value("--cgal-arap", [&](const std::string& value) -> Status {
    MD_ASSIGN_OR_RETURN(options.cgal_variant, parse_cgal_arap_variant(value));
    return Status::success();
  });
  flags.integer("--cgal-max-iterations", options.cgal_max_converge_iterations, 1);
  flags.flag("--no-cgal", [&] { options.run_cgal = false; });
  MD_RETURN_IF_ERROR(flags.parse(argc, argv));
  return options;
}

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

struct OurRun {
  double precompute_seconds = 0;
  double solve_seconds = 0;
  double init_seconds = 0;          // Laplacian initialisation (history[0].elapsed_seconds)
  int iterations = 0;
  bool converged = false;
  int factorizations = 0;
  int pcg_iterations = 0;
  AngleErrors errors;
  AngleErrors init_errors;          // of the Laplacian starting guess
  double move_seconds = 0;
  int move_iterations = 0;
  int move_factorizations = 0;
  int move_pcg_iterations = 0;
  AngleErrors move_errors;
  std::vector<core::IterationInfo> history;
  double per_iteration_seconds() const {
    return iterations > 0 ? (solve_seconds - init_seconds) / iterations : 0.0;
  }
};

struct CgalRun {
  CgalArapResult raw;
  AngleErrors fixed_errors, converged_errors, move_errors;
  double per_iteration_seconds() const {
    return raw.fixed_iterations > 0 ? raw.fixed_seconds / raw.fixed_iterations : 0.0;
  }
};

// One method of the comparison table (paper Section 6 / issue 3): precompute + solve time and
// the errors of its result, all through core::make_deformer on the same mesh and edit.
struct MethodRun {
  std::string name;
  double seconds = 0;
  int iterations = 0;
  AngleErrors errors;
};

struct ModelRow {
  std::string name;
  std::vector<MethodRun> methods;
  int vertices = 0;
  int faces = 0;
  int fixed = 0;
  int handles = 0;
  bool move_used_fallback = false;
  OurRun ours;
  std::optional<CgalRun> cgal;
};

AngleErrors errors_of(const core::Measures& rest, const Positions& V, const Triangles& F,
                      const core::MeshTopology& topology) {
  return core::angle_errors(rest, core::compute_measures(V, F, topology));
}

Result<ModelRow> run_model(const core::DeformationBenchmark& model, const Options& options) {
  ModelRow row;
  row.name = model.name;
  const Positions& V0 = model.mesh.V;
  const Triangles& F = model.mesh.F;
  row.vertices = static_cast<int>(V0.rows());
  row.faces = static_cast<int>(F.rows());
  for (Eigen::Index i = 0; i < model.selection.size(); ++i) {
    row.fixed += model.selection(i) == static_cast<int>(core::VertexRole::Fixed) ? 1 : 0;
    row.handles += model.selection(i) == static_cast<int>(core::VertexRole::Handle) ? 1 : 0;
  }

  MD_ASSIGN_OR_RETURN(const core::HandleSetup setup,
                      core::constraints_from_selection(V0, model.selection, model.transform));
  const Eigen::Matrix4d move_transform =
      affine_power(model.transform, 1.0 + options.move_fraction, &row.move_used_fallback);
  MD_ASSIGN_OR_RETURN(const core::HandleSetup move_setup,
                      core::constraints_from_selection(V0, model.selection, move_transform));
  MD_ASSIGN_OR_RETURN(const core::MeshTopology topology,
                      core::build_topology(F, static_cast<int>(V0.rows())));
  const core::Measures rest = core::compute_measures(V0, F, topology);

  // Ours: precompute, then from Auto's start (the Laplacian guess at rigidity 0, converged ARAP
  // above) to convergence or the budget.
  std::cerr << "[" << row.name << "] " << row.vertices << " vertices: scale-aware create\n";
  core::ScaleAwareSettings settings;
  settings.threads = options.threads;
  auto start = std::chrono::steady_clock::now();
  MD_ASSIGN_OR_RETURN(core::ScaleAwareSolver solver,
                      core::ScaleAwareSolver::create(V0, F, setup.constrained, settings));
  row.ours.precompute_seconds = seconds_since(start);

  core::SolveOptions solve_options;
  solve_options.max_iterations = options.iterations;
  solve_options.track_metrics = options.track_metrics;
  solve_options.rigidity = options.rigidity;
  std::cerr << "[" << row.name << "] scale-aware solve (budget " << options.iterations << ")\n";
  MD_ASSIGN_OR_RETURN(const core::SolveReport report, solver.solve(setup.targets, solve_options));
  row.ours.solve_seconds = report.seconds;
  row.ours.init_seconds = report.history.empty() ? 0.0 : report.history.front().elapsed_seconds;
  row.ours.iterations = report.iterations;
  row.ours.converged = report.converged;
  row.ours.factorizations = report.factorizations;
  row.ours.pcg_iterations = report.pcg_iterations;
  row.ours.history = report.history;
  row.ours.errors = errors_of(rest, report.V, F, topology);
  if (!report.history.empty() && options.track_metrics) {
    row.ours.init_errors.e_theta = report.history.front().e_theta;
    row.ours.init_errors.e_phi = report.history.front().e_phi;
  }

  // The interactive figure: continue the edit a little and solve with a small budget, warm from the
  // previous result with the cached factor.
  core::SolveOptions move_options = solve_options;
  move_options.max_iterations = options.move_iterations;
  move_options.start = core::StartFrom::Previous;
  std::cerr << "[" << row.name << "] scale-aware warm move\n";
  MD_ASSIGN_OR_RETURN(const core::SolveReport move, solver.solve(move_setup.targets, move_options));
  row.ours.move_seconds = move.seconds;
  row.ours.move_iterations = move.iterations;
  row.ours.move_factorizations = move.factorizations;
  row.ours.move_pcg_iterations = move.pcg_iterations;
  row.ours.move_errors = errors_of(rest, move.V, F, topology);

  // The method comparison: Laplacian editing, ARAP (ours), scale-aware, scale-aware + ORA.
  struct Variant {
    const char* name;
    core::Method method;
    bool ora;
    core::StepTwoPreconditioner preconditioner = core::StepTwoPreconditioner::BlockTrace;
  };
  for (const Variant& variant :
       {Variant{"laplacian", core::Method::Laplacian, false},
        Variant{"arap", core::Method::Arap, false},
        Variant{"scale_aware", core::Method::ScaleAware, false},
        Variant{"scale_aware (lagged Cholesky PCG)", core::Method::ScaleAware, false,
                core::StepTwoPreconditioner::LaggedCholesky},
        Variant{"scale_aware+ora", core::Method::ScaleAware, true}}) {
    std::cerr << "[" << row.name << "] method " << variant.name << "\n";
    core::DeformerSettings deformer_settings;
    deformer_settings.threads = options.threads;
    deformer_settings.preconditioner = variant.preconditioner;
    const auto method_start = std::chrono::steady_clock::now();
    MD_ASSIGN_OR_RETURN(std::unique_ptr<core::Deformer> deformer,
                        core::make_deformer(variant.method, V0, F, setup.constrained,
                                            deformer_settings));
    core::SolveOptions method_options = solve_options;
    method_options.ora = variant.ora;
    MD_ASSIGN_OR_RETURN(const core::SolveReport result,
                        deformer->solve(setup.targets, method_options));
    row.methods.push_back({variant.name, seconds_since(method_start), result.iterations,
                           errors_of(rest, result.V, F, topology)});
  }

  if (options.run_cgal) {
    std::cerr << "[" << row.name << "] CGAL ARAP (" << cgal_arap_variant_name(options.cgal_variant)
              << ")\n";
    CgalArapOptions cgal_options;
    cgal_options.variant = options.cgal_variant;
    cgal_options.fixed_iterations = options.iterations;
    cgal_options.max_converge_iterations = options.cgal_max_converge_iterations;
    cgal_options.move_iterations = options.move_iterations;
    MD_ASSIGN_OR_RETURN(CgalArapResult raw,
                        run_cgal_arap(V0, F, setup.constrained, setup.targets, move_setup.targets,
                                      cgal_options));
    CgalRun cgal;
    cgal.fixed_errors = errors_of(rest, raw.V_fixed, F, topology);
    if (raw.V_converged.rows() > 0) cgal.converged_errors = errors_of(rest, raw.V_converged, F, topology);
    if (raw.V_move.rows() > 0) cgal.move_errors = errors_of(rest, raw.V_move, F, topology);
    cgal.raw = std::move(raw);
    row.cgal = std::move(cgal);
  }
  std::cerr << "[" << row.name << "] done\n";
  return row;
}

// ---- targets ----------------------------------------------------------------------------------

struct TargetCheck {
  std::string target;
  std::string model;
  double value = 0;
  double threshold = 0;
  std::string unit;
  bool met = false;
};

std::vector<TargetCheck> check_targets(const std::vector<ModelRow>& rows) {
  std::vector<TargetCheck> checks;
  for (const ModelRow& row : rows) {
    if (row.name == "bumpy_plane" && row.vertices >= kPlaneTargetMinVertices) {
      checks.push_back({"plane: Laplacian init to convergence / budget <= 3 s", row.name,
                        row.ours.solve_seconds, kPlaneSolveTargetSeconds, "s",
                        row.ours.solve_seconds <= kPlaneSolveTargetSeconds});
    }
    if (row.cgal && row.cgal->per_iteration_seconds() > 0) {
      const double ratio = row.ours.per_iteration_seconds() / row.cgal->per_iteration_seconds();
      checks.push_back({"per outer iteration <= 2x CGAL ARAP per iteration", row.name, ratio,
                        kPerIterationRatioTarget, "x", ratio <= kPerIterationRatioTarget});
    }
    if (row.name != "bumpy_plane" && row.vertices >= kMidSizeMinVertices &&
        row.vertices <= kMidSizeMaxVertices) {
      const double per_it = row.ours.per_iteration_seconds();
      checks.push_back({"~5k-vertex model: <= 15 ms per outer iteration", row.name, 1e3 * per_it,
                        1e3 * kMidSizePerIterationTarget, "ms",
                        per_it <= kMidSizePerIterationTarget});
    }
  }
  return checks;
}

// ---- output -----------------------------------------------------------------------------------

std::string fmt(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}
std::string ms(double seconds) { return fmt("%.1f", 1e3 * seconds); }
std::string sec(double seconds) { return fmt("%.3f", seconds); }
std::string err(double radians) { return fmt("%.4f", radians); }

std::string markdown(const MachineInfo& machine, const std::string& load_at_end, const Options& options,
                     const std::vector<ModelRow>& rows, const std::vector<TargetCheck>& checks) {
  std::ostringstream out;
  out << "# Table 1: scale-aware solver vs CGAL ARAP" << (options.small ? " (small suite)" : "")
      << "\n\n";
  out << "- date: " << machine.date_utc << "\n";
  out << "- machine: nproc " << machine.hardware_threads << ", CPU " << machine.cpu_model
      << "; load average (1/5/15 min) " << machine.load_average << " at start, " << load_at_end
      << " at end\n";
  out << "- BLAS: " << machine.blas << " (" << machine.blas_env << ")\n";
  out << "- compiler: " << machine.compiler << "; build type: " << machine.build_type << "\n";
  out << "- source: git " << machine.git_revision << "\n";
  out << "- suite: " << (options.small ? "SuiteScale::Small" : "SuiteScale::Paper")
      << "; our solver: SolveOptions defaults, rigidity " << options.rigidity
      << (options.rigidity == 0 ? " (the paper's method)" : "") << ", max_iterations "
      << options.iterations
      << ", track_metrics " << (options.track_metrics ? "true" : "false") << ", threads "
      << (options.threads == 0 ? std::string("0 (all)") : std::to_string(options.threads))
      << ", step-two preconditioner: block trace (the default; the lagged Cholesky factor is "
         "compared in the methods table)\n";
  out << "- CGAL: Surface_mesh_deformation<Surface_mesh<Simple_cartesian<double>::Point_3>>, "
      << cgal_arap_variant_name(options.cgal_variant)
      << ", default cotangent weights and Eigen SparseLU/COLAMD solver, single thread; every vertex in "
         "the ROI, fixed and handle vertices as control vertices; "
      << options.iterations << " iterations with tolerance 0 (timed), then to convergence "
         "(tolerance 1e-4, cap " << options.cgal_max_converge_iterations << ") from the rest pose\n";
  out << "- warm move: the edit continued to T^" << fmt("%.2f", 1.0 + options.move_fraction)
      << ", budget " << options.move_iterations
      << " outer iterations (ours: warm start + cached factor; CGAL: deform("
      << options.move_iterations << ", 0) from its " << options.iterations << "-iteration state)\n";
  out << "- errors: E_theta, E_phi = RMS radians (paper Section 5.1), area = RMS of log(area'/area) "
         "over faces; all computed by core::angle_errors for both methods\n\n";

  out << "## Ours (scale-aware)\n\n";
  out << "| model | #V | precompute (s) | solve (s) | init (s) | outer its | converged | "
         "ms / outer it | factorizations | PCG its | E_theta | E_phi | area | paper: s / E_theta / "
         "E_phi |\n";
  out << "|---|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|---|\n";
  for (const ModelRow& row : rows) {
    const OurRun& o = row.ours;
    const PaperRow* paper = paper_row(row.name);
    out << "| " << row.name << " | " << row.vertices << " | " << sec(o.precompute_seconds) << " | "
        << sec(o.solve_seconds) << " | " << sec(o.init_seconds) << " | " << o.iterations << " | "
        << (o.converged ? "yes" : "no") << " | " << ms(o.per_iteration_seconds()) << " | "
        << o.factorizations << " | " << o.pcg_iterations << " | " << err(o.errors.e_theta) << " | "
        << err(o.errors.e_phi) << " | " << err(o.errors.area_log_rms) << " | "
        << (paper != nullptr ? fmt("%.0f", paper->seconds) + " / " + fmt("%.3f", paper->e_theta) +
                                   " / " + fmt("%.3f", paper->e_phi)
                             : std::string("-"))
        << " |\n";
  }

  bool any_cgal = false;
  for (const ModelRow& row : rows) any_cgal = any_cgal || row.cgal.has_value();
  if (any_cgal) {
    out << "\n## CGAL ARAP (" << cgal_arap_variant_name(options.cgal_variant) << ")\n\n";
    out << "| model | #V | preprocess (s) | " << options.iterations << " its (s) | ms / it | E_theta | "
        << "E_phi | area | conv. its | conv. (s) | conv. E_theta | conv. E_phi | conv. area |\n";
    out << "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for (const ModelRow& row : rows) {
      if (!row.cgal) continue;
      const CgalRun& c = *row.cgal;
      out << "| " << row.name << " | " << row.vertices << " | " << sec(c.raw.preprocess_seconds)
          << " | " << sec(c.raw.fixed_seconds) << " | " << ms(c.per_iteration_seconds()) << " | "
          << err(c.fixed_errors.e_theta) << " | " << err(c.fixed_errors.e_phi) << " | "
          << err(c.fixed_errors.area_log_rms) << " | " << c.raw.converge_iterations
          << (c.raw.converge_iterations >= options.cgal_max_converge_iterations ? " (cap)" : "")
          << " | " << sec(c.raw.converge_seconds) << " | " << err(c.converged_errors.e_theta)
          << " | " << err(c.converged_errors.e_phi) << " | " << err(c.converged_errors.area_log_rms)
          << " |\n";
    }

    out << "\n## Ratios and the warm move\n\n";
    out << "| model | ours ms / outer it | CGAL ms / it | per-it ratio | ours total (s) | CGAL total (s) "
           "| total ratio | ours move (ms, its) | CGAL move (ms, its) | ours move E_theta / E_phi / area "
           "| CGAL move E_theta / E_phi / area |\n";
    out << "|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---|\n";
    for (const ModelRow& row : rows) {
      if (!row.cgal) continue;
      const OurRun& o = row.ours;
      const CgalRun& c = *row.cgal;
      const double ours_total = o.precompute_seconds + o.solve_seconds;
      const double cgal_total = c.raw.preprocess_seconds + c.raw.fixed_seconds;
      out << "| " << row.name << " | " << ms(o.per_iteration_seconds()) << " | "
          << ms(c.per_iteration_seconds()) << " | "
          << fmt("%.2f", o.per_iteration_seconds() / c.per_iteration_seconds()) << " | "
          << sec(ours_total) << " | " << sec(cgal_total) << " | "
          << fmt("%.2f", ours_total / cgal_total) << " | " << ms(o.move_seconds) << ", "
          << o.move_iterations << " | " << ms(c.raw.move_seconds) << ", " << options.move_iterations
          << " | " << err(o.move_errors.e_theta) << " / " << err(o.move_errors.e_phi) << " / "
          << err(o.move_errors.area_log_rms) << " | " << err(c.move_errors.e_theta) << " / "
          << err(c.move_errors.e_phi) << " / " << err(c.move_errors.area_log_rms) << " |\n";
    }
    out << "\nTotals: ours = precompute + solve (from Auto's start: the Laplacian guess at rigidity "
           "0, ARAP run to convergence above); CGAL = preprocess + "
        << options.iterations << " iterations. Per-iteration: ours = (solve - init) / outer its; "
           "CGAL = fixed-run time / "
        << options.iterations << ".\n";
  }

  out << "\n## Methods on the same edit\n\n";
  out << "Each through core::make_deformer: precompute + solve from Auto's start, budget "
      << options.iterations << " iterations (Laplacian: one solve). Area = RMS log(area'/area).\n\n";
  out << "| model | method | time (s) | its | E_theta | E_phi | area |\n";
  out << "|---|---|---:|---:|---:|---:|---:|\n";
  for (const ModelRow& row : rows) {
    for (const MethodRun& m : row.methods) {
      out << "| " << row.name << " | " << m.name << " | " << sec(m.seconds) << " | " << m.iterations
          << " | " << err(m.errors.e_theta) << " | " << err(m.errors.e_phi) << " | "
          << err(m.errors.area_log_rms) << " |\n";
    }
  }

  out << "\n## Targets\n\n";
  if (checks.empty()) {
    out << "No target applies to the models run (the size targets are for the paper-size suite).\n";
  } else {
    out << "| target | model | measured | threshold | met |\n|---|---|---:|---:|---|\n";
    for (const TargetCheck& check : checks) {
      const char* format = check.unit == "x" ? "%.2f" : (check.unit == "ms" ? "%.1f" : "%.3f");
      out << "| " << check.target << " | " << check.model << " | " << fmt(format, check.value)
          << " " << check.unit << " | " << fmt(format, check.threshold) << " " << check.unit
          << " | " << (check.met ? "met" : "NOT met") << " |\n";
    }
  }
  return out.str();
}

nlohmann::json errors_json(const AngleErrors& e) {
  return {{"e_theta", e.e_theta}, {"e_phi", e.e_phi}, {"area_log_rms", e.area_log_rms}};
}

nlohmann::json to_json(const MachineInfo& machine, const std::string& load_at_end, const Options& options,
                       const std::vector<ModelRow>& rows, const std::vector<TargetCheck>& checks) {
  nlohmann::json out;
  out["machine"] = machine_json(machine, load_at_end);
  out["options"] = {{"suite", options.small ? "small" : "paper"},
                    {"iterations", options.iterations},
                    {"rigidity", options.rigidity},
                    {"threads", options.threads},
                    {"track_metrics", options.track_metrics},
                    {"move_fraction", options.move_fraction},
                    {"move_iterations", options.move_iterations},
                    {"cgal_variant", cgal_arap_variant_name(options.cgal_variant)},
                    {"cgal_max_converge_iterations", options.cgal_max_converge_iterations},
                    {"cgal_converge_tolerance", CgalArapOptions{}.converge_tolerance}};
  out["models"] = nlohmann::json::array();
  for (const ModelRow& row : rows) {
    const OurRun& o = row.ours;
    nlohmann::json model = {{"name", row.name},
                            {"vertices", row.vertices},
                            {"faces", row.faces},
                            {"fixed_vertices", row.fixed},
                            {"handle_vertices", row.handles},
                            {"move_transform_fallback", row.move_used_fallback}};
    nlohmann::json methods = nlohmann::json::array();
    for (const MethodRun& m : row.methods) {
      methods.push_back({{"method", m.name},
                         {"seconds", m.seconds},
                         {"iterations", m.iterations},
                         {"errors", errors_json(m.errors)}});
    }
    model["methods"] = methods;
    model["ours"] = {{"precompute_seconds", o.precompute_seconds},
                     {"solve_seconds", o.solve_seconds},
                     {"init_seconds", o.init_seconds},
                     {"outer_iterations", o.iterations},
                     {"converged", o.converged},
                     {"seconds_per_outer_iteration", o.per_iteration_seconds()},
                     {"factorizations", o.factorizations},
                     {"pcg_iterations", o.pcg_iterations},
                     {"errors", errors_json(o.errors)},
                     // The Laplacian guess's positions are not returned: angles only, from history.
                     {"init_errors",
                      {{"e_theta", o.init_errors.e_theta}, {"e_phi", o.init_errors.e_phi}}},
                     {"history", io::history_to_json(o.history)},
                     {"move",
                      {{"seconds", o.move_seconds},
                       {"outer_iterations", o.move_iterations},
                       {"factorizations", o.move_factorizations},
                       {"pcg_iterations", o.move_pcg_iterations},
                       {"errors", errors_json(o.move_errors)}}}};
    if (row.cgal) {
      const CgalRun& c = *row.cgal;
      model["cgal"] = {{"variant", cgal_arap_variant_name(options.cgal_variant)},
                       {"build_seconds", c.raw.build_seconds},
                       {"preprocess_seconds", c.raw.preprocess_seconds},
                       {"fixed_seconds", c.raw.fixed_seconds},
                       {"fixed_iterations", c.raw.fixed_iterations},
                       {"seconds_per_iteration", c.per_iteration_seconds()},
                       {"errors", errors_json(c.fixed_errors)},
                       {"converge_seconds", c.raw.converge_seconds},
                       {"converge_iterations", c.raw.converge_iterations},
                       {"converged_errors", errors_json(c.converged_errors)},
                       {"move",
                        {{"seconds", c.raw.move_seconds},
                         {"iterations", options.move_iterations},
                         {"errors", errors_json(c.move_errors)}}}};
      const double ours_total = o.precompute_seconds + o.solve_seconds;
      const double cgal_total = c.raw.preprocess_seconds + c.raw.fixed_seconds;
      model["ratios"] = {{"per_iteration", o.per_iteration_seconds() / c.per_iteration_seconds()},
                         {"total", ours_total / cgal_total}};
    }
    if (const PaperRow* paper = paper_row(row.name)) {
      model["paper"] = {{"vertices", paper->vertices},
                        {"seconds", paper->seconds},
                        {"e_theta", paper->e_theta},
                        {"e_phi", paper->e_phi}};
    }
    out["models"].push_back(model);
  }
  out["targets"] = nlohmann::json::array();
  for (const TargetCheck& check : checks) {
    out["targets"].push_back({{"target", check.target},
                              {"model", check.model},
                              {"value", check.value},
                              {"threshold", check.threshold},
                              {"unit", check.unit},
                              {"met", check.met}});
  }
  return out;
}

Status run(int argc, char** argv) {
  MD_ASSIGN_OR_RETURN(const Options options, parse_options(argc, argv));

  std::vector<core::DeformationBenchmark> suite =
      core::make_suite(options.small ? core::SuiteScale::Small : core::SuiteScale::Paper);
  std::set<std::string> known;
  for (const auto& model : suite) known.insert(model.name);
  for (const std::string& name : options.models) {
    if (known.count(name) == 0) {
      std::string names;
      for (const std::string& k : known) names += (names.empty() ? "" : ", ") + k;
      return Error(ErrorCode::InvalidArgument, "unknown model '" + name + "' (" + names + ")");
    }
  }

  const MachineInfo machine = collect_machine_info();
  std::vector<ModelRow> rows;
  for (const core::DeformationBenchmark& model : suite) {
    if (!options.models.empty() &&
        std::find(options.models.begin(), options.models.end(), model.name) == options.models.end()) {
      continue;
    }
    MD_ASSIGN_OR_RETURN(ModelRow row, run_model(model, options));
    rows.push_back(std::move(row));
  }
  const std::vector<TargetCheck> checks = check_targets(rows);

  const std::string load_at_end = read_load_average();
  const std::string md = markdown(machine, load_at_end, options, rows, checks);
  std::cout << md << std::flush;

  std::error_code error;
  std::filesystem::create_directories(options.out_dir, error);
  if (error) {
    return Error(ErrorCode::Internal, "cannot create " + options.out_dir + ": " + error.message());
  }
  const std::string stem = options.small ? "table1_small" : "table1";
  const std::filesystem::path dir(options.out_dir);
  MD_RETURN_IF_ERROR(write_file(dir / (stem + ".md"), md));
  MD_RETURN_IF_ERROR(write_file(dir / (stem + ".json"),
                                to_json(machine, load_at_end, options, rows, checks).dump(2) + "\n"));
  std::cerr << "wrote " << (dir / (stem + ".md")).string() << " and "
            << (dir / (stem + ".json")).string() << "\n";
  return Status::success();
}

}  // namespace
}  // namespace meshdeform::bench

int main(int argc, char** argv) {
  return meshdeform::bench::bench_main(argc, argv, "meshdeform-bench-table1", meshdeform::bench::print_usage,
                                        meshdeform::bench::run);
}
