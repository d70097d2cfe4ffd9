#include "cli/deform_run.h"

#include <algorithm>
#include <chrono>
#include <fstream>
#include <utility>
#include <vector>

#include "core/io/mesh_io.h"
#include "core/io/report_json.h"
#include "core/topology.h"
#include "core/validate.h"

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

const char* start_name(core::StartFrom start) {
  switch (start) {
    case core::StartFrom::Auto:
      return "auto";
    case core::StartFrom::Laplacian:
      return "laplacian";
    case core::StartFrom::Previous:
      return "previous";
  }
  return "auto";
}

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
        return io::resolve_edit(spec, raw_V);
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
  MD_ASSIGN_OR_RETURN(core::ScaleAwareSolver solver,
                      core::ScaleAwareSolver::create(input.mesh.V, input.mesh.F,
                                                     input.setup.constrained, run.settings));
  outcome.precompute_seconds = seconds_between(t0, std::chrono::steady_clock::now());

  ProgressPrinter printer(run.progress, run.options.max_iterations, run.label);
  auto solved = solver.solve(input.setup.targets, run.options, printer.callback());
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
  j["method"] = "scale_aware";
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
                  {"start", start_name(run.options.start)},
                  {"pcg_tolerance", run.options.pcg_tolerance},
                  {"adaptive_pcg", run.options.adaptive_pcg},
                  {"threads", run.settings.threads}};
  j["history"] = io::history_to_json(report.history);
  j["iterations"] = report.iterations;
  j["converged"] = report.converged;
  j["factorizations"] = report.factorizations;
  j["pcg_iterations"] = report.pcg_iterations;
  j["precompute_seconds"] = outcome.precompute_seconds;
  j["solve_seconds"] = report.seconds;
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
