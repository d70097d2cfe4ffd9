#include "cli/commands.h"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>
#include <system_error>
#include <utility>
#include <vector>

#include "cli/args.h"
#include "cli/curve_command.h"
#include "cli/deform_run.h"
#include "cli/paths.h"
#include "core/io/deform_spec.h"
#include "core/io/mesh_io.h"
#include "core/samples/samples.h"

namespace meshdeform::cli {
namespace {

namespace fs = std::filesystem;

constexpr const char* kProgram = "meshdeform-cli";

constexpr const char* kMainHelp =
    R"(meshdeform-cli: scale-aware, detail-preserving mesh deformation (Liu et al.)

Usage:
  meshdeform-cli deform   --mesh IN (--sel S.sel --def D.def | --edit EDIT.json) --out OUT [options]
  meshdeform-cli generate --model NAME|all [--small] --out-dir DIR
  meshdeform-cli demo     [--out-dir DIR]
  meshdeform-cli curve    --koch LEVEL [--pull DY] --svg OUT.svg [--report OUT.json]
  meshdeform-cli COMMAND --help

Commands:
  deform    deform a mesh file toward handle targets and write the result and a JSON report
  generate  write the paper's Table 1 models (bumpy_plane, cylinder, bar, cactus) as .off/.sel/.def
  demo      bend the built-in cylinder; writes demo_result.glb/.obj and demo_report.json
  curve     2D Koch-curve edit with Laplacian, ARAP and scale-aware side by side (paper Fig. 9)

Exit codes: 0 success, 1 runtime error, 2 usage error.
)";

constexpr const char* kDeformHelp =
    R"(Usage: meshdeform-cli deform --mesh IN --out OUT (--sel S.sel --def D.def | --edit EDIT.json) [options]

Deforms IN (scale-aware by default) and writes the result to OUT.

Inputs:
  --mesh PATH               mesh to deform (.obj .off .ply .stl .glb .gltf)
  --sel PATH                Botsch & Sorkine selection: one role per vertex (0 fixed, 1 free, 2 handle)
  --def PATH                4x4 row-major transform applied to the handle vertices (with --sel)
  --edit PATH               JSON edit spec (fixed vertices, handle groups, magnify regions,
                            options), instead of --sel/--def
Outputs:
  --out PATH                deformed mesh (.obj .off .ply .stl .glb .gltf)
  --report PATH             JSON report: inputs, options, per-iteration history, timings, errors
Method:
  --method NAME             scale_aware (default), arap or laplacian (an edit spec may set it)
  --ora                     optimal rigidity approximation after the solve (scale-aware only)
  --rigidity X              scale control, X >= 0 (scale-aware only): 0 is the paper's method,
                            larger keeps local scale closer to the handles' (default 30;
                            an edit spec may set it)
Solver:
  --iterations N            outer iterations at full resolution, the budget (default 15; an
                            edit spec may set it)
  --tolerance T             converged when the estimated remaining relative energy change is
                            at most T (default 1e-3; see --stopping)
  --stopping RULE           remaining (default): the last relative energy change d divided by
                            1 - q, q the larger of the last two change ratios (at most 0.95),
                            i.e. how far the energy still has to go; change: d alone (the rule
                            before this release, which stops slow tails early)
  --multilevel on|off       on meshes of more than 20,000 vertices (scale-aware, auto start):
                            solve coarse-to-fine through a decimated hierarchy (default on);
                            off: one level, at full resolution
  --inner-iterations K      step-one sweeps per outer iteration (default 5)
  --anderson M              Anderson acceleration of the outer iteration: mix the last M
                            updates (default 6; 0 = the plain iteration)
  --start auto|laplacian|previous|rigid|propagated|paper  starting guess (default auto:
                            with scale control (--rigidity > 0) the rigid start, or, when its
                            result has folds, the result from laplacian or then paper that has
                            fewer at most 1.5x the rigid start's energy (the report's start_used
                            says which); at --rigidity 0 laplacian; laplacian: the paper's
                            initialisation; rigid: ARAP run to convergence first (relative
                            change 1e-6, at most 1000 iterations); propagated: the handles'
                            rotations spread over the surface; paper: the paper's method
                            (rigidity 0) from laplacian until it has no folds, then the
                            rigidity)
  --lambda L                handle weight (default 100)
  --threads N               solver threads, 0 = all (default 1)
Output control:
  --verbose                 one progress line per iteration on stderr (a bar is shown on terminals)
  --help                    this text

On success prints one summary line on stdout. Exit codes: 0 ok, 1 runtime error, 2 usage error.
)";

constexpr const char* kGenerateHelp =
    R"(Usage: meshdeform-cli generate --model NAME|all [--small] --out-dir DIR

Writes the procedural Table 1 benchmark models as DIR/NAME.off (mesh), DIR/NAME.sel (per-vertex
roles: 0 fixed, 1 free, 2 handle) and DIR/NAME.def (handle transform), ready for `deform`.

  --model NAME     bumpy_plane (40,401 vertices), cylinder (4,802), bar (2,602), cactus (5,289),
                   or all
  --small          small versions for quick tests (441, 420, 554, 336 vertices)
  --out-dir DIR    output directory (created if missing)
  --help           this text
)";

constexpr const char* kDemoHelp = R"(Usage: meshdeform-cli demo [--out-dir DIR] [--verbose]

Bends the built-in cylinder (4,802 vertices, 120 degrees) with the scale-aware solver and writes
DIR/demo_result.glb, DIR/demo_result.obj and DIR/demo_report.json, then prints a short summary.

  --out-dir DIR    output directory, created if missing (default ./out)
  --verbose        one progress line per iteration on stderr (a bar is shown on terminals)
  --help           this text
)";

int usage_error(const std::string& command, const std::string& message) {
  std::fprintf(stderr, "%s %s: %s\nTry '%s %s --help'.\n", kProgram, command.c_str(),
               message.c_str(), kProgram, command.c_str());
  return kExitUsage;
}

int runtime_error(const std::string& command, const Status& status) {
  std::fprintf(stderr, "%s %s: error: %s\n", kProgram, command.c_str(), status.to_string().c_str());
  return kExitRuntimeError;
}

/// Creates `dir` (and parents) if needed.
Status ensure_directory(const fs::path& dir) {
  std::error_code ec;
  if (fs::is_directory(dir, ec)) return Status::success();
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir)) {
    return Error(ErrorCode::Internal, "cannot create directory '" + dir.string() + "'" +
                                          (ec ? ": " + ec.message() : std::string()));
  }
  return Status::success();
}


/// Parses the solver flags into `run` (flags override what an edit spec set).
std::optional<std::string> apply_solver_flags(const ParsedArgs& parsed, RunSettings& run) {
  if (auto text = parsed.get("iterations")) {
    const auto value = parse_integer(*text);
    if (!value || *value < 0 || *value > 100000) {
      return "--iterations must be an integer in [0, 100000], got '" + *text + "'";
    }
    run.options.max_iterations = static_cast<int>(*value);
  }
  if (auto text = parsed.get("tolerance")) {
    const auto value = parse_double(*text);
    if (!value || *value < 0) return "--tolerance must be a number >= 0, got '" + *text + "'";
    run.options.tolerance = *value;
  }
  if (auto text = parsed.get("inner-iterations")) {
    const auto value = parse_integer(*text);
    if (!value || *value < 1 || *value > 10000) {
      return "--inner-iterations must be an integer in [1, 10000], got '" + *text + "'";
    }
    run.options.inner_iterations = static_cast<int>(*value);
  }
  if (auto text = parsed.get("anderson")) {
    const auto value = parse_integer(*text);
    if (!value || *value < 0 || *value > 64) {
      return "--anderson must be an integer in [0, 64], got '" + *text + "'";
    }
    run.options.anderson_window = static_cast<int>(*value);
  }
  if (auto text = parsed.get("start")) {
    const Result<core::StartFrom> start = core::parse_start(*text);
    if (!start.ok()) {
      return "--start must be 'auto', 'laplacian', 'previous', 'rigid', 'propagated' or "
             "'paper', got '" + *text + "'";
    }
    run.options.start = *start;
  }
  if (auto text = parsed.get("lambda")) {
    const auto value = parse_double(*text);
    if (!value || *value <= 0) return "--lambda must be a number > 0, got '" + *text + "'";
    run.options.lambda = *value;
    run.settings.lambda = *value;
  }
  if (auto text = parsed.get("method")) {
    auto method = core::parse_method(*text);
    if (!method.ok()) return "--method: " + method.status().message();
    run.method = *method;
  }
  if (parsed.has("ora")) run.options.ora = true;
  if (auto text = parsed.get("rigidity")) {
    const auto value = parse_double(*text);
    if (!value || !core::check_rigidity(*value).ok()) {
      return "--rigidity must be a finite number >= 0, got '" + *text + "'";
    }
    run.options.rigidity = *value;
  }
  if (auto text = parsed.get("stopping")) {
    if (*text == "remaining") {
      run.options.stopping_rule = core::StoppingRule::Remaining;
    } else if (*text == "change") {
      run.options.stopping_rule = core::StoppingRule::Change;
    } else {
      return "--stopping must be 'remaining' or 'change', got '" + *text + "'";
    }
  }
  if (auto text = parsed.get("multilevel")) {
    if (*text == "on") {
      run.options.multilevel = true;
      run.settings.multilevel_above = core::kDefaultMultilevelAbove;
    } else if (*text == "off") {
      run.options.multilevel = false;
      run.settings.multilevel_above = 0;  // nor build the hierarchy
    } else {
      return "--multilevel must be 'on' or 'off', got '" + *text + "'";
    }
  }
  if (auto text = parsed.get("threads")) {
    const auto value = parse_integer(*text);
    if (!value || *value < 0 || *value > 4096) {
      return "--threads must be an integer in [0, 4096], got '" + *text + "'";
    }
    run.settings.threads = static_cast<int>(*value);
  }
  return std::nullopt;
}

double start_e_theta(const core::SolveReport& report) {
  return report.history.empty() ? 0.0 : report.history.front().e_theta;
}
double start_e_phi(const core::SolveReport& report) {
  return report.history.empty() ? 0.0 : report.history.front().e_phi;
}

std::optional<core::DeformationBenchmark> make_model(const std::string& name, bool is_small) {
  if (name == "bumpy_plane")
    return is_small ? core::make_bumpy_plane(21) : core::make_bumpy_plane();
  if (name == "cylinder") return is_small ? core::make_cylinder(20, 21) : core::make_cylinder();
  if (name == "bar") return is_small ? core::make_bar(20, 6) : core::make_bar();
  if (name == "cactus") return is_small ? core::make_cactus(1) : core::make_cactus();
  return std::nullopt;
}

}  // namespace

int run_deform(const std::vector<std::string>& args) {
  const std::string command = "deform";
  ParsedArgs parsed;
  const std::vector<OptionSpec> specs = {{"mesh"},           {"sel"},        {"def"},
                                         {"edit"},           {"out"},        {"report"},
                                         {"iterations"},     {"tolerance"},  {"inner-iterations"},
                                         {"start"},          {"lambda"},     {"threads"},
                                         {"method"},         {"ora", false}, {"verbose", false},
                                         {"rigidity"},       {"anderson"},   {"stopping"},
                                         {"multilevel"},     {"help", false}};
  if (auto error = parse_args(args, specs, parsed)) return usage_error(command, error->message);
  if (parsed.has("help")) {
    std::fputs(kDeformHelp, stdout);
    return kExitOk;
  }
  const auto mesh_path = parsed.get("mesh");
  const auto out_path = parsed.get("out");
  if (!mesh_path) return usage_error(command, "missing --mesh");
  if (!out_path) return usage_error(command, "missing --out");
  const bool has_edit = parsed.has("edit");
  const bool has_sel = parsed.has("sel"), has_def = parsed.has("def");
  if (has_edit && (has_sel || has_def)) {
    return usage_error(command, "give either --edit or --sel/--def, not both");
  }
  if (!has_edit && !(has_sel && has_def)) {
    if (has_sel) return usage_error(command, "--sel needs --def (the handle transform)");
    if (has_def) return usage_error(command, "--def needs --sel (the vertex roles)");
    return usage_error(command, "missing constraints: give --sel and --def, or --edit");
  }
  if (auto format = io::format_from_path(*out_path); !format.ok()) {
    return usage_error(command, "--out: " + format.status().message());
  }
  RunSettings run;
  run.progress = choose_progress_style(parsed.has("verbose"));
  run.label = fs::path(*mesh_path).filename().string();
  // Validate the flags before any file work; they are applied again after an edit spec's options.
  {
    RunSettings probe = run;
    if (auto error = apply_solver_flags(parsed, probe)) return usage_error(command, *error);
  }
  if (Status s = check_output_parent(*out_path); !s.ok()) return runtime_error(command, s);
  if (auto report_path = parsed.get("report")) {
    if (Status s = check_output_parent(*report_path); !s.ok()) return runtime_error(command, s);
  }

  auto input = has_edit ? load_edit_input(*mesh_path, *parsed.get("edit"))
                        : load_benchmark_input(*mesh_path, *parsed.get("sel"), *parsed.get("def"));
  if (!input.ok()) return runtime_error(command, input.status());
  const io::EditOptions& spec_options = input->edit_options;
  if (spec_options.iterations) run.options.max_iterations = *spec_options.iterations;
  if (spec_options.tolerance) run.options.tolerance = *spec_options.tolerance;
  if (spec_options.inner_iterations) run.options.inner_iterations = *spec_options.inner_iterations;
  if (spec_options.ora) run.options.ora = *spec_options.ora;
  if (spec_options.rigidity) run.options.rigidity = *spec_options.rigidity;
  if (spec_options.method) {
    auto method = core::parse_method(*spec_options.method);
    if (!method.ok()) return runtime_error(command, method.status());
    run.method = *method;
  }
  if (auto error = apply_solver_flags(parsed, run)) return usage_error(command, *error);

  auto outcome = run_deformation(*input, run);
  if (!outcome.ok()) return runtime_error(command, outcome.status());

  MeshData result{outcome->report.V, input->mesh.F};
  if (Status s = io::write_mesh(*out_path, result); !s.ok()) return runtime_error(command, s);
  if (auto report_path = parsed.get("report")) {
    nlohmann::json report = make_report(*input, run, *outcome);
    report["output"] = *out_path;
    if (Status s = write_json(*report_path, report); !s.ok()) return runtime_error(command, s);
  }
  const core::SolveReport& r = outcome->report;
  std::printf(
      "%s: %lld vertices, %lld constrained, %d iterations%s in %.2f s (+%.2f s precompute); "
      "E_theta %.4g -> %.4g, E_phi %.4g -> %.4g; wrote %s\n",
      run.label.c_str(), static_cast<long long>(input->mesh.V.rows()),
      static_cast<long long>(input->setup.constrained.size()), r.iterations,
      r.converged ? " (converged)" : "", r.seconds, outcome->precompute_seconds, start_e_theta(r),
      outcome->final_errors.e_theta, start_e_phi(r), outcome->final_errors.e_phi,
      out_path->c_str());
  return kExitOk;
}

int run_generate(const std::vector<std::string>& args) {
  const std::string command = "generate";
  ParsedArgs parsed;
  const std::vector<OptionSpec> specs = {{"model"}, {"out-dir"}, {"small", false}, {"help", false}};
  if (auto error = parse_args(args, specs, parsed)) return usage_error(command, error->message);
  if (parsed.has("help")) {
    std::fputs(kGenerateHelp, stdout);
    return kExitOk;
  }
  const auto model = parsed.get("model");
  const auto out_dir = parsed.get("out-dir");
  if (!model)
    return usage_error(command, "missing --model (bumpy_plane, cylinder, bar, cactus or all)");
  if (!out_dir) return usage_error(command, "missing --out-dir");
  std::vector<std::string> names;
  if (*model == "all") {
    names = {"bumpy_plane", "cylinder", "bar", "cactus"};
  } else if (make_model(*model, true)) {
    names = {*model};
  } else {
    return usage_error(command, "unknown model '" + *model +
                                    "' (expected bumpy_plane, cylinder, bar, cactus or all)");
  }
  if (Status s = ensure_directory(*out_dir); !s.ok()) return runtime_error(command, s);
  for (const std::string& name : names) {
    const auto bench = make_model(name, parsed.has("small"));
    const fs::path base = fs::path(*out_dir) / name;
    fs::path off = base, sel = base, def = base;
    off += ".off";
    sel += ".sel";
    def += ".def";
    if (Status s = io::write_mesh(off, bench->mesh); !s.ok()) return runtime_error(command, s);
    if (Status s = io::write_sel(sel, bench->selection); !s.ok()) return runtime_error(command, s);
    if (Status s = io::write_def(def, bench->transform); !s.ok()) return runtime_error(command, s);
    std::printf("%s: %lld vertices, %lld faces -> %s (.sel, .def)\n", name.c_str(),
                static_cast<long long>(bench->mesh.V.rows()),
                static_cast<long long>(bench->mesh.F.rows()), off.string().c_str());
  }
  return kExitOk;
}

int run_demo(const std::vector<std::string>& args) {
  const std::string command = "demo";
  ParsedArgs parsed;
  const std::vector<OptionSpec> specs = {{"out-dir"}, {"verbose", false}, {"help", false}};
  if (auto error = parse_args(args, specs, parsed)) return usage_error(command, error->message);
  if (parsed.has("help")) {
    std::fputs(kDemoHelp, stdout);
    return kExitOk;
  }
  const fs::path out_dir = parsed.get("out-dir").value_or("out");
  if (out_dir.empty()) return usage_error(command, "--out-dir is empty");
  if (Status s = ensure_directory(out_dir); !s.ok()) return runtime_error(command, s);

  const core::DeformationBenchmark bench = core::make_cylinder();
  auto input = benchmark_input(bench);
  if (!input.ok()) return runtime_error(command, input.status());
  RunSettings run;
  run.progress = choose_progress_style(parsed.has("verbose"));
  run.label = "demo (" + bench.name + ")";
  auto outcome = run_deformation(*input, run);
  if (!outcome.ok()) return runtime_error(command, outcome.status());

  const MeshData result{outcome->report.V, input->mesh.F};
  const fs::path glb = out_dir / "demo_result.glb";
  const fs::path obj = out_dir / "demo_result.obj";
  const fs::path json = out_dir / "demo_report.json";
  if (Status s = io::write_mesh(glb, result); !s.ok()) return runtime_error(command, s);
  if (Status s = io::write_mesh(obj, result); !s.ok()) return runtime_error(command, s);
  nlohmann::json report = make_report(*input, run, *outcome);
  report["output"] = {glb.string(), obj.string()};
  report["edit"] = "cylinder bent by 120 degrees (bottom rings fixed, top rings handle)";
  if (Status s = write_json(json, report); !s.ok()) return runtime_error(command, s);

  const core::SolveReport& r = outcome->report;
  std::printf("meshdeform demo: %s bent by 120 degrees\n", bench.name.c_str());
  std::printf("  mesh        %lld vertices, %lld faces, %lld constrained (%d at rest, %d moved)\n",
              static_cast<long long>(input->mesh.V.rows()),
              static_cast<long long>(input->mesh.F.rows()),
              static_cast<long long>(input->setup.constrained.size()), input->at_rest_count,
              input->moved_count);
  std::printf("  solve       %d iterations%s, %.2f s (+%.2f s precompute), %d factorizations\n",
              r.iterations, r.converged ? " (converged)" : "", r.seconds,
              outcome->precompute_seconds, r.factorizations);
  std::printf("  E_theta     %.5f (Laplacian start) -> %.5f (result) rad\n", start_e_theta(r),
              outcome->final_errors.e_theta);
  std::printf("  E_phi       %.5f (Laplacian start) -> %.5f (result) rad\n", start_e_phi(r),
              outcome->final_errors.e_phi);
  std::printf("  area        RMS log ratio %.5f\n", outcome->final_errors.area_log_rms);
  std::printf("  wrote       %s, %s, %s\n", glb.string().c_str(), obj.string().c_str(),
              json.string().c_str());
  return kExitOk;
}

int run_cli(const std::vector<std::string>& args) {
  if (args.empty()) {
    std::fputs(kMainHelp, stderr);
    return kExitUsage;
  }
  const std::string& command = args.front();
  const std::vector<std::string> rest(args.begin() + 1, args.end());
  if (command == "--help" || command == "-h" || command == "help") {
    std::fputs(kMainHelp, stdout);
    return kExitOk;
  }
  if (command == "--version") {
    std::printf("meshdeform-cli 0.1.0\n");
    return kExitOk;
  }
  if (command == "deform") return run_deform(rest);
  if (command == "generate") return run_generate(rest);
  if (command == "demo") return run_demo(rest);
  if (command == "curve") return run_curve(rest);
  std::fprintf(stderr,
               "%s: unknown command '%s' (expected deform, generate, demo or curve)\nTry '%s --help'.\n",
               kProgram, command.c_str(), kProgram);
  return kExitUsage;
}

}  // namespace meshdeform::cli
