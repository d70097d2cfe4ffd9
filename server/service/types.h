#pragma once
/// @file types.h
/// Domain types of the transport-free deformation service (issue 4): sessions, tokens, handle
/// groups, move requests, results, watch updates, limits. Eigen and core types only: no gRPC, no
/// protobuf, so every front end (gRPC, browser gateway, tests) shares them.

#include <algorithm>
#include <chrono>
#include <cstddef>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/methods/deformer.h"
#include "core/methods/edit_types.h"
#include "core/base/format_number.h"
#include "core/io/mesh_io.h"
#include "core/mesh/mesh_data.h"
#include "core/methods/ora.h"
#include "server/service/admission.h"
#include "server/service/bytes_memo.h"

namespace meshdeform::service {

/// Opaque session identifier (32 lower-case hex digits, random).
struct SessionId {
  std::string value;
  auto operator<=>(const SessionId&) const = default;
};

/// A bearer secret: 64 lower-case hex digits (32 random bytes). Compared in constant time.
struct Token {
  std::string value;
};

/// The clock used for idle-TTL bookkeeping; injectable for tests.
using Clock = std::function<std::chrono::steady_clock::time_point()>;

// The edit vocabulary (one definition, shared with the client and the wire mapping).
using core::GroupMove;
using core::HandleGroup;
using core::HandleRole;
using core::HistoryAction;
using core::VertexTarget;

/// Everything SetHandles takes.
struct SetHandlesRequest {
  std::vector<HandleGroup> groups;  ///< no vertex may be in two groups
  /// The method whose factorization to build now (others are built on their first move).
  core::Method prepare = core::Method::ScaleAware;
  /// The front end's name for the caller (as for rate limits): heavy work is admitted per client.
  /// Empty by default (`{}`: aggregate initialisations that leave it out stay warning-free).
  std::string client{};
};

/// What a move solved with: kept with the session so that any client opening it later (a
/// reload, a shared link, another replica) continues with the same settings (issue 17).
struct EditSettings {
  core::Method method = core::Method::ScaleAware;
  bool ora = false;
  double rigidity = 0;  ///< the scale control the move used (resolved: never unset)
  std::vector<core::MagnifyRegion> magnify;  ///< as MoveRequest::magnify
  int max_iterations = 2;
  double tolerance = 1e-4;
};

/// One state of a session's undo history: handle-group moves and explicit vertex targets that,
/// applied to the anchors (groups without a move stay at their anchors), give the targets.
struct EditStep {
  std::vector<GroupMove> moves;       ///< at most one per group, ascending group
  std::vector<VertexTarget> targets;  ///< at most one per vertex, ascending vertex
  /// The gesture of the moves recorded here (MoveRequest::gesture; 0 none).
  std::uint64_t gesture = 0;
  /// The settings the step was solved with (issue 44: a settings change is a step of its own).
  /// Unset for step 0 of a session without moves and for steps stored before steps had them.
  std::optional<EditSettings> settings{};
  /// In memory only (never stored or sent as such): the revision that last showed this step
  /// while the session keeps its positions (EditState::kept). Undo and redo to the step commit
  /// those positions again instead of solving.
  std::optional<std::uint64_t> revision{};
};

/// Positions of one revision, kept for exact undo (EditState::kept).
struct KeptPositions {
  std::uint64_t revision = 0;
  std::shared_ptr<const Positions> positions;
};

/// A session's edit state: its settings and its undo history since the last set_handles.
/// Invariant: steps[position] applied to the anchors gives the current targets.
struct EditState {
  std::optional<EditSettings> settings;  ///< of the last committed move; unset before any
  std::vector<EditStep> steps{EditStep{}};  ///< oldest first; never empty
  int position = 0;                         ///< the current step
  /// In memory only (never stored or sent): the positions of revisions that showed steps the
  /// session left, oldest first, at most kept_positions_limit(#V) of them (edit_history.h).
  /// They outlive set_handles: MoveRequest::restore_revision can still name them.
  std::vector<KeptPositions> kept{};
};

/// One edit: new handle targets (vertices not mentioned keep their previous targets) and how to
/// solve for them.
struct MoveRequest {
  std::vector<GroupMove> moves;
  std::vector<VertexTarget> targets;
  core::Method method = core::Method::ScaleAware;
  bool ora = false;        ///< optimal rigidity approximation (scale-aware only)
  /// Scale control of the scale-aware method (core::SolveOptions::rigidity; 0 = the paper's
  /// pure method); unset: the session's (CreateSessionRequest::rigidity). [0, kMaxRigidity].
  std::optional<double> rigidity;
  /// Regions to magnify in this move and its background refinement (scale-aware only; paper
  /// Section 5.3): the faces whose three vertices are all in a region's `vertices` get scale^2
  /// times their rest area. Regions are named by vertices: `faces` must stay empty (the undo
  /// history stores vertices only). Absolute like the moves: an empty list magnifies nothing. A
  /// face in several regions takes the last. At most kMaxMagnifyRegions.
  std::vector<core::MagnifyRegion> magnify;
  /// Outer-iteration budget, 1..kMaxMoveIterations; small for interactive drags.
  int max_iterations = 2;
  /// The estimated remaining relative energy change that stops the solve early
  /// (core/methods/convergence.h), >= 0.
  double tolerance = 1e-4;
  /// Undo history: Record (the default) records the move's state as a step; Undo / Redo apply
  /// the previous / next step instead of `moves` and `targets` (which must then be empty).
  HistoryAction history = HistoryAction::Record;
  /// Moves of one gesture (a drag) record one step: a Record move whose gesture equals the
  /// current step's (and is not 0) replaces that step instead of adding one.
  std::uint64_t gesture = 0;
  /// A one-off solve: the session's stored EditSettings stay as they are.
  bool keep_settings = false;
  /// Record only (issue 44): instead of solving, commit the positions of this earlier revision
  /// again, exactly; `moves` and `targets` are recorded as the state they show, as for any
  /// move. Revision 0 (the rest mesh) is always available, others while the session keeps them
  /// (the newest ServiceOptions::kept_revisions and EditState::kept).
  std::optional<std::uint64_t> restore_revision{};
  /// Stop the solve (DeadlineExceeded) once steady_clock passes this point.
  std::optional<std::chrono::steady_clock::time_point> deadline;
  std::string editor;  ///< free-form label forwarded to watchers ("who edited")
};

/// A committed revision.
struct DeformResult {
  std::uint64_t revision = 0;  ///< 0 is the rest mesh; every committed move adds one
  core::Method method = core::Method::ScaleAware;
  double rigidity = 0;          ///< scale control the solve used (0 for ARAP / Laplacian)
  std::shared_ptr<const Positions> positions;  ///< #V x 3, the full new positions
  /// Vertices whose position differs (exactly, threshold 0) from the previous revision, ascending.
  std::vector<int> changed;
  Positions changed_positions;  ///< #changed x 3, their new positions
  double e_theta = 0;           ///< RMS corner-angle error against the rest mesh (radians)
  double e_phi = 0;             ///< RMS dihedral-angle error against the rest mesh (radians)
  double area_log_rms = 0;      ///< RMS of log(area'/area) over faces
  int iterations = 0;           ///< outer iterations run
  bool converged = false;
  double solve_seconds = 0;     ///< wall time of the solve (without factorization)
  /// A move's own result only (not the watchers' copy): how long the move waited on the server
  /// between its arrival and the start of its solve (finding the session, its earlier edits, then
  /// a free worker). With solve_seconds it splits the server's part of a move's latency.
  double queue_seconds = 0;
  bool built_deformer = false;  ///< this move had to factor a new system (new method/handle set)
  std::string editor;
  /// Committed by background refinement (ServiceOptions::refine_budget) on the previous
  /// revision's targets, not by a move; editor is "refinement".
  bool refinement = false;
  /// No refinement revision follows this one (until the next edit): it converged, background
  /// refinement is off, or this is refinement's last slice (converged or its budget spent).
  /// Watchers that ask for it get a settled revision exactly (UpdateOptions.lossless_settled).
  bool settled = false;
  int pcg_iterations = 0;       ///< conjugate-gradient iterations of step two in this solve
  /// A multiresolution session's move solved on its coarse level (then prolonged into
  /// `positions`): that level's mesh and positions, for watchers that draw the coarse level
  /// during a drag (issue 44). Null for full-resolution solves and refinements, and in results
  /// relayed from another replica.
  std::shared_ptr<const core::CoarseLevelPositions> coarse;
  /// A move's own result only (not the watchers' copy): the session's undo-history position
  /// (EditState::position) after the move.
  std::optional<int> history_position{};
  /// The positions in the transport's wire encodings, made once for the move's response and
  /// every watcher. Copies share it: a copy whose positions or changed lists then change takes
  /// a new memo. The session clears it when a newer revision commits (only the newest is worth
  /// keeping encoded).
  std::shared_ptr<BytesMemo> encoded = std::make_shared<BytesMemo>();
};

/// What a watcher receives.
struct DeformUpdate {
  std::shared_ptr<const DeformResult> result;  ///< shared by every watcher
  /// True on join and after a gap: only result->positions is meaningful (the changed lists are
  /// relative to a revision this watcher never saw).
  bool is_snapshot = false;
  std::uint64_t skipped_revisions = 0;  ///< revisions dropped since the last taken update
};

/// A summary of a session.
struct SessionInfo {
  SessionId id;
  int vertices = 0;
  int faces = 0;
  int boundary_loops = 0;
  int components = 0;
  Eigen::Vector3d bbox_min = Eigen::Vector3d::Zero();  ///< of the rest mesh
  Eigen::Vector3d bbox_max = Eigen::Vector3d::Zero();
  std::uint64_t revision = 0;
  std::vector<HandleGroup> groups;
  std::optional<core::Method> last_method;  ///< method of the last committed move
  double rigidity = 0;                      ///< scale control of moves that do not set one
  EditState edit;                           ///< settings and undo history (issue 17)
  /// The Handle and Fixed groups' anchors (positions when the handles were set), #C x 3: the
  /// groups in order, each group's vertices in its order.
  Positions group_anchors;
  std::size_t estimated_bytes = 0;          ///< what the memory budget charges this session
  int cached_deformers = 0;
  int watchers = 0;
  /// Filled by DeformationService::session_info only: whether the token asked with is the edit
  /// token, and then the view token (so that an editor opened from a link can share a watch link).
  bool token_can_edit = false;
  std::string view_token;
};

/// Progress of heavy work (create_session's parse, set_handles' precompute), so that a client of a
/// big mesh sees phases instead of a silent wait. Every phase reports fraction 0 when it starts
/// and 1 when it ends; long ones (decimation) report fractions between. Phases, in order:
///  - "queued": admitted, waiting for a worker (fraction 0) or started (1);
///  - create_session: "parse" (reading, cleaning and checking the upload, or making the sample),
///    "session" (the rest measures and the session's own setup);
///  - set_handles: the precompute's phases (core::BuildProgress): "validate", "rigid_start",
///    "step_two" (scale-aware), "factorize" (ARAP, Laplacian), or for a multiresolution session
///    "decimate", "validate", "prolongation", "coarse_precompute". None when the factorization
///    is cached.
struct ProgressEvent {
  std::string phase;
  double fraction = 0;         ///< of the phase, in [0, 1]
  double elapsed_seconds = 0;  ///< since the call was admitted
};
/// Receives ProgressEvents on the worker doing the work (must not block for long).
using ProgressFn = std::function<void(const ProgressEvent&)>;

/// CreateSession input: exactly one of mesh bytes or a built-in sample name.
struct CreateSessionRequest {
  std::string mesh_bytes;                     ///< whole file contents
  io::MeshFormat format = io::MeshFormat::Obj;
  std::string sample;                         ///< see DeformationService::sample_names()
  bool weld = false;                          ///< weld coincident vertices (STL always is)
  core::DeformerSettings settings;            ///< lambda etc., fixed for the session
  /// Scale control of the session's scale-aware moves that do not set their own (unset:
  /// core::kDefaultRigidity). [0, kMaxRigidity].
  std::optional<double> rigidity;
  /// The front end's name for the caller (as for rate limits): uploads are admitted per client.
  std::string client;
};

/// CreateSession output.
struct CreatedSession {
  SessionId id;
  Token edit_token;  ///< needed to edit (set handles, move, close)
  Token view_token;  ///< enough to watch, read the mesh and the info
  SessionInfo info;
  int welded_vertices = 0;        ///< cleaning: vertex indices refer to the cleaned mesh
  int dropped_unreferenced = 0;
  std::vector<HandleGroup> suggested_groups;  ///< samples: the benchmark's fixed and handle sets
};

/// The largest outer-iteration budget of one move (MoveRequest::max_iterations).
inline constexpr int kMaxMoveIterations = 1000;
/// Moves of at most this many iterations are short: while every worker runs a long solve,
/// those solves run waiting short moves of other sessions between two of their iterations, so
/// a drag is never queued behind another client's 1000-iteration solve (solver time is shared;
/// a long solve is paused, not slowed, by what it runs).
inline constexpr int kShortMoveIterations = 15;

/// Moves that arrive less than this apart belong to one drag (Session::drag_interval()).
inline constexpr std::chrono::milliseconds kDragGap{1000};

/// How long a session's handles must rest after a move before background refinement starts:
/// ServiceOptions::refine_delay, or twice the interval between the drag's last two moves if
/// that is longer (a drag over a slow line pauses longer between its moves than the delay, and
/// a slice started in such a pause would send a refinement revision between two moves and hold
/// up the next one until it stops), at most kDragGap. A delay of 0 stays 0 (no wait).
inline std::chrono::steady_clock::duration refinement_rest(
    std::chrono::milliseconds refine_delay, std::chrono::steady_clock::duration drag_interval) {
  if (refine_delay.count() <= 0) return std::chrono::steady_clock::duration::zero();
  const std::chrono::steady_clock::duration delay = refine_delay;
  return std::max(delay, std::min(2 * drag_interval,
                                  std::chrono::steady_clock::duration(kDragGap)));
}

/// At most this many magnify regions per move (each is resolved over every face).
inline constexpr int kMaxMagnifyRegions = 64;

/// The largest scale control a request may ask for (core::SolveOptions::rigidity): far past
/// ARAP-like behaviour, and the solve stays well conditioned. Requests are checked with
/// core::check_rigidity(value, kMaxRigidity).
inline constexpr double kMaxRigidity = 1e4;

/// A group move's scale lies in [1 / kMaxMoveScale, kMaxMoveScale]: beyond, the handles' targets
/// leave the range the solver represents (or collapse to a point).
inline constexpr double kMaxMoveScale = 1e6;
/// A magnify region's scale lies in [1 / kMaxMagnifyScale, kMaxMagnifyScale] (areas change by
/// its square).
inline constexpr double kMaxMagnifyScale = 1e3;
/// A move's targets lie within kMaxReach times the mesh's extent (the larger of its bounding
/// box's diagonal and its largest coordinate) of the origin: squares of coordinates, which the
/// solver forms, then stay far from overflow.
inline constexpr double kMaxReach = 1e6;
/// The handle weight lambda (CreateSession) lies in [kMinLambda, kMaxLambda]: the default is
/// 100; beyond these the Eq. 12 system is too ill-conditioned to solve.
inline constexpr double kMinLambda = 1e-6;
inline constexpr double kMaxLambda = 1e8;

/// The one range check of a session's lambda. @return InvalidArgument naming the value and the
///         range (NaN included).
inline Status check_lambda(double lambda) {
  if (lambda >= kMinLambda && lambda <= kMaxLambda) return Status::success();
  return Error(ErrorCode::InvalidArgument, "lambda " + core::format_number(lambda, "%g") +
                                               " is outside [" +
                                               core::format_number(kMinLambda, "%g") + ", " +
                                               core::format_number(kMaxLambda, "%g") + "]");
}

/// The calls limited per client (DeformationService::admit).
enum class RateLimitedCall { CreateSession, MoveHandles };

/// One kind of call's limit per client. per_second <= 0 means unlimited.
struct RateLimit {
  double per_second = 0;  ///< sustained rate
  double burst = 1;       ///< bucket size: calls allowed at once after a quiet spell (>= 1)
};

/// Limits and sizes; every one has a sane default.
struct ServiceOptions {
  int workers = 0;                 ///< solver threads; 0 = std::thread::hardware_concurrency()
  int max_vertices = 1'000'000;    ///< per mesh (the memory budget bounds what is solved)
  int max_sessions = 64;
  std::size_t memory_budget_bytes = std::size_t{2} << 30;  ///< estimated, see estimate_session_bytes
  std::chrono::seconds idle_ttl{30 * 60};
  int kept_revisions = 4;          ///< GetMesh can read the newest K revisions
  int max_cached_deformers = 4;    ///< per session, least recently used dropped first
  /// OpenMP threads inside one solve of a session on a mesh of at least `parallel_solve_above`
  /// vertices; 0 = one per core. Smaller sessions solve on one thread: many of them share the
  /// cores through the worker pool, and a second thread does not pay on a small mesh when the
  /// other core is busy (issue 13, measured in bench/results/realistic_threads.md).
  int solver_threads = 0;
  int parallel_solve_above = 20'000;
  /// Scale-aware sessions on meshes of more vertices than this move on a coarse level of a mesh
  /// hierarchy and refine at full resolution in the background (core::DeformerSettings::
  /// multires_above, issue 15); 0 = always full resolution.
  int multires_above = 100'000;
  int multires_coarse_vertices = 10'000;  ///< the coarse level's target size
  /// Background refinement: after a committed move, while no other edit of the session waits,
  /// the service keeps running outer iterations on the same targets (in slices, committing each
  /// improvement as a revision) up to this many in total; 0 = off.
  int refine_budget = 0;
  /// ... and it starts only once the handles have rested this long after a move (or longer:
  /// refinement_rest()): while a user drags, every refinement revision would be a wasted solve
  /// and a full update to every watcher between two moves.
  std::chrono::milliseconds refine_delay{150};
  /// A move's solve yields to other sessions' short moves between its iterations (its rigid
  /// start's and coarse levels' included) only once it has run this long: a long solve shares
  /// the workers, but a drag's move of a few milliseconds is not held back while the moves
  /// queued after it run in its place (first come, first served among short moves). Background
  /// refinement yields at every iteration.
  std::chrono::milliseconds yield_after{25};
  /// Directory for session state files (persistence.h); empty = in memory only. Sessions whose
  /// file is younger than idle_ttl are restored on their first request after a restart (or on
  /// another replica sharing the directory).
  std::string state_dir;
  /// With a shared store (issue 16): how often the sessions watched here are caught up with the
  /// revisions other replicas commit.
  std::chrono::milliseconds shared_poll{10};
  /// Per-client limits (a client is what the front end names it: its network address). The
  /// defaults stop a runaway script without touching interactive use or a 16-session load test:
  /// 2 sessions per second (bursts of 30) and 200 moves per second (bursts of 400).
  RateLimit create_rate{2.0, 30.0};
  RateLimit move_rate{200.0, 400.0};
  /// Heavy work (CreateSession parsing/cleaning, SetHandles precompute) admitted at once per
  /// client and in total; beyond, ResourceExhausted (admission.h).
  HeavyWorkLimits heavy_work;
  /// Workers that may run heavy work; 0 = workers - 1 (at least 1): the rest keep serving moves.
  int heavy_lanes = 0;
  /// Sessions one client may hold open at once; 0 = a quarter of max_sessions (at least 1), so
  /// that one client cannot take every slot. Clients are what the front end names them (their
  /// network address); the empty name (in-process callers) is not limited.
  int max_sessions_per_client = 0;
  /// Estimated memory (as memory_budget_bytes counts it) one client's sessions may hold; 0 =
  /// three quarters of memory_budget_bytes. Room for a client is made by evicting, in this
  /// order, its own idle sessions, then idle sessions of clients over this quota, then (only
  /// where sessions persist: a state directory or a shared store, so eviction loses nothing) any
  /// idle session; in memory only, another client's session within its quota is never evicted.
  std::size_t memory_budget_per_client_bytes = 0;
  /// Test seam of the state directory (persistence.h): consulted before each system call that
  /// writes a state file, with the call's name; a non-zero errno fails that call as the OS would
  /// (ENOSPC: a full disk, EMFILE: no descriptors). Empty in production.
  std::function<int(std::string_view call)> state_write_fault;
  Clock clock;                     ///< default: std::chrono::steady_clock::now
};

/// Service-wide counters (metrics and tests).
struct ServiceStats {
  std::uint64_t deformer_constructions = 0;  ///< make_deformer calls that succeeded
  std::uint64_t moves_committed = 0;
  std::uint64_t moves_cancelled = 0;         ///< Cancelled or DeadlineExceeded
  std::uint64_t refinements_committed = 0;   ///< revisions committed by background refinement
  std::uint64_t refinements_preempted = 0;   ///< refinement slices stopped by a new edit
  /// Full-resolution solvers of multiresolution sessions built off the strand and installed.
  std::uint64_t background_builds_installed = 0;
  std::uint64_t pcg_iterations = 0;          ///< step-two CG iterations over all solves
  std::uint64_t outer_iterations = 0;        ///< outer iterations over all solves
  std::uint64_t sessions_restored = 0;       ///< loaded from the state directory
  std::uint64_t state_files_corrupt = 0;     ///< found corrupt (startup scan or restore) and skipped
  std::uint64_t persist_failures = 0;        ///< state writes that failed (logged)
  std::uint64_t evicted_lru = 0;             ///< sessions evicted for the memory budget
  std::uint64_t evicted_idle = 0;            ///< sessions evicted by the idle TTL
  std::uint64_t rate_limited_creates = 0;    ///< CreateSession calls refused by create_rate
  std::uint64_t rate_limited_moves = 0;      ///< MoveHandles calls refused by move_rate
  /// In-memory sessions dropped because another replica sharing the state directory had changed
  /// (or removed) their file since (find_or_restore restores the newer state instead).
  std::uint64_t stale_copies_dropped = 0;
  std::uint64_t heavy_rejected = 0;          ///< uploads/precomputes refused by admission control
  std::uint64_t uploads_cancelled = 0;       ///< CreateSession parses stopped by deadline/cancel
  std::uint64_t precomputes_cancelled = 0;   ///< SetHandles precomputes stopped by deadline/cancel
  /// Moves of other sessions run by a long solve between two of its iterations (fairness).
  std::uint64_t yielded_tasks = 0;
  std::size_t solves_running = 0;            ///< moves and refinement slices solving now
  int heavy_admitted = 0;                    ///< heavy tasks admitted now (queued or running)
  int heavy_running = 0;                     ///< heavy tasks running now
  std::size_t queued_normal = 0;             ///< worker-pool tasks waiting, by class
  std::size_t queued_heavy = 0;
  std::size_t queued_background = 0;
  std::size_t sessions = 0;
  std::size_t estimated_bytes = 0;
  std::size_t resident_bytes = 0;            ///< the process's resident set (Linux), 0 if unknown
  int watchers = 0;
  int workers = 0;
};

/// Memory charge of a session, for budgeting (an estimate, calibrated by measurement): positions
/// of the rest mesh, the current and the kept revisions, topology and measures, plus per cached
/// deformer 5.2 KB per vertex (the scale-aware solver's measured heap, the largest method's).
/// Positions kept for exact undo are charged on top as they are kept (Session::estimated_bytes,
/// kept_positions_bytes in edit_history.h): a new session holds none.
/// @param[in] vertices, faces   mesh size.
/// @param[in] cached_deformers  prefactored systems held.
/// @param[in] kept_revisions    ServiceOptions::kept_revisions.
std::size_t estimate_session_bytes(int vertices, int faces, int cached_deformers,
                                   int kept_revisions);

}  // namespace meshdeform::service
