// meshdeform-bench-rigidity: issue 12's sweep of SolveOptions::rigidity (the in-loop scale term)
// per edit, against ARAP run to convergence and against the paper's ORA, on the Table 1
// look-alikes, their irregular variants (core::make_irregular_suite), a strip stretched between two
// handle patches and three edits of tests/data/spot.obj. Writes <out-dir>/rigidity_sweep.{md,json}
// and a Pareto plot <out-dir>/rigidity_pareto.svg (E_theta and E_phi against area distortion, each
// divided by converged ARAP's). Everything but the timings is deterministic.

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <map>
#include <nlohmann/json.hpp>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "bench/bench_config.h"
#include "bench/bench_args.h"
#include "bench/machine_info.h"
#include "core/methods/deform_types.h"
#include "core/methods/deformer.h"
#include "core/io/mesh_io.h"
#include "core/mesh/measures.h"
#include "core/samples/generators.h"
#include "core/base/status.h"
#include "core/mesh/topology.h"

namespace meshdeform::bench {
namespace {

using core::AngleErrors;

// One edit: a mesh, the constrained vertices and their targets.
struct Edit {
  std::string name;
  std::string family;  // "table1", "irregular", "spot", "strip"
  Positions V;
  Triangles F;
  Eigen::VectorXi constrained;
  Positions targets;
};

Result<Edit> edit_from_benchmark(const core::DeformationBenchmark& b, const std::string& name,
                                 const std::string& family) {
  MD_ASSIGN_OR_RETURN(const core::HandleSetup setup,
                      core::constraints_from_selection(b.mesh.V, b.selection, b.transform));
  return Edit{name, family, b.mesh.V, b.mesh.F, setup.constrained, setup.targets};
}

// A strip (length 4, width 1, 40 x 10 quads) with handle patches at both ends pulled apart by
// half its length: the "inflating lobes" edit.
Edit make_strip_stretch() {
  const int nx = 40, ny = 10;
  Edit e;
  e.name = "strip_stretch";
  e.family = "strip";
  e.V.resize((nx + 1) * (ny + 1), 3);
  for (int j = 0; j <= ny; ++j) {
    for (int i = 0; i <= nx; ++i) e.V.row(j * (nx + 1) + i) << 4.0 * i / nx, 1.0 * j / ny, 0.0;
  }
  e.F.resize(2 * nx * ny, 3);
  int f = 0;
  for (int j = 0; j < ny; ++j) {
    for (int i = 0; i < nx; ++i) {
      const int a = j * (nx + 1) + i, b = a + 1, c = a + nx + 1, d = c + 1;
      e.F.row(f++) << a, b, d;
      e.F.row(f++) << a, d, c;
    }
  }
  std::vector<int> idx;
  std::vector<Eigen::RowVector3d> t;
  for (int v = 0; v < e.V.rows(); ++v) {
    const double x = e.V(v, 0);
    if (x <= 0.3 + 1e-9) {
      idx.push_back(v);
      t.emplace_back(e.V.row(v) + Eigen::RowVector3d(-1.0, 0, 0));
    } else if (x >= 3.7 - 1e-9) {
      idx.push_back(v);
      t.emplace_back(e.V.row(v) + Eigen::RowVector3d(1.0, 0, 0));
    }
  }
  e.constrained = Eigen::Map<Eigen::VectorXi>(idx.data(), static_cast<Eigen::Index>(idx.size()));
  e.targets.resize(static_cast<Eigen::Index>(t.size()), 3);
  for (size_t k = 0; k < t.size(); ++k) e.targets.row(static_cast<Eigen::Index>(k)) = t[k];
  return e;
}

// Spot edits: patches of the vertices within 12% of the length from each end of the long (z)
// axis. stretch: both patches move apart by 15% of the length each; bend: the front patch
// rotates by 60 degrees about x through the centre of the bounding box; twist: the front patch
// rotates by 135 degrees about its own axis parallel to the long axis (through its centroid).
std::vector<Edit> make_spot_edits(const MeshData& spot) {
  const Eigen::RowVector3d lo = spot.V.colwise().minCoeff(), hi = spot.V.colwise().maxCoeff();
  const double length = hi.z() - lo.z();
  const Eigen::Vector3d centre = (0.5 * (lo + hi)).transpose();
  std::vector<int> back, front;
  for (int v = 0; v < spot.V.rows(); ++v) {
    if (spot.V(v, 2) <= lo.z() + 0.12 * length) back.push_back(v);
    if (spot.V(v, 2) >= hi.z() - 0.12 * length) front.push_back(v);
  }
  auto build = [&](const std::string& name, const Eigen::Affine3d& back_map,
                   const Eigen::Affine3d& front_map) {
    Edit e;
    e.name = name;
    e.family = "spot";
    e.V = spot.V;
    e.F = spot.F;
    std::vector<std::pair<int, Eigen::RowVector3d>> rows;
    for (int v : back)
      rows.emplace_back(v, (back_map * Eigen::Vector3d(spot.V.row(v))).transpose());
    for (int v : front)
      rows.emplace_back(v, (front_map * Eigen::Vector3d(spot.V.row(v))).transpose());
    std::sort(rows.begin(), rows.end(),
              [](const auto& a, const auto& b) { return a.first < b.first; });
    e.constrained.resize(static_cast<Eigen::Index>(rows.size()));
    e.targets.resize(static_cast<Eigen::Index>(rows.size()), 3);
    for (size_t k = 0; k < rows.size(); ++k) {
      e.constrained(static_cast<Eigen::Index>(k)) = rows[k].first;
      e.targets.row(static_cast<Eigen::Index>(k)) = rows[k].second;
    }
    return e;
  };
  const Eigen::Affine3d id = Eigen::Affine3d::Identity();
  std::vector<Edit> edits;
  edits.push_back(build("spot_stretch", Eigen::Affine3d(Eigen::Translation3d(0, 0, -0.15 * length)),
                        Eigen::Affine3d(Eigen::Translation3d(0, 0, 0.15 * length))));
  const Eigen::Affine3d bend = Eigen::Translation3d(centre) *
                               Eigen::AngleAxisd(M_PI / 3, Eigen::Vector3d::UnitX()) *
                               Eigen::Translation3d(-centre);
  edits.push_back(build("spot_bend60", id, bend));
  Eigen::Vector3d front_centre = Eigen::Vector3d::Zero();
  for (int v : front) front_centre += spot.V.row(v).transpose();
  front_centre /= static_cast<double>(front.size());
  const Eigen::Affine3d twist = Eigen::Translation3d(front_centre) *
                                Eigen::AngleAxisd(0.75 * M_PI, Eigen::Vector3d::UnitZ()) *
                                Eigen::Translation3d(-front_centre);
  edits.push_back(build("spot_twist135", id, twist));
  return edits;
}

struct Options {
  std::vector<std::string> models;  // empty: all
  bool small = false;
  std::string out_dir = MESHDEFORM_BENCH_RESULTS_DIR;
  std::vector<double> rigidities = {0.0, 0.03, 0.1, 0.3, 1.0, 3.0, 10.0, 30.0};
  int arap_max_iterations = 2000;
  double arap_tolerance = 1e-8;
  double pull = core::ScaleAwareSettings{}.scale_pull;
  double smooth_length = core::ScaleAwareSettings{}.scale_smooth_length;
  double normal_tie = core::ScaleAwareSettings{}.scale_normal_tie;
  int rigid_start_iterations = core::SolveOptions{}.rigid_start_iterations;
  double rigid_start_tolerance = core::SolveOptions{}.rigid_start_tolerance;
  int iterations = core::SolveOptions{}.max_iterations;
  core::StartFrom start = core::StartFrom::Auto;
  double tolerance = core::SolveOptions{}.tolerance;
};

struct Run {
  std::string method;  // "scale_aware", "scale_aware+ora", "arap_converged"
  double rigidity = 0;
  AngleErrors errors;
  int iterations = 0;
  bool converged = false;
  double seconds = 0;
  double handle_error = 0;  // max |v - target| over constrained vertices / bbox diagonal
  int pcg_iterations = 0;   // step two's PCG iterations, all outer iterations together
  int folds = 0;            // interior edges whose dihedral angle changed by more than 90 degrees
  std::string start = "-";  // scale-aware: the start its result came from (SolveReport::start)
  Positions V;              // the result (kept for the figure)
};

struct Row {
  Edit edit;
  std::vector<Run> runs;
  const Run* arap() const {
    for (const Run& r : runs) {
      if (r.method == "arap_converged") return &r;
    }
    return nullptr;
  }
};

double handle_error(const Edit& e, const Positions& V) {
  const double diag = (e.V.colwise().maxCoeff() - e.V.colwise().minCoeff()).norm();
  double worst = 0;
  for (Eigen::Index j = 0; j < e.constrained.size(); ++j) {
    worst = std::max(worst, (V.row(e.constrained(j)) - e.targets.row(j)).norm());
  }
  return worst / diag;
}

// Local folds: interior edges whose dihedral angle moved by more than 90 degrees from the rest.
int folds_of(const core::Measures& rest, const core::Measures& deformed) {
  return core::count_folds(rest.phi, deformed.phi);
}

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

Result<Row> run_edit(const Edit& edit, const Options& options) {
  Row row;
  row.edit = edit;
  MD_ASSIGN_OR_RETURN(const core::MeshTopology topology,
                      core::build_topology(edit.F, static_cast<int>(edit.V.rows())));
  const core::Measures rest = core::compute_measures(edit.V, edit.F, topology);
  auto errors_of = [&](const Positions& V) {
    return core::angle_errors(rest, core::compute_measures(V, edit.F, topology));
  };

  std::cerr << "[" << edit.name << "] " << edit.V.rows() << " vertices: ARAP to convergence\n";
  {
    const auto start = std::chrono::steady_clock::now();
    MD_ASSIGN_OR_RETURN(auto deformer,
                        core::make_deformer(core::Method::Arap, edit.V, edit.F, edit.constrained));
    core::SolveOptions o;
    o.max_iterations = options.arap_max_iterations;
    o.tolerance = options.arap_tolerance;
    o.track_metrics = false;
    MD_ASSIGN_OR_RETURN(const core::SolveReport r, deformer->solve(edit.targets, o));
    Run run;
    run.method = "arap_converged";
    run.errors = errors_of(r.V);
    run.iterations = r.iterations;
    run.converged = r.converged;
    run.seconds = seconds_since(start);
    run.handle_error = handle_error(edit, r.V);
    run.folds = folds_of(rest, core::compute_measures(r.V, edit.F, topology));
    run.V = r.V;
    row.runs.push_back(run);
  }

  core::DeformerSettings settings;
  auto scale_aware = [&](double rigidity, bool ora) -> Result<Run> {
    const auto start = std::chrono::steady_clock::now();
    core::ScaleAwareSettings sa;
    sa.scale_pull = options.pull;
    sa.scale_smooth_length = options.smooth_length;
    sa.scale_normal_tie = options.normal_tie;
    MD_ASSIGN_OR_RETURN(core::ScaleAwareSolver solver,
                        core::ScaleAwareSolver::create(edit.V, edit.F, edit.constrained, sa));
    core::SolveOptions o;  // the defaults a user gets, except the swept value
    o.rigidity = rigidity;
    o.rigid_start_iterations = options.rigid_start_iterations;
    o.rigid_start_tolerance = options.rigid_start_tolerance;
    o.max_iterations = options.iterations;
    o.start = options.start;
    o.tolerance = options.tolerance;
    o.ora = ora;
    o.track_metrics = false;
    MD_ASSIGN_OR_RETURN(const core::SolveReport r, solver.solve(edit.targets, o));
    Run run;
    run.method = ora ? "scale_aware+ora" : "scale_aware";
    run.rigidity = rigidity;
    run.errors = errors_of(r.V);
    run.pcg_iterations = r.pcg_iterations;
    run.iterations = r.iterations;
    run.converged = r.converged;
    run.seconds = seconds_since(start);
    run.handle_error = handle_error(edit, r.V);
    run.folds = folds_of(rest, core::compute_measures(r.V, edit.F, topology));
    run.start = core::start_name(r.start);
    run.V = r.V;
    return run;
  };
  for (double rho : options.rigidities) {
    std::cerr << "[" << edit.name << "] rigidity " << rho << "\n";
    MD_ASSIGN_OR_RETURN(Run run, scale_aware(rho, false));
    row.runs.push_back(run);
  }
  std::cerr << "[" << edit.name << "] ORA (rigidity 0 and default)\n";
  MD_ASSIGN_OR_RETURN(Run ora0, scale_aware(0.0, true));
  row.runs.push_back(ora0);
  if (core::kDefaultRigidity != 0.0) {
    MD_ASSIGN_OR_RETURN(Run ora_default, scale_aware(core::kDefaultRigidity, true));
    row.runs.push_back(ora_default);
  }
  return row;
}

// ---- output -----------------------------------------------------------------------------------

std::string fmt(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

// value / reference, or "-" when the reference is 0 (E_phi of a flat edit).
std::string ratio(double value, double reference) {
  return reference > 1e-12 ? fmt("%.2f", value / reference) : std::string("-");
}

// The targets for one run against converged ARAP on the same edit.
struct Verdict {
  bool theta = false, phi = false, area = false;
  bool all() const { return theta && phi && area; }
};
Verdict verdict(const Run& run, const Run& arap) {
  // A flat in-plane edit has no dihedral change at all: E_phi = 0 for both counts as met.
  const bool both_flat = run.errors.e_phi <= 1e-9 && arap.errors.e_phi <= 1e-9;
  return {run.errors.e_theta < arap.errors.e_theta,
          run.errors.e_phi < arap.errors.e_phi || both_flat,
          run.errors.area_log_rms <= 1.5 * arap.errors.area_log_rms};
}

std::string markdown(const MachineInfo& machine, const Options& options,
                     const std::vector<Row>& rows) {
  std::ostringstream out;
  out << "# Rigidity sweep: scale control (issue 12) against converged ARAP and ORA\n\n";
  out << "- date: " << machine.date_utc << "; machine: nproc " << machine.hardware_threads
      << ", CPU " << machine.cpu_model << "; load " << machine.load_average << "\n";
  out << "- compiler: " << machine.compiler << "; build type: " << machine.build_type
      << "; source: git " << machine.git_revision << "\n";
  out << "- scale-aware: SolveOptions defaults except rigidity (max_iterations "
      << options.iterations << ", tolerance " << options.tolerance << ", start "
      << (options.start == core::StartFrom::Auto
              ? "auto (the rigid start at rigidity > 0; where its result has folds, the "
                "Laplacian guess's and then the paper start's result when it has fewer at most "
                "1.5x the rigid start's energy; the Laplacian guess at 0)"
              : core::start_name(options.start))
      << ", rigid start: ARAP to relative energy change " << options.rigid_start_tolerance
      << " or " << options.rigid_start_iterations << " iterations); scale_pull " << options.pull
      << ", scale_smooth_length "
      << options.smooth_length << "; default rigidity " << core::kDefaultRigidity << "\n";
  out << "- ARAP: core::Method::Arap (cotangent, handles pinned) to relative energy change < "
      << options.arap_tolerance << " or " << options.arap_max_iterations << " iterations\n";
  out << "- ORA: the paper's stitch (Section 5.3) after the scale-aware solve\n";
  out << "- errors: E_theta, E_phi RMS radians; area = RMS log(area'/area); ratios are to "
         "converged "
         "ARAP on the same edit; targets: E_theta < ARAP, E_phi < ARAP, area <= 1.5x ARAP\n";
  out << "- handles: max |v - target| / bbox diagonal; folds: interior edges whose dihedral angle "
         "changed by more than 90 degrees from the rest\n\n";

  // Auto starts a fresh solver from the Laplacian guess, the paper's start.
  const bool paper_start =
      options.start == core::StartFrom::Auto || options.start == core::StartFrom::Laplacian;
  out << "## Default (rigidity " << core::kDefaultRigidity << ") against converged ARAP\n\n";
  out << "| edit | #V | ARAP its | ARAP E_theta / E_phi / area | default E_theta / E_phi / area | "
         "ratios | targets met | rigidity 0 "
      << (paper_start ? std::string("(paper)")
                      : "(" + std::string(core::start_name(options.start)) + " start, not the paper)")
      << " E_theta / E_phi / area | ORA (rigidity 0) "
         "E_theta / E_phi / area |\n";
  out << "|---|---:|---:|---|---|---|---|---|---|\n";
  auto triple = [](const AngleErrors& e) {
    return fmt("%.4f", e.e_theta) + " / " + fmt("%.4f", e.e_phi) + " / " +
           fmt("%.4f", e.area_log_rms);
  };
  int met_all = 0;
  int no_new_folds = 0;
  std::string fold_notes;  // edits where any of the three results folds
  for (const Row& row : rows) {
    const Run* arap = row.arap();
    const Run *def = nullptr, *pure = nullptr, *ora = nullptr;
    for (const Run& r : row.runs) {
      if (r.method == "scale_aware" && r.rigidity == core::kDefaultRigidity) def = &r;
      if (r.method == "scale_aware" && r.rigidity == 0.0) pure = &r;
      if (r.method == "scale_aware+ora" && r.rigidity == 0.0) ora = &r;
    }
    if (arap == nullptr || def == nullptr || pure == nullptr || ora == nullptr) continue;
    const Verdict v = verdict(*def, *arap);
    met_all += v.all() ? 1 : 0;
    no_new_folds += def->folds <= pure->folds ? 1 : 0;
    if (def->folds + pure->folds + arap->folds > 0) {
      fold_notes += (fold_notes.empty() ? "" : ", ") + row.edit.name + " " +
                    std::to_string(def->folds) + " / " + std::to_string(pure->folds) + " / " +
                    std::to_string(arap->folds);
    }
    out << "| " << row.edit.name << " | " << row.edit.V.rows() << " | " << arap->iterations
        << (arap->converged ? "" : " (cap)") << " | " << triple(arap->errors) << " | "
        << triple(def->errors) << " | " << ratio(def->errors.e_theta, arap->errors.e_theta) << " / "
        << ratio(def->errors.e_phi, arap->errors.e_phi) << " / "
        << ratio(def->errors.area_log_rms, arap->errors.area_log_rms) << " | "
        << (v.theta ? "" : "E_theta NOT; ") << (v.phi ? "" : "E_phi NOT; ")
        << (v.area ? "" : "area NOT; ") << (v.all() ? "all" : "") << " | " << triple(pure->errors)
        << " | " << triple(ora->errors) << " |\n";
  }
  out << "\nAll three targets met on " << met_all << " of " << rows.size() << " edits.\n";
  out << "\nNo new folds at the default (folded edges at most the paper's, rigidity 0) on "
      << no_new_folds << " of " << rows.size() << " edits. Folded edges, default / paper / "
      << "converged ARAP, where any has one: " << (fold_notes.empty() ? "none" : fold_notes)
      << ".\n";

  out << "\n## Every run\n\n";
  out << "| edit | method | rigidity | its | conv. | E_theta | E_phi | area | E_theta/ARAP | "
         "E_phi/ARAP | area/ARAP | targets | handles | folds | s | PCG / it | start |\n";
  out << "|---|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---|---:|---:|---:|---:|---|\n";
  for (const Row& row : rows) {
    const Run* arap = row.arap();
    for (const Run& r : row.runs) {
      const Verdict v = verdict(r, *arap);
      out << "| " << row.edit.name << " | " << r.method << " | "
          << (r.method == "arap_converged" ? std::string("-") : fmt("%g", r.rigidity)) << " | "
          << r.iterations << " | " << (r.converged ? "yes" : "no") << " | "
          << fmt("%.4f", r.errors.e_theta) << " | " << fmt("%.4f", r.errors.e_phi) << " | "
          << fmt("%.4f", r.errors.area_log_rms) << " | "
          << ratio(r.errors.e_theta, arap->errors.e_theta) << " | "
          << ratio(r.errors.e_phi, arap->errors.e_phi) << " | "
          << ratio(r.errors.area_log_rms, arap->errors.area_log_rms) << " | "
          << (r.method == "arap_converged"
                  ? std::string("-")
                  : std::string(v.theta ? "T" : "-") + (v.phi ? "P" : "-") + (v.area ? "A" : "-"))
          << " | " << fmt("%.1e", r.handle_error) << " | " << r.folds << " | "
          << fmt("%.2f", r.seconds) << " | "
          << (r.method == "arap_converged" || r.iterations == 0
                  ? std::string("-")
                  : fmt("%.1f", static_cast<double>(r.pcg_iterations) / r.iterations))
          << " | " << r.start << " |\n";
    }
  }
  out << "\nTargets column: T = E_theta below ARAP's, P = E_phi below ARAP's, A = area <= 1.5x "
         "ARAP's. s: create + solve seconds (shared, noisy machine). PCG / it: step two's "
         "conjugate-gradient iterations per outer iteration (with rigidity > 0 over the joint "
         "(x, s) system). start: the start the scale-aware result came from (Auto's choice).\n";
  return out.str();
}

nlohmann::json to_json(const MachineInfo& machine, const Options& options,
                       const std::vector<Row>& rows) {
  nlohmann::json out;
  out["machine"] = {{"date_utc", machine.date_utc},        {"nproc", machine.hardware_threads},
                    {"cpu_model", machine.cpu_model},      {"compiler", machine.compiler},
                    {"build_type", machine.build_type},    {"git_revision", machine.git_revision},
                    {"load_average", machine.load_average}};
  out["options"] = {{"rigidities", options.rigidities},
                    {"default_rigidity", core::kDefaultRigidity},
                    {"scale_pull", options.pull},
                    {"scale_smooth_length", options.smooth_length},
                    {"scale_normal_tie", std::isfinite(options.normal_tie) ? nlohmann::json(options.normal_tie) : nlohmann::json("inf")},
                    {"arap_max_iterations", options.arap_max_iterations},
                    {"arap_tolerance", options.arap_tolerance}};
  out["edits"] = nlohmann::json::array();
  for (const Row& row : rows) {
    nlohmann::json runs = nlohmann::json::array();
    for (const Run& r : row.runs) {
      runs.push_back({{"method", r.method},
                      {"rigidity", r.rigidity},
                      {"iterations", r.iterations},
                      {"converged", r.converged},
                      {"seconds", r.seconds},
                      {"e_theta", r.errors.e_theta},
                      {"e_phi", r.errors.e_phi},
                      {"area_log_rms", r.errors.area_log_rms},
                      {"handle_error", r.handle_error},
                      {"folds", r.folds},
                      {"start", r.start},
                      {"pcg_iterations", r.pcg_iterations}});
    }
    out["edits"].push_back({{"name", row.edit.name},
                            {"family", row.edit.family},
                            {"vertices", row.edit.V.rows()},
                            {"faces", row.edit.F.rows()},
                            {"runs", runs}});
  }
  return out;
}

// Two panels (E_theta, E_phi) against area, all divided by converged ARAP's, log axes: one
// polyline per edit through the swept rigidities, ORA as a cross, ARAP at (1, 1), the target
// region (area <= 1.5, error < 1) shaded.
std::string pareto_svg(const std::vector<Row>& rows) {
  const double W = 520, H = 420, ml = 60, mr = 20, mt = 40, mb = 50;
  const double x_lo = std::log10(0.5), x_hi = std::log10(20.0), y_lo = std::log10(0.1),
               y_hi = std::log10(5.0);
  auto X = [&](double v) {
    return ml + (std::log10(std::clamp(v, 0.5, 20.0)) - x_lo) / (x_hi - x_lo) * (W - ml - mr);
  };
  auto Y = [&](double v) {
    return H - mb - (std::log10(std::clamp(v, 0.1, 5.0)) - y_lo) / (y_hi - y_lo) * (H - mt - mb);
  };
  const char* colours[] = {"#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd",
                           "#8c564b", "#e377c2", "#7f7f7f", "#bcbd22", "#17becf",
                           "#393b79", "#637939", "#8c6d31", "#843c39"};
  std::ostringstream svg;
  svg << "<svg xmlns='http://www.w3.org/2000/svg' width='" << 2 * W + 200 << "' height='" << H
      << "' font-family='sans-serif' font-size='11'>\n<rect width='100%' height='100%' "
         "fill='white'/>\n";
  for (int panel = 0; panel < 2; ++panel) {
    svg << "<g transform='translate(" << panel * W << ",0)'>\n";
    svg << "<text x='" << W / 2 << "' y='20' text-anchor='middle' font-size='13'>"
        << (panel == 0 ? "E_theta" : "E_phi")
        << " / ARAP vs area / ARAP (converged ARAP = 1; log axes)</text>\n";
    svg << "<rect x='" << X(0.5) << "' y='" << Y(1.0) << "' width='" << X(1.5) - X(0.5)
        << "' height='" << Y(0.1) - Y(1.0) << "' fill='#e8f5e9'/>\n";
    for (double t : {0.5, 1.0, 1.5, 2.0, 5.0, 10.0, 20.0}) {
      svg << "<line x1='" << X(t) << "' y1='" << mt << "' x2='" << X(t) << "' y2='" << H - mb
          << "' stroke='#ddd'/><text x='" << X(t) << "' y='" << H - mb + 14
          << "' text-anchor='middle'>" << fmt("%g", t) << "</text>\n";
    }
    for (double t : {0.1, 0.2, 0.5, 1.0, 2.0, 5.0}) {
      svg << "<line x1='" << ml << "' y1='" << Y(t) << "' x2='" << W - mr << "' y2='" << Y(t)
          << "' stroke='#ddd'/><text x='" << ml - 4 << "' y='" << Y(t) + 4 << "' text-anchor='end'>"
          << fmt("%g", t) << "</text>\n";
    }
    svg << "<text x='" << (ml + W - mr) / 2 << "' y='" << H - 12
        << "' text-anchor='middle'>area distortion / converged ARAP's</text>\n";
    svg << "<circle cx='" << X(1) << "' cy='" << Y(1) << "' r='5' fill='black'/>\n";
    for (size_t i = 0; i < rows.size(); ++i) {
      const Row& row = rows[i];
      const Run* arap = row.arap();
      const char* colour = colours[i % (sizeof(colours) / sizeof(colours[0]))];
      if (panel == 1 && arap->errors.e_phi <= 1e-12) continue;  // flat edit: no E_phi
      auto point = [&](const Run& r) {
        const double a = r.errors.area_log_rms / arap->errors.area_log_rms;
        const double e = panel == 0 ? r.errors.e_theta / arap->errors.e_theta
                                    : r.errors.e_phi / arap->errors.e_phi;
        return std::pair<double, double>{X(a), Y(e)};
      };
      std::ostringstream path;
      for (const Run& r : row.runs) {
        if (r.method != "scale_aware") continue;
        const auto [px, py] = point(r);
        path << (path.tellp() == 0 ? "M" : "L") << px << "," << py << " ";
        const bool is_default = r.rigidity == core::kDefaultRigidity;
        svg << "<circle cx='" << px << "' cy='" << py << "' r='" << (is_default ? 4.5 : 2.5)
            << "' fill='" << (is_default ? "white" : colour) << "' stroke='" << colour << "'/>\n";
      }
      svg << "<path d='" << path.str() << "' fill='none' stroke='" << colour << "'/>\n";
      for (const Run& r : row.runs) {
        if (r.method != "scale_aware+ora") continue;
        const auto [px, py] = point(r);
        svg << "<path d='M" << px - 4 << "," << py - 4 << " L" << px + 4 << "," << py + 4 << " M"
            << px - 4 << "," << py + 4 << " L" << px + 4 << "," << py - 4 << "' stroke='" << colour
            << "' stroke-width='1.5'/>\n";
      }
    }
    svg << "</g>\n";
  }
  for (size_t i = 0; i < rows.size(); ++i) {
    const char* colour = colours[i % (sizeof(colours) / sizeof(colours[0]))];
    svg << "<text x='" << 2 * W + 10 << "' y='" << 50 + 16 * i << "' fill='" << colour << "'>"
        << rows[i].edit.name << "</text>\n";
  }
  svg << "<text x='" << 2 * W + 10 << "' y='" << 60 + 16 * rows.size()
      << "'>line: rigidity sweep</text>\n<text x='" << 2 * W + 10 << "' y='"
      << 76 + 16 * rows.size() << "'>open circle: default</text>\n<text x='" << 2 * W + 10
      << "' y='" << 92 + 16 * rows.size() << "'>cross: ORA</text>\n<text x='" << 2 * W + 10
      << "' y='" << 108 + 16 * rows.size() << "'>dot: ARAP; green: targets</text>\n";
  svg << "</svg>\n";
  return svg.str();
}

// The README picture: for a few edits, the paper's result (rigidity 0), the default and converged
// ARAP side by side, each face coloured by log(area'/area) (red grows, blue shrinks, white kept;
// clamped at +-1) and shaded by its normal. Orthographic, painter's algorithm, one shared scale
// per row.
std::string figure_svg(const std::vector<Row>& rows, const std::vector<std::string>& names) {
  const double panel_w = 300, title_h = 48;
  std::ostringstream body;
  double y0 = 10;
  const double total_w = 3 * panel_w + 20;
  for (const std::string& name : names) {
    const Row* row = nullptr;
    for (const Row& r : rows) {
      if (r.edit.name == name) row = &r;
    }
    if (row == nullptr) continue;
    const Run *pure = nullptr, *def = nullptr, *arap = row->arap();
    for (const Run& r : row->runs) {
      if (r.method == "scale_aware" && r.rigidity == 0.0) pure = &r;
      if (r.method == "scale_aware" && r.rigidity == core::kDefaultRigidity) def = &r;
    }
    if (pure == nullptr || def == nullptr || arap == nullptr) continue;
    // View: the longest rest extent across the screen, the rest tilted by 30 degrees.
    const Eigen::RowVector3d extent =
        row->edit.V.colwise().maxCoeff() - row->edit.V.colwise().minCoeff();
    int axes[3] = {0, 1, 2};
    std::sort(axes, axes + 3, [&](int a, int b) { return extent(a) > extent(b); });
    Eigen::Matrix3d view;  // rows: screen x, screen y (up), toward the viewer
    const double t = M_PI / 6;
    Eigen::Vector3d u = Eigen::Vector3d::Unit(axes[0]), w = Eigen::Vector3d::Unit(axes[1]),
                    v = Eigen::Vector3d::Unit(axes[2]);
    view.row(0) = u.transpose();
    view.row(1) = (std::cos(t) * w + std::sin(t) * v).transpose();
    view.row(2) = (-std::sin(t) * w + std::cos(t) * v).transpose();
    const Run* panels[3] = {pure, def, arap};
    const bool closed = [&] {
      auto topology = core::build_topology(row->edit.F, static_cast<int>(row->edit.V.rows()));
      return topology.ok() && topology->boundary_edge_count == 0;
    }();
    const std::string titles[3] = {"paper (rigidity 0)",
                                   "default (rigidity " + fmt("%g", core::kDefaultRigidity) + ")",
                                   "ARAP, converged"};
    Eigen::Vector2d lo(1e300, 1e300), hi(-1e300, -1e300);
    for (const Run* r : panels) {
      const Eigen::MatrixXd P = r->V * view.transpose();
      lo = lo.cwiseMin(P.leftCols(2).colwise().minCoeff().transpose());
      hi = hi.cwiseMax(P.leftCols(2).colwise().maxCoeff().transpose());
    }
    const double scale = (panel_w - 20) / std::max(hi.x() - lo.x(), 1e-12);
    const double panel_h = std::max(60.0, (hi.y() - lo.y()) * scale + 20);
    body << "<text x='10' y='" << y0 + 14 << "' font-size='13'>" << name << "</text>\n";
    for (int k = 0; k < 3; ++k) {
      const Run& r = *panels[k];
      const double ox = k * panel_w + 10, oy = y0 + title_h;
      // Two lines per panel title: the method, then its errors (one line overran the panel).
      body << "<text x='" << ox + 10 << "' y='" << oy - 18 << "'>" << titles[k]
           << "</text>\n<text x='" << ox + 10 << "' y='" << oy - 4 << "'>E_theta "
           << fmt("%.3f", r.errors.e_theta) << ", E_phi " << fmt("%.3f", r.errors.e_phi)
           << ", area " << fmt("%.3f", r.errors.area_log_rms) << "</text>\n";
      const Eigen::MatrixXd P = r.V * view.transpose();
      const Triangles& F = row->edit.F;
      std::vector<std::pair<double, int>> order;
      order.reserve(F.rows());
      for (int f = 0; f < F.rows(); ++f) {
        order.emplace_back(P(F(f, 0), 2) + P(F(f, 1), 2) + P(F(f, 2), 2), f);
      }
      std::sort(order.begin(), order.end());  // far (small z toward the viewer) first
      for (const auto& [depth, f] : order) {
        const Eigen::Vector3d a = P.row(F(f, 0)), b = P.row(F(f, 1)), c = P.row(F(f, 2));
        const Eigen::Vector3d n = (b - a).cross(c - a);
        const double len = n.norm();
        if (!(len > 0)) continue;
        if (closed && n.z() < 0) continue;  // a back face of a closed surface is hidden
        const Eigen::Vector3d a0 = row->edit.V.row(F(f, 0)), b0 = row->edit.V.row(F(f, 1)),
                              c0 = row->edit.V.row(F(f, 2));
        const double ratio = 0.5 * len / (0.5 * (b0 - a0).cross(c0 - a0).norm());
        const double g = std::clamp(std::log(ratio), -1.0, 1.0);
        const double shade = 0.35 + 0.65 * std::abs(n.z()) / len;
        const double rr = g > 0 ? 1.0 : 1.0 + g, gg = 1.0 - std::abs(g), bb = g < 0 ? 1.0 : 1.0 - g;
        char colour[8];
        std::snprintf(colour, sizeof(colour), "#%02x%02x%02x", static_cast<int>(255 * rr * shade),
                      static_cast<int>(255 * gg * shade), static_cast<int>(255 * bb * shade));
        auto X = [&](const Eigen::Vector3d& p) { return ox + 10 + (p.x() - lo.x()) * scale; };
        auto Y = [&](const Eigen::Vector3d& p) { return oy + 10 + (hi.y() - p.y()) * scale; };
        body << "<path d='M" << fmt("%.0f", X(a)) << " " << fmt("%.0f", Y(a)) << "L"
             << fmt("%.0f", X(b)) << " " << fmt("%.0f", Y(b)) << "L" << fmt("%.0f", X(c)) << " "
             << fmt("%.0f", Y(c)) << "Z' fill='" << colour << "' stroke='" << colour << "'/>\n";
      }
    }
    y0 += title_h + panel_h + 16;
  }
  std::ostringstream svg;
  svg << "<svg xmlns='http://www.w3.org/2000/svg' width='" << total_w << "' height='" << y0 + 24
      << "' font-family='sans-serif' font-size='11'>\n<rect width='100%' height='100%' "
         "fill='white'/>\n"
      << body.str() << "<text x='10' y='" << y0 + 12
      << "'>face colour: log(area'/area), red = grew, blue = shrank, white = kept (clamped at "
         "+-1); shading by normal</text>\n</svg>\n";
  return svg.str();
}

Result<double> parse_number(const std::string& flag, const std::string& text) {
  char* end = nullptr;
  const double value = std::strtod(text.c_str(), &end);
  if (end == text.c_str() || *end != '\0' || !std::isfinite(value) || value < 0) {
    return Error(ErrorCode::InvalidArgument, flag + " wants a number >= 0, got '" + text + "'");
  }
  return value;
}

Result<Options> parse_options(int argc, char** argv) {
  Options options;
  BenchFlags flags;
  const auto number = [&flags](const std::string& name, double& out) {
    flags.value(name, [name, &out](const std::string& value) -> Status {
      MD_ASSIGN_OR_RETURN(out, parse_number(name, value));
      return Status::success();
    });
  };
  const auto count = [&flags](const std::string& name, int& out) {  // a number, truncated
    flags.value(name, [name, &out](const std::string& value) -> Status {
      MD_ASSIGN_OR_RETURN(const double k, parse_number(name, value));
      out = static_cast<int>(k);
      return Status::success();
    });
  };
  flags.list("--models", options.models);
  flags.flag("--small", [&] { options.small = true; });
  flags.text("--out-dir", options.out_dir);
  flags.value("--rigidities", [&](const std::string& value) -> Status {
    options.rigidities.clear();
    for (const std::string& item : split_commas(value)) {
      MD_ASSIGN_OR_RETURN(const double rho, parse_number("--rigidities", item));
      options.rigidities.push_back(rho);
    }
    return Status::success();
  });
  number("--pull", options.pull);
  count("--rigid-start-iterations", options.rigid_start_iterations);
  number("--rigid-start-tolerance", options.rigid_start_tolerance);
  count("--iterations", options.iterations);
  flags.value("--start", [&](const std::string& value) -> Status {
    MD_ASSIGN_OR_RETURN(options.start, core::parse_start(value));
    return Status::success();
  });
  number("--tolerance", options.tolerance);
  number("--smooth-length", options.smooth_length);
  number("--normal-tie", options.normal_tie);
  MD_RETURN_IF_ERROR(flags.parse(argc, argv));
  if (std::find(options.rigidities.begin(), options.rigidities.end(), 0.0) ==
      options.rigidities.end()) {
    options.rigidities.insert(options.rigidities.begin(), 0.0);
  }
  if (std::find(options.rigidities.begin(), options.rigidities.end(), core::kDefaultRigidity) ==
      options.rigidities.end()) {
    options.rigidities.push_back(core::kDefaultRigidity);
  }
  std::sort(options.rigidities.begin(), options.rigidities.end());
  return options;
}

void print_usage(std::ostream& out) {
  out << "usage: meshdeform-bench-rigidity [options]\n"
         "  --models a,b        edits to run (default all; see the names in the output)\n"
         "  --small             the small procedural suite (quick check; writes *_small.*)\n"
         "  --out-dir DIR       default " MESHDEFORM_BENCH_RESULTS_DIR
         "\n"
         "  --rigidities a,b    values swept (0 and the default are always included)\n"
         "  --pull X            ScaleAwareSettings::scale_pull (study only)\n"
         "  --smooth-length X   ScaleAwareSettings::scale_smooth_length (study only)\n"
         "  --normal-tie X      ScaleAwareSettings::scale_normal_tie (study only; default 0.3)\n"
         "  --rigid-start-iterations K  SolveOptions::rigid_start_iterations\n"
         "  --rigid-start-tolerance T   SolveOptions::rigid_start_tolerance\n"
         "  --iterations N      SolveOptions::max_iterations of the scale-aware runs (default 15)\n"
         "  --tolerance T       SolveOptions::tolerance of the scale-aware runs (default 1e-4)\n"
         "  --start S           auto (default), laplacian, rigid or propagated\n";
}

Status run(int argc, char** argv) {
  MD_ASSIGN_OR_RETURN(const Options options, parse_options(argc, argv));
  std::vector<Edit> edits;
  const auto suite =
      core::make_suite(options.small ? core::SuiteScale::Small : core::SuiteScale::Paper);
  for (const auto& b : suite) {
    MD_ASSIGN_OR_RETURN(Edit e, edit_from_benchmark(b, b.name, "table1"));
    edits.push_back(std::move(e));
  }
  // The project's irregular variants (core/samples/generators: non-uniform density, flips, jitter,
  // slivers), as the speed issue's realistic benchmark uses them.
  MD_ASSIGN_OR_RETURN(const std::vector<core::DeformationBenchmark> irregular,
                      core::make_irregular_suite(options.small ? core::SuiteScale::Small
                                                               : core::SuiteScale::Paper));
  for (const auto& b : irregular) {
    MD_ASSIGN_OR_RETURN(Edit e, edit_from_benchmark(b, b.name, "irregular"));
    edits.push_back(std::move(e));
  }
  edits.push_back(make_strip_stretch());
  MD_ASSIGN_OR_RETURN(const MeshData spot,
                      io::read_mesh(std::filesystem::path(MESHDEFORM_BENCH_SOURCE_DIR) / "tests" /
                                    "data" / "spot.obj"));
  for (Edit& e : make_spot_edits(spot)) edits.push_back(std::move(e));

  const MachineInfo machine = collect_machine_info();
  std::vector<Row> rows;
  for (const Edit& e : edits) {
    if (!options.models.empty() &&
        std::find(options.models.begin(), options.models.end(), e.name) == options.models.end()) {
      continue;
    }
    MD_ASSIGN_OR_RETURN(Row row, run_edit(e, options));
    rows.push_back(std::move(row));
  }
  const std::string md = markdown(machine, options, rows);
  std::cout << md << std::flush;
  std::filesystem::create_directories(options.out_dir);
  const std::string stem = options.small ? "rigidity_sweep_small" : "rigidity_sweep";
  const std::filesystem::path dir(options.out_dir);
  std::ofstream(dir / (stem + ".md")) << md;
  std::ofstream(dir / (stem + ".json")) << to_json(machine, options, rows).dump(2) << "\n";
  std::ofstream(dir / (options.small ? "rigidity_pareto_small.svg" : "rigidity_pareto.svg"))
      << pareto_svg(rows);
  std::ofstream(dir / (options.small ? "rigidity_figure_small.svg" : "rigidity_figure.svg"))
      << figure_svg(rows, {"bar", "strip_stretch"});
  std::cerr << "wrote " << (dir / stem).string() << ".{md,json} and the Pareto SVG\n";
  return Status::success();
}

}  // namespace
}  // namespace meshdeform::bench

int main(int argc, char** argv) {
  return meshdeform::bench::bench_main(argc, argv, "meshdeform-bench-rigidity", meshdeform::bench::print_usage,
                                        meshdeform::bench::run);
}
