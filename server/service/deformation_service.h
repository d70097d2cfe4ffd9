#pragma once
/// @file deformation_service.h
/// The transport-free deformation service of issue 4 ("Scale-aware shape manipulation", Liu et
/// al.): sessions created from mesh bytes or built-in samples, handle groups, handle moves solved
/// on a worker pool with cached factorizations, meshes at a revision, watchers, limits.
///
/// Threading: every call may come from any thread. Solves and factorizations run on the
/// service's own WorkerPool (never on the caller's thread): the *_async calls return at once and
/// call `done` on a worker. Edits to one session run one at a time in submission order; different
/// sessions run in parallel. create_session and get_mesh (parsing / serialising) have *_async
/// forms that run on the pool too; session_info, watch and close_session are quick and run on the
/// caller's thread.
///
/// Access: create_session returns an edit token and a view token. Edits (set_handles,
/// move_handles, close_session) need the edit token; reads and watches accept either token.
/// Every call checks the session first (NotFound), then the token (PermissionDenied).

#include <chrono>
#include <atomic>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "core/io/mesh_io.h"
#include "core/base/status.h"
#include "server/service/admission.h"
#include "server/service/delay_queue.h"
#include "server/service/persistence.h"
#include "server/service/rate_limiter.h"
#include "server/service/session.h"
#include "server/service/session_store.h"
#include "server/service/shared_store.h"
#include "server/service/types.h"
#include "server/service/watcher.h"
#include "server/service/worker_pool.h"

namespace meshdeform::service {

class DeformationService {
 public:
  explicit DeformationService(ServiceOptions options = {});
  /// With `shared` (issue 16): sessions live in that store instead of options.state_dir, so
  /// that every replica on the same store can serve every session (see shared_store.h): a
  /// session unknown here is loaded from the store on first use, edits take the session's lease
  /// and commit by compare-and-set, and watchers also receive the revisions other replicas
  /// commit (polled every ServiceOptions::shared_poll while the session has watchers here).
  DeformationService(ServiceOptions options, std::shared_ptr<SharedStateStore> shared);
  /// Cancels running solves (their `done` receives Cancelled), runs the queued ones (which see
  /// the stop at once), joins the workers and closes every session.
  ~DeformationService();
  DeformationService(const DeformationService&) = delete;
  DeformationService& operator=(const DeformationService&) = delete;

  /// Built-in samples: "bumpy_plane", "cylinder", "bar", "cactus" (the paper's Table 1 sizes,
  /// procedural), the same with "_small" (< 1,000 vertices) and "bumpy_plane_large" (the bumpy
  /// plane at 187,489 vertices, for big-mesh editing). Meshes from data files ("spot") are not
  /// available at run time.
  static std::vector<std::string> sample_names();

  /// Creates a session from mesh bytes (cleaned and validated by io::load_mesh_from_memory) or a
  /// sample. Also sweeps expired sessions. Parsing and cleaning stop when `stop` is requested
  /// (Cancelled); their work is bounded by the size of the bytes (io's "work bounded by bytes").
  /// @return ids, tokens and the summary; InvalidArgument for both or neither of bytes and sample,
  ///         an unknown sample (listing the known ones) or a bad mesh (naming the element);
  ///         ResourceExhausted for a mesh over max_vertices (naming both counts), max_sessions
  ///         open sessions, or a memory budget that eviction of idle sessions cannot meet.
  /// `progress` (may be empty) hears the phases "parse" and "session" (see ProgressEvent).
  [[nodiscard]] Result<CreatedSession> create_session(const CreateSessionRequest& request,
                                                      std::stop_token stop = {},
                                                      const ProgressFn& progress = {});
  /// create_session on the worker pool as heavy work (parsing a large upload can take a while: it
  /// must not hold a transport thread, nor the workers that serve moves). Admission control first:
  /// ResourceExhausted (at once, nothing queued) when request.client already has
  /// ServiceOptions::heavy_work.per_client uploads/precomputes admitted or the server has
  /// heavy_work.total. Cancelled if `stop` is requested before it starts or mid-parse (the worker
  /// is freed within a few thousand parse steps). `done` runs on a worker thread, or on the
  /// caller's thread when refused. `progress` (may be empty) hears "queued" when admitted (on the
  /// caller's thread) and when started, then create_session's phases, all before `done`.
  void create_session_async(CreateSessionRequest request, std::stop_token stop,
                            std::function<void(Result<CreatedSession>)> done,
                            ProgressFn progress = {});

  /// Sets the handle groups on the worker pool as heavy work (its precompute factors matrices);
  /// see Session::set_handles for the errors, plus NotFound (unknown/expired/closed session),
  /// PermissionDenied (not the edit token), ResourceExhausted from admission control as for
  /// create_session_async (request.client), and Cancelled if `stop` is requested before it
  /// starts or between the precompute's phases. `done` runs on a worker thread, or on the
  /// caller's thread when refused. `progress` (may be empty) hears "queued" when admitted and
  /// when started, then the precompute's phases (see ProgressEvent), all before `done`.
  void set_handles_async(const SessionId& id, const Token& edit_token, SetHandlesRequest request,
                         std::stop_token stop, std::function<void(Result<SessionInfo>)> done,
                         ProgressFn progress = {});
  /// Blocking set_handles_async.
  [[nodiscard]] Result<SessionInfo> set_handles(const SessionId& id, const Token& edit_token,
                                                SetHandlesRequest request,
                                                std::stop_token stop = {},
                                                ProgressFn progress = {});

  /// Moves handles and solves on the worker pool; see Session::move for the errors, plus
  /// NotFound and PermissionDenied. `stop` (tied by the transport to client cancellation),
  /// shutdown and request.deadline make one stop (CallStop) that stops the solve mid-iteration:
  /// Cancelled, or DeadlineExceeded past the deadline. Nothing is committed on error. `done` runs on a worker thread and must not block for long.
  void move_handles_async(const SessionId& id, const Token& edit_token, MoveRequest request,
                          std::stop_token stop, std::function<void(Result<DeformResult>)> done);
  /// Blocking move_handles_async.
  [[nodiscard]] Result<DeformResult> move_handles(const SessionId& id, const Token& edit_token,
                                                  MoveRequest request, std::stop_token stop = {});

  /// Serialises the mesh at `revision` (default: current). Revision 0 (the rest mesh) is always
  /// kept; of the others, the newest ServiceOptions::kept_revisions.
  /// @return the bytes (GLB/glTF float32, OBJ/OFF/PLY full precision, STL float32); NotFound
  ///         for an unknown session or a revision not kept (naming the kept range);
  ///         PermissionDenied for a wrong token; InvalidArgument if the format cannot hold it.
  [[nodiscard]] Result<std::string> get_mesh(const SessionId& id, const Token& token,
                                             io::MeshFormat format,
                                             std::optional<std::uint64_t> revision = {});
  /// get_mesh on the worker pool (serialising a large mesh is not for transport threads).
  void get_mesh_async(SessionId id, Token token, io::MeshFormat format,
                      std::optional<std::uint64_t> revision, std::stop_token stop,
                      std::function<void(Result<std::string>)> done);

  /// @return the summary, with token_can_edit (and then view_token) telling the caller what its
  ///         token allows; NotFound; PermissionDenied.
  [[nodiscard]] Result<SessionInfo> session_info(const SessionId& id, const Token& token);

  /// Closes a session: queued edits end with NotFound, watchers are closed.
  /// @return NotFound; PermissionDenied (the view token cannot close).
  [[nodiscard]] Status close_session(const SessionId& id, const Token& edit_token);

  /// Subscribes to every committed revision. The mailbox starts with a full snapshot of the
  /// current revision; a watcher that does not keep up skips to the newest (see Watcher).
  /// @return the subscription (unsubscribes when destroyed); NotFound; PermissionDenied.
  [[nodiscard]] Result<Subscription> watch(const SessionId& id, const Token& view_token);

  /// Removes sessions idle for longer than the TTL (call from a timer; create_session also does).
  /// @return how many were removed.
  /// Server shutdown: ends every open watch (with Unavailable: the session lives on, a client
  /// may watch again) so that draining does not wait for streams that would never end on their
  /// own. Sessions stay open.
  void end_watches() {
    store_.close_all_watchers(
        Error(ErrorCode::Unavailable, "the server is shutting down; watch again to continue"));
  }

  std::size_t evict_expired();
  std::size_t evict_expired(std::chrono::steady_clock::time_point now);

  ServiceStats stats() const;

  /// Admits one call of `client` under ServiceOptions::create_rate / move_rate. Front ends call
  /// it before they hand the call to the service; `client` is their name for the caller (a
  /// network address such as "ipv4:10.1.2.3"; empty is one anonymous client).
  /// @param[out] retry_after  if not null, set to the wait when refused (0 when admitted).
  /// @return success; ResourceExhausted naming the limit and the wait when the client is over it.
  Status admit(std::string_view client, RateLimitedCall call,
               std::chrono::milliseconds* retry_after = nullptr);

  /// The admission control of heavy work (tests hold tickets through it).
  HeavyWorkAdmission& heavy_work() { return heavy_; }

  /// Where front ends record their calls (MetricsRegistry::record_rpc).
  MetricsRegistry& metrics() { return counters_->metrics; }
  /// The Prometheus text exposition of stats() and the recorded metrics (for GET /metrics).
  std::string render_metrics() const { return counters_->metrics.render(stats()); }

 private:
  /// The session from the store, or restored from the state directory (nullptr if neither).
  std::shared_ptr<Session> find_or_restore(const SessionId& id);
  /// With a shared store: the session, caught up with the store (loaded on first use).
  /// @return NotFound when the store does not have it; Internal when the store fails.
  Result<std::shared_ptr<Session>> find_shared(const SessionId& id);
  /// Keeps the watched sessions caught up with the shared store until stopped.
  void feed_loop(std::stop_token stop);
  Result<std::shared_ptr<Session>> find_for_edit(const SessionId& id, const Token& token);
  Result<std::shared_ptr<Session>> find_for_view(const SessionId& id, const Token& token);
  /// Queues `task` on the session's strand and the strand on the pool. An edit (not
  /// `is_refinement`) preempts a running refinement slice of the session.
  void post(const std::shared_ptr<Session>& session, std::function<void()> task,
            bool is_refinement = false, Session::StrandStep step = {});
  /// If the session wants refinement: starts the background build refinement needs, if any, at
  /// once (run_background_build); otherwise queues one slice at background priority (it runs
  /// when no edit of any session waits) and, after it, the next. `after_move`, or a move that
  /// arrived or committed within the rest (refinement_rest(): ServiceOptions::refine_delay, or
  /// longer for a drag whose moves come further apart): wait for that much rest first.
  void schedule_refinement(const std::shared_ptr<Session>& session, bool after_move);
  /// What a solve calls between its iterations: once the solve has run `after` (its progress'
  /// elapsed_seconds), runs short moves of other sessions that wait while every worker is busy
  /// (WorkerPool::run_short_here), so that long solves share the workers with them.
  core::ProgressCallback yield_point(std::chrono::milliseconds after);
  /// Starts the background build refinement needs (Session::take_background_build ->
  /// run_background_build). Strand only. @return true if one is running now (started here or
  /// before): refinement waits for its install, which schedules refinement again.
  bool start_background_build(const std::shared_ptr<Session>& session);
  /// Runs a session's background build (Session::take_background_build) on the pool's background
  /// class, off the strand, then installs it on the strand and resumes refinement.
  void run_background_build(const std::shared_ptr<Session>& session,
                            Session::BackgroundBuild build);

  ServiceOptions options_;
  std::shared_ptr<ServiceCounters> counters_;
  std::stop_source shutdown_;
  std::optional<StateDirectory> state_dir_;
  std::mutex restore_mutex_;  ///< one restore at a time, so a session is loaded once
  std::atomic<std::uint64_t> sessions_restored_{0};
  std::atomic<std::uint64_t> state_files_corrupt_{0};
  RateLimiter limiter_;
  std::atomic<std::uint64_t> rate_limited_creates_{0};
  std::atomic<std::uint64_t> rate_limited_moves_{0};
  std::atomic<std::uint64_t> stale_copies_dropped_{0};
  std::atomic<std::uint64_t> uploads_cancelled_{0};
  std::atomic<std::uint64_t> precomputes_cancelled_{0};
  HeavyWorkAdmission heavy_;  // declared before pool_: tickets held by queued tasks outlive it
  SessionStore store_;
  /// Moves' deadlines (CallStop): its timers only request stops, so it outlives the pool whose
  /// tasks post into it.
  DelayQueue deadlines_;
  WorkerPool pool_;  // destroyed (drained, joined) before the store
  DelayQueue delays_;  // no timer posts into a dead pool: destroyed before it
  std::shared_ptr<SharedStateStore> shared_;  ///< null without a shared store
  std::jthread feed_;  // declared last: stopped and joined first
};

}  // namespace meshdeform::service
