#include "cli/curve_command.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <string>
#include <system_error>
#include <vector>

#include "cli/args.h"
#include "cli/commands.h"
#include "cli/paths.h"
#include "core/curves/curve2d.h"
#include "core/curves/curve2d_svg.h"
#include "core/curves/koch.h"
#include "core/base/status.h"

namespace meshdeform::cli {
namespace {

namespace fs = std::filesystem;

constexpr const char* kCommand = "curve";
// 4^7 + 1 = 16,385 points keeps every method well under a second; the library allows more.
constexpr int kMaxCliLevel = 7;

constexpr const char* kCurveHelp =
    R"(Usage: meshdeform-cli curve --koch LEVEL --svg OUT.svg [--pull DY] [--report OUT.json] [options]

The paper's 2D curve edit (Section 6.1, Fig. 9): the Koch curve of LEVEL (4^LEVEL + 1 points, from
(0,0) to (1,0)) with both ends fixed and the middle point (the apex of the central bump) pulled up
by DY, deformed with Laplacian editing, ARAP and the scale-aware method. Writes the rest curve and
the three results side by side as an SVG, with E_theta (RMS turning-angle change) as captions.

  --koch LEVEL       Koch level, 1..7
  --pull DY          upward pull of the middle point in curve units (default 0.3; the curve is 1 wide)
  --svg PATH         the figure (SVG)
  --report PATH      JSON report: per method E_theta, length-ratio measure, time, iterations
  --lambda L         weight of the point constraints (default 100)
  --iterations N     ARAP iteration budget (default 50; it also stops at relative change 1e-6)
  --help             this text

Prints one line per method. Exit codes: 0 ok, 1 runtime error, 2 usage error.
)";

int usage_error(const std::string& message) {
  std::fprintf(stderr, "meshdeform-cli %s: %s\nTry 'meshdeform-cli %s --help'.\n", kCommand,
               message.c_str(), kCommand);
  return kExitUsage;
}

int runtime_error(const Status& status) {
  std::fprintf(stderr, "meshdeform-cli %s: error: %s\n", kCommand, status.to_string().c_str());
  return kExitRuntimeError;
}


Status write_text(const fs::path& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return Error(ErrorCode::Internal, "cannot open '" + path.string() + "' for writing");
  out << text;
  out.close();
  if (!out) return Error(ErrorCode::Internal, "cannot write '" + path.string() + "'");
  return Status::success();
}

const char* display_name(core::CurveMethod method) {
  switch (method) {
    case core::CurveMethod::Laplacian:
      return "Laplacian";
    case core::CurveMethod::Arap:
      return "ARAP";
    case core::CurveMethod::ScaleAware:
      return "scale-aware (ours)";
  }
  return "unknown";
}

nlohmann::json points_json(const core::Points2& P) {
  nlohmann::json rows = nlohmann::json::array();
  for (Eigen::Index i = 0; i < P.rows(); ++i) rows.push_back({P(i, 0), P(i, 1)});
  return rows;
}

}  // namespace

int run_curve(const std::vector<std::string>& args) {
  ParsedArgs parsed;
  const std::vector<OptionSpec> specs = {{"koch"},   {"pull"},       {"svg"},        {"report"},
                                         {"lambda"}, {"iterations"}, {"help", false}};
  if (auto error = parse_args(args, specs, parsed)) return usage_error(error->message);
  if (parsed.has("help")) {
    std::fputs(kCurveHelp, stdout);
    return kExitOk;
  }
  const auto level_text = parsed.get("koch");
  const auto svg_path = parsed.get("svg");
  if (!level_text) return usage_error("missing --koch LEVEL");
  if (!svg_path) return usage_error("missing --svg OUT.svg");
  if (svg_path->empty()) return usage_error("--svg is empty");
  const auto level = parse_integer(*level_text);
  if (!level || *level < 1 || *level > kMaxCliLevel) {
    return usage_error("--koch must be an integer in [1, " + std::to_string(kMaxCliLevel) +
                       "], got '" + *level_text + "'");
  }
  double pull = 0.3;
  if (auto text = parsed.get("pull")) {
    const auto value = parse_double(*text);
    if (!value) return usage_error("--pull must be a finite number, got '" + *text + "'");
    pull = *value;
  }
  core::CurveOptions options;
  if (auto text = parsed.get("lambda")) {
    const auto value = parse_double(*text);
    if (!value || *value <= 0)
      return usage_error("--lambda must be a number > 0, got '" + *text + "'");
    options.lambda = *value;
  }
  if (auto text = parsed.get("iterations")) {
    const auto value = parse_integer(*text);
    if (!value || *value < 0 || *value > 100000) {
      return usage_error("--iterations must be an integer in [0, 100000], got '" + *text + "'");
    }
    options.max_iterations = static_cast<int>(*value);
  }
  const auto report_path = parsed.get("report");
  if (report_path && report_path->empty()) return usage_error("--report is empty");
  if (Status s = check_output_parent(*svg_path); !s.ok()) return runtime_error(s);
  if (report_path) {
    if (Status s = check_output_parent(*report_path); !s.ok()) return runtime_error(s);
  }

  auto edit = core::make_koch_edit(static_cast<int>(*level), pull);
  if (!edit.ok()) return runtime_error(edit.status());

  nlohmann::json methods = nlohmann::json::array();
  std::vector<core::CurvePanel> panels;
  for (const core::CurveMethod method :
       {core::CurveMethod::Laplacian, core::CurveMethod::Arap, core::CurveMethod::ScaleAware}) {
    auto result = core::deform_curve(method, edit->rest, edit->constrained, edit->targets, options);
    if (!result.ok()) return runtime_error(result.status());
    auto errors = core::curve_errors(edit->rest, result->P);
    if (!errors.ok()) return runtime_error(errors.status());
    double constraint_error = 0;
    for (Eigen::Index j = 0; j < edit->constrained.size(); ++j) {
      constraint_error = std::max(
          constraint_error, (result->P.row(edit->constrained(j)) - edit->targets.row(j)).norm());
    }
    panels.push_back({display_name(method), result->P, errors->e_theta});
    methods.push_back({{"method", core::curve_method_name(method)},
                       {"e_theta", errors->e_theta},
                       {"scale_log_rms", errors->scale_log_rms},
                       {"seconds", result->seconds},
                       {"iterations", result->iterations},
                       {"converged", result->converged},
                       {"energy", result->energy_history.back()},
                       {"max_constraint_error", constraint_error}});
    std::string note;
    if (method == core::CurveMethod::Arap) {
      note = " (" + std::to_string(result->iterations) + " iterations, " +
             (result->converged ? "converged)" : "budget reached)");
    }
    std::printf("%-19s E_theta %.5f rad, length-ratio log RMS %.5f, %.4f s%s\n",
                display_name(method), errors->e_theta, errors->scale_log_rms, result->seconds,
                note.c_str());
  }

  if (Status s = write_text(*svg_path, core::curve_comparison_svg(*edit, panels)); !s.ok()) {
    return runtime_error(s);
  }
  if (report_path) {
    nlohmann::json report = {
        {"edit",
         {{"curve", "koch"},
          {"level", *level},
          {"points", edit->rest.P.rows()},
          {"pull", pull},
          {"constrained", std::vector<int>(edit->constrained.data(),
                                           edit->constrained.data() + edit->constrained.size())},
          {"handle", edit->handle},
          {"targets", points_json(edit->targets)}}},
        {"options",
         {{"lambda", options.lambda},
          {"arap_max_iterations", options.max_iterations},
          {"arap_tolerance", options.tolerance}}},
        {"methods", methods},
        {"svg", *svg_path},
    };
    if (Status s = write_text(*report_path, report.dump(2) + "\n"); !s.ok())
      return runtime_error(s);
  }
  std::printf("wrote %s%s%s\n", svg_path->c_str(), report_path ? " and " : "",
              report_path ? report_path->c_str() : "");
  return kExitOk;
}

}  // namespace meshdeform::cli
