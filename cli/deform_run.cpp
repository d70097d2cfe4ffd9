#include "cli/deform_run.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <utility>
#include <vector>

#include "core/io/mesh_io.h"
#include "core/io/report_json.h"
#include "core/mesh/topology.h"
#include "core/mesh/validate.h"

namespace meshdeform::cli {
namespace {

/// Moves constraints given on the file's vertices onto the cleaned mesh: vertices dropped as
/// unreferenced lose their (meaningless) constraint; welded duplicates must agree on the target.
Result<core::HandleSetup> remap_setup(const core::HandleSetup& setup,
                                      const Eigen::VectorXi& old_to_new) {
  std::vector<std::pair<int, Eigen::Index>> moved;  // (new index, row in setup)
  for (Eigen::Index j = 0; j < setup.constrained.size(); ++j) {
    const int old_index = setup.constrained(j);
    const int new_index = old_to_new(old_index);
    if (new_index >= 0) moved.emplace_back(new_index, j);
  }
  std::stable_sort(moved.begin(), moved.end(),
                   [](const auto& a, const auto& b) { return a.first < b.first; });
  core::HandleSetup out;
  std::vector<std::pair<int, Eigen::Index>> unique;
  for (const auto& entry : moved) {
    if (!unique.empty() && unique.back().first == entry.first) {
      const Eigen::Index a = unique.back().second, b = entry.second;
      if (!setup.targets.row(a).isApprox(setup.targets.row(b), 1e-12)) {
        return Error(ErrorCode::InvalidArgument,
                     "vertices " + std::to_string(setup.constrained(a)) + " and " +
                         std::to_string(setup.constrained(b)) +
                         " are at the same position (welded) but have different targets");
      }
      continue;
    }
    unique.push_back(entry);
  }
  out.constrained.resize(static_cast<Eigen::Index>(unique.size()));
  out.targets.resize(static_cast<Eigen::Index>(unique.size()), 3);
  for (size_t k = 0; k < unique.size(); ++k) {
    out.constrained(static_cast<Eigen::Index>(k)) = unique[k].first;
    out.targets.row(static_cast<Eigen::Index>(k)) = setup.targets.row(unique[k].second);
  }
  return out;
}

bool is_identity(const Eigen::VectorXi& old_to_new) {
  for (Eigen::Index v = 0; v < old_to_new.size(); ++v) {
    if (old_to_new(v) != v) return false;
  }
  return true;
}

/// Counts constrained vertices held at rest and moved (a handle vertex on a rotation axis counts
/// as held at rest: this describes the targets, not the selection).
void count_roles(DeformInput& input) {
  int fixed = 0;
  for (Eigen::Index j = 0; j < input.setup.constrained.size(); ++j) {
    const auto rest = input.mesh.V.row(input.setup.constrained(j));
    if ((input.setup.targets.row(j) - rest).norm() == 0.0) ++fixed;
  }
  input.at_rest_count = fixed;
  input.moved_count = static_cast<int>(input.setup.constrained.size()) - fixed;
}

/// Reads and cleans the mesh, then applies `constraints_on_raw` (which sees the vertices as
/// written in the file, the numbering .sel files and edit specs use).
template <typename MakeSetup>
Result<DeformInput> load_with(const std::filesystem::path& mesh_path, MakeSetup make_setup) {
  // Read raw, then clean a copy: .sel files and edit specs number the vertices as written.
  io::LoadOptions raw_options;
  raw_options.clean = false;
  MD_ASSIGN_OR_RETURN(io::LoadedMesh loaded, io::load_mesh(mesh_path, raw_options));
  DeformInput input;
  input.mesh = loaded.mesh;
  // STL is a triangle soup: it must be welded to have any connectivity.
  auto cleaned = core::clean_mesh(input.mesh, loaded.format == io::MeshFormat::Stl);
  if (!cleaned.ok()) {
    return Error(cleaned.status().code(), mesh_path.string() + ": " + cleaned.status().message());
  }
  MD_ASSIGN_OR_RETURN(core::HandleSetup raw_setup, make_setup(loaded.mesh.V, input));
  input.welded_vertices = cleaned->welded_vertices;
  input.dropped_unreferenced = cleaned->dropped_unreferenced;
  if (is_identity(cleaned->old_to_new) && cleaned->old_to_new.size() == input.mesh.V.rows()) {
    input.setup = std::move(raw_setup);
  } else {
    MD_ASSIGN_OR_RETURN(input.setup, remap_setup(raw_setup, cleaned->old_to_new));
    for (core::MagnifyRegion& region : input.magnify) {
      std::vector<int> kept;
      for (Eigen::Index k = 0; k < region.vertices.size(); ++k) {
        const int v = region.vertices(k);
        if (v >= 0 && v < cleaned->old_to_new.size() && cleaned->old_to_new(v) >= 0) {
          kept.push_back(cleaned->old_to_new(v));
        }
      }
      region.vertices = Eigen::Map<Eigen::VectorXi>(kept.data(), static_cast<int>(kept.size()));
    }
  }
  count_roles(input);
  input.sources["mesh"] = mesh_path.string();
  return input;
}

double seconds_between(std::chrono::steady_clock::time_point a,
                       std::chrono::steady_clock::time_point b) {
  return std::chrono::duration<double>(b - a).count();
}

}  // namespace

Result<DeformInput> load_benchmark_input(const std::filesystem::path& mesh_path,
                                         const std::filesystem::path& sel_path,
                                         const std::filesystem::path& def_path) {
  MD_ASSIGN_OR_RETURN(Eigen::Matrix4d transform, io::read_def(def_path));
  auto input =
      load_with(mesh_path, [&](const Positions& raw_V, DeformInput&) -> Result<core::HandleSetup> {
        MD_ASSIGN_OR_RETURN(Eigen::VectorXi selection,
                            io::read_sel(sel_path, static_cast<int>(raw_V.rows())));
        return core::constraints_from_selection(raw_V, selection, transform);
      });
  if (!input.ok()) return input.status();
  input->sources["selection"] = sel_path.string();
  input->sources["transform"] = def_path.string();
  return input;
}

Result<DeformInput> load_edit_input(const std::filesystem::path& mesh_path,
                                    const std::filesystem::path& edit_path) {
  MD_ASSIGN_OR_RETURN(io::EditSpec spec, io::read_edit_spec(edit_path));
  auto input = load_with(
      mesh_path, [&](const Positions& raw_V, DeformInput& out) -> Result<core::HandleSetup> {
        out.edit_options = spec.options;
        MD_ASSIGN_OR_RETURN(core::HandleSetup setup, io::resolve_edit(spec, raw_V));
        // Magnification (Figs. 12-13): handles inside a region grow with it, about its centre.
        for (size_t r = 0; r < spec.magnify.size(); ++r) {
          const io::MagnifySpec& m = spec.magnify[r];
          core::MagnifyRegion region;
          region.vertices = Eigen::Map<const Eigen::VectorXi>(m.vertices.data(),
                                                              static_cast<int>(m.vertices.size()));
          region.scale = m.scale;
          Eigen::RowVector3d centre = Eigen::RowVector3d::Zero();
          std::vector<char> inside(raw_V.rows(), 0);
          for (int v : m.vertices) {
            if (v < 0 || v >= raw_V.rows()) {
              return Error(ErrorCode::InvalidArgument,
                           "magnify[" + std::to_string(r) + "]: vertex " + std::to_string(v) +
                               " out of range (#V=" + std::to_string(raw_V.rows()) + ")");
            }
            centre += raw_V.row(v);
            inside[v] = 1;
          }
          centre /= static_cast<double>(m.vertices.size());
          for (Eigen::Index j = 0; j < setup.constrained.size(); ++j) {
            if (inside[setup.constrained(j)]) {
              setup.targets.row(j) = centre + m.scale * (setup.targets.row(j) - centre);
            }
          }
          out.magnify.push_back(std::move(region));
        }
        return setup;
      });
  if (!input.ok()) return input.status();
  input->sources["edit"] = edit_path.string();
  return input;
}

Result<DeformInput> benchmark_input(const core::DeformationBenchmark& bench) {
  DeformInput input;
  input.mesh = bench.mesh;
  MD_ASSIGN_OR_RETURN(input.setup, core::constraints_from_selection(bench.mesh.V, bench.selection,
                                                                    bench.transform));
  count_roles(input);
  input.sources["procedural"] = bench.name;
  return input;
}

Result<DeformOutcome> run_deformation(const DeformInput& input, const RunSettings& run) {
  DeformOutcome outcome;
  const auto t0 = std::chrono::steady_clock::now();
  core::SolveOptions options = run.options;
  if (!input.magnify.empty()) {
    MD_ASSIGN_OR_RETURN(options.face_scale,
                        core::face_scales_from_regions(input.magnify, input.mesh.F,
                                                       static_cast<int>(input.mesh.V.rows())));
  }
  if (run.method != core::Method::ScaleAware && (options.ora || options.face_scale.size() != 0)) {
    return Error(ErrorCode::InvalidArgument,
                 std::string("ORA and magnification belong to the scale-aware method, not ") +
                     core::method_name(run.method));
  }
  ProgressPrinter printer(run.progress, run.options.max_iterations, run.label);
  auto made = core::make_deformer(run.method, input.mesh.V, input.mesh.F,
                                  input.setup.constrained, run.settings, {},
                                  printer.build_callback());
  if (!made.ok()) {
    printer.finish();
    return made.status();
  }
  std::unique_ptr<core::Deformer> deformer = std::move(made).value();
  outcome.precompute_seconds = seconds_between(t0, std::chrono::steady_clock::now());

  auto solved = deformer->solve(input.setup.targets, options, printer.callback());
  printer.finish();
  if (!solved.ok()) return solved.status();
  outcome.report = std::move(solved).value();

  MD_ASSIGN_OR_RETURN(core::MeshTopology topology,
                      core::build_topology(input.mesh.F, static_cast<int>(input.mesh.V.rows())));
  const core::Measures rest = core::compute_measures(input.mesh.V, input.mesh.F, topology);
  const core::Measures result = core::compute_measures(outcome.report.V, input.mesh.F, topology);
  outcome.final_errors = core::angle_errors(rest, result);
  return outcome;
}

nlohmann::json make_report(const DeformInput& input, const RunSettings& run,
                           const DeformOutcome& outcome) {
  using nlohmann::json;
  const core::SolveReport& report = outcome.report;
  json j;
  j["tool"] = "meshdeform-cli";
  j["method"] = core::method_name(run.method);
  j["input"] = {{"sources", input.sources},
                {"vertices", input.mesh.V.rows()},
                {"faces", input.mesh.F.rows()},
                {"constrained", input.setup.constrained.size()},
                {"constrained_at_rest", input.at_rest_count},
                {"constrained_moved", input.moved_count},
                {"welded_vertices", input.welded_vertices},
                {"dropped_unreferenced", input.dropped_unreferenced}};
  j["options"] = {{"max_iterations", run.options.max_iterations},
                  {"tolerance", run.options.tolerance},
                  {"inner_iterations", run.options.inner_iterations},
                  {"lambda", run.options.lambda},
                  {"start", core::start_name(run.options.start)},
                  {"pcg_tolerance", run.options.pcg_tolerance},
                  {"adaptive_pcg", run.options.adaptive_pcg},
                  {"ora", run.options.ora},
                  {"threads", run.settings.threads},
                  {"rigidity", run.options.rigidity},
                  {"rigid_start_iterations", run.options.rigid_start_iterations},
                  {"rigid_start_tolerance", run.options.rigid_start_tolerance},
                  {"anderson_window", run.options.anderson_window},
                  {"stopping_rule", core::stopping_rule_name(run.options.stopping_rule)},
                  {"multilevel", run.options.multilevel &&
                                     run.settings.multilevel_above > 0}};
  if (!input.magnify.empty()) {
    json regions = json::array();
    for (const core::MagnifyRegion& region : input.magnify) {
      regions.push_back({{"vertices", region.vertices.size()}, {"scale", region.scale}});
    }
    j["magnify"] = regions;
  }
  if (report.stitch.applied) {
    j["stitch"] = {{"before", {{"e_theta", report.stitch.e_theta_before},
                               {"e_phi", report.stitch.e_phi_before},
                               {"area_log_rms", report.stitch.area_before}}},
                   {"after", {{"e_theta", report.stitch.e_theta_after},
                              {"e_phi", report.stitch.e_phi_after},
                              {"area_log_rms", report.stitch.area_after}}},
                   {"seconds", report.stitch.seconds}};
  }
  j["history"] = io::history_to_json(report.history);
  j["iterations"] = report.iterations;
  j["converged"] = report.converged;
  j["factorizations"] = report.factorizations;
  j["pcg_iterations"] = report.pcg_iterations;
  j["anderson_rejections"] = report.anderson_rejections;
  j["start_used"] = core::start_name(report.start);
  j["start_candidates"] = report.start_candidates;
  j["folded_edges"] = report.folded_edges >= 0 ? json(report.folded_edges) : json(nullptr);
  j["paper_start_iterations"] = report.paper_iterations;
  j["precompute_seconds"] = outcome.precompute_seconds;
  j["solve_seconds"] = report.seconds;
  // Issue 41: which rule "converged" is, and where the time went.
  j["stopping"] = {{"rule", core::stopping_rule_name(run.options.stopping_rule)},
                   {"description", core::stopping_rule_description(run.options.stopping_rule)},
                   {"tolerance", run.options.tolerance},
                   {"estimated_remaining", std::isfinite(report.estimated_remaining)
                                               ? json(report.estimated_remaining)
                                               : json(nullptr)}};
  j["phases"] = {{"setup_seconds", outcome.precompute_seconds},
                 {"start_seconds", report.phases.start},
                 {"levels_seconds", report.phases.levels},
                 {"fine_seconds", report.phases.fine}};
  json levels = json::array();
  for (const core::LevelReport& level : report.levels) {
    levels.push_back({{"level", level.level},
                      {"vertices", level.vertices},
                      {"start_iterations", level.start_iterations},
                      {"start_seconds", level.start_seconds},
                      {"iterations", level.iterations},
                      {"converged", level.converged},
                      {"seconds", level.seconds},
                      {"energy", level.energy},
                      {"handle_error", level.handle_error}});
  }
  j["multilevel"] = {{"used", !report.levels.empty()}, {"levels", levels}};
  if (!report.history.empty()) {
    j["start"] = {{"e_theta", report.history.front().e_theta},
                  {"e_phi", report.history.front().e_phi},
                  {"energy", report.history.front().energy}};
  }
  j["final"] = {{"e_theta", outcome.final_errors.e_theta},
                {"e_phi", outcome.final_errors.e_phi},
                {"area_log_rms", outcome.final_errors.area_log_rms},
                {"energy", report.history.empty() ? 0.0 : report.history.back().energy}};
  return j;
}

Status write_json(const std::filesystem::path& path, const nlohmann::json& json) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return Error(ErrorCode::Internal, "cannot open '" + path.string() + "' for writing");
  out << json.dump(2) << '\n';
  out.close();
  if (!out) return Error(ErrorCode::Internal, "cannot write '" + path.string() + "'");
  return Status::success();
}

}  // namespace meshdeform::cli
