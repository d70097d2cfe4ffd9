#pragma once
/// @file multires.h
/// Multiresolution editing of large meshes (issue 15): solve the scale-aware method on a coarse
/// level, bring the result back to full resolution with the fine detail, and refine there.
///
/// Levels. `MeshHierarchy::build` decimates the input with OpenMesh's decimation framework
/// (BaseDecimaterT and its modules). Each step collapses one half-edge, chosen as the cheapest of
/// a few random candidates (multiple-choice decimation, Wu & Kobbelt 2002: several times faster
/// than OpenMesh's priority queue over all vertices, at nearly the same quality) and priced by
/// Garland-Heckbert quadric error plus boundary-edge quadrics, so that open borders keep their
/// shape. Collapses that rotate a face normal by more than `max_normal_deviation_degrees` or
/// create faces worse than `max_aspect_ratio` are refused, and OpenMesh's link condition keeps
/// every level a 2-manifold of the input's topology; each level is then checked with
/// validate_triangle_mesh (a failure is reported, never returned as a level). Level 0 is the
/// input, level k decimates level k - 1 to `level_vertices[k - 1]`. A half-edge collapse removes
/// one vertex and never moves the other, so every level is a subset of the fine vertices at
/// their rest positions (`MeshLevel::to_fine`): no resampling, no coarse-to-fine correspondence
/// to search for, and the coarse targets of an edit are rows of the fine targets.
/// Constrained vertices are locked (never removed): with ConstraintLevels::KeepAll all of them,
/// so each level holds the whole handle set; with KeepBorders only those with an unconstrained
/// neighbour (the borders of the fixed and handle regions). KeepBorders is for edits whose
/// regions cover much of the mesh: Spot's edits constrain 43% of the vertices, so with KeepAll no
/// level of Spot 187k can have fewer than 81k vertices.
///
/// Detail encoding (`Prolongation`; Kobbelt et al. 1998, Botsch & Sorkine 2008 section 6). The
/// fine mesh is split into a smooth base surface B and details D = V - B:
///  - B is the harmonic interpolation of the coarse positions: the coarse vertices are fine
///    vertices, held at their coarse positions, and the others solve L_ff B_f = -L_fc B_c with
///    the clamped-cotangent Laplacian of the rest mesh (core/methods/laplacian.h), factored once. The
///    system is linear and L annihilates constants, so an affine map of the coarse mesh maps B
///    exactly; every fine vertex depends smoothly on all the coarse ones (no seams at coarse
///    edges, unlike a projection onto the nearest coarse triangle, whose per-triangle frames jump
///    across coarse edges and leave steps a fine solve must then remove).
///  - Each detail vector is stored in the local frame of B at its vertex at rest (area-weighted
///    normal, the tangent towards the most tangential neighbour, their cross product), divided by
///    the local scale sqrt(one-ring area of B). After a deformation it is re-applied in the frame
///    of the deformed base, times the deformed local scale: rest poses are reproduced to
///    round-off, rigid motions and uniform scalings of the coarse mesh exactly (to round-off), and
///    details follow the local scale the scale-aware method lets vary.
/// Why scale details: the scale-aware method keeps angles, not lengths, so a region may grow or
/// shrink; details scaled with it keep their shape (their angles) there.
/// Why a harmonic base rather than the bi-Laplacian (thin-plate) one of Botsch & Sorkine: one
/// sparse factor with the sparsity of L, kept in simplicial form for its few right-hand sides,
/// so a prolongation is three back-substitutions and two linear passes over the mesh (measured
/// 55-70 ms at 187k vertices, 280-350 ms at 750k, most of it the back-substitutions); a
/// bi-Laplacian factor is several times denser. With two threads the factor is split in two
/// halves of the mesh and a small dense separator block (core/linalg/split_cholesky.h), factored and
/// solved side by side: half the set-up's factorization time at 187k. The harmonic base is smooth only between coarse vertices (it has a kink at each),
/// but the details absorb that at rest and follow it under near-rigid local motion.
///
/// `MultiresDeformer` drives the two levels: interactive moves solve on the coarse level and
/// prolong; `refine` runs the full-resolution ScaleAwareSolver warm-started from the prolonged
/// positions (ScaleAwareSolver::set_positions), e.g. on a worker while the client is idle.

#include <cstdint>
#include <functional>
#include <future>
#include <memory>
#include <optional>
#include <stop_token>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "core/base/status.h"
#include "core/mesh/mesh_data.h"
#include "core/mesh/topology.h"
#include "core/methods/deform_types.h"
#include "core/methods/scale_aware.h"
#include "core/multires/multilevel.h"

namespace meshdeform::core {

class MultiresDeformer;
class MultilevelSolver;

/// Which constrained vertices the coarse levels keep.
enum class ConstraintLevels {
  /// Every constrained vertex is locked: each level holds the whole handle set at its rest
  /// position, and the coarse constraints are the fine ones. A level cannot have fewer vertices
  /// than there are constrained vertices.
  KeepAll,
  /// Only constrained vertices with an unconstrained neighbour (region borders) are locked; the
  /// inside of a fixed or handle region is decimated like the rest. Every vertex of a level that
  /// is constrained on the fine mesh is constrained on that level too.
  KeepBorders,
};

/// How a hierarchy is built.
struct MultiresSettings {
  /// Target vertex counts of the coarse levels, strictly decreasing. A level stops above its
  /// target when no legal collapse is left (locked vertices, quality limits).
  std::vector<int> level_vertices = {15000};
  ConstraintLevels constraint_levels = ConstraintLevels::KeepAll;
  /// Largest rotation of a face normal by one collapse, in degrees (0, 180].
  double max_normal_deviation_degrees = 45.0;
  /// Largest aspect ratio (longest edge over height) a collapse may create, unless it improves
  /// the worst face of its one-ring; >= 1.
  double max_aspect_ratio = 10.0;
  /// Half-edges drawn per collapse by the multiple-choice decimation (the cheapest legal one is
  /// collapsed; Wu & Kobbelt 2002): more is closer to greedy, and slower. >= 1.
  int samples = 8;
  /// Seed of the decimation's draws: a build is deterministic for a seed.
  std::uint64_t seed = 1;
  /// Weight of the boundary-edge quadrics (planes through a boundary edge, perpendicular to its
  /// face) relative to the face quadrics; >= 0. 0 lets open borders shrink.
  double boundary_weight = 100.0;
  /// Meshes with more vertices than this are decimated to the first level in two halves: the
  /// vertices are split at the median of the unlocked ones along the bounding box's longest
  /// axis, each half's inside is decimated by its own decimater (its own draws, seeded from
  /// `seed`) while a band two vertices wide along the cut stays untouched, then the band is
  /// decimated and the level finished over the whole mesh. The halves touch disjoint parts of
  /// the mesh, so they can run on two threads; the result does not depend on `threads`. 0 never
  /// splits.
  int split_above_vertices = 50000;
  /// Threads for a split decimation (1 or more; only two are used). 1 runs the halves in turn.
  /// MultiresDeformer also gives them to its Prolongation (its factorization and solves).
  int threads = 1;
};

// BuildProgress (core/methods/deform_types.h) phases of a multiresolution build: "decimate", "validate",
// "prolongation", "coarse_precompute", "fine_precompute".

/// One level of a hierarchy.
struct MeshLevel {
  Positions V;               ///< #Vk x 3 rest positions, V.row(i) = fine V.row(to_fine(i))
  Triangles F;               ///< #Fk x 3 triangles, oriented like the fine mesh
  Eigen::VectorXi to_fine;   ///< #Vk fine vertex of each vertex, ascending (level 0: identity)
  Eigen::VectorXi constrained;  ///< this level's constrained vertices, ascending by fine index
  /// Row of each of them in the fine constrained list: their targets are those rows of the fine
  /// targets (see MeshHierarchy::level_targets).
  Eigen::VectorXi constrained_rows;
};

/// A mesh and its decimated levels.
class MeshHierarchy {
 public:
  /// Decimates (V, F) level by level.
  /// @param[in] V            #V x 3 rest positions.
  /// @param[in] F            #F x 3 triangles, validate_triangle_mesh(V, F) ok.
  /// @param[in] constrained  #C distinct vertex indices (fixed and handle vertices alike), in
  ///                         the order of the targets later given to level_targets.
  /// @param[in] settings     levels and quality limits.
  /// @param[in] progress     "decimate" (fraction of the collapses of all levels) and
  ///                         "validate" reports; may be empty.
  /// @param[in] stop         checked every few hundred collapses.
  /// @return the hierarchy; InvalidArgument for an invalid mesh, a bad or repeated index or bad
  ///         settings; Cancelled when `stop` is requested; Internal naming the level and the
  ///         rule if a level fails validation (non-manifold or degenerate; never expected).
  [[nodiscard]] static Result<MeshHierarchy> build(const Positions& V, const Triangles& F,
                                                   const Eigen::VectorXi& constrained,
                                                   const MultiresSettings& settings = {},
                                                   const BuildProgress& progress = {},
                                                   std::stop_token stop = {});

  /// 1 + the number of coarse levels.
  int level_count() const { return static_cast<int>(levels_.size()); }
  /// Level k in [0, level_count()); 0 is the input mesh.
  const MeshLevel& level(int k) const { return levels_.at(static_cast<size_t>(k)); }
  /// The targets of level k's constrained vertices, from #C x 3 fine targets (row j for
  /// constrained(j) as given to build). @return InvalidArgument for a wrong shape or level.
  [[nodiscard]] Result<Positions> level_targets(int k, const Positions& fine_targets) const;

 private:
  friend class MultiresDeformer;
  friend class MultilevelSolver;
  /// build() on a mesh already validated, with its topology.
  [[nodiscard]] static Result<MeshHierarchy> build_checked(
      const Positions& V, const Triangles& F, const MeshTopology& topology,
      const Eigen::VectorXi& constrained, const MultiresSettings& settings,
      const BuildProgress& progress, const std::stop_token& stop);
  std::vector<MeshLevel> levels_;
};

/// Coarse positions -> fine positions: harmonic base plus details in local frames (see the top
/// of this file). Precomputes one sparse factorization; apply() is cheap.
class Prolongation {
 public:
  /// @param[in] V               #V x 3 fine rest positions.
  /// @param[in] F               #F x 3 fine triangles, validate_triangle_mesh(V, F) ok.
  /// @param[in] coarse_to_fine  #Vc distinct fine indices of the coarse vertices (a level's
  ///                            to_fine); every connected component must hold one.
  /// @param[in] stop            checked before and after the factorization.
  /// @param[in] threads         >= 1; with 2 or more a large base system (20k free vertices
  ///                            and up) is factored in two halves side by side, and apply()
  ///                            solves them side by side too (core/linalg/split_cholesky.h: half the
  ///                            factorization time at 187k vertices). The result is the same
  ///                            to round-off.
  /// @return the operator; InvalidArgument for a bad index, a component without a coarse
  ///         vertex or threads < 1; NumericalFailure if the factorization fails or the rest
  ///         base surface has a degenerate vertex frame (naming the vertex); Cancelled.
  [[nodiscard]] static Result<Prolongation> create(const Positions& V, const Triangles& F,
                                                   const Eigen::VectorXi& coarse_to_fine,
                                                   std::stop_token stop = {}, int threads = 1);

  /// Fine positions for #Vc x 3 coarse positions (row i for coarse_to_fine(i)); coarse
  /// vertices land exactly on their coarse positions.
  /// @return InvalidArgument for a wrong shape or a non-finite value; NumericalFailure if the
  ///         result is not finite.
  [[nodiscard]] Result<Positions> apply(const Positions& coarse) const;

  int fine_vertex_count() const;
  int coarse_vertex_count() const;

  Prolongation(Prolongation&&) noexcept;
  Prolongation& operator=(Prolongation&&) noexcept;
  ~Prolongation();

 private:
  friend class MultiresDeformer;
  friend class MultilevelSolver;
  /// create() on a mesh already validated, with its topology; `laplacian`, when given, yields
  /// its clamped-cotangent Laplacian (built on another thread meanwhile).
  [[nodiscard]] static Result<Prolongation> create_checked(
      const Positions& V, const Triangles& F, const MeshTopology& topology,
      const Eigen::VectorXi& coarse_to_fine, const std::stop_token& stop, int threads,
      std::future<Eigen::SparseMatrix<double>>* laplacian);
  struct Impl;
  explicit Prolongation(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// Settings of a MultiresDeformer.
struct MultiresDeformerSettings {
  MultiresSettings hierarchy;
  ScaleAwareSettings solver;  ///< for the coarse and the full-resolution solver alike
  int level = -1;             ///< the coarse level moves solve on; -1 the coarsest
  /// The full-resolution solver is a MultilevelSolver (core/multires/multilevel.h) built with
  /// `cascade` (its `solver` is replaced by the `solver` above), and a full-resolution solve
  /// that does not continue the fine solver's own result (the first refine after moves, or
  /// before any) with start Auto, rigidity > 0 and SolveOptions::multilevel runs its cascade
  /// toward the targets instead of iterating from the prolonged move: the prolonged coarse
  /// result differs from the full-resolution fixed point at low frequency, which the
  /// full-resolution iteration removes slowly (docs/multilevel.md, "Refinement after a
  /// drag"). Later refines continue the cascade's result warm. Off: every refine iterates
  /// from the prolonged move (the fine solver is a single-level ScaleAwareSolver). A cascade
  /// that a move must be able to preempt wants `cascade.keep_fine_start` (make_deformer sets
  /// it): the start's full-resolution factorization is then built with the solver.
  bool refine_cascade = false;
  MultilevelSettings cascade;
};

/// Seconds spent by MultiresDeformer::create, and the sizes it chose.
struct MultiresBuildReport {
  double hierarchy_seconds = 0;      ///< decimation and validation
  double prolongation_seconds = 0;   ///< Prolongation::create
  double coarse_solver_seconds = 0;  ///< ScaleAwareSolver::create on the coarse level
  int coarse_vertices = 0;
  int coarse_constrained = 0;
};

/// An interactive move.
struct MultiresMove {
  Positions V;           ///< #V x 3 full-resolution positions (coarse solution, prolonged)
  SolveReport coarse;    ///< the coarse solve (coarse.V: the coarse level's positions)
  double prolong_seconds = 0;
};

/// Scale-aware deformation of a large mesh through a coarse level. Not thread-safe: one caller
/// at a time (a session's worker).
class MultiresDeformer {
 public:
  /// Builds the hierarchy, the prolongation of the chosen level and its coarse solver. The
  /// full-resolution solver is built by prepare_refinement (or the first refine).
  /// @param[in] V, F, constrained  as for ScaleAwareSolver::create.
  /// @param[in] progress  phases "decimate", "validate", "prolongation", "coarse_precompute".
  /// @return errors of MeshHierarchy::build, Prolongation::create and ScaleAwareSolver::create;
  ///         InvalidArgument for a level out of range.
  [[nodiscard]] static Result<MultiresDeformer> create(
      const Positions& V, const Triangles& F, const Eigen::VectorXi& constrained,
      const MultiresDeformerSettings& settings = {}, const BuildProgress& progress = {},
      std::stop_token stop = {});
  /// The same for a mesh the caller has validated (validate_triangle_mesh) and whose topology
  /// it has built (build_topology(F, #V)), e.g. a server session at upload: neither is done
  /// again (0.17 s at 187k vertices). The constrained indices are still checked.
  [[nodiscard]] static Result<MultiresDeformer> create(
      const Positions& V, const Triangles& F, const MeshTopology& topology,
      const Eigen::VectorXi& constrained, const MultiresDeformerSettings& settings = {},
      const BuildProgress& progress = {}, std::stop_token stop = {});

  /// Solves on the coarse level toward #C x 3 fine targets (the coarse solver warm-starts from
  /// its previous move as usual) and prolongs the result; it becomes positions().
  /// @return errors of ScaleAwareSolver::solve and Prolongation::apply; the deformer unchanged
  ///         on error.
  [[nodiscard]] Result<MultiresMove> move(const Positions& targets,
                                          const SolveOptions& options = {},
                                          const ProgressCallback& progress = {},
                                          std::stop_token stop = {});

  /// Builds the full-resolution ScaleAwareSolver (the expensive part at 10^5-10^6 vertices);
  /// does nothing when it exists. Reports phase "fine_precompute".
  [[nodiscard]] Status prepare_refinement(const BuildProgress& progress = {},
                                          std::stop_token stop = {});

  /// What building the full-resolution solver needs, copied: build_fine_solver can then run on
  /// another thread while this deformer keeps moving on its coarse level (seconds at 187k
  /// vertices that a drag need not wait for), and install_fine_solver hands the result over.
  struct FineSolverInputs {
    Positions V;
    Triangles F;
    Eigen::VectorXi constrained;  ///< in the order of the targets' rows
    MeshTopology topology;        ///< of (V, F), validated at create: not built again
    ScaleAwareSettings settings;
    /// The rigidity the first refinement will solve at: its setup (ScaleAwareSolver::prepare)
    /// is built with the solver; negative: none.
    double rigidity = -1;
    /// MultiresDeformerSettings::cascade when refine_cascade is set (its hierarchy is built
    /// too); otherwise a single level.
    MultilevelSettings multilevel;
  };
  /// True until the fine solver is built or installed.
  [[nodiscard]] bool needs_fine_solver() const;
  /// The inputs, or nothing when the fine solver exists.
  /// @param[in] rigidity  what the first refinement will solve at (negative: unknown).
  [[nodiscard]] std::optional<FineSolverInputs> fine_solver_inputs(double rigidity = -1) const;
  /// MultilevelSolver::create on the inputs; touches no deformer (any thread).
  [[nodiscard]] static Result<MultilevelSolver> build_fine_solver(const FineSolverInputs& inputs,
                                                                  std::stop_token stop = {});
  /// Installs a solver from build_fine_solver(fine_solver_inputs()); a no-op when one exists.
  void install_fine_solver(MultilevelSolver solver);

  /// Full-resolution solve toward the same kind of targets. With options.start Auto or
  /// Previous it starts from positions() once a move or a refinement has run (Auto before that:
  /// the Laplacian guess); Laplacian and Rigid behave as in ScaleAwareSolver. With
  /// MultiresDeformerSettings::refine_cascade, an Auto solve at rigidity > 0 with
  /// options.multilevel that does not continue an earlier refine runs the multilevel cascade
  /// instead (the report's levels and phases filled in; options.max_iterations is its
  /// full-resolution budget). The result becomes positions(). Builds the fine solver first if
  /// needed.
  [[nodiscard]] Result<SolveReport> refine(const Positions& targets,
                                           const SolveOptions& options = {},
                                           const ProgressCallback& progress = {},
                                           std::stop_token stop = {});

  /// Forgets every result: positions() is the rest mesh, the next move starts the coarse solver
  /// from its Laplacian guess.
  void reset();

  /// The latest full-resolution positions (the rest mesh before the first move).
  const Positions& positions() const;
  const MeshHierarchy& hierarchy() const;
  /// The level moves solve on.
  int coarse_level() const;
  const MultiresBuildReport& build_report() const;
  /// The coarse solver (e.g. to reset it).
  ScaleAwareSolver& coarse_solver();
  /// The full-resolution solver, null before prepare_refinement.
  ScaleAwareSolver* fine_solver();

  MultiresDeformer(MultiresDeformer&&) noexcept;
  MultiresDeformer& operator=(MultiresDeformer&&) noexcept;
  ~MultiresDeformer();

 private:
  struct Impl;
  explicit MultiresDeformer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace meshdeform::core
