#include "server/service/deformation_service.h"

#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <future>
#include <string_view>
#include <utility>

#include "core/samples/samples.h"
#include "core/mesh/validate.h"
#include "server/service/call_stop.h"
#include "server/service/guard.h"
#include "server/service/log.h"
#include "server/service/tokens.h"

namespace meshdeform::service {
namespace {

/// Counts a solve in ServiceCounters::solves_running for its lifetime.
class RunningSolve {
 public:
  explicit RunningSolve(std::atomic<std::uint64_t>& count) : count_(count) { count_.fetch_add(1); }
  ~RunningSolve() { count_.fetch_sub(1); }
  RunningSolve(const RunningSolve&) = delete;
  RunningSolve& operator=(const RunningSolve&) = delete;

 private:
  std::atomic<std::uint64_t>& count_;
};

/// Turns phase reports into ProgressEvents timed from its construction (the admission of the
/// call). Empty function: reports nothing. Copies share the start time.
class PhaseReporter {
 public:
  explicit PhaseReporter(ProgressFn fn) : fn_(std::move(fn)) {}
  void operator()(std::string_view phase, double fraction) const {
    if (!fn_) return;
    ProgressEvent event;
    event.phase = std::string(phase);
    event.fraction = std::clamp(std::isfinite(fraction) ? fraction : 0.0, 0.0, 1.0);
    event.elapsed_seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    fn_(event);
  }
  /// For a callee that reports its own phases: events keep this reporter's start time.
  ProgressFn fn() const {
    if (!fn_) return {};
    return [self = *this](const ProgressEvent& event) { self(event.phase, event.fraction); };
  }
  /// The same, as core's precompute callback.
  core::BuildProgress build_progress() const {
    if (!fn_) return {};
    return [self = *this](std::string_view phase, double fraction) { self(phase, fraction); };
  }

 private:
  ProgressFn fn_;
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now();
};

constexpr std::size_t kSessionIdBytes = 16;
constexpr std::size_t kTokenBytes = 32;

/// The resident set of this process from /proc/self/statm (Linux); 0 where unavailable.
std::size_t resident_set_bytes() {
  std::FILE* file = std::fopen("/proc/self/statm", "r");
  if (file == nullptr) return 0;
  unsigned long long size_pages = 0, resident_pages = 0;
  const int read = std::fscanf(file, "%llu %llu", &size_pages, &resident_pages);
  std::fclose(file);
  if (read != 2) return 0;
  const long page = sysconf(_SC_PAGESIZE);
  return static_cast<std::size_t>(resident_pages) * static_cast<std::size_t>(page > 0 ? page : 4096);
}

/// Ids come from clients: keep error messages short.
std::string short_id(const SessionId& id) {
  return id.value.size() <= 64 ? id.value : id.value.substr(0, 64) + "...";
}

struct Sample {
  MeshData mesh;
  std::vector<HandleGroup> groups;
};

std::vector<HandleGroup> groups_from_selection(const Eigen::VectorXi& selection) {
  HandleGroup fixed{HandleRole::Fixed, {}}, handle{HandleRole::Handle, {}};
  for (Eigen::Index v = 0; v < selection.size(); ++v) {
    if (selection(v) == static_cast<int>(core::VertexRole::Fixed)) {
      fixed.vertices.push_back(static_cast<int>(v));
    } else if (selection(v) == static_cast<int>(core::VertexRole::Handle)) {
      handle.vertices.push_back(static_cast<int>(v));
    }
  }
  std::vector<HandleGroup> groups;
  if (!fixed.vertices.empty()) groups.push_back(std::move(fixed));
  if (!handle.vertices.empty()) groups.push_back(std::move(handle));
  return groups;
}

// The big-mesh demo: 433^2 = 187,489 vertices, the size of issue 15's Spot at 187k (above the
// default --multires-above, so the server edits it on a coarse level first).
constexpr int kLargeBumpyPlaneSide = 433;

Result<Sample> make_sample(const std::string& name) {
  const std::string kSmall = "_small";
  std::optional<core::DeformationBenchmark> bench;
  if (name.size() > kSmall.size() && name.ends_with(kSmall)) {
    const std::string base = name.substr(0, name.size() - kSmall.size());
    for (core::DeformationBenchmark& b : core::make_suite(core::SuiteScale::Small)) {
      if (b.name == base) bench = std::move(b);
    }
  } else if (name == "bumpy_plane") {
    bench = core::make_bumpy_plane();
  } else if (name == "bumpy_plane_large") {
    bench = core::make_bumpy_plane(kLargeBumpyPlaneSide);
  } else if (name == "cylinder") {
    bench = core::make_cylinder();
  } else if (name == "bar") {
    bench = core::make_bar();
  } else if (name == "cactus") {
    bench = core::make_cactus();
  }
  if (!bench) {
    std::string known;
    for (const std::string& n : DeformationService::sample_names()) {
      known += (known.empty() ? "" : ", ") + n;
    }
    return Error(ErrorCode::InvalidArgument,
                 "unknown sample '" + name.substr(0, 64) + "' (known: " + known + ")");
  }
  return Sample{std::move(bench->mesh), groups_from_selection(bench->selection)};
}

}  // namespace

DeformationService::DeformationService(ServiceOptions options,
                                       std::shared_ptr<SharedStateStore> shared)
    : DeformationService([&] {
        if (shared) options.state_dir.clear();  // the shared store replaces the state directory
        return std::move(options);
      }()) {
  shared_ = std::move(shared);
  if (shared_) store_.set_eviction_lossless(true);  // an evicted session comes back from Redis
  if (shared_) feed_ = std::jthread([this](std::stop_token stop) { feed_loop(stop); });
}

DeformationService::DeformationService(ServiceOptions options)
    : options_([&] {
        if (!options.clock) options.clock = [] { return std::chrono::steady_clock::now(); };
        return options;
      }()),
      counters_(std::make_shared<ServiceCounters>()),
      limiter_(options_.create_rate, options_.move_rate, options_.clock),
      heavy_(options_.heavy_work),
      store_(options_),
      pool_(options_.workers, options_.heavy_lanes) {
  if (options_.state_dir.empty()) return;
  // A state file holds the rest mesh, the positions and the history: far less than 1 KiB per
  // vertex (the bound keeps an endless file from being read whole).
  const std::uint64_t max_file_bytes =
      (std::uint64_t{64} << 20) + std::uint64_t{1024} * static_cast<std::uint64_t>(options_.max_vertices);
  Result<StateDirectory> dir =
      StateDirectory::open(options_.state_dir, options_.state_write_fault, max_file_bytes);
  if (!dir.ok()) {
    log_event(LogLevel::Error, "state_dir_unusable",
              LogFields().add("path", options_.state_dir).add("message", dir.status().message()));
    return;
  }
  state_dir_.emplace(std::move(dir).value());
  store_.set_eviction_lossless(true);  // an evicted session comes back from its file
  // Check every file now so corruption is reported at start; sessions load on first use. Only
  // regular files of bounded size are opened (a FIFO would block, a link to /dev/zero would
  // never end): the others are reported one by one.
  std::vector<SkippedStateFile> skipped;
  const std::vector<SessionId> ids = state_dir_->scan(skipped);
  for (const SkippedStateFile& file : skipped) {
    state_files_corrupt_.fetch_add(1);
    log_event(LogLevel::Warn, "state_file_skipped",
              LogFields().add("file", file.file).add("reason", file.reason));
  }
  int good = 0;
  for (const SessionId& id : ids) {
    Result<PersistedSession> state = state_dir_->read(id);
    if (state.ok()) {
      ++good;
    } else {
      state_files_corrupt_.fetch_add(1);
      log_event(LogLevel::Warn, "state_file_corrupt",
                LogFields().add("session", id.value).add("message", state.status().message()));
    }
  }
  log_event(LogLevel::Info, "state_dir",
            LogFields().add("path", state_dir_->path()).add("sessions", good)
                .add("corrupt", static_cast<std::uint64_t>(state_files_corrupt_.load())));
}

DeformationService::~DeformationService() {
  shutdown_.request_stop();
  if (feed_.joinable()) {
    feed_.request_stop();
    feed_.join();
  }
  // pool_ is destroyed after this body (drains with the stop requested), then store_.
  store_.clear();
}

std::vector<std::string> DeformationService::sample_names() {
  return {"bumpy_plane",       "cylinder",       "bar",       "cactus",
          "bumpy_plane_small", "cylinder_small", "bar_small", "cactus_small",
          "bumpy_plane_large"};
}

Result<CreatedSession> DeformationService::create_session(const CreateSessionRequest& request,
                                                          std::stop_token stop,
                                                          const ProgressFn& progress_fn) {
  const PhaseReporter progress(progress_fn);
  return run_guarded("CreateSession", [&]() -> Result<CreatedSession> {
    const bool has_bytes = !request.mesh_bytes.empty(), has_sample = !request.sample.empty();
    if (has_bytes == has_sample) {
      return Error(ErrorCode::InvalidArgument,
                   "give exactly one of mesh bytes and a sample name (got " +
                       std::string(has_bytes ? "both" : "neither") + ")");
    }
    if (request.rigidity) MD_RETURN_IF_ERROR(core::check_rigidity(*request.rigidity, kMaxRigidity));
    MD_RETURN_IF_ERROR(check_lambda(request.settings.lambda));
    CreatedSession created;
    MeshData mesh;
    progress("parse", 0.0);
    if (has_sample) {
      MD_ASSIGN_OR_RETURN(Sample sample, make_sample(request.sample));
      MD_RETURN_IF_ERROR(core::validate_triangle_mesh(sample.mesh.V, sample.mesh.F));
      mesh = std::move(sample.mesh);
      created.suggested_groups = std::move(sample.groups);
    } else {
      io::LoadOptions load;
      load.weld = request.weld;
      load.control.stop = stop;
      MD_ASSIGN_OR_RETURN(io::LoadedMesh loaded,
                          io::load_mesh_from_memory(request.mesh_bytes, request.format, load));
      mesh = std::move(loaded.mesh);
      created.welded_vertices = loaded.report.welded_vertices;
      created.dropped_unreferenced = loaded.report.dropped_unreferenced;
    }
    progress("parse", 1.0);
    if (mesh.V.rows() > options_.max_vertices) {
      return Error(ErrorCode::ResourceExhausted,
                   "mesh has " + std::to_string(mesh.V.rows()) + " vertices, the limit is " +
                       std::to_string(options_.max_vertices));
    }
    const auto cancelled = [] {
      return Error(ErrorCode::Cancelled, "create_session cancelled (deadline or client)");
    };
    if (stop.stop_requested()) return cancelled();
    created.id = SessionId{random_hex(kSessionIdBytes)};
    created.edit_token = Token{random_hex(kTokenBytes)};
    created.view_token = Token{random_hex(kTokenBytes)};
    progress("session", 0.0);
    SessionStore* store = &store_;
    MD_ASSIGN_OR_RETURN(
        std::shared_ptr<Session> session,
        Session::create(created.id, created.edit_token, created.view_token, std::move(mesh),
                        request.settings, options_, counters_,
                        [store](std::size_t bytes, const Session& requester) {
                          return store->reserve(bytes, requester);
                        }));
    if (request.rigidity) session->set_default_rigidity(*request.rigidity);
    session->set_owner(request.client);
    // The caller left while the session was built: commit nothing (it would never be used).
    if (stop.stop_requested()) return cancelled();
    // Limits first (nobody knows the id yet), then stored before anyone hears of it: durable,
    // and with a shared store any replica can serve it from the first call on.
    MD_RETURN_IF_ERROR(store_.insert(session));
    Status stored;
    if (state_dir_) {
      session->set_state_directory(&*state_dir_);
      stored = session->persist();
    }
    if (shared_) {
      session->set_shared_store(shared_.get(), 0);
      stored = shared_->create(session->persisted_state());
    }
    if (!stored.ok()) {
      store_.erase(session->id());
      return stored;
    }
    created.info = session->info();
    progress("session", 1.0);
    return created;
  });
}

void DeformationService::create_session_async(CreateSessionRequest request, std::stop_token stop,
                                              std::function<void(Result<CreatedSession>)> done,
                                              ProgressFn progress_fn) {
  Result<HeavyWorkAdmission::Ticket> admitted = heavy_.admit(request.client, "CreateSession");
  if (!admitted.ok()) {
    done(admitted.status());
    return;
  }
  PhaseReporter progress(std::move(progress_fn));
  progress("queued", 0.0);
  // std::function needs a copyable callable: the ticket travels in a shared_ptr.
  auto ticket = std::make_shared<HeavyWorkAdmission::Ticket>(std::move(admitted).value());
  std::string client = request.client;  // read before `request` moves into the task
  pool_.submit(
      [this, ticket, request = std::move(request), stop = std::move(stop), done = std::move(done),
       progress = std::move(progress)] {
        if (stop.stop_requested() || shutdown_.stop_requested()) {
          ticket->release();
          uploads_cancelled_.fetch_add(1);
          done(Error(ErrorCode::Cancelled, "create_session cancelled before it started"));
          return;
        }
        progress("queued", 1.0);
        const CallStop call_stop(stop, shutdown_.get_token());
        Result<CreatedSession> created = create_session(request, call_stop.token(), progress.fn());
        ticket->release();  // before done: a client that retries at once is admitted
        if (!created.ok() && created.status().code() == ErrorCode::Cancelled) {
          uploads_cancelled_.fetch_add(1);
        }
        done(std::move(created));
      },
      TaskClass::Heavy, std::move(client));
}

void DeformationService::get_mesh_async(SessionId id, Token token, io::MeshFormat format,
                                        std::optional<std::uint64_t> revision,
                                        std::stop_token stop,
                                        std::function<void(Result<std::string>)> done) {
  pool_.submit([this, id = std::move(id), token = std::move(token), format, revision,
                stop = std::move(stop), done = std::move(done)] {
    if (stop.stop_requested() || shutdown_.stop_requested()) {
      done(Error(ErrorCode::Cancelled, "get_mesh cancelled before it started"));
      return;
    }
    done(get_mesh(id, token, format, revision));
  });
}

std::shared_ptr<Session> DeformationService::find_or_restore(const SessionId& id) {
  std::shared_ptr<Session> cached = store_.find(id);
  // With a shared state directory another replica may have served the session since this copy
  // last wrote or read its file (a failover and back, or the replica that created it): one stat
  // tells (never confused by this copy's own writes: Session::is_fresh), and a stale copy is
  // replaced by the file's newer state, its watchers handed over (or, when the file is gone,
  // closed elsewhere or expired, the session is gone here too).
  if (cached && cached->is_fresh()) return cached;
  if (!state_dir_ || !is_valid_session_id(id.value)) return nullptr;
  const std::lock_guard lock(restore_mutex_);
  cached = store_.find(id);
  if (cached && cached->is_fresh()) return cached;  // restored meanwhile
  std::shared_ptr<Session> stale;
  if (cached) {
    store_.erase_without_closing(id);
    stale = std::move(cached);
    stale_copies_dropped_.fetch_add(1);
    log_event(LogLevel::Info, "session_stale_dropped", LogFields().add("session", id.value));
  }
  auto gone = [&stale]() -> std::shared_ptr<Session> {
    if (stale) stale->close();  // closed or expired elsewhere: its watches end OK
    return nullptr;
  };
  FileStamp stamp;
  Result<PersistedSession> state = state_dir_->read(id, &stamp);
  if (!state.ok()) {
    if (state.status().code() != ErrorCode::NotFound) {
      state_files_corrupt_.fetch_add(1);
      log_event(LogLevel::Warn, "state_file_corrupt",
                LogFields().add("session", id.value).add("message", state.status().message()));
    }
    return gone();
  }
  const std::optional<double> age = state_dir_->age_seconds(id);
  if (!age || *age > std::chrono::duration<double>(options_.idle_ttl).count()) {
    state_dir_->remove_if(id, stamp);  // expired while no server held it
    return gone();
  }
  SessionStore* store = &store_;
  Result<std::shared_ptr<Session>> restored = run_guarded("restore", [&] {
    return Session::restore(std::move(state).value(), options_, counters_,
                            [store](std::size_t bytes, const Session& requester) {
                              return store->reserve(bytes, requester);
                            });
  });
  if (!restored.ok()) {
    state_files_corrupt_.fetch_add(1);
    log_event(LogLevel::Warn, "state_restore_failed",
              LogFields().add("session", id.value).add("message", restored.status().message()));
    return gone();
  }
  std::shared_ptr<Session> session = std::move(restored).value();
  session->set_state_directory(&*state_dir_);
  session->set_persisted_stamp(stamp);
  if (const Status inserted = store_.insert(session); !inserted.ok()) {
    log_event(LogLevel::Warn, "state_restore_refused",
              LogFields().add("session", id.value).add("message", inserted.message()));
    if (stale) {
      stale->close(Error(ErrorCode::Unavailable, "session " + short_id(id) +
                                                     " could not be reloaded here: " +
                                                     inserted.message()));
    }
    return nullptr;
  }
  if (stale) stale->hand_over_watchers(*session);  // watches go on with the newer state
  sessions_restored_.fetch_add(1);
  log_event(LogLevel::Info, "session_restored",
            LogFields().add("session", id.value).add("revision", session->revision()));
  return session;
}

Result<std::shared_ptr<Session>> DeformationService::find_shared(const SessionId& id) {
  const auto not_found = [&id] {
    return Error(ErrorCode::NotFound,
                 "session '" + short_id(id) + "' not found (unknown, closed or expired)");
  };
  if (std::shared_ptr<Session> cached = store_.find(id)) {
    // One round trip tells whether another replica committed since: then replay its revisions.
    if (const Status synced = cached->sync_shared(); !synced.ok()) {
      if (synced.code() == ErrorCode::NotFound) {
        store_.erase(id);
        return not_found();
      }
      return synced;
    }
    return cached;
  }
  if (!is_valid_session_id(id.value)) return not_found();
  const std::lock_guard lock(restore_mutex_);
  if (std::shared_ptr<Session> cached = store_.find(id)) return cached;  // loaded meanwhile
  Result<SharedState> loaded = shared_->load(id);
  if (!loaded.ok()) {
    if (loaded.status().code() == ErrorCode::NotFound) return not_found();
    if (loaded.status().code() == ErrorCode::InvalidArgument) state_files_corrupt_.fetch_add(1);
    log_event(LogLevel::Warn, "shared_load_failed",
              LogFields().add("session", id.value).add("message", loaded.status().message()));
    return loaded.status();
  }
  const std::uint64_t version = loaded->version;
  SessionStore* store = &store_;
  // The factorizations are this replica's own: they are built on the first edit here.
  MD_ASSIGN_OR_RETURN(std::shared_ptr<Session> session, run_guarded("load_shared", [&] {
                        return Session::restore(std::move(loaded->state), options_, counters_,
                                                [store](std::size_t bytes, const Session& who) {
                                                  return store->reserve(bytes, who);
                                                });
                      }));
  session->set_shared_store(shared_.get(), version);
  MD_RETURN_IF_ERROR(store_.insert(session));
  sessions_restored_.fetch_add(1);
  log_event(LogLevel::Info, "session_loaded_shared",
            LogFields().add("session", id.value).add("revision", session->revision())
                .add("version", version));
  return session;
}

void DeformationService::feed_loop(std::stop_token stop) {
  std::mutex mutex;
  std::condition_variable_any cv;
  while (!stop.stop_requested()) {
    for (const std::shared_ptr<Session>& session : store_.watched()) {
      if (stop.stop_requested()) return;
      const Status synced = session->sync_shared();
      if (synced.code() == ErrorCode::NotFound) {
        store_.erase(session->id());  // closed through another replica: end the watches
      } else if (!synced.ok()) {
        log_event(LogLevel::Debug, "shared_sync_failed",
                  LogFields().add("session", session->id().value).add("message", synced.message()));
      }
    }
    std::unique_lock lock(mutex);
    cv.wait_for(lock, stop, options_.shared_poll, [] { return false; });
  }
}

Result<std::shared_ptr<Session>> DeformationService::find_for_view(const SessionId& id,
                                                                   const Token& token) {
  if (shared_) {
    MD_ASSIGN_OR_RETURN(std::shared_ptr<Session> session, find_shared(id));
    if (!session->can_view(token)) {
      return Error(ErrorCode::PermissionDenied, "wrong token for session '" + short_id(id) + "'");
    }
    return session;
  }
  std::shared_ptr<Session> session = find_or_restore(id);
  if (!session) {
    return Error(ErrorCode::NotFound,
                 "session '" + short_id(id) + "' not found (unknown, closed or expired)");
  }
  if (!session->can_view(token)) {
    return Error(ErrorCode::PermissionDenied, "wrong token for session '" + short_id(id) + "'");
  }
  return session;
}

Result<std::shared_ptr<Session>> DeformationService::find_for_edit(const SessionId& id,
                                                                   const Token& token) {
  MD_ASSIGN_OR_RETURN(std::shared_ptr<Session> session, find_for_view(id, token));
  if (!session->can_edit(token)) {
    return Error(ErrorCode::PermissionDenied,
                 "the view token cannot edit session '" + short_id(id) + "'");
  }
  return session;
}

void DeformationService::post(const std::shared_ptr<Session>& session, std::function<void()> task,
                              bool is_refinement, Session::StrandStep step) {
  if (!is_refinement) session->preempt_refinement();
  session->inflight().fetch_add(1);
  SessionStore* store = &store_;
  auto wrapped = [session, store, task = std::move(task)] {
    struct Done {  // the edit is over even if `task` throws
      Session* session;
      SessionStore* store;
      ~Done() {
        session->touch(store->now());
        // With a shared store: the lease goes back once this replica has nothing queued.
        if (!session->has_queued_edits()) session->end_shared_edit();
        session->inflight().fetch_sub(1);
      }
    } done{session.get(), store};
    task();
  };
  const std::optional<Session::StrandStep> first = session->enqueue(std::move(wrapped), step);
  if (!first) return;  // the strand is already scheduled
  // One pool task per step of the strand: other sessions' edits interleave between steps, and
  // each step runs in its own class (a SetHandles precompute on a heavy lane, a move on any).
  struct Drain {
    std::shared_ptr<Session> session;
    WorkerPool* pool;
    void operator()() const { schedule(pool, session, session->run_next()); }
    static void schedule(WorkerPool* pool, const std::shared_ptr<Session>& session,
                         const std::optional<Session::StrandStep>& step) {
      if (!step) return;
      if (step->task_class == TaskClass::Normal && step->is_short) {
        pool->submit_short(Drain{session, pool});
      } else {
        pool->submit(Drain{session, pool}, step->task_class, step->client);
      }
    }
  };
  Drain::schedule(&pool_, session, first);
}

core::ProgressCallback DeformationService::yield_point(std::chrono::milliseconds after) {
  const double after_seconds = std::chrono::duration<double>(after).count();
  return [this, after_seconds](const core::IterationInfo& info) {
    // A short solve finishes soon: the moves queued after it wait their turn rather than
    // run inside it (which would hold its result back by theirs).
    if (info.elapsed_seconds < after_seconds) return;
    // A few at most: the solve that yields is paused while they run.
    constexpr int kMostPerYield = 8;
    int ran = 0;
    while (ran < kMostPerYield && pool_.run_short_here()) ++ran;
  };
}

void DeformationService::set_handles_async(const SessionId& id, const Token& edit_token,
                                           SetHandlesRequest request, std::stop_token stop,
                                           std::function<void(Result<SessionInfo>)> done,
                                           ProgressFn progress_fn) {
  Result<std::shared_ptr<Session>> found = find_for_edit(id, edit_token);
  if (!found.ok()) {
    done(found.status());
    return;
  }
  std::shared_ptr<Session> session = std::move(found).value();
  Result<HeavyWorkAdmission::Ticket> admitted = heavy_.admit(request.client, "SetHandles");
  if (!admitted.ok()) {
    done(admitted.status());
    return;
  }
  auto ticket = std::make_shared<HeavyWorkAdmission::Ticket>(std::move(admitted).value());
  PhaseReporter progress(std::move(progress_fn));
  progress("queued", 0.0);
  Session::StrandStep step{TaskClass::Heavy, request.client};  // before `request` moves
  post(
      session,
      [this, session, ticket, request = std::move(request), stop = std::move(stop),
       done = std::move(done), progress = std::move(progress)] {
        Result<SessionInfo> result = run_guarded("SetHandles", [&]() -> Result<SessionInfo> {
          if (stop.stop_requested() || shutdown_.stop_requested()) {
            return Error(ErrorCode::Cancelled, "set_handles cancelled before it started");
          }
          progress("queued", 1.0);
          const CallStop call_stop(stop, shutdown_.get_token());
          return session->set_handles(request, call_stop.token(), progress.build_progress());
        });
        ticket->release();
        if (!result.ok() && result.status().code() == ErrorCode::Cancelled) {
          precomputes_cancelled_.fetch_add(1);
        }
        done(std::move(result));
      },
      /*is_refinement=*/false, std::move(step));
}

Result<SessionInfo> DeformationService::set_handles(const SessionId& id, const Token& edit_token,
                                                    SetHandlesRequest request,
                                                    std::stop_token stop, ProgressFn progress) {
  std::promise<Result<SessionInfo>> promise;
  std::future<Result<SessionInfo>> future = promise.get_future();
  set_handles_async(
      id, edit_token, std::move(request), std::move(stop),
      [&promise](Result<SessionInfo> r) { promise.set_value(std::move(r)); }, std::move(progress));
  return future.get();
}

void DeformationService::move_handles_async(const SessionId& id, const Token& edit_token,
                                            MoveRequest request, std::stop_token stop,
                                            std::function<void(Result<DeformResult>)> done) {
  const auto arrived = std::chrono::steady_clock::now();
  Result<std::shared_ptr<Session>> found = find_for_edit(id, edit_token);
  if (!found.ok()) {
    done(found.status());
    return;
  }
  std::shared_ptr<Session> session = std::move(found).value();
  session->note_move_arrival();
  Session::StrandStep step;
  step.is_short = request.max_iterations <= kShortMoveIterations;
  post(
      session,
      [this, session, request = std::move(request), stop = std::move(stop),
       done = std::move(done), arrived] {
        const double queue_seconds =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - arrived).count();
        Result<DeformResult> result = run_guarded("MoveHandles", [&]() -> Result<DeformResult> {
          const CallStop call_stop(stop, shutdown_.get_token(), request.deadline, deadlines_);
          const RunningSolve running(counters_->solves_running);
          return session->move(request, call_stop.token(), yield_point(options_.yield_after));
        });
        if (result.ok()) {
          result->queue_seconds = queue_seconds;
          counters_->metrics.record_move_queue_wait(queue_seconds);
        }
        done(std::move(result));
        schedule_refinement(session, /*after_move=*/true);
      },
      /*is_refinement=*/false, std::move(step));
}

void DeformationService::schedule_refinement(const std::shared_ptr<Session>& session,
                                             bool after_move) {
  if (options_.refine_budget <= 0 || shutdown_.stop_requested()) return;
  // Strand-only state, read on the strand: this runs at the end of an edit or refinement task.
  if (!session->wants_refinement() || session->has_queued_edits()) return;
  // What refinement needs first (the full-resolution solver of a multiresolution session,
  // seconds at 10^5 vertices) is built off the strand at once, during the drag, so that
  // refinement can start as soon as the handles rest; its install schedules refinement again.
  if (start_background_build(session)) return;
  // A move arrived or committed within the rest delay (refinement_rest: the configured delay,
  // longer when the drag's own moves come further apart). (By value: the timer keeps it.)
  auto dragging = [this, session] {
    return std::chrono::steady_clock::now() - session->last_move_time() <
           refinement_rest(options_.refine_delay, session->drag_interval());
  };
  // A slice that starts while moves keep coming (e.g. the full-resolution solver of a
  // multiresolution session installed mid-drag) would be preempted by the next move after
  // taking a core from it, and delay it until it stops: wait for the rest delay as after a move.
  if ((after_move || dragging()) && options_.refine_delay.count() > 0) {
    // Start once the handles rest: every move posts a timer, and only the one whose move is
    // still the last when it fires goes on (the others see a newer move, arrived or committed,
    // and drop out).
    const auto rest = refinement_rest(options_.refine_delay, session->drag_interval());
    delays_.post_after(rest, [this, session, dragging] {
      if (dragging()) return;
      post(session, [this, session] { schedule_refinement(session, /*after_move=*/false); },
           /*is_refinement=*/true);
    });
    return;
  }
  pool_.submit_background([this, session] {
    post(
        session,
        [this, session] {
          // An edit queued meanwhile runs first and schedules refinement again after itself.
          if (session->has_queued_edits() || shutdown_.stop_requested()) return;
          // A build refinement needs that became due since (a deformer built meanwhile).
          if (start_background_build(session)) return;
          const Result<std::optional<DeformResult>> refined = run_guarded(
              "refinement", [&]() -> Result<std::optional<DeformResult>> {
                const CallStop slice({}, shutdown_.get_token());
                const RunningSolve running(counters_->solves_running);
                return session->refine(slice.source(), yield_point(std::chrono::milliseconds{0}));
              });
          if (refined.ok() && refined->has_value()) {
            const DeformResult& r = **refined;
            log_event(LogLevel::Debug, "refinement",
                      LogFields()
                          .add("session", session->id().value)
                          .add("revision", r.revision)
                          .add("iterations", r.iterations)
                          .add("converged", r.converged)
                          .add("e_theta", r.e_theta)
                          .add("solve_seconds", r.solve_seconds));
          }
          if (refined.ok()) schedule_refinement(session, /*after_move=*/false);
        },
        /*is_refinement=*/true);
  });
}

bool DeformationService::start_background_build(const std::shared_ptr<Session>& session) {
  if (session->background_build_running()) return true;
  std::optional<Session::BackgroundBuild> build = session->take_background_build();
  if (!build) return false;
  run_background_build(session, std::move(*build));
  return true;
}

void DeformationService::run_background_build(const std::shared_ptr<Session>& session,
                                              Session::BackgroundBuild build) {
  pool_.submit_background([this, session, build = std::move(build)] {
    const auto start = std::chrono::steady_clock::now();
    const CallStop stop(session->background_build_stop(), shutdown_.get_token());
    Result<core::Deformer::Installer> installer = run_guarded(
        "background build",
        [&]() -> Result<core::Deformer::Installer> { return build.task(stop.token()); });
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    auto shared_installer =
        std::make_shared<Result<core::Deformer::Installer>>(std::move(installer));
    // The task (and the mesh copy it holds) is done: only which deformer it was for travels on.
    const Session::BackgroundBuild done{{}, build.method, build.key};
    post(
        session,
        [this, session, done, shared_installer, seconds] {
          const Status status = shared_installer->status();
          const bool installed =
              session->finish_background_build(done, std::move(*shared_installer));
          const bool quiet = status.ok() || status.code() == ErrorCode::Cancelled;
          log_event(quiet ? LogLevel::Debug : LogLevel::Warn, "background_build",
                    LogFields()
                        .add("session", session->id().value)
                        .add("installed", installed)
                        .add("seconds", seconds)
                        .add("message", status.ok() ? std::string() : status.message()));
          schedule_refinement(session, /*after_move=*/false);
        },
        /*is_refinement=*/true);
  });
}

Result<DeformResult> DeformationService::move_handles(const SessionId& id, const Token& edit_token,
                                                      MoveRequest request, std::stop_token stop) {
  std::promise<Result<DeformResult>> promise;
  std::future<Result<DeformResult>> future = promise.get_future();
  move_handles_async(id, edit_token, std::move(request), std::move(stop),
                     [&promise](Result<DeformResult> r) { promise.set_value(std::move(r)); });
  return future.get();
}

Result<std::string> DeformationService::get_mesh(const SessionId& id, const Token& token,
                                                 io::MeshFormat format,
                                                 std::optional<std::uint64_t> revision) {
  return run_guarded("GetMesh", [&]() -> Result<std::string> {
    MD_ASSIGN_OR_RETURN(std::shared_ptr<Session> session, find_for_view(id, token));
    MD_ASSIGN_OR_RETURN(std::shared_ptr<const Positions> positions, session->positions_at(revision));
    const MeshData mesh{*positions, session->rest().F};
    return io::write_mesh_to_memory(mesh, format);
  });
}

Result<SessionInfo> DeformationService::session_info(const SessionId& id, const Token& token) {
  return run_guarded("GetSessionInfo", [&]() -> Result<SessionInfo> {
    MD_ASSIGN_OR_RETURN(std::shared_ptr<Session> session, find_for_view(id, token));
    SessionInfo info = session->info();
    info.token_can_edit = session->can_edit(token);
    if (info.token_can_edit) info.view_token = session->view_token().value;
    return info;
  });
}

Status DeformationService::close_session(const SessionId& id, const Token& edit_token) {
  Result<std::shared_ptr<Session>> found = find_for_edit(id, edit_token);
  if (!found.ok()) return found.status();
  // Closed first: its running solve stops and no write of it can follow; then its state goes.
  (*found)->close();
  store_.erase(id);
  if (state_dir_) state_dir_->remove(id);
  if (shared_) shared_->remove(id);
  return Status::success();
}

Result<Subscription> DeformationService::watch(const SessionId& id, const Token& view_token) {
  return run_guarded("Watch", [&]() -> Result<Subscription> {
    MD_ASSIGN_OR_RETURN(std::shared_ptr<Session> session, find_for_view(id, view_token));
    return Subscription(session->add_watcher());
  });
}

std::size_t DeformationService::evict_expired() { return store_.evict_expired(options_.clock()); }

std::size_t DeformationService::evict_expired(std::chrono::steady_clock::time_point now) {
  return store_.evict_expired(now);
}

Status DeformationService::admit(std::string_view client, RateLimitedCall call,
                                 std::chrono::milliseconds* retry_after) {
  const std::optional<std::chrono::milliseconds> wait = limiter_.admit(client, call);
  if (retry_after != nullptr) *retry_after = wait.value_or(std::chrono::milliseconds(0));
  if (!wait) return Status::success();
  const bool create = call == RateLimitedCall::CreateSession;
  (create ? rate_limited_creates_ : rate_limited_moves_).fetch_add(1);
  const RateLimit& limit = create ? options_.create_rate : options_.move_rate;
  char rate[64];
  std::snprintf(rate, sizeof rate, "%g per second, bursts of %g", limit.per_second, limit.burst);
  return Error(ErrorCode::ResourceExhausted,
               std::string("rate limit: ") + (create ? "session creations" : "moves") +
                   " from this client exceed " + rate + "; retry in " +
                   std::to_string(wait->count()) + " ms");
}

ServiceStats DeformationService::stats() const {
  ServiceStats stats;
  stats.deformer_constructions = counters_->deformer_constructions.load();
  stats.moves_committed = counters_->moves_committed.load();
  stats.moves_cancelled = counters_->moves_cancelled.load();
  stats.refinements_committed = counters_->refinements_committed.load();
  stats.refinements_preempted = counters_->refinements_preempted.load();
  stats.background_builds_installed = counters_->background_builds_installed.load();
  stats.pcg_iterations = counters_->pcg_iterations.load();
  stats.outer_iterations = counters_->outer_iterations.load();
  stats.resident_bytes = resident_set_bytes();
  stats.sessions_restored = sessions_restored_.load();
  stats.state_files_corrupt = state_files_corrupt_.load();
  stats.persist_failures = counters_->persist_failures.load();
  stats.solves_running = counters_->solves_running.load();
  stats.yielded_tasks = pool_.ran_at_yield_points();
  stats.watchers = store_.watcher_count();
  stats.evicted_lru = store_.evicted_lru();
  stats.evicted_idle = store_.evicted_idle();
  stats.rate_limited_creates = rate_limited_creates_.load();
  stats.rate_limited_moves = rate_limited_moves_.load();
  stats.stale_copies_dropped = stale_copies_dropped_.load();
  stats.sessions = store_.size();
  stats.estimated_bytes = store_.total_bytes();
  stats.workers = pool_.size();
  stats.heavy_rejected = heavy_.rejected();
  stats.heavy_admitted = heavy_.admitted();
  stats.uploads_cancelled = uploads_cancelled_.load();
  stats.precomputes_cancelled = precomputes_cancelled_.load();
  const QueueDepths depths = pool_.depths();
  stats.heavy_running = depths.heavy_running;
  stats.queued_normal = depths.normal;
  stats.queued_heavy = depths.heavy;
  stats.queued_background = depths.background;
  return stats;
}

}  // namespace meshdeform::service
