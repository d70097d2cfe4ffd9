#pragma once
/// @file session.h
/// One editing session: the rest mesh and its measures, the current positions and the newest
/// revisions, the handle groups and targets, the cached prefactored deformers, and the watchers.

#include <atomic>
#include <chrono>
#include <cstdint>
#include <deque>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <vector>

#include "core/methods/deformer.h"
#include "core/mesh/measures.h"
#include "core/mesh/topology.h"
#include "server/service/deformer_cache.h"
#include "server/service/metrics.h"
#include "server/service/persistence.h"
#include "server/service/shared_store.h"
#include "server/service/types.h"
#include "server/service/watcher.h"
#include "server/service/worker_pool.h"

namespace meshdeform::service {

/// Counters shared by every session of a service.
struct ServiceCounters {
  std::atomic<std::uint64_t> deformer_constructions{0};
  std::atomic<std::uint64_t> moves_committed{0};
  std::atomic<std::uint64_t> moves_cancelled{0};
  std::atomic<std::uint64_t> refinements_committed{0};
  std::atomic<std::uint64_t> refinements_preempted{0};
  std::atomic<std::uint64_t> background_builds_installed{0};
  std::atomic<std::uint64_t> pcg_iterations{0};
  std::atomic<std::uint64_t> outer_iterations{0};
  std::atomic<std::uint64_t> persist_failures{0};
  std::atomic<std::uint64_t> persisted_writes{0};
  std::atomic<std::uint64_t> solves_running{0};  ///< moves and refinement slices in a solve now
  MetricsRegistry metrics;  ///< RPC and solve histograms (see metrics.h)
};

/// A session. Reads (info, positions_at, add_watcher) are safe from any thread. Edits
/// (set_handles, move) must be serialised by the caller: DeformationService runs them one at a
/// time per session on its worker pool (a strand), so different sessions solve in parallel.
class Session : public std::enable_shared_from_this<Session> {
 public:
  /// Asks the store for `bytes` more budget (evicting idle sessions); ResourceExhausted if not.
  using ReserveFn = std::function<Status(std::size_t bytes, const Session& requester)>;

  /// @pre core::validate_triangle_mesh(mesh.V, mesh.F) is ok.
  /// @return the session; InvalidArgument if the topology cannot be built.
  [[nodiscard]] static Result<std::shared_ptr<Session>> create(
      SessionId id, Token edit_token, Token view_token, MeshData mesh,
      const core::DeformerSettings& settings, const ServiceOptions& options,
      std::shared_ptr<ServiceCounters> counters, ReserveFn reserve);

  /// Recreates a session from its state file (see persistence.h); the factorizations are rebuilt
  /// on the next move. @return the session; InvalidArgument if the stored mesh, groups or sizes
  /// do not validate.
  [[nodiscard]] static Result<std::shared_ptr<Session>> restore(
      PersistedSession state, const ServiceOptions& options,
      std::shared_ptr<ServiceCounters> counters, ReserveFn reserve);
  /// Writes every committed revision and handle change to `dir` before it is applied here,
  /// acknowledged or published, from now on; nullptr stops. Call before the session is shared.
  void set_state_directory(const StateDirectory* dir) { state_dir_ = dir; }
  /// Writes the current state now (creation: there must be no file yet).
  /// @return as persist_state().
  [[nodiscard]] Status persist();
  /// The state as a state file or the shared store holds it; without `with_rest` the rest mesh
  /// is left empty (what a shared-store commit writes).
  PersistedSession persisted_state(bool with_rest = true) const;

  /// Shares the session through `store` (issue 16) from now on: every edit first takes the
  /// session's lease and catches this copy up with the store, and every committed revision and
  /// handle change is a compare-and-set on the stored version, acknowledged only once the store
  /// accepted it (an edit the store refuses fails and changes nothing here). `version` is the
  /// stored version this copy holds. Call before the session is shared; nullptr stops.
  void set_shared_store(SharedStateStore* store, std::uint64_t version);
  /// Shared store only: brings this copy up to the stored state, replaying the store's log (each
  /// revision published to the watchers, in order) or, past a gap or a handle change, loading the
  /// whole state (published as a snapshot). Any thread.
  /// @return success (also without a shared store); NotFound, after closing this copy, when the
  ///         session is no longer stored (closed elsewhere or expired); Internal when the store
  ///         fails.
  [[nodiscard]] Status sync_shared();
  /// Shared store only: gives the session's lease back (call once no edit is queued).
  void end_shared_edit();
  /// The version of the state file this copy last wrote or was restored from (nullopt before
  /// the first write, or without a state directory).
  std::optional<FileStamp> persisted_stamp() const;
  void set_persisted_stamp(const FileStamp& stamp);
  /// False when the session's state file is no longer the one this copy wrote or read: another
  /// replica sharing the directory changed (or removed) it, so this copy is stale. True without
  /// a state directory or before the first write. A write of this copy is never mistaken for
  /// another's: the file's replacement and the copy's record of it happen under one lock.
  bool is_fresh() const;
  /// Moves this (stale) copy's watchers to `fresh`, the state restored from the file, which
  /// publishes its current revision to them as a snapshot; then closes this copy.
  void hand_over_watchers(Session& fresh);
  /// The client (as the front end names it) that created the session; empty when unknown (a
  /// session restored from a state file or the shared store).
  const std::string& owner() const { return owner_; }
  /// Call before the session is shared.
  void set_owner(std::string owner) { owner_ = std::move(owner); }

  const SessionId& id() const { return id_; }
  const MeshData& rest() const { return rest_; }
  /// True for the edit token.
  bool can_edit(const Token& token) const;
  /// True for the view token or the edit token.
  bool can_view(const Token& token) const;
  /// The view token (handed to editors, who may share it; never logged).
  const Token& view_token() const { return view_token_; }
  /// The scale control (core::SolveOptions::rigidity) of scale-aware moves that do not set one.
  /// Call before the session is shared. @pre core::check_rigidity(rigidity, kMaxRigidity) succeeds.
  void set_default_rigidity(double rigidity) { default_rigidity_ = rigidity; }

  /// Sets the handle groups, anchors them at the current positions (targets = anchors) and builds
  /// (or reuses) the factorization of `request.prepare` for the constrained set.
  /// @return the new info; InvalidArgument for no groups, an empty group, an index out of range or
  ///         a vertex in two groups (naming it); FailedPrecondition if the method cannot pin a
  ///         connected component (scale-aware needs two constrained vertices per component, ARAP
  ///         and Laplacian one); ResourceExhausted over the memory budget; NotFound once closed;
  ///         NumericalFailure if the factorization fails; Cancelled when `stop` is requested
  ///         (before or between the precompute's phases; nothing changes).
  /// @param[in] progress  the precompute's phases (core::BuildProgress); none when cached.
  [[nodiscard]] Result<SessionInfo> set_handles(const SetHandlesRequest& request,
                                                std::stop_token stop = {},
                                                const core::BuildProgress& progress = {});

  /// Applies a move and solves, warm-starting the cached deformer of (method, constrained set)
  /// from its last result (a deformer whose last result is not the current revision, e.g. after
  /// a method switch, restarts from the Laplacian guess: core's Deformer cannot be seeded). Only
  /// changing targets never refactors. Commits a revision and publishes it to the watchers.
  /// @return the result; FailedPrecondition before set_handles or for a component the method
  ///         cannot pin; InvalidArgument for a bad group/vertex index, a move of a Fixed group, a
  ///         non-finite or out-of-range value (max_iterations, tolerance, rigidity, a zero
  ///         quaternion, a scale <= 0, more than kMaxMagnifyRegions regions), naming the field
  ///         as clients write it ("moves[1].scale"), or options the method rejects (ORA on ARAP
  ///         or Laplacian); Cancelled when `stop` is requested, DeadlineExceeded when it is and
  ///         request.deadline has passed, or when the move starts past it (nothing committed
  ///         either way); NotFound once closed; ResourceExhausted when a new factorization does
  ///         not fit the budget; NumericalFailure if the solve breaks down.
  /// @param stop  the call's one stop: the caller requests it on cancellation and at
  ///              request.deadline (DeformationService does, through CallStop); the session
  ///              polls nothing else.
  /// @param between_iterations  called after each outer iteration of the solve, on this
  ///              thread (the service runs other sessions' waiting moves there: fairness).
  [[nodiscard]] Result<DeformResult> move(const MoveRequest& request, std::stop_token stop,
                                          const core::ProgressCallback& between_iterations = {});

  /// Background refinement (ServiceOptions::refine_budget > 0). A committed move that did not
  /// converge leaves the session wanting refinement: more outer iterations of the same method on
  /// the same targets, warm-started from the committed result, in slices of a few iterations,
  /// each committed as a revision marked `refinement`, until the solver converges or the budget
  /// is spent. set_handles, a failed move and closing end it; a new edit preempts a running slice.
  /// Edit (strand) only.
  /// @param slice  the slice's stop (the caller ties it to shutdown); preempt_refinement()
  ///               requests it, and so does this call when an edit is already queued.
  /// @return the committed revision; nullopt when there was nothing to refine (or the state
  ///         changed since); Cancelled when preempted or stopped (nothing committed); the
  ///         solver's error otherwise (refinement then ends).
  [[nodiscard]] Result<std::optional<DeformResult>> refine(
      std::stop_source slice, const core::ProgressCallback& between_iterations = {});
  /// True while refinement should continue. Edit (strand) only.
  bool wants_refinement() const { return refine_.has_value() && !is_closed(); }
  /// Stops a running refinement slice (any thread). Called when a new edit is queued.
  void preempt_refinement();
  /// True when edits are queued behind the running one (any thread).
  bool has_queued_edits();

  /// Refinement's precompute off the strand (core::Deformer::background_build: the
  /// multiresolution deformer's full-resolution solver). Before this, the first refinement slice
  /// built it on the strand, every move preempted the build, and the next idle moment started it
  /// again: at 187k vertices a drag paid seconds of wasted builds and waited for their phases.
  struct BackgroundBuild {
    core::Deformer::BackgroundBuild task;
    core::Method method = core::Method::ScaleAware;  ///< ... of this method
    const core::Deformer* key = nullptr;             ///< the deformer it is for
  };
  /// When refinement waits for such a build that is not running yet: marks it running and
  /// returns it (run it on any thread, then finish_background_build on the strand). Strand only.
  [[nodiscard]] std::optional<BackgroundBuild> take_background_build();
  /// True while a taken build has not finished. Strand only.
  bool background_build_running() const { return background_build_running_; }
  /// Installs a finished build into its deformer if that is still cached; a failed one ends
  /// refinement (wants_refinement() turns false). Strand only.
  /// @return whether it was installed.
  bool finish_background_build(const BackgroundBuild& build,
                               Result<core::Deformer::Installer> installer);
  /// Stops a running build: requested by close() (any thread).
  std::stop_token background_build_stop() const { return closed_stop_.get_token(); }

  SessionInfo info() const;
  /// Positions at `revision` (default: the current one). Revision 0, the rest mesh, is always
  /// kept (a late watcher or a reopened link compares against it); of the others the newest
  /// ServiceOptions::kept_revisions.
  /// @return NotFound naming the kept range for a revision that is not (or no longer) kept.
  [[nodiscard]] Result<std::shared_ptr<const Positions>> positions_at(
      std::optional<std::uint64_t> revision) const;
  std::uint64_t revision() const;

  /// Adds a watcher whose mailbox already holds a full snapshot of the current revision.
  std::shared_ptr<Watcher> add_watcher();
  void remove_watcher(const Watcher* watcher);
  int watcher_count() const;

  /// Closes the session: a running solve or precompute stops, later edits fail with NotFound,
  /// nothing is written to the state directory after it returns, and watchers are closed with
  /// `reason` (success: the session was closed; their streams end OK).
  void close(Status reason = Status::success());
  /// Ends every watch with `reason` without closing the session (server shutdown: Unavailable).
  void close_watchers(Status reason);
  bool is_closed() const { return closed_.load(); }

  /// What the memory budget charges: the mesh, its revisions, the positions kept for exact undo
  /// (as they are kept) and the cached deformers.
  std::size_t estimated_bytes() const {
    return base_bytes_ + kept_bytes_.load() + deformers_->bytes();
  }
  std::chrono::steady_clock::time_point last_used() const;
  /// When a move (not refinement) last arrived or was last committed, whichever came later; the
  /// epoch before any. Refinement waits until this is ServiceOptions::refine_delay old: a move
  /// still queued or running counts from its arrival, not only from the previous commit.
  std::chrono::steady_clock::time_point last_move_time() const {
    return std::chrono::steady_clock::time_point(
        std::chrono::steady_clock::duration(last_move_ticks_.load()));
  }
  /// Records a move's arrival (before it is queued on the strand), and the interval since the
  /// previous one when that is under kDragGap (the moves of one drag; 0 otherwise).
  void note_move_arrival() {
    const auto now = std::chrono::steady_clock::now().time_since_epoch().count();
    last_move_ticks_.store(now);
    const auto previous = last_arrival_ticks_.exchange(now);
    const auto interval = now - previous;
    drag_interval_ticks_.store(
        previous != 0 && interval < std::chrono::steady_clock::duration(kDragGap).count()
            ? interval
            : 0);
  }
  /// The interval between the last two moves' arrivals when they belong to one drag (under
  /// kDragGap apart); zero otherwise. Refinement waits for a rest longer than the drag's
  /// own pauses (refinement_rest()).
  std::chrono::steady_clock::duration drag_interval() const {
    return std::chrono::steady_clock::duration(drag_interval_ticks_.load());
  }
  void touch(std::chrono::steady_clock::time_point now);
  /// Edits queued or running (the store only evicts sessions with none).
  std::atomic<int>& inflight() { return inflight_; }
  int inflight_count() const { return inflight_.load(); }
  /// OpenMP threads inside this session's solves (ServiceOptions::solver_threads when the mesh
  /// has at least parallel_solve_above vertices, else 1).
  int solve_threads() const { return settings_.threads; }

  /// How the strand's next step is to be scheduled on the pool.
  struct StrandStep {
    TaskClass task_class = TaskClass::Normal;
    std::string client;  ///< who asked (fairness of heavy work)
    /// A short normal step (a move of at most kShortMoveIterations): it may also run at a long
    /// solve's yield point (WorkerPool::submit_short).
    bool is_short = false;
  };
  /// Strand: the service queues edits here, each with its cost class and client; `run_next`
  /// pops one.
  /// @return how to schedule a drain if the caller must schedule one (the strand was idle);
  ///         nullopt otherwise.
  std::optional<StrandStep> enqueue(std::function<void()> task, StrandStep step);
  /// Runs the oldest queued edit. @return how to schedule the next one if more remain.
  std::optional<StrandStep> run_next();

 private:
  Session() = default;
  Status check_pinnable(core::Method method, const std::vector<int>& constrained) const;
  /// The #F face scales of the request's magnify regions (empty when it has none).
  /// @return InvalidArgument for regions with a method other than scale-aware, a bad scale, an
  ///         index out of range, or a region covering no whole face (naming the region).
  Result<Eigen::VectorXd> magnify_scales(const MoveRequest& request) const;
  /// Sets up deformers_ and base_bytes_ for the mesh and options (create only).
  void init_deformer_cache();
  /// Makes `state`, this session's next state, durable before anything else sees it: staged,
  /// then published over the file this copy holds (a compare-and-set, see StateDirectory).
  /// Failures are counted (persist_failures) and logged.
  /// @return success (also without a state directory); NotFound once closed (or closed
  ///         elsewhere); Aborted when another replica changed the file; ResourceExhausted
  ///         (disk or descriptors ran out) or Unavailable from the OS.
  Status persist_state(const PersistedSession& state);
  /// The one check of a move's targets: finite and within reach of the solver (a limit relative
  /// to the mesh's size and position: squares of coordinates must not overflow).
  /// @return InvalidArgument naming `field` and the limit.
  Status check_reach(const Eigen::RowVector3d& target, const std::string& field) const;
  /// Turns a solver report into the next revision, publishes it and updates the deformer entry.
  /// Strand only.
  /// @return the revision; with a shared store, the store's refusal (Aborted naming the current
  ///         revision, NotFound, Internal), and then nothing is committed.
  /// @param settled  no refinement revision will follow (DeformResult::settled).
  /// @param edit  the session's edit state after this revision (null: unchanged, refinement).
  Result<DeformResult> commit(core::SolveReport report, core::Method method, double rigidity,
                              const Positions& targets, std::uint64_t base_revision,
                              const std::shared_ptr<const Positions>& base_positions, bool built,
                              const std::string& editor, bool refinement, bool settled,
                              DeformerCache::Entry* entry,
                              const EditState* edit);
  /// Shared store: takes the lease (waiting at most `wait`) and catches up (sync_shared).
  Status begin_shared_edit(std::chrono::milliseconds wait, std::stop_token stop);
  Status sync_shared_locked();
  /// Loads the whole stored state into this copy. @return as sync_shared.
  Status reload_shared_locked();
  /// Applies one logged revision. @return false when it does not fit this copy (reload then).
  bool apply_shared_locked(const SharedLogEntry& entry);

  /// What background refinement continues (strand only).
  struct RefineState {
    core::Method method = core::Method::ScaleAware;
    bool ora = false;
    Eigen::VectorXd face_scale;  ///< magnification of the move being refined (empty: none)
    double tolerance = 1e-4;
    int remaining = 0;  ///< outer iterations left in the budget
    double rigidity = 0;  ///< scale control of the move being refined
  };
  std::shared_ptr<const DeformResult> snapshot_locked() const;
  /// Appends a revision to history_ (dropping the oldest beyond kept_revisions) and clears the
  /// previous newest's encodings. state_mutex_ held.
  void push_history_locked(std::shared_ptr<const DeformResult> result);

  SessionId id_;
  Token edit_token_, view_token_;
  MeshData rest_;
  std::shared_ptr<const Positions> rest_positions_;  ///< revision 0, always kept
  core::MeshTopology topology_;
  core::Measures rest_measures_;
  int boundary_loops_ = 0;
  core::DeformerSettings settings_;
  double default_rigidity_ = core::kDefaultRigidity;  ///< for moves that do not set one
  ServiceOptions options_;
  std::shared_ptr<ServiceCounters> counters_;
  ReserveFn reserve_;

  // Touched only by the strand (edits), except the cache's size and bytes.
  std::unique_ptr<DeformerCache> deformers_;  ///< set by create()
  /// The cached deformer of `method` for the current constrained set, or null. Strand only.
  DeformerCache::Entry* cached_deformer(core::Method method);
  std::optional<RefineState> refine_;
  bool background_build_running_ = false;
  std::stop_source closed_stop_;  ///< requested by close(): stops solves, precomputes, builds
  std::string owner_;
  double reach_ = 0;  ///< largest coordinate a target may have (check_reach); set by create()

  // Guarded by state_mutex_.
  mutable std::mutex state_mutex_;
  std::uint64_t revision_ = 0;
  std::deque<std::shared_ptr<const DeformResult>> history_;  ///< newest last, <= kept_revisions
  std::vector<HandleGroup> groups_;
  std::vector<int> constrained_;  ///< ascending union of the groups
  Positions anchors_;             ///< #C x 3, positions when the handles were set
  Positions targets_;             ///< #C x 3, current targets
  std::vector<int> vertex_group_; ///< #V group of each vertex or -1
  std::optional<core::Method> last_method_;
  EditState edit_;                ///< settings and undo history (edit_history.h)
  std::vector<std::shared_ptr<Watcher>> watchers_;
  std::chrono::steady_clock::time_point last_used_{};

  const StateDirectory* state_dir_ = nullptr;
  SharedStateStore* shared_ = nullptr;
  /// Serialises catching up and committing with a shared store (taken before state_mutex_).
  std::mutex shared_mutex_;
  std::uint64_t shared_version_ = 0;  ///< the stored version this copy holds; shared_mutex_
  std::atomic<std::chrono::steady_clock::rep> last_move_ticks_{0};
  std::atomic<std::chrono::steady_clock::rep> last_arrival_ticks_{0};   ///< moves only
  std::atomic<std::chrono::steady_clock::rep> drag_interval_ticks_{0};  ///< drag_interval()
  /// Held while this copy replaces its state file and records the new stamp, while is_fresh()
  /// compares them, and while close() marks the session closed: a write is either done before
  /// the close returns or refused.
  mutable std::mutex stamp_mutex_;
  std::optional<FileStamp> stamp_;  ///< guarded by stamp_mutex_

  std::mutex refine_mutex_;
  std::stop_source refine_stop_;  ///< the running refinement slice's; guarded by refine_mutex_

  std::mutex strand_mutex_;
  struct StrandTask {
    std::function<void()> task;
    StrandStep step;
  };
  std::deque<StrandTask> strand_;
  bool strand_running_ = false;

  std::atomic<bool> closed_{false};
  std::size_t base_bytes_ = 0;  ///< estimate_session_bytes without deformers; set by create()
  /// kept_positions_bytes(edit_), updated whenever edit_ is committed (issue 44).
  std::atomic<std::size_t> kept_bytes_{0};
  std::atomic<int> inflight_{0};
};

}  // namespace meshdeform::service
