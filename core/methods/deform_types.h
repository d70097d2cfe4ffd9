#pragma once
/// @file deform_types.h
/// Options, progress and reports shared by every deformation method (scale-aware, and the
/// baselines added later), so callers switch methods without changing code.

#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>

#include "core/base/format_number.h"
#include "core/base/status.h"
#include "core/mesh/mesh_data.h"
#include "core/methods/convergence.h"

namespace meshdeform::core {

/// Where an iterative solve starts.
enum class StartFrom {
  /// The previous result when there is one; else, for the scale-aware method with scale control
  /// (rigidity > 0), the Rigid start (ARAP to convergence: measured in
  /// bench/results/rigidity_sweep.md, the issue-12 targets on 12 of 12 edits against 9 of 12 from
  /// the Laplacian guess, whose basin is worse on 135-degree twists), unless its result has folds
  /// (count_folds): then the results from the Laplacian guess and, if the best so far still has
  /// folds, from the Paper start are computed too, and one replaces the best if it has fewer
  /// folds at no more than 1.5x the rigid start's energy (SolveReport::start says which; the
  /// Spot twist's other basin costs 2.1-2.6x); at rigidity 0 and for the other
  /// methods the Laplacian-editing guess (the paper's start: rigidity 0 stays the paper's method).
  Auto,
  Laplacian,  ///< always the Laplacian-editing guess (paper Section 5.2)
  Previous,   ///< the previous result (the rest mesh before the first solve)
  /// Scale-aware only (other methods treat it as Laplacian): a rotation-aware start, ARAP from
  /// its own Laplacian guess until its relative energy change falls below
  /// SolveOptions::rigid_start_tolerance, at most rigid_start_iterations iterations
  /// (docs/algorithm.md section 8: the Laplacian guess is poor for large twists). The bent
  /// cylinders keep some of converged ARAP's creases from it (4-5 folded edges; ARAP's own: 6),
  /// which is why Auto then compares with the Laplacian guess's and the Paper start's results.
  Rigid,
  /// Scale-aware only (other methods treat it as Laplacian): the handles' rotations propagated
  /// harmonically over the surface, then ARAP's global step with them (core/methods/rotation_start.h;
  /// Zayer et al. 2005): a rotation-aware start without ARAP iterations. Measured in
  /// bench/results/rigidity_propagated_start/: no folds on the twisted bars and their E_phi
  /// below ARAP's, but their E_theta 1.4x ARAP's at the default rigidity, so Auto does not use it.
  Propagated,
  /// Scale-aware only (other methods treat it as Laplacian): the paper's own solve (rigidity 0)
  /// from the Laplacian guess until its result has no folds (count_folds; at most max_iterations
  /// iterations), then the solve at the requested rigidity from there. The Laplacian guess of a
  /// large bend has many folds (64 on the irregular bent cylinder) that the paper's iteration
  /// removes within ~10 iterations; with the scale term on from the start some of them set into
  /// creases that more iterations do not remove. At rigidity 0 it is the Laplacian start.
  Paper,
};

/// Progress of a precompute (building a solver or a hierarchy), called on the building thread: a
/// phase name and the fraction of that phase done, in [0, 1]. Every phase reports 0 when it starts
/// and 1 when it ends; long phases report fractions in between. Phase names: "validate" (mesh
/// checks, topology, rest measures), "rigid_start" (the ARAP factorization of the scale-aware
/// solver's default start; with two or more solver threads the scale term's system beside it),
/// "step_two" (the scale-aware solver's step-two matrix), "factorize"
/// (ARAP's and Laplacian editing's factorizations), and for a multiresolution deformer (core/
/// multires.h) "decimate", "prolongation", "coarse_precompute", "fine_precompute".
using BuildProgress = std::function<void(std::string_view phase, double fraction)>;

/// Calls `progress` if it is set.
inline void report_progress(const BuildProgress& progress, std::string_view phase,
                            double fraction) {
  if (progress) progress(phase, fraction);
}

/// Default SolveOptions::rigidity, chosen from bench/results/rigidity_sweep.md (with the default
/// ScaleAwareSettings::scale_normal_tie 0.3 and Auto's rigid start: all three targets of issue 12
/// on 12 of its 12 edits; 100 meets 11, the bar's E_phi 1.02x ARAP's).
inline constexpr double kDefaultRigidity = 30.0;

/// The one check of a scale control (SolveOptions::rigidity) everywhere it is taken: finite and
/// in [0, upper]. The library's range is [0, infinity) (solve(), prepare(), the CLI); the service
/// caps requests lower (service::kMaxRigidity) and passes its cap as `upper`.
/// @return InvalidArgument naming the value and the range (NaN included).
[[nodiscard]] inline Status check_rigidity(
    double rigidity, double upper = std::numeric_limits<double>::infinity()) {
  if (rigidity >= 0.0 && rigidity <= upper && std::isfinite(rigidity)) return Status::success();
  if (std::isinf(upper)) {
    return Error(ErrorCode::InvalidArgument,
                 "rigidity must be a finite number >= 0, got " + format_number(rigidity, "%g"));
  }
  return Error(ErrorCode::InvalidArgument, "rigidity " + format_number(rigidity, "%g") +
                                               " is outside [0, " + format_number(upper, "%g") +
                                               "]");
}

/// Per-solve options. Defaults follow docs/algorithm.md.
struct SolveOptions {
  /// Outer (step one + step two) iterations, the budget; of a multilevel solve
  /// (core/multires/multilevel.h), the budget of the full-resolution level (coarse levels: their own).
  int max_iterations = 15;
  /// Stop when `stopping_rule` holds at this tolerance (core/methods/convergence.h): by default when the
  /// estimated remaining relative energy change is at most this. 1e-3 by measurement
  /// (docs/multilevel.md): the result's E_theta / E_phi within about 1% of where the iteration
  /// settles. (Before issue 41: 1e-4 on the last relative change, StoppingRule::Change.)
  double tolerance = 1e-3;
  /// The stopping rule (core/methods/convergence.h): Remaining, the default, or Change (the rule before
  /// issue 41: the last relative energy change below `tolerance`).
  StoppingRule stopping_rule = StoppingRule::Remaining;
  /// Scale-aware deformers built with DeformerSettings::multilevel_above: a cold Auto solve runs
  /// the multilevel cascade (core/multires/multilevel.h). false: the single-level solve at full
  /// resolution, as without a hierarchy (for comparison). Other deformers ignore it.
  bool multilevel = true;
  int inner_iterations = 5;     ///< cap on step-one local/global sweeps per outer iteration
  double lambda = 100.0;        ///< handle weight of Eq. 12 (fixed per solver; see precompute)
  StartFrom start = StartFrom::Auto;
  bool track_metrics = true;    ///< compute E_theta / E_phi after every outer iteration
  /// Step two's conjugate-gradient tolerance (relative residual). With `adaptive_pcg` this is the
  /// tightest tolerance used: early iterations solve loosely, tied to the outer progress
  /// (inexact alternating minimisation), and tighten as the energy settles.
  double pcg_tolerance = 1e-10;
  bool adaptive_pcg = true;
  /// Anderson acceleration of the outer local/global iteration (Peng et al. 2018, "Anderson
  /// Acceleration for Geometry Optimization and Physics Simulation"): each step mixes the last
  /// `anderson_window` fixed-point updates; 0 turns it off. Safeguarded by the energy: an
  /// accelerated iterate whose energy exceeds the last accepted one is replaced by the plain
  /// update and the window restarts, so ARAP's energy still never increases. Used by ARAP and by
  /// the scale-aware solver (there the merit is the joint energy at an iterate after its own
  /// step one and scale step, which the plain iteration does not always lower either; core/methods/scale_aware.cpp; rejections are counted in
  /// SolveReport::anderson_rejections). Scale-aware at the default rigidity, small suite: the
  /// energy of 15 plain iterations in 5-12 accelerated ones, 1.0-2.5x sooner in wall time.
  /// Default 6 by measurement (bench/results/realistic.md): on the irregular Table 1 models accelerated ARAP reaches the
  /// energy of 100 plain iterations in 25-50 iterations, 1.9-3.3x sooner in wall time (one
  /// iteration costs ~15% more), with lower E_theta and E_phi at 15 iterations. The first
  /// iteration of every solve is the plain one, so a 1-iteration move is unchanged.
  int anderson_window = 6;
  /// Optimal rigidity approximation (paper Section 5.3): after the solve, rescale every triangle
  /// to its rest area and stitch (scale-aware method only).
  bool ora = false;
  /// Region magnification (Figs. 12-13): #F linear target scales (k on a region, 1 elsewhere;
  /// see face_scales_from_regions in core/methods/ora.h). Non-empty implies the ORA stitch with areas
  /// k^2 x rest area. Scale handle targets inside a region yourself (about its centre, by k).
  Eigen::VectorXd face_scale;
  /// Scale control (issue 12), scale-aware method only: weight rho >= 0 (finite) of an in-loop
  /// term that keeps local scale smooth and close to the scale the handles imply (per-face
  /// frames following the step-one normals, per-face scales smoothed over the surface and pulled
  /// toward that reference; see core/methods/scale_control.h). 0 is the paper's pure method on the same
  /// code path, bit for bit. Larger values trade the paper's angle preservation for ARAP-like
  /// area preservation (measured in bench/results/rigidity_sweep.md); similarities stay exact at
  /// every value. The handle weight becomes lambda (1 + rho). Per solve: a new value refactors
  /// only the n x n block-trace preconditioner (cached for the last value).
  double rigidity = kDefaultRigidity;
  /// Most ARAP iterations of the Rigid start (>= 0; 0 is ARAP's Laplacian guess with hard
  /// handles). 1000 lets the 135-degree twists converge (ARAP needs 140-540 iterations there).
  int rigid_start_iterations = 1000;
  /// The Rigid start stops when ARAP's relative energy change falls below this (>= 0; 0 runs all
  /// rigid_start_iterations). 1e-6 by measurement: 1e-5 leaves the twisted bar's E_phi above
  /// converged ARAP's (bench/results/rigidity_sweep.md's notes).
  double rigid_start_tolerance = 1e-6;
  /// Multiresolution deformers only (DeformerSettings::multires_above): solve at full
  /// resolution (a refinement) instead of on the coarse level. Other deformers ignore it.
  bool full_resolution = false;
};

/// Which part of a solve an iteration belongs to (a multilevel solve, core/multires/multilevel.h, runs all
/// three; a single-level solve reports its own iterations as Fine).
enum class SolvePhase {
  Fine,    ///< the scale-aware iteration at full resolution (the result's own iterations)
  Start,   ///< the rigid start's ARAP iterations (a multilevel solve: on every level)
  Levels,  ///< the scale-aware iteration on a coarse level of a multilevel solve
};
/// "fine", "start", "levels".
inline const char* solve_phase_name(SolvePhase phase) {
  switch (phase) {
    case SolvePhase::Start:
      return "start";
    case SolvePhase::Levels:
      return "levels";
    case SolvePhase::Fine:
      return "fine";
  }
  return "fine";
}

/// What one outer iteration did (iteration 0 is the starting guess).
struct IterationInfo {
  int iteration = 0;
  double energy = 0;            ///< Eq. 12 objective (+ rigidity x scale term) after step two
  /// The same objective for the iterate entering this iteration, evaluated after this
  /// iteration's step one (its normals and, with rigidity > 0, the face frames that follow them).
  /// The scale step and step two are exact minimisers or descent steps, so energy <=
  /// energy_before up to round-off (iteration 0: equal to energy).
  double energy_before = 0;
  double e_theta = 0;           ///< radians RMS (0 unless track_metrics)
  double e_phi = 0;
  double elapsed_seconds = 0;   ///< since the solve started
  int pcg_iterations = 0;       ///< conjugate-gradient iterations of step two
  int normal_sweeps = 0;        ///< step-one local/global sweeps run
  bool refactored = false;      ///< step two refactored its matrix this iteration
  double normals_seconds = 0;   ///< step one (normals on the Gauss map)
  double assemble_seconds = 0;  ///< filling step two's matrix
  double linear_seconds = 0;    ///< refactorization and PCG
  /// A multilevel solve's progress (core/multires/multilevel.h) also reports its start's ARAP
  /// iterations and its coarse levels' iterations: their phase, the level (0 = full resolution)
  /// and its vertex count; elapsed_seconds then counts from the start of the whole solve. A
  /// single-level solve reports its rigid start's ARAP iterations (StartFrom::Rigid, and Auto's
  /// cold start) as Start, level 0, with the mesh's vertex count, and its outer iterations as
  /// Fine, level 0, vertices 0. SolveReport::history holds the full-resolution outer iterations
  /// only: count Fine reports to follow it.
  SolvePhase phase = SolvePhase::Fine;
  int level = 0;
  int level_vertices = 0;
};

/// Called after every outer iteration (of every phase and level of a multilevel solve); runs on
/// the solving thread. A general per-iteration hook: besides progress displays, a caller may do
/// other work between iterations here (the service runs waiting short moves of other sessions).
using ProgressCallback = std::function<void(const IterationInfo&)>;

/// One level of a multilevel solve (core/multires/multilevel.h), coarsest first.
struct LevelReport {
  int level = 0;                ///< 0 = full resolution
  int vertices = 0;
  int start_iterations = 0;     ///< ARAP iterations of the rigid start on this level
  double start_seconds = 0;
  int iterations = 0;           ///< scale-aware outer iterations on this level
  bool converged = false;       ///< the stopping rule held (level tolerance; level 0: the solve's)
  double seconds = 0;           ///< the scale-aware part on this level (transfer included)
  double energy = 0;            ///< the level's final energy (its own mesh's)
  /// The level's scale-aware result: the largest distance of a constrained vertex of this level
  /// from its target, over the full-resolution mesh's bounding-box diagonal.
  double handle_error = 0;
};

/// Wall time by phase. Single-level: start = everything before the returned result's first
/// outer iteration (the rigid start, other start candidates), fine = its iterations, levels 0.
/// Multilevel: start = the rigid start's ARAP cascade on every level (solver set-up included),
/// levels = the scale-aware iteration on the coarse levels and the transfers between them,
/// fine = the transfer to full resolution and the full-resolution iterations.
struct PhaseSeconds {
  double start = 0;
  double levels = 0;
  double fine = 0;
};

/// Errors before and after the ORA / magnification stitch.
struct StitchReport {
  bool applied = false;
  double e_theta_before = 0, e_phi_before = 0, area_before = 0;  ///< the solver's own result
  double e_theta_after = 0, e_phi_after = 0, area_after = 0;     ///< after rescaling and stitching
  double seconds = 0;
};

/// The coarse level a multiresolution move solved on (core/multires/multires.h): its triangles
/// and which full-resolution vertex each of its vertices is, shared by every move of one
/// deformer. A client can draw it during a drag (issue 44) instead of the full mesh.
struct CoarseLevelMesh {
  Triangles F;              ///< #Fc x 3 triangles on the coarse vertices
  Eigen::VectorXi to_fine;  ///< #Vc full-resolution vertex of each coarse vertex, ascending
  /// A hash of F and to_fine (FNV-1a, 64 bits): equal meshes have equal keys, on every server.
  std::uint64_t key = 0;
};

/// A multiresolution move's positions on its coarse level. The prolongation keeps coarse
/// vertices where the coarse solve put them: V.row(i) equals the full result's row to_fine(i).
struct CoarseLevelPositions {
  std::shared_ptr<const CoarseLevelMesh> mesh;
  Positions V;  ///< #Vc x 3
};

/// The key of CoarseLevelMesh: FNV-1a over the vertex count, to_fine and F.
std::uint64_t coarse_level_key(const Triangles& F, const Eigen::VectorXi& to_fine);

/// The outcome of a solve.
struct SolveReport {
  Positions V;                          ///< #V x 3 deformed positions
  std::vector<IterationInfo> history;   ///< starting guess, then each outer iteration
  int iterations = 0;                   ///< outer iterations run
  bool converged = false;               ///< stopped on tolerance rather than budget
  int factorizations = 0;               ///< numeric factorizations during this solve
  int pcg_iterations = 0;               ///< total PCG iterations during this solve
  int anderson_rejections = 0;          ///< accelerated iterates the safeguard replaced
  double seconds = 0;                   ///< wall time of the solve (every candidate start)
  /// The start the result came from: Laplacian, Previous, Rigid, Propagated or Paper (Auto
  /// resolved).
  StartFrom start = StartFrom::Auto;
  /// Auto's cold start with scale control (scale-aware, rigidity > 0) checks its result for folds
  /// (count_folds in core/mesh/measures.h) and, while the best result so far has any, solves from the
  /// Laplacian guess and then from the Paper start too; a candidate replaces the best one if it
  /// has fewer folds at no more than 1.5x the rigid start's energy (or as many at less energy).
  /// The number of candidates solved (1-3); the other fields (history, iterations,
  /// pcg_iterations, ...) describe the returned candidate.
  int start_candidates = 1;
  /// With start Paper: the paper's iterations (rigidity 0) before the solve at the requested
  /// rigidity (whose iterations `history` and `iterations` describe); 0 otherwise.
  int paper_iterations = 0;
  /// Folded edges of the returned result when that check ran; -1 when it did not.
  int folded_edges = -1;
  StitchReport stitch;                  ///< ORA / magnification, when requested
  /// The stopping rule's last estimate (ConvergenceMonitor::estimated_remaining; infinity when
  /// it could not be formed, e.g. after one iteration).
  double estimated_remaining = 0;
  PhaseSeconds phases;                  ///< where `seconds` went
  /// A multilevel solve's levels, coarsest first, full resolution last; empty for a
  /// single-level solve.
  std::vector<LevelReport> levels;
  /// A move a multiresolution deformer solved on its coarse level and prolonged: that level's
  /// positions. Null for every full-resolution solve.
  std::shared_ptr<const CoarseLevelPositions> coarse;
};

}  // namespace meshdeform::core
