#include "server/service/session.h"

#include "core/methods/similarity.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>
#include <thread>
#include <unordered_map>

#include "core/base/format_number.h"
#include "core/methods/ora.h"
#include "server/service/call_stop.h"
#include "core/mesh/validate.h"
#include "server/service/edit_history.h"
#include "server/service/log.h"
#include "server/service/tokens.h"

namespace meshdeform::service {
namespace {

/// Most ARAP iterations of an interactive move's rigid start (see Session::move).
constexpr int kMoveRigidStartIterations = 30;

// ServiceOptions::solver_threads for a big session, one thread for the rest.
int threads_for(const ServiceOptions& options, int vertices) {
  if (vertices < options.parallel_solve_above) return 1;
  if (options.solver_threads > 0) return options.solver_threads;
  return std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
}

std::string vec_str(const Eigen::Vector3d& v) {
  std::string out = "(";
  out += std::to_string(v.x());
  out += ", ";
  out += std::to_string(v.y());
  out += ", ";
  out += std::to_string(v.z());
  out += ")";
  return out;
}

/// InvalidArgument naming `field` (as the client wrote it) when `v` is not finite.
Status check_finite(const Eigen::Vector3d& v, const std::string& field) {
  if (v.allFinite()) return Status::success();
  return Error(ErrorCode::InvalidArgument, field + " has a non-finite component " + vec_str(v));
}

/// The one check of a group move's transform: finite numbers, a rotation quaternion that can be
/// normalised, a positive scale. `where` is the move's field ("moves[2]").
Status check_transform(const GroupMove& move, const std::string& where) {
  MD_RETURN_IF_ERROR(check_finite(move.translation, where + ".translation"));
  if (!move.rotation.coeffs().allFinite()) {
    return Error(ErrorCode::InvalidArgument, where + ".rotation has a non-finite component");
  }
  if (move.rotation.norm() < 1e-12) {
    return Error(ErrorCode::InvalidArgument,
                 where + ".rotation is the zero quaternion (it has no rotation to normalise)");
  }
  if (!(move.scale >= 1.0 / kMaxMoveScale && move.scale <= kMaxMoveScale)) {
    return Error(ErrorCode::InvalidArgument,
                 where + ".scale " + core::format_number(move.scale, "%g") + " is outside [" +
                     core::format_number(1.0 / kMaxMoveScale, "%g") + ", " +
                     core::format_number(kMaxMoveScale, "%g") + "]");
  }
  if (move.pivot) MD_RETURN_IF_ERROR(check_finite(*move.pivot, where + ".pivot"));
  return Status::success();
}

/// The one range check of a move's solver budget.
Status check_budget(const MoveRequest& request) {
  if (request.max_iterations < 1 || request.max_iterations > kMaxMoveIterations) {
    return Error(ErrorCode::InvalidArgument,
                 "max_iterations " + std::to_string(request.max_iterations) + " is outside [1, " +
                     std::to_string(kMaxMoveIterations) + "]");
  }
  if (!std::isfinite(request.tolerance) || request.tolerance < 0) {
    return Error(ErrorCode::InvalidArgument,
                 "tolerance " + std::to_string(request.tolerance) + " is not finite and >= 0");
  }
  if (request.magnify.size() > static_cast<std::size_t>(kMaxMagnifyRegions)) {
    return Error(ErrorCode::InvalidArgument,
                 std::to_string(request.magnify.size()) + " magnify regions (at most " +
                     std::to_string(kMaxMagnifyRegions) + ")");
  }
  if (!request.rigidity) return Status::success();
  return core::check_rigidity(*request.rigidity, kMaxRigidity);
}

}  // namespace

std::size_t estimate_session_bytes(int vertices, int faces, int cached_deformers,
                                   int kept_revisions) {
  const auto v = static_cast<std::size_t>(std::max(vertices, 0));
  const auto f = static_cast<std::size_t>(std::max(faces, 0));
  // Rest + current + kept revisions + anchors/targets (24 B per vertex each), topology CSR arrays
  // (~64 B per vertex), faces (12 B) and measures (theta, ratio, phi, area: ~100 B per face),
  // and the newest revision's wire encodings (DeformResult::encoded: float32 and meshopt, up to
  // 12 B per vertex each).
  const std::size_t base =
      v * (24 * (3 + static_cast<std::size_t>(std::max(kept_revisions, 0))) + 64 + 24) +
      f * 112 + 4096;
  // One charge for every method, the largest one's: measured heap of a built and solved
  // deformer on Spot at 187k vertices (issue 15): scale-aware 5.1 KB per vertex (the Laplacian
  // guess's bi-Laplacian factor, the n x n and #F x #F preconditioner factors, the scale term's
  // per-face arrays), multiresolution 1.0 KB while moving on the coarse level and 4.6 KB once the
  // background refinement built its full-resolution solver, ARAP 1.0 KB, Laplacian 1.7 KB. The
  // faces are in it (a closed mesh has two per vertex). Since the cold solve frees its start's
  // solvers (git 09c4c30 and after) a single-level scale-aware deformer holds 2.4 KB per vertex
  // after its first move (Spot 47k) and peaks at about 3.5 KB during a cold one; the charge
  // stays as measured, above the multiresolution deformer's 4.6 KB (issue 15's bench at 187k:
  // 977 MiB peak with the refinement, 1020 before). Refinement slices that continue one another
  // keep Anderson's window between them (288 B per vertex, twice that while a slice runs: the
  // bench's 187k refinement in slices peaked at 1,067 MiB against 998 as one solve), which the
  // charge covered (4.6 + 0.6 KB). Since refinement after a drag runs the multilevel cascade
  // (issue 41: its hierarchy, prolongations and full-resolution ARAP factor are kept) the
  // multiresolution deformer holds 5.9 KB per vertex after a drag, its background build and
  // three refinement slices (measured 2026-12-07 on Spot at 187k: 1,052 MiB resident against
  // 793 without the cascade, 4.4 KB per vertex), plus the window's copy while a slice runs: the
  // charge is 6.2 KB.
  const std::size_t per_deformer = v * 6200;
  return base + per_deformer * static_cast<std::size_t>(std::max(cached_deformers, 0));
}

Result<std::shared_ptr<Session>> Session::create(SessionId id, Token edit_token, Token view_token,
                                                 MeshData mesh,
                                                 const core::DeformerSettings& settings,
                                                 const ServiceOptions& options,
                                                 std::shared_ptr<ServiceCounters> counters,
                                                 ReserveFn reserve) {
  MD_ASSIGN_OR_RETURN(core::MeshTopology topology,
                      core::build_topology(mesh.F, static_cast<int>(mesh.V.rows())));
  std::shared_ptr<Session> session(new Session());
  session->id_ = std::move(id);
  session->edit_token_ = std::move(edit_token);
  session->view_token_ = std::move(view_token);
  session->rest_measures_ = core::compute_measures(mesh.V, mesh.F, topology);
  session->boundary_loops_ = core::count_boundary_loops(mesh.F, static_cast<int>(mesh.V.rows()));
  session->topology_ = std::move(topology);
  session->rest_ = std::move(mesh);
  session->settings_ = settings;
  session->settings_.threads = threads_for(options, static_cast<int>(session->rest_.V.rows()));
  session->settings_.multires_above = options.multires_above;
  session->settings_.multires_coarse_vertices = options.multires_coarse_vertices;
  session->options_ = options;
  session->options_.kept_revisions = std::max(1, options.kept_revisions);
  session->options_.max_cached_deformers = std::max(1, options.max_cached_deformers);
  session->counters_ = std::move(counters);
  session->reserve_ = std::move(reserve);
  session->vertex_group_.assign(static_cast<std::size_t>(session->rest_.V.rows()), -1);
  {
    const Positions& V = session->rest_.V;
    const double diagonal = (V.colwise().maxCoeff() - V.colwise().minCoeff()).norm();
    const double extent = std::max({diagonal, V.cwiseAbs().maxCoeff(), 1e-300});
    session->reach_ = kMaxReach * extent;
  }

  auto rest = std::make_shared<DeformResult>();
  rest->revision = 0;
  rest->positions = std::make_shared<const Positions>(session->rest_.V);
  session->rest_positions_ = rest->positions;
  rest->changed_positions.resize(0, 3);
  session->history_.push_back(std::move(rest));
  session->init_deformer_cache();
  return session;
}

Result<std::shared_ptr<Session>> Session::restore(PersistedSession state,
                                                  const ServiceOptions& options,
                                                  std::shared_ptr<ServiceCounters> counters,
                                                  ReserveFn reserve) {
  MD_RETURN_IF_ERROR(core::validate_triangle_mesh(state.rest.V, state.rest.F));
  core::DeformerSettings settings;
  settings.lambda = state.lambda;
  const int nv = static_cast<int>(state.rest.V.rows());
  MD_ASSIGN_OR_RETURN(std::shared_ptr<Session> session,
                      create(state.id, state.edit_token, state.view_token, std::move(state.rest),
                             settings, options, std::move(counters), std::move(reserve)));
  std::vector<int> group_of(static_cast<std::size_t>(nv), -1);
  std::vector<int> constrained;
  for (std::size_t g = 0; g < state.groups.size(); ++g) {
    for (int v : state.groups[g].vertices) {
      if (group_of[static_cast<std::size_t>(v)] >= 0) {
        return Error(ErrorCode::InvalidArgument,
                     "state file: vertex " + std::to_string(v) + " is in two groups");
      }
      group_of[static_cast<std::size_t>(v)] = static_cast<int>(g);
      constrained.push_back(v);
    }
  }
  std::sort(constrained.begin(), constrained.end());
  auto current = std::make_shared<DeformResult>();
  current->revision = state.revision;
  current->positions = std::make_shared<const Positions>(std::move(state.positions));
  current->changed_positions.resize(0, 3);
  if (state.last_method) current->method = *state.last_method;
  {
    std::lock_guard lock(session->state_mutex_);
    session->groups_ = std::move(state.groups);
    session->constrained_ = std::move(constrained);
    session->anchors_ = std::move(state.anchors);
    session->targets_ = std::move(state.targets);
    session->vertex_group_ = std::move(group_of);
    session->revision_ = state.revision;
    session->last_method_ = state.last_method;
    session->edit_ = std::move(state.edit);
    session->history_.clear();
    session->history_.push_back(std::move(current));
  }
  return session;
}

PersistedSession Session::persisted_state(bool with_rest) const {
  PersistedSession state;
  state.id = id_;
  state.edit_token = edit_token_;
  state.view_token = view_token_;
  state.lambda = settings_.lambda;
  if (with_rest) state.rest = rest_;
  {
    std::lock_guard lock(state_mutex_);
    state.groups = groups_;
    state.anchors = anchors_;
    state.targets = targets_;
    state.positions = *history_.back()->positions;
    state.revision = revision_;
    state.last_method = last_method_;
    state.edit = edit_;
  }
  if (state.anchors.rows() == 0) state.anchors.resize(0, 3);
  if (state.targets.rows() == 0) state.targets.resize(0, 3);
  return state;
}

Status Session::persist() {
  if (state_dir_ == nullptr) return Status::success();
  return persist_state(persisted_state());
}

Status Session::persist_state(const PersistedSession& state) {
  if (state_dir_ == nullptr) return Status::success();
  auto failed = [this](const Status& status) {
    // Losing to another replica or to a close is not a failure of the store; the OS's errors are.
    if (status.code() != ErrorCode::Aborted && status.code() != ErrorCode::NotFound) {
      counters_->persist_failures.fetch_add(1);
    }
    log_event(LogLevel::Error, "persist_failed",
              LogFields().add("session", id_.value).add("message", status.message()));
    return status;
  };
  // The slow part (encoding, writing, fsync) under no lock.
  Result<StagedWrite> staged = state_dir_->stage(state);
  if (!staged.ok()) return failed(staged.status());
  Status published;
  {
    const std::lock_guard lock(stamp_mutex_);
    if (closed_.load()) {
      return Error(ErrorCode::NotFound, "session " + id_.value + " is closed");
    }
    std::optional<FileStamp> written;
    published = state_dir_->publish(std::move(staged).value(), stamp_, written);
    // The file is ours once renamed, even when the directory's fsync then failed.
    if (written) stamp_ = written;
  }
  if (!published.ok()) return failed(published);
  counters_->persisted_writes.fetch_add(1);
  return Status::success();
}

std::optional<FileStamp> Session::persisted_stamp() const {
  const std::lock_guard lock(stamp_mutex_);
  return stamp_;
}

void Session::set_persisted_stamp(const FileStamp& stamp) {
  const std::lock_guard lock(stamp_mutex_);
  stamp_ = stamp;
}

bool Session::is_fresh() const {
  if (state_dir_ == nullptr) return true;
  // Under the lock a write of this copy holds from its rename to recording the new stamp.
  const std::lock_guard lock(stamp_mutex_);
  if (!stamp_) return true;
  return state_dir_->stamp(id_) == stamp_;
}

void Session::hand_over_watchers(Session& fresh) {
  std::vector<std::shared_ptr<Watcher>> watchers;
  {
    std::lock_guard lock(state_mutex_);
    watchers.swap(watchers_);
  }
  {
    std::lock_guard lock(fresh.state_mutex_);
    for (const std::shared_ptr<Watcher>& watcher : watchers) {
      watcher->set_owner(fresh.weak_from_this());
      // Newer than what the watcher saw: a snapshot (an older or equal revision is ignored).
      watcher->publish_snapshot(fresh.snapshot_locked());
      if (fresh.closed_.load()) {
        watcher->close();
      } else {
        fresh.watchers_.push_back(watcher);
      }
    }
  }
  close();
}

namespace {
Status stale_copy(const SessionId& id) {
  return Error(ErrorCode::Aborted, "session " + id.value.substr(0, 8) +
                                       "... was changed by another replica; retry the call");
}
}  // namespace

bool Session::can_edit(const Token& token) const {
  return constant_time_equal(token.value, edit_token_.value);
}

bool Session::can_view(const Token& token) const {
  // Evaluate both so the time does not tell which token matched.
  const bool view = constant_time_equal(token.value, view_token_.value);
  const bool edit = constant_time_equal(token.value, edit_token_.value);
  return view || edit;
}

Status Session::check_pinnable(core::Method method, const std::vector<int>& constrained) const {
  const int needed = method == core::Method::ScaleAware ? 2 : 1;
  std::vector<int> count(static_cast<std::size_t>(topology_.component_count), 0);
  for (int v : constrained) ++count[static_cast<std::size_t>(topology_.component(v))];
  for (std::size_t c = 0; c < count.size(); ++c) {
    if (count[c] < needed) {
      return Error(ErrorCode::FailedPrecondition,
                   std::string("method ") + core::method_name(method) + " needs at least " +
                       std::to_string(needed) + " constrained vertices in every connected " +
                       "component; component " + std::to_string(c) + " has " +
                       std::to_string(count[c]));
    }
  }
  return Status::success();
}

Result<Eigen::VectorXd> Session::magnify_scales(const MoveRequest& request) const {
  if (request.magnify.empty()) return Eigen::VectorXd();
  if (request.method != core::Method::ScaleAware) {
    return Error(ErrorCode::InvalidArgument,
                 std::string("magnify regions need the scale-aware method, not ") +
                     core::method_name(request.method));
  }
  for (std::size_t r = 0; r < request.magnify.size(); ++r) {
    if (request.magnify[r].faces.size() != 0) {
      return Error(ErrorCode::InvalidArgument, "magnify[" + std::to_string(r) +
                                                   "]: name the region by vertices, not faces");
    }
    const double k = request.magnify[r].scale;
    if (!(k >= 1.0 / kMaxMagnifyScale && k <= kMaxMagnifyScale)) {
      return Error(ErrorCode::InvalidArgument,
                   "magnify[" + std::to_string(r) + "].scale " + core::format_number(k, "%g") +
                       " is outside [" + core::format_number(1.0 / kMaxMagnifyScale, "%g") +
                       ", " + core::format_number(kMaxMagnifyScale, "%g") + "]");
    }
  }
  return core::face_scales_from_regions(request.magnify, rest_.F,
                                        static_cast<int>(rest_.V.rows()));
}

void Session::init_deformer_cache() {
  const int v = static_cast<int>(rest_.V.rows()), f = static_cast<int>(rest_.F.rows());
  base_bytes_ = estimate_session_bytes(v, f, 0, options_.kept_revisions);
  const std::size_t per_deformer = estimate_session_bytes(v, f, 1, 0) - estimate_session_bytes(v, f, 0, 0);
  // The session owns the cache, so the cache's functions may hold `this`.
  DeformerCache::BuildFn build = [this](core::Method method, const Eigen::VectorXi& constrained,
                                        std::stop_token stop, const core::BuildProgress& progress)
      -> Result<std::unique_ptr<core::Deformer>> {
    MD_ASSIGN_OR_RETURN(std::unique_ptr<core::Deformer> deformer,
                        core::make_deformer(method, rest_.V, rest_.F, topology_, constrained,
                                            settings_, stop, progress));
    counters_->deformer_constructions.fetch_add(1);
    return deformer;
  };
  DeformerCache::ReserveFn reserve;
  if (reserve_) reserve = [this](std::size_t bytes) { return reserve_(bytes, *this); };
  deformers_ = std::make_unique<DeformerCache>(options_.max_cached_deformers, per_deformer,
                                               std::move(build), std::move(reserve));
}

Result<SessionInfo> Session::set_handles(const SetHandlesRequest& request, std::stop_token stop,
                                         const core::BuildProgress& progress) {
  if (is_closed()) return Error(ErrorCode::NotFound, "session " + id_.value + " is closed");
  if (!is_fresh()) return stale_copy(id_);  // never overwrite a newer revision of another replica
  if (shared_ != nullptr) MD_RETURN_IF_ERROR(begin_shared_edit(shared_->lease_wait(), stop));
  refine_.reset();  // new anchors: the old solve is not worth continuing
  const int nv = static_cast<int>(rest_.V.rows());
  if (request.groups.empty()) {
    return Error(ErrorCode::InvalidArgument, "set_handles needs at least one handle group");
  }
  std::vector<int> group_of(static_cast<std::size_t>(nv), -1);
  std::vector<int> constrained;
  // "fixed group 0", "handle group 1": the messages name each group's role.
  auto group_name = [&request](std::size_t g) {
    return std::string(request.groups[g].role == HandleRole::Fixed ? "fixed" : "handle") +
           " group " + std::to_string(g);
  };
  for (std::size_t g = 0; g < request.groups.size(); ++g) {
    const HandleGroup& group = request.groups[g];
    if (group.vertices.empty()) {
      return Error(ErrorCode::InvalidArgument, group_name(g) + " is empty");
    }
    for (int v : group.vertices) {
      if (v < 0 || v >= nv) {
        return Error(ErrorCode::InvalidArgument, group_name(g) + " references vertex " +
                                                     std::to_string(v) + " (#V=" +
                                                     std::to_string(nv) + ")");
      }
      int& owner = group_of[static_cast<std::size_t>(v)];
      if (owner >= 0) {
        return Error(ErrorCode::InvalidArgument,
                     "vertex " + std::to_string(v) + " is in " +
                         group_name(static_cast<std::size_t>(owner)) + " and in " +
                         group_name(g));
      }
      owner = static_cast<int>(g);
      constrained.push_back(v);
    }
  }
  std::sort(constrained.begin(), constrained.end());
  MD_RETURN_IF_ERROR(check_pinnable(request.prepare, constrained));
  // A close stops the precompute too.
  const CallStop closed_or_stopped(stop, closed_stop_.get_token());
  MD_RETURN_IF_ERROR(
      deformers_->get_or_build(request.prepare, constrained, closed_or_stopped.token(), progress)
          .status());

  {
    std::unique_lock shared_lock(shared_mutex_, std::defer_lock);
    if (shared_ != nullptr) shared_lock.lock();  // the anchors are the current positions: no
                                                 // replay may slip in between
    // The new state, stored before it is applied here (the store or the state file first).
    if (shared_ != nullptr || state_dir_ != nullptr) {
      PersistedSession state = persisted_state(/*with_rest=*/shared_ == nullptr);
      state.groups = request.groups;
      state.anchors.resize(static_cast<Eigen::Index>(constrained.size()), 3);
      for (std::size_t j = 0; j < constrained.size(); ++j)
        state.anchors.row(static_cast<Eigen::Index>(j)) = state.positions.row(constrained[j]);
      state.targets = state.anchors;
      restart_history(state.edit);
      if (shared_ != nullptr) {
        MD_RETURN_IF_ERROR(shared_->commit(state, shared_version_, SharedLogEntry{}));
        ++shared_version_;
      } else {
        MD_RETURN_IF_ERROR(persist_state(state));
      }
    }
    std::lock_guard lock(state_mutex_);
    if (closed_.load()) return Error(ErrorCode::NotFound, "session " + id_.value + " is closed");
    const Positions& current = *history_.back()->positions;
    Positions anchors(static_cast<Eigen::Index>(constrained.size()), 3);
    for (std::size_t j = 0; j < constrained.size(); ++j)
      anchors.row(static_cast<Eigen::Index>(j)) = current.row(constrained[j]);
    groups_ = request.groups;
    constrained_ = std::move(constrained);
    anchors_ = anchors;
    targets_ = std::move(anchors);
    vertex_group_ = std::move(group_of);
    restart_history(edit_);  // new anchors: older steps meant other targets
  }
  return info();
}

Status Session::check_reach(const Eigen::RowVector3d& target, const std::string& field) const {
  if (target.allFinite() && target.cwiseAbs().maxCoeff() <= reach_) return Status::success();
  return Error(ErrorCode::InvalidArgument,
               field + " puts a target at (" + core::format_number(target.x(), "%g") + ", " +
                   core::format_number(target.y(), "%g") + ", " +
                   core::format_number(target.z(), "%g") + "), beyond the " +
                   core::format_number(reach_, "%g") + " a target may reach on this mesh (" +
                   core::format_number(kMaxReach, "%g") + " times its size)");
}

Result<DeformResult> Session::move(const MoveRequest& request, std::stop_token stop,
                                   const core::ProgressCallback& between_iterations) {
  if (is_closed()) return Error(ErrorCode::NotFound, "session " + id_.value + " is closed");
  if (!is_fresh()) return stale_copy(id_);  // never overwrite a newer revision of another replica
  if (shared_ != nullptr) {
    std::chrono::milliseconds wait = shared_->lease_wait();
    if (request.deadline) {
      wait = std::min(wait, std::max(std::chrono::milliseconds(0),
                                     std::chrono::duration_cast<std::chrono::milliseconds>(
                                         *request.deadline - std::chrono::steady_clock::now())));
    }
    MD_RETURN_IF_ERROR(begin_shared_edit(wait, stop));
  }
  std::vector<HandleGroup> groups;
  std::vector<int> constrained;
  Positions anchors, targets;
  std::vector<int> vertex_group;
  std::uint64_t base_revision = 0;
  std::shared_ptr<const Positions> base_positions;
  EditState edit;
  {
    std::lock_guard lock(state_mutex_);
    groups = groups_;
    constrained = constrained_;
    anchors = anchors_;
    targets = targets_;
    vertex_group = vertex_group_;
    base_revision = revision_;
    base_positions = history_.back()->positions;
    edit = edit_;
  }
  if (groups.empty()) {
    return Error(ErrorCode::FailedPrecondition,
                 "no handle groups: call set_handles before moving handles");
  }
  MD_RETURN_IF_ERROR(check_budget(request));
  const double rigidity = request.rigidity.value_or(default_rigidity_);
  // Exact undo (issue 44): the step the session leaves keeps the positions that show it, and
  // positions to commit again instead of solving (an undo or redo to a step that kept its own,
  // or restore_revision).
  const int kept_limit = kept_positions_limit(static_cast<int>(rest_.V.rows()));
  const KeptPositions shown{base_revision, base_positions};
  std::shared_ptr<const Positions> restored;
  // Undo / redo: the step's moves and targets, applied to the anchors (a step is a whole state).
  const std::vector<GroupMove>* moves = &request.moves;
  const std::vector<VertexTarget>* vertex_targets = &request.targets;
  EditStep step;
  if (request.history != HistoryAction::Record) {
    const std::string action = request.history == HistoryAction::Undo ? "undo" : "redo";
    if (!request.moves.empty() || !request.targets.empty()) {
      return Error(ErrorCode::InvalidArgument,
                   action + " applies a step of the history: send no moves or targets with it");
    }
    if (request.restore_revision) {
      return Error(ErrorCode::InvalidArgument,
                   action + " restores its step's own positions: send no restore_revision with it");
    }
    MD_ASSIGN_OR_RETURN(const int target, history_target(edit, request.history));
    remember_step(edit, edit.position, shown, kept_limit);
    edit.position = target;
    step = edit.steps[static_cast<std::size_t>(edit.position)];
    if (step.revision) restored = kept_positions(edit, *step.revision);
    moves = &step.moves;
    vertex_targets = &step.targets;
    targets = anchors;
  } else if (request.restore_revision) {
    const std::uint64_t wanted = *request.restore_revision;
    restored = kept_positions(edit, wanted);
    if (!restored && wanted <= base_revision) {
      Result<std::shared_ptr<const Positions>> kept = positions_at(wanted);
      if (kept.ok()) restored = *kept;
    }
    if (!restored) {
      return Error(ErrorCode::FailedPrecondition,
                   "restore_revision " + std::to_string(wanted) +
                       " is not kept (the session keeps revision 0, its newest " +
                       std::to_string(options_.kept_revisions) +
                       " and those its undo history names)");
    }
  }
  // Row of each constrained vertex in anchors/targets.
  auto row_of = [&constrained](int v) {
    return static_cast<Eigen::Index>(std::lower_bound(constrained.begin(), constrained.end(), v) -
                                     constrained.begin());
  };
  for (std::size_t m = 0; m < moves->size(); ++m) {
    const GroupMove& move = (*moves)[m];
    const std::string where = "moves[" + std::to_string(m) + "]";
    if (move.group < 0 || move.group >= static_cast<int>(groups.size())) {
      return Error(ErrorCode::InvalidArgument, where + ".group " + std::to_string(move.group) +
                                                   " does not exist (" +
                                                   std::to_string(groups.size()) + " groups)");
    }
    const HandleGroup& group = groups[static_cast<std::size_t>(move.group)];
    if (group.role != HandleRole::Handle) {
      return Error(ErrorCode::InvalidArgument, where + ".group " + std::to_string(move.group) +
                                                   " is fixed and cannot move");
    }
    MD_RETURN_IF_ERROR(check_transform(move, where));
    core::GroupSimilarity transform;
    transform.rotation = move.rotation.normalized().toRotationMatrix();
    transform.scale = move.scale;
    transform.translation = move.translation;
    transform.pivot = move.pivot;
    Positions group_anchors(static_cast<Eigen::Index>(group.vertices.size()), 3);
    for (std::size_t i = 0; i < group.vertices.size(); ++i) {
      group_anchors.row(static_cast<Eigen::Index>(i)) = anchors.row(row_of(group.vertices[i]));
    }
    const Positions moved = core::apply_similarity(transform, group_anchors);
    for (std::size_t i = 0; i < group.vertices.size(); ++i) {
      const Eigen::RowVector3d target = moved.row(static_cast<Eigen::Index>(i));
      if (const Status reach = check_reach(target, where); !reach.ok()) {
        // Name the field that sent it there.
        const bool pivot_far = move.pivot && !check_reach(move.pivot->transpose(), "").ok();
        const bool translation_far = !check_reach(move.translation.transpose(), "").ok();
        return check_reach(target, where + (translation_far ? ".translation"
                                            : pivot_far     ? ".pivot"
                                                            : ""));
      }
      targets.row(row_of(group.vertices[i])) = target;
    }
  }
  const int nv = static_cast<int>(rest_.V.rows());
  for (std::size_t t = 0; t < vertex_targets->size(); ++t) {
    const VertexTarget& target = (*vertex_targets)[t];
    const std::string where = "targets.vertices[" + std::to_string(t) + "]: ";
    if (target.vertex < 0 || target.vertex >= nv) {
      return Error(ErrorCode::InvalidArgument, where + "vertex " + std::to_string(target.vertex) +
                                                   " is out of range (#V=" + std::to_string(nv) +
                                                   ")");
    }
    const int g = vertex_group[static_cast<std::size_t>(target.vertex)];
    if (g < 0) {
      return Error(ErrorCode::InvalidArgument,
                   where + "vertex " + std::to_string(target.vertex) + " is not constrained");
    }
    if (groups[static_cast<std::size_t>(g)].role != HandleRole::Handle) {
      return Error(ErrorCode::InvalidArgument, where + "vertex " + std::to_string(target.vertex) +
                                                   " is in fixed group " + std::to_string(g));
    }
    MD_RETURN_IF_ERROR(check_finite(target.position, "targets.positions of vertex " +
                                                         std::to_string(target.vertex)));
    MD_RETURN_IF_ERROR(check_reach(target.position.transpose(),
                                   "targets.positions of vertex " + std::to_string(target.vertex)));
    targets.row(row_of(target.vertex)) = target.position.transpose();
  }
  MD_RETURN_IF_ERROR(check_pinnable(request.method, constrained));
  MD_ASSIGN_OR_RETURN(Eigen::VectorXd face_scale, magnify_scales(request));
  if (request.history == HistoryAction::Record) {
    // Explicit targets kept over all steps: bounded by a multiple of the constrained set.
    const std::size_t max_targets = std::max<std::size_t>(16 * constrained.size(), 1024);
    const EditStep& current = edit.steps[static_cast<std::size_t>(edit.position)];
    EditStep next =
        merge_step(current, request.moves, request.targets, vertex_group, request.gesture);
    // A settings change alone is a step too; a one-off solve keeps the step's settings.
    next.settings = request.keep_settings
                        ? current.settings
                        : std::optional<EditSettings>(settings_of(request, rigidity));
    if (record_step(edit, std::move(next), max_targets) == Recorded::Added) {
      remember_step(edit, edit.position - 1, shown, kept_limit);
    }
  }
  if (!request.keep_settings) edit.settings = settings_of(request, rigidity);

  // `stop` is the call's one stop (the service requests it at the deadline too): the solver
  // polls it. The deadline itself only tells which error a stop is.
  auto deadline_passed = [&request] {
    return request.deadline && std::chrono::steady_clock::now() >= *request.deadline;
  };
  auto stopped_status = [&]() -> Status {
    counters_->moves_cancelled.fetch_add(1);
    if (is_closed()) {
      return Error(ErrorCode::NotFound,
                   "session " + id_.value + " was closed; its running solve was stopped");
    }
    if (deadline_passed()) {
      return Error(ErrorCode::DeadlineExceeded, "deadline exceeded; revision " +
                                                    std::to_string(base_revision) + " unchanged");
    }
    return Error(ErrorCode::Cancelled,
                 "move cancelled; revision " + std::to_string(base_revision) + " unchanged");
  };
  if (stop.stop_requested() || deadline_passed()) return stopped_status();

  if (restored) {
    // The kept positions, exactly: no solve, so nothing to refine either. No deformer's
    // positions() equal them, so the cached ones restart at their next move (state_revision).
    core::SolveReport report;
    report.V = *restored;
    report.converged = true;
    DeformerCache::Entry no_deformer;
    Result<DeformResult> committed =
        commit(std::move(report), request.method, rigidity, targets, base_revision, base_positions,
               /*built=*/false, request.editor, /*refinement=*/false, /*settled=*/true,
               &no_deformer, &edit);
    if (!committed.ok()) return committed.status();
    DeformResult result = std::move(committed).value();
    counters_->moves_committed.fetch_add(1);
    last_move_ticks_.store(std::chrono::steady_clock::now().time_since_epoch().count());
    refine_.reset();
    result.history_position = edit.position;
    return result;
  }

  MD_ASSIGN_OR_RETURN(const DeformerCache::Found found,
                      deformers_->get_or_build(request.method, constrained));
  DeformerCache::Entry* entry = found.entry;
  const bool built = found.built;
  if (entry->state_revision != base_revision) entry->deformer->reset();

  core::SolveOptions options;
  options.max_iterations = request.max_iterations;
  options.tolerance = request.tolerance;
  options.lambda = settings_.lambda;
  options.ora = request.ora;
  options.face_scale = face_scale;
  options.rigidity = rigidity;
  // A cold move (the first after SetHandles, a method switch) starts from ARAP (StartFrom::Auto);
  // run to convergence toward far targets that could take seconds at 10^5 vertices, so a move
  // runs at most this many ARAP iterations and background refinement goes on from there. A drag
  // starts near rest, where ARAP converges in a few.
  options.rigid_start_iterations =
      std::min(options.rigid_start_iterations, kMoveRigidStartIterations);
  // commit() measures E_theta / E_phi once; per-iteration tracking would measure the mesh three
  // more times per interactive move (rest, guess, each iteration).
  options.track_metrics = false;
  // The call's stop and the session's close, one token for the solver.
  const CallStop closed_or_stopped(stop, closed_stop_.get_token());
  Result<core::SolveReport> report =
      entry->deformer->solve(targets, options, between_iterations, closed_or_stopped.token());
  if (!report.ok()) {
    if (report.status().code() == ErrorCode::Cancelled) return stopped_status();
    // The deformer may have moved; make sure it restarts cleanly next time.
    entry->state_revision = ~std::uint64_t{0};
    return report.status();
  }
  if (is_closed()) return Error(ErrorCode::NotFound, "session " + id_.value + " was closed");

  // Settled when no refinement will follow.
  const bool settled = options_.refine_budget <= 0 || report->converged;
  Result<DeformResult> committed =
      commit(std::move(report).value(), request.method, rigidity, targets, base_revision,
             base_positions, built, request.editor, /*refinement=*/false, settled, entry, &edit);
  if (!committed.ok()) return committed.status();
  DeformResult result = std::move(committed).value();
  counters_->moves_committed.fetch_add(1);
  last_move_ticks_.store(std::chrono::steady_clock::now().time_since_epoch().count());
  result.history_position = edit.position;
  if (!settled) {
    refine_ = RefineState{request.method,           request.ora, std::move(face_scale),
                          request.tolerance,        options_.refine_budget, rigidity};
  } else {
    refine_.reset();
  }
  return result;
}

Result<DeformResult> Session::commit(core::SolveReport report, core::Method method,
                                     double rigidity, const Positions& targets,
                                     std::uint64_t base_revision,
                                     const std::shared_ptr<const Positions>& base_positions,
                                     bool built, const std::string& editor, bool refinement,
                                     bool settled, DeformerCache::Entry* entry,
                                     const EditState* edit) {
  const int nv = static_cast<int>(rest_.V.rows());
  auto result = std::make_shared<DeformResult>();
  result->method = method;
  result->rigidity = method == core::Method::ScaleAware ? rigidity : 0.0;
  result->positions = std::make_shared<const Positions>(std::move(report.V));
  const Positions& V = *result->positions;
  for (int v = 0; v < nv; ++v) {
    if (V.row(v) != base_positions->row(v)) result->changed.push_back(v);
  }
  result->changed_positions.resize(static_cast<Eigen::Index>(result->changed.size()), 3);
  for (std::size_t j = 0; j < result->changed.size(); ++j)
    result->changed_positions.row(static_cast<Eigen::Index>(j)) = V.row(result->changed[j]);
  const core::AngleErrors errors =
      core::angle_errors(rest_measures_, V, rest_.F, topology_, settings_.threads);
  if (!V.allFinite() || !std::isfinite(errors.e_theta) || !std::isfinite(errors.e_phi)) {
    // Inputs are checked to give finite results; never commit or send NaN if one does not.
    entry->state_revision = ~std::uint64_t{0};
    return Error(ErrorCode::NumericalFailure,
                 "the solve gave non-finite positions; revision " + std::to_string(base_revision) +
                     " unchanged");
  }
  result->e_theta = errors.e_theta;
  result->e_phi = errors.e_phi;
  result->area_log_rms = errors.area_log_rms;
  result->iterations = report.iterations;
  result->converged = report.converged;
  result->solve_seconds = report.seconds;
  result->built_deformer = built;
  result->editor = editor;
  result->refinement = refinement;
  result->settled = settled;
  result->pcg_iterations = report.pcg_iterations;
  result->coarse = std::move(report.coarse);
  counters_->pcg_iterations.fetch_add(static_cast<std::uint64_t>(std::max(report.pcg_iterations, 0)));
  counters_->outer_iterations.fetch_add(static_cast<std::uint64_t>(std::max(report.iterations, 0)));
  counters_->metrics.record_solve(refinement, report.seconds);

  std::vector<std::shared_ptr<Watcher>> watchers;
  std::unique_lock shared_lock(shared_mutex_, std::defer_lock);
  if (shared_ != nullptr) {
    // Acknowledged only once the store took it: a compare-and-set on the stored version, from
    // the lease holder. Refused, nothing changes here and the deformer restarts next time.
    shared_lock.lock();
    if (revision() != base_revision) {
      entry->state_revision = ~std::uint64_t{0};
      return Error(ErrorCode::Aborted, "session " + id_.value.substr(0, 8) +
                                           "... was changed by another replica (revision " +
                                           std::to_string(revision()) + " is current); retry");
    }
    PersistedSession state = persisted_state(/*with_rest=*/false);
    state.revision = base_revision + 1;
    state.positions = *result->positions;
    state.targets = targets;
    state.last_method = method;
    if (edit != nullptr) state.edit = *edit;
    SharedLogEntry logged;
    logged.result = result;
    logged.targets = targets;
    if (edit != nullptr) logged.edit = *edit;
    if (const Status stored = shared_->commit(state, shared_version_, std::move(logged));
        !stored.ok()) {
      entry->state_revision = ~std::uint64_t{0};
      // Losing a race (Aborted) is not a store failure; an error of the store is.
      if (stored.code() != ErrorCode::Aborted) counters_->persist_failures.fetch_add(1);
      log_event(LogLevel::Warn, "shared_commit_refused",
                LogFields().add("session", id_.value).add("message", stored.message()));
      return stored;
    }
    ++shared_version_;
    counters_->persisted_writes.fetch_add(1);
  }
  if (state_dir_ != nullptr) {
    // Durable before it is applied, acknowledged or published; refused, nothing changes here.
    PersistedSession state = persisted_state();
    state.revision = base_revision + 1;
    state.positions = *result->positions;
    state.targets = targets;
    state.last_method = method;
    if (edit != nullptr) state.edit = *edit;
    if (const Status stored = persist_state(state); !stored.ok()) {
      entry->state_revision = ~std::uint64_t{0};  // the deformer holds the refused result
      return stored;
    }
  }
  {
    std::lock_guard lock(state_mutex_);
    if (closed_.load()) {
      entry->state_revision = ~std::uint64_t{0};
      return Error(ErrorCode::NotFound, "session " + id_.value + " was closed");
    }
    result->revision = ++revision_;
    push_history_locked(result);
    targets_ = targets;
    last_method_ = method;
    if (edit != nullptr) {
      edit_ = *edit;
      kept_bytes_.store(kept_positions_bytes(edit_));
    }
    watchers = watchers_;
  }
  entry->state_revision = result->revision;
  // Revisions are committed by one strand task at a time, so publishing outside the lock keeps
  // them in order; a watcher joining in between drops the older one (see Watcher::offer).
  for (const std::shared_ptr<Watcher>& watcher : watchers) watcher->publish(result);
  return DeformResult(*result);
}

DeformerCache::Entry* Session::cached_deformer(core::Method method) {
  std::vector<int> constrained;
  {
    std::lock_guard lock(state_mutex_);
    constrained = constrained_;
  }
  return deformers_->find(method, constrained);
}

std::optional<Session::BackgroundBuild> Session::take_background_build() {
  if (!refine_ || background_build_running_ || is_closed()) return std::nullopt;
  DeformerCache::Entry* entry = cached_deformer(refine_->method);
  if (entry == nullptr || !entry->deformer->needs_background_build()) return std::nullopt;
  core::SolveOptions next;  // what refine() will solve with: its rigidity's setup comes along
  next.rigidity = refine_->rigidity;
  BackgroundBuild build{entry->deformer->background_build(next), refine_->method,
                        entry->deformer.get()};
  if (!build.task) return std::nullopt;
  background_build_running_ = true;
  return build;
}

bool Session::finish_background_build(const BackgroundBuild& build,
                                      Result<core::Deformer::Installer> installer) {
  background_build_running_ = false;
  if (!installer.ok() || is_closed()) {
    // A failed (or stopped) build ends refinement, as a failed refinement solve does: trying
    // again would fail again.
    refine_.reset();
    return false;
  }
  // The deformer it was built for, if the cache still holds it (the installer itself also
  // refuses any other deformer).
  DeformerCache::Entry* entry = cached_deformer(build.method);
  if (entry == nullptr || entry->deformer.get() != build.key) return false;
  (*installer)(*entry->deformer);
  if (entry->deformer->needs_background_build()) return false;
  counters_->background_builds_installed.fetch_add(1);
  return true;
}

Result<std::optional<DeformResult>> Session::refine(
    std::stop_source slice, const core::ProgressCallback& between_iterations) {
  if (!refine_ || is_closed() || !is_fresh()) {
    refine_.reset();
    return std::optional<DeformResult>{};
  }
  // Shared: refinement never waits for another replica's lease; whoever edits there wins.
  if (shared_ != nullptr &&
      !begin_shared_edit(std::chrono::milliseconds(0), slice.get_token()).ok()) {
    refine_.reset();
    return std::optional<DeformResult>{};
  }
  const RefineState state = *refine_;
  std::vector<int> constrained;
  Positions targets;
  std::uint64_t base_revision = 0;
  std::shared_ptr<const Positions> base_positions;
  {
    std::lock_guard lock(state_mutex_);
    constrained = constrained_;
    targets = targets_;
    base_revision = revision_;
    base_positions = history_.back()->positions;
  }
  DeformerCache::Entry* entry = deformers_->find(state.method, constrained);
  // The deformer must still hold the current revision (it is warm-started from it); otherwise
  // something else committed or the cache dropped it, and there is nothing to continue.
  if (entry == nullptr || entry->state_revision != base_revision) {
    refine_.reset();
    return std::optional<DeformResult>{};
  }
  deformers_->touch(*entry);

  {
    std::lock_guard lock(refine_mutex_);
    refine_stop_ = slice;  // preempt_refinement() stops this slice
  }
  if (has_queued_edits()) slice.request_stop();  // an edit is waiting: yield to it

  // Short slices keep a waiting edit's latency to about one outer iteration.
  constexpr int kSliceIterations = 2;
  core::SolveOptions options;
  options.max_iterations = std::min(kSliceIterations, state.remaining);
  options.tolerance = state.tolerance;
  options.lambda = settings_.lambda;
  options.ora = state.ora;
  options.face_scale = state.face_scale;
  options.rigidity = state.rigidity;
  options.track_metrics = false;  // as in move(): commit() measures once
  // A multiresolution deformer's moves ran on its coarse level: refinement is at full resolution.
  options.full_resolution = true;
  const CallStop closed_or_stopped(slice.get_token(), closed_stop_.get_token());
  Result<core::SolveReport> report =
      slice.stop_requested()
          ? Result<core::SolveReport>(Error(ErrorCode::Cancelled, "refinement preempted"))
          : entry->deformer->solve(targets, options, between_iterations,
                                   closed_or_stopped.token());
  {
    std::lock_guard lock(refine_mutex_);
    refine_stop_ = std::stop_source(std::nostopstate);
  }
  if (!report.ok()) {
    if (report.status().code() == ErrorCode::Cancelled) {
      counters_->refinements_preempted.fetch_add(1);
      return report.status();  // state untouched: refinement resumes after the edit if wanted
    }
    entry->state_revision = ~std::uint64_t{0};
    refine_.reset();
    return report.status();
  }
  if (is_closed()) {
    refine_.reset();
    return Error(ErrorCode::NotFound, "session " + id_.value + " was closed");
  }
  const int iterations = report->iterations;
  // The last slice: converged, or the budget ends with it.
  const bool last = report->converged || state.remaining - std::max(iterations, 1) <= 0;
  Result<DeformResult> committed =
      commit(std::move(report).value(), state.method, state.rigidity, targets, base_revision,
             base_positions, /*built=*/false, "refinement", /*refinement=*/true,
             /*settled=*/last, entry, /*edit=*/nullptr);
  if (!committed.ok()) {
    refine_.reset();
    return committed.status();
  }
  DeformResult result = std::move(committed).value();
  counters_->refinements_committed.fetch_add(1);
  refine_->remaining -= std::max(iterations, 1);
  if (last) refine_.reset();
  return std::optional<DeformResult>(std::move(result));
}

void Session::preempt_refinement() {
  std::lock_guard lock(refine_mutex_);
  refine_stop_.request_stop();
}

bool Session::has_queued_edits() {
  std::lock_guard lock(strand_mutex_);
  return !strand_.empty();
}

SessionInfo Session::info() const {
  SessionInfo info;
  info.id = id_;
  info.vertices = static_cast<int>(rest_.V.rows());
  info.faces = static_cast<int>(rest_.F.rows());
  info.boundary_loops = boundary_loops_;
  info.components = topology_.component_count;
  info.bbox_min = rest_.V.colwise().minCoeff().transpose();
  info.bbox_max = rest_.V.colwise().maxCoeff().transpose();
  info.estimated_bytes = estimated_bytes();
  std::lock_guard lock(state_mutex_);
  info.revision = revision_;
  info.groups = groups_;
  info.last_method = last_method_;
  info.edit = edit_;
  // anchors_ rows follow the ascending constrained set; the info lists them group by group.
  std::size_t constrained = 0;
  for (const HandleGroup& g : groups_) constrained += g.vertices.size();
  info.group_anchors.resize(static_cast<Eigen::Index>(constrained), 3);
  Eigen::Index row = 0;
  for (const HandleGroup& g : groups_) {
    for (int v : g.vertices) {
      const auto at = std::lower_bound(constrained_.begin(), constrained_.end(), v);
      info.group_anchors.row(row++) = anchors_.row(at - constrained_.begin());
    }
  }
  info.rigidity = default_rigidity_;
  info.watchers = static_cast<int>(watchers_.size());
  info.cached_deformers = deformers_->size();
  return info;
}

std::uint64_t Session::revision() const {
  std::lock_guard lock(state_mutex_);
  return revision_;
}

Result<std::shared_ptr<const Positions>> Session::positions_at(
    std::optional<std::uint64_t> revision) const {
  if (revision && *revision == 0) return rest_positions_;
  std::lock_guard lock(state_mutex_);
  if (!revision) return history_.back()->positions;
  for (const auto& entry : history_) {
    if (entry->revision == *revision) return entry->positions;
  }
  return Error(ErrorCode::NotFound, "revision " + std::to_string(*revision) +
                                        " is not kept (kept: 0 and " +
                                        std::to_string(history_.front()->revision) + ".." +
                                        std::to_string(history_.back()->revision) + ")");
}

std::shared_ptr<const DeformResult> Session::snapshot_locked() const { return history_.back(); }

void Session::push_history_locked(std::shared_ptr<const DeformResult> result) {
  // Responses and watchers encode the newest revision; an older one's bytes are rarely wanted
  // again (a lagging watcher skips to the newest), and at 10^5 vertices they are megabytes.
  if (!history_.empty()) history_.back()->encoded->clear();
  history_.push_back(std::move(result));
  while (static_cast<int>(history_.size()) > options_.kept_revisions) history_.pop_front();
}

std::shared_ptr<Watcher> Session::add_watcher() {
  auto watcher = std::make_shared<Watcher>();
  watcher->set_owner(weak_from_this());
  std::lock_guard lock(state_mutex_);
  watcher->publish_snapshot(snapshot_locked());
  if (closed_.load()) {
    watcher->close();
  } else {
    watchers_.push_back(watcher);
  }
  return watcher;
}

void Session::remove_watcher(const Watcher* watcher) {
  std::lock_guard lock(state_mutex_);
  std::erase_if(watchers_, [watcher](const auto& w) { return w.get() == watcher; });
}

int Session::watcher_count() const {
  std::lock_guard lock(state_mutex_);
  return static_cast<int>(watchers_.size());
}

void Session::close(Status reason) {
  {
    // After this no write of this copy reaches the state directory (persist_state checks the
    // flag under the same lock), and one in progress has finished.
    const std::lock_guard lock(stamp_mutex_);
    closed_.store(true);
  }
  std::vector<std::shared_ptr<Watcher>> watchers;
  {
    std::lock_guard lock(state_mutex_);
    watchers.swap(watchers_);
  }
  closed_stop_.request_stop();  // a running solve, precompute or background build stops
  for (const auto& watcher : watchers) watcher->close(reason);
}

void Session::close_watchers(Status reason) {
  std::vector<std::shared_ptr<Watcher>> watchers;
  {
    std::lock_guard lock(state_mutex_);
    watchers.swap(watchers_);
  }
  for (const auto& watcher : watchers) watcher->close(reason);
}

std::chrono::steady_clock::time_point Session::last_used() const {
  std::lock_guard lock(state_mutex_);
  return last_used_;
}

void Session::touch(std::chrono::steady_clock::time_point now) {
  std::lock_guard lock(state_mutex_);
  last_used_ = std::max(last_used_, now);
}

std::optional<Session::StrandStep> Session::enqueue(std::function<void()> task, StrandStep step) {
  std::lock_guard lock(strand_mutex_);
  strand_.push_back({std::move(task), step});
  if (strand_running_) return std::nullopt;
  strand_running_ = true;
  return step;
}

std::optional<Session::StrandStep> Session::run_next() {
  std::function<void()> task;
  {
    std::lock_guard lock(strand_mutex_);
    if (strand_.empty()) {
      strand_running_ = false;
      return std::nullopt;
    }
    task = std::move(strand_.front().task);
    strand_.pop_front();
  }
  task();
  std::lock_guard lock(strand_mutex_);
  if (strand_.empty()) {
    strand_running_ = false;
    return std::nullopt;
  }
  return strand_.front().step;
}

// --- Shared store (issue 16) ----------------------------------------------------------------------

void Session::set_shared_store(SharedStateStore* store, std::uint64_t version) {
  const std::lock_guard lock(shared_mutex_);
  shared_ = store;
  shared_version_ = version;
}

Status Session::sync_shared() {
  if (shared_ == nullptr) return Status::success();
  const std::lock_guard lock(shared_mutex_);
  return sync_shared_locked();
}

void Session::end_shared_edit() {
  if (shared_ != nullptr) shared_->release_lease(id_);
}

Status Session::begin_shared_edit(std::chrono::milliseconds wait, std::stop_token stop) {
  MD_RETURN_IF_ERROR(shared_->acquire_lease(id_, wait, std::move(stop)));
  return sync_shared();
}

Status Session::sync_shared_locked() {
  if (is_closed()) return Error(ErrorCode::NotFound, "session " + id_.value + " is closed");
  MD_ASSIGN_OR_RETURN(const std::optional<std::uint64_t> stored, shared_->version(id_));
  if (!stored) {
    close();
    return Error(ErrorCode::NotFound,
                 "session " + id_.value.substr(0, 8) + "... was closed or expired");
  }
  if (*stored == shared_version_) return Status::success();
  if (*stored > shared_version_) {
    // Replay the log in version order; a bounded number of rounds, then load the whole state.
    constexpr int kBatch = 128, kRounds = 8;
    for (int round = 0; round < kRounds && shared_version_ < *stored; ++round) {
      MD_ASSIGN_OR_RETURN(std::vector<SharedLogEntry> entries,
                          shared_->read_log(id_, shared_version_, kBatch));
      if (entries.empty()) break;
      for (const SharedLogEntry& logged : entries) {
        if (logged.version <= shared_version_) continue;
        // A handle change, a trimmed gap or an entry that does not fit: load the whole state.
        if (logged.version != shared_version_ + 1 || !logged.result ||
            !apply_shared_locked(logged)) {
          return reload_shared_locked();
        }
      }
    }
    if (shared_version_ >= *stored) return Status::success();
  } else {
    // The store went back (Redis lost acknowledged writes: see docs/scale-out.md on appendfsync).
    log_event(LogLevel::Error, "shared_state_went_back",
              LogFields().add("session", id_.value).add("held_version", shared_version_)
                  .add("stored_version", *stored));
  }
  return reload_shared_locked();
}

bool Session::apply_shared_locked(const SharedLogEntry& logged) {
  const int nv = static_cast<int>(rest_.V.rows());
  const Positions& V = *logged.result->positions;
  std::shared_ptr<const Positions> previous;
  {
    std::lock_guard lock(state_mutex_);
    if (V.rows() != nv || logged.targets.rows() != targets_.rows() ||
        logged.revision != revision_ + 1) {
      return false;
    }
    if (logged.edit) {
      for (const EditStep& step : logged.edit->steps) {
        for (const GroupMove& m : step.moves) {
          if (m.group >= static_cast<int>(groups_.size())) return false;
        }
      }
    }
    previous = history_.back()->positions;
  }
  auto result = std::make_shared<DeformResult>(*logged.result);
  result->encoded = std::make_shared<BytesMemo>();  // its changed lists are recomputed here
  result->changed.clear();
  for (int v = 0; v < nv; ++v) {
    if (V.row(v) != previous->row(v)) result->changed.push_back(v);
  }
  result->changed_positions.resize(static_cast<Eigen::Index>(result->changed.size()), 3);
  for (std::size_t j = 0; j < result->changed.size(); ++j)
    result->changed_positions.row(static_cast<Eigen::Index>(j)) = V.row(result->changed[j]);
  std::vector<std::shared_ptr<Watcher>> watchers;
  {
    std::lock_guard lock(state_mutex_);
    revision_ = logged.revision;
    push_history_locked(result);
    targets_ = logged.targets;
    last_method_ = result->method;
    if (logged.edit) {
      edit_ = *logged.edit;
      kept_bytes_.store(kept_positions_bytes(edit_));
    }
    watchers = watchers_;
  }
  shared_version_ = logged.version;
  for (const std::shared_ptr<Watcher>& watcher : watchers) watcher->publish(result);
  return true;
}

Status Session::reload_shared_locked() {
  Result<SharedState> loaded = shared_->load(id_);
  if (!loaded.ok()) {
    if (loaded.status().code() == ErrorCode::NotFound) close();
    return loaded.status();
  }
  PersistedSession& state = loaded->state;
  const int nv = static_cast<int>(rest_.V.rows());
  if (state.rest.V.rows() != rest_.V.rows() || state.rest.F.rows() != rest_.F.rows() ||
      state.positions.rows() != nv) {
    return Error(ErrorCode::Internal, "stored state of session " + id_.value.substr(0, 8) +
                                          "... does not match its mesh");
  }
  std::vector<int> group_of(static_cast<std::size_t>(nv), -1);
  std::vector<int> constrained;
  for (std::size_t g = 0; g < state.groups.size(); ++g) {
    for (int v : state.groups[g].vertices) {
      if (v < 0 || v >= nv || group_of[static_cast<std::size_t>(v)] >= 0) {
        return Error(ErrorCode::Internal, "stored handle groups of session " +
                                              id_.value.substr(0, 8) + "... are invalid");
      }
      group_of[static_cast<std::size_t>(v)] = static_cast<int>(g);
      constrained.push_back(v);
    }
  }
  std::sort(constrained.begin(), constrained.end());
  if (state.anchors.rows() != static_cast<Eigen::Index>(constrained.size()) ||
      state.targets.rows() != state.anchors.rows()) {
    return Error(ErrorCode::Internal, "stored handles of session " + id_.value.substr(0, 8) +
                                          "... do not match its groups");
  }
  auto current = std::make_shared<DeformResult>();
  current->revision = state.revision;
  current->positions = std::make_shared<const Positions>(std::move(state.positions));
  current->changed_positions.resize(0, 3);
  if (state.last_method) current->method = *state.last_method;
  std::vector<std::shared_ptr<Watcher>> watchers;
  bool new_revision = false;
  {
    std::lock_guard lock(state_mutex_);
    groups_ = std::move(state.groups);
    constrained_ = std::move(constrained);
    anchors_ = std::move(state.anchors);
    targets_ = std::move(state.targets);
    vertex_group_ = std::move(group_of);
    last_method_ = state.last_method;
    edit_ = std::move(state.edit);
    if (state.revision != revision_ || *current->positions != *history_.back()->positions) {
      new_revision = state.revision > revision_;
      if (state.revision <= revision_) history_.clear();  // went back: older copies are void
      revision_ = state.revision;
      push_history_locked(current);
    }
    watchers = watchers_;
  }
  shared_version_ = loaded->version;
  // The revisions in between are gone from the log: watchers get the newest as a snapshot.
  if (new_revision) {
    for (const std::shared_ptr<Watcher>& watcher : watchers) watcher->publish_snapshot(current);
  }
  return Status::success();
}

}  // namespace meshdeform::service
