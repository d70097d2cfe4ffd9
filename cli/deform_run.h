#pragma once
/// @file deform_run.h
/// The deformation pipeline behind `deform` and `demo`: load inputs, solve with the scale-aware
/// solver, measure the result, and describe everything in a JSON report.

#include <filesystem>
#include <string>

#include <nlohmann/json.hpp>

#include "cli/progress.h"
#include "core/methods/deform_types.h"
#include "core/io/deform_spec.h"
#include "core/mesh/measures.h"
#include "core/mesh/mesh_data.h"
#include "core/samples/samples.h"
#include "core/methods/deformer.h"
#include "core/methods/ora.h"
#include "core/methods/scale_aware.h"
#include "core/base/status.h"

namespace meshdeform::cli {

/// A mesh with its constraints, ready to solve, plus where it came from (for the report).
struct DeformInput {
  MeshData mesh;            ///< cleaned and validated
  core::HandleSetup setup;  ///< constraints on `mesh` (indices after cleaning)
  int at_rest_count = 0;    ///< constrained vertices whose target is their rest position
  int moved_count = 0;      ///< constrained vertices whose target differs from it
  int welded_vertices = 0;  ///< merged by cleaning
  int dropped_unreferenced = 0;
  nlohmann::json sources;        ///< paths or a description of the inputs
  io::EditOptions edit_options;  ///< options carried by a JSON edit spec (empty otherwise)
  /// Regions to magnify (vertex form, numbering of `mesh`); handle targets inside a region are
  /// already scaled by its k about the region's rest centroid.
  std::vector<core::MagnifyRegion> magnify;
};

/// Loads a mesh file and a Botsch & Sorkine .sel/.def pair.
/// @return the input; the errors of io::load_mesh, io::read_sel (the count must match the file's
///         vertices), io::read_def and core::constraints_from_selection.
[[nodiscard]] Result<DeformInput> load_benchmark_input(const std::filesystem::path& mesh_path,
                                                       const std::filesystem::path& sel_path,
                                                       const std::filesystem::path& def_path);

/// Loads a mesh file and a JSON edit spec.
/// @return the input; the errors of io::load_mesh, io::read_edit_spec and io::resolve_edit.
[[nodiscard]] Result<DeformInput> load_edit_input(const std::filesystem::path& mesh_path,
                                                  const std::filesystem::path& edit_path);

/// A procedural benchmark as input (no files).
[[nodiscard]] Result<DeformInput> benchmark_input(const core::DeformationBenchmark& bench);

/// Solver configuration of one run.
struct RunSettings {
  core::Method method = core::Method::ScaleAware;
  core::SolveOptions options;
  core::DeformerSettings settings;
  ProgressStyle progress = ProgressStyle::None;
  std::string label = "deform";  ///< progress label
};

/// What a run produced.
struct DeformOutcome {
  core::SolveReport report;
  double precompute_seconds = 0;
  core::AngleErrors final_errors;  ///< E_theta, E_phi and area distortion of the result
};

/// Precomputes the chosen method and solves once (with ORA / magnification when asked).
/// @return the outcome; the errors of core::make_deformer / solve, core::face_scales_from_regions
///         and core::build_topology; InvalidArgument for ORA or magnification with a method
///         other than scale-aware.
[[nodiscard]] Result<DeformOutcome> run_deformation(const DeformInput& input,
                                                    const RunSettings& run);

/// The JSON report: input summary, options, per-iteration history, totals and final errors.
nlohmann::json make_report(const DeformInput& input, const RunSettings& run,
                           const DeformOutcome& outcome);

/// Writes JSON (indented) to a file.
/// @return success; Internal naming the path if it cannot be written.
[[nodiscard]] Status write_json(const std::filesystem::path& path, const nlohmann::json& json);

/// "laplacian", "previous" or "auto".


}  // namespace meshdeform::cli
