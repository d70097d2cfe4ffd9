// meshdeform-bench-curves: the paper's 2D curve edit (Section 6.1, Fig. 9). For Koch levels 3-5,
// both ends fixed and the middle point pulled up by 0.3, runs Laplacian editing, ARAP (at the
// default 50-iteration budget and run to convergence) and the scale-aware method, and writes a
// Markdown table (stdout and <out-dir>/curves.md) and the level-4 figure (<out-dir>/fig9_koch.svg).
// Everything except the timings is deterministic. Not a test: it asserts nothing.
//
// Usage: meshdeform-bench-curves [OUT_DIR]   (default: bench/results in the source tree)

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "bench/bench_config.h"
#include "common/command_line.h"
#include "core/base/allocator.h"
#include "core/curves/curve2d.h"
#include "core/curves/curve2d_svg.h"
#include "core/curves/koch.h"
#include "core/base/status.h"

namespace meshdeform::bench {
namespace {

namespace fs = std::filesystem;
using core::CurveMethod;
namespace command_line = meshdeform::command_line;

constexpr double kPull = 0.3;
constexpr int kRepeats = 7;                   // timings: the median of this many runs ...
constexpr double kRepeatBudgetSeconds = 2.0;  // ... or of the runs that fit in this budget
constexpr int kFigureLevel = 4;

struct Variant {
  const char* label;
  CurveMethod method;
  core::CurveOptions options;
};

std::vector<Variant> variants() {
  core::CurveOptions converged;
  converged.max_iterations = 100000;
  converged.tolerance = 1e-10;
  return {
      {"Laplacian", CurveMethod::Laplacian, {}},
      {"ARAP (50 it.)", CurveMethod::Arap, {}},
      {"ARAP (converged, 1e-10)", CurveMethod::Arap, converged},
      {"scale-aware (ours)", CurveMethod::ScaleAware, {}},
  };
}

struct Row {
  int level = 0;
  int points = 0;
  std::string method;
  core::CurveErrors errors;
  double seconds = 0;
  int iterations = 0;
  bool converged = true;
  double constraint_error = 0;
};

double median(std::vector<double> values) {
  std::sort(values.begin(), values.end());
  return values[values.size() / 2];
}

std::string fmt(const char* format, double value) {
  char buffer[64];
  std::snprintf(buffer, sizeof(buffer), format, value);
  return buffer;
}

int fail(const Status& status) {
  std::fprintf(stderr, "meshdeform-bench-curves: %s\n", status.to_string().c_str());
  return 1;
}

int run(int argc, char** argv) {
  // One optional positional argument, read by CLI11 (common/command_line.h); anything else on
  // the line is refused rather than taken for a directory name.
  std::string out_dir_text = MESHDEFORM_BENCH_RESULTS_DIR;
  CLI::App app;
  command_line::configure(app);
  app.add_option("OUT_DIR", out_dir_text);
  if (const auto problem = command_line::parse(
          app, std::vector<std::string>(argv + 1, argv + argc), command_line::Repeats::LastWins)) {
    return fail(Error(ErrorCode::InvalidArgument,
                      "unexpected argument '" + problem->word +
                          "' (usage: meshdeform-bench-curves [OUT_DIR])"));
  }
  const fs::path out_dir(out_dir_text);
  std::error_code ec;
  fs::create_directories(out_dir, ec);

  std::vector<Row> rows;
  std::vector<core::CurvePanel> figure_panels;
  core::CurveEdit figure_edit;
  for (int level = 3; level <= 5; ++level) {
    auto edit = core::make_koch_edit(level, kPull);
    if (!edit.ok()) return fail(edit.status());
    for (const Variant& v : variants()) {
      std::vector<double> times;
      core::CurveResult result;
      double total = 0;
      for (int r = 0; r < kRepeats && total < kRepeatBudgetSeconds; ++r) {
        auto run_result =
            core::deform_curve(v.method, edit->rest, edit->constrained, edit->targets, v.options);
        if (!run_result.ok()) return fail(run_result.status());
        times.push_back(run_result->seconds);
        total += run_result->seconds;
        result = std::move(*run_result);
      }
      auto errors = core::curve_errors(edit->rest, result.P);
      if (!errors.ok()) return fail(errors.status());
      Row row;
      row.level = level;
      row.points = static_cast<int>(edit->rest.P.rows());
      row.method = v.label;
      row.errors = *errors;
      row.seconds = median(times);
      row.iterations = result.iterations;
      row.converged = result.converged;
      for (Eigen::Index j = 0; j < edit->constrained.size(); ++j) {
        row.constraint_error =
            std::max(row.constraint_error,
                     (result.P.row(edit->constrained(j)) - edit->targets.row(j)).norm());
      }
      rows.push_back(row);
      if (level == kFigureLevel &&
          v.options.max_iterations == core::CurveOptions{}.max_iterations) {
        figure_panels.push_back(
            {v.method == CurveMethod::Arap ? "ARAP" : v.label, result.P, errors->e_theta});
      }
    }
    if (level == kFigureLevel) figure_edit = *edit;
  }

  // The scale-aware method's per-target cost once prefactored (what an interactive drag pays).
  std::ostringstream solve_only;
  for (int level = 3; level <= 5; ++level) {
    const auto edit = *core::make_koch_edit(level, kPull);
    auto solver = core::ScaleAwareCurveSolver::create(edit.rest, edit.constrained);
    if (!solver.ok()) return fail(solver.status());
    std::vector<double> times;
    for (int r = 0; r < kRepeats; ++r) {
      const auto start = std::chrono::steady_clock::now();
      auto P = solver->solve(edit.targets);
      times.push_back(
          std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
      if (!P.ok()) return fail(P.status());
    }
    solve_only << (level > 3 ? ", " : "") << "level " << level << ": "
               << fmt("%.3f", 1e3 * median(times)) << " ms";
  }

  std::ostringstream md;
  md << "# 2D curve editing: the Koch edit of Fig. 9\n\n"
     << "Generated by `meshdeform-bench-curves` (bench/curves_main.cpp); compiler "
     << MESHDEFORM_BENCH_COMPILER << ", build " << MESHDEFORM_BENCH_BUILD_TYPE << ".\n\n"
     << "Edit: `core::make_koch_edit(level, " << kPull
     << ")`: the Koch curve from (0,0) to (1,0), both end points fixed, the middle point (index "
        "n/2, the apex of the central bump) pulled up by "
     << kPull
     << ". Soft constraints, lambda = 100. E_theta: RMS change of the signed turning angles "
        "(radians); length ratio: RMS of log(l'/l) of the ratios of consecutive segment lengths. "
        "Both are invariant to similarities. Time: median of "
     << kRepeats << " runs (fewer when they exceed " << kRepeatBudgetSeconds
     << " s in all) of `core::deform_curve` (set-up, factorization, solve; ARAP: all iterations), "
        "one thread, on a shared 2-core machine. |c| = max distance of a constrained point from "
        "its target.\n\n"
     << "| level | points | method | E_theta (rad) | length-ratio log RMS | time (ms) | iterations "
        "| |c| |\n"
     << "|---:|---:|---|---:|---:|---:|---:|---:|\n";
  for (const Row& r : rows) {
    md << "| " << r.level << " | " << r.points << " | " << r.method << " | "
       << fmt("%.5f", r.errors.e_theta) << " | " << fmt("%.5f", r.errors.scale_log_rms) << " | "
       << fmt("%.3f", 1e3 * r.seconds) << " | "
       << (r.method.rfind("ARAP", 0) == 0
               ? std::to_string(r.iterations) + (r.converged ? "" : " (budget)")
               : std::string("-"))
       << " | " << fmt("%.1e", r.constraint_error) << " |\n";
  }
  md << "\nScale-aware, prefactored (`ScaleAwareCurveSolver::solve` only, one back-substitution): "
     << solve_only.str() << ".\n\n"
     << "Figure: `fig9_koch.svg` (level " << kFigureLevel
     << "; Laplacian, ARAP at its 50-iteration default, scale-aware).\n";

  std::cout << md.str();
  const fs::path md_path = out_dir / "curves.md";
  const fs::path svg_path = out_dir / "fig9_koch.svg";
  std::ofstream(md_path, std::ios::trunc) << md.str();
  std::ofstream(svg_path, std::ios::trunc)
      << core::curve_comparison_svg(figure_edit, figure_panels);
  if (!fs::exists(md_path) || !fs::exists(svg_path)) {
    return fail(Error(ErrorCode::Internal, "cannot write to '" + out_dir.string() + "'"));
  }
  std::cout << "\nwrote " << md_path.string() << " and " << svg_path.string() << "\n";
  return 0;
}

}  // namespace
}  // namespace meshdeform::bench

int main(int argc, char** argv) {
  meshdeform::core::keep_freed_heap_for_solver_arrays();
  return meshdeform::bench::run(argc, argv);
}
