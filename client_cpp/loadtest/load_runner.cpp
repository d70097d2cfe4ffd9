#include "client_cpp/loadtest/load_runner.h"

#include <grpcpp/create_channel.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/security/credentials.h>
#include <grpcpp/support/channel_arguments.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cctype>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <cstdlib>
#include <ctime>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "client_cpp/loadtest/scripted_drag.h"
#include "codec/update_codec.h"
#include "linkemu/link_emulator.h"
#include "meshdeform/v1/deformation.grpc.pb.h"
#include "proto/wire/delta_mapping.h"
#include "proto/wire/wire_mapping.h"

namespace meshdeform::loadtest {
namespace {

v1::PositionEncoding encoding_to_proto(Encoding encoding) {
  switch (encoding) {
    case Encoding::Float32:
      return v1::POSITION_ENCODING_FLOAT32;
    case Encoding::Meshopt:
      return v1::POSITION_ENCODING_MESHOPT;
    case Encoding::Doubles:
      break;
  }
  return v1::POSITION_ENCODING_UNSPECIFIED;
}

using Clock = std::chrono::steady_clock;

// After --duration, moves still in flight get this long (their deadline is capped to it).
constexpr auto kDrain = std::chrono::seconds(5);
// Deadline of GetServerStats and CloseSession.
constexpr auto kShortCallDeadline = std::chrono::seconds(5);
// Deadlines of CreateSession (parsing an upload) and SetHandles (a factorization); both are
// also capped by the end of the run.
constexpr auto kSetupCallDeadline = std::chrono::seconds(60);
// How long a session waits for its watchers' join snapshots before starting to move.
constexpr auto kWatchJoinWait = std::chrono::seconds(10);
// After CloseSession, how long the watch streams get to end by themselves before cancellation.
constexpr auto kWatcherEndWait = std::chrono::seconds(5);
// Watch streams never outlive the run by more than this (a backstop; they are cancelled first).
constexpr auto kWatchBackstop = std::chrono::seconds(30);
// Bounds the per-watcher arrival log used for propagation delays (counts continue past it).
constexpr std::size_t kMaxSeenPerWatcher = 250'000;
// Bounds the per-session latency samples (a very fast laplacian run at rate 0 stays far below).
constexpr std::size_t kMaxSamplesPerSession = 1'000'000;
// Move parameterisation at rate 0: move i is the drag at i / kNominalRateHz seconds.
constexpr double kNominalRateHz = 10.0;
// Uploads without suggested groups: fixed / handle = lowest / highest slab of this fraction.
constexpr double kSlabFraction = 0.05;
// Stored error messages are cut to this length.
constexpr std::size_t kMaxMessageChars = 300;

double ms_between(Clock::time_point from, Clock::time_point to) {
  return std::chrono::duration<double, std::milli>(to - from).count();
}

double seconds_between(Clock::time_point from, Clock::time_point to) {
  return std::chrono::duration<double>(to - from).count();
}

/// "DEADLINE_EXCEEDED"; "CODE_<n>" for a value without a name (the wire mapping's table).
std::string code_name(grpc::StatusCode code) {
  return wire::grpc_code_label(static_cast<int>(code));
}

std::string truncated(std::string text) {
  if (text.size() > kMaxMessageChars) {
    text.resize(kMaxMessageChars);
    text += "...";
  }
  return text;
}

// Sets a steady-clock deadline on a call (gRPC takes system-clock time points).
void set_deadline(grpc::ClientContext& context, Clock::time_point deadline) {
  const auto remaining = std::max(Clock::duration::zero(), deadline - Clock::now());
  context.set_deadline(std::chrono::system_clock::now() +
                       std::chrono::duration_cast<std::chrono::system_clock::duration>(remaining));
}

std::string read_first_line(const char* path, const std::string& prefix) {
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line)) {
    if (prefix.empty() || line.rfind(prefix, 0) == 0) return line;
  }
  return {};
}

std::string load_average() {
  std::istringstream in(read_first_line("/proc/loadavg", ""));
  std::string one, five, fifteen;
  if (!(in >> one >> five >> fifteen)) return "unknown";
  return one + " " + five + " " + fifteen;
}

MachineFacts collect_machine_facts() {
  MachineFacts facts;
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char date[32];
  std::strftime(date, sizeof date, "%Y-%m-%dT%H:%M:%SZ", &utc);
  facts.date_utc = date;
  facts.hardware_threads = static_cast<int>(sysconf(_SC_NPROCESSORS_ONLN));
  std::string model = read_first_line("/proc/cpuinfo", "model name");
  if (const std::size_t colon = model.find(':'); colon != std::string::npos) {
    model = model.substr(colon + 1);
    model.erase(0, model.find_first_not_of(" \t"));
    if (!model.empty()) facts.cpu_model = model;
  }
  facts.load_average_start = load_average();
#ifdef MESHDEFORM_LOADTEST_BUILD_TYPE
  if (const std::string build_type = MESHDEFORM_LOADTEST_BUILD_TYPE; !build_type.empty()) {
    facts.build_type = build_type;
  }
#endif
  return facts;
}

// The arrival of one update at a watcher.
struct Seen {
  std::uint64_t revision = 0;
  Clock::time_point at;
  bool is_refinement = false;
};

struct WatcherState {
  std::unique_ptr<grpc::ClientContext> context = std::make_unique<grpc::ClientContext>();
  std::thread thread;
  WatcherResult result;
  std::vector<Seen> seen;
};

struct SessionState {
  SessionResult result;
  v1::DeformationService::Stub* stub = nullptr;
  std::string session_id;
  std::string edit_token;
  std::string view_token;
  std::array<double, 3> bbox_min{};
  std::array<double, 3> bbox_max{};
  std::uint32_t handle_group = 1;
  // Own revisions (written by the mover only): when the move was sent and when it returned.
  std::map<std::uint64_t, std::pair<Clock::time_point, Clock::time_point>> move_times;
  // The newest own revision and its response, whatever the sample cap (mover only).
  std::uint64_t last_own_revision = 0;
  Clock::time_point last_own_response;

  std::mutex mutex;  //< guards the counters below
  std::condition_variable changed;
  int watchers_joined = 0;    //< got the join snapshot or ended
  int watchers_finished = 0;  //< stream ended
  // The newest converged revision any watcher received, and when it first arrived.
  std::uint64_t converged_revision = 0;
  Clock::time_point converged_at;
  // The same for settled revisions, and whether that update was lossless.
  std::uint64_t settled_revision = 0;
  Clock::time_point settled_at;
  bool settled_lossless = false;
  std::vector<std::unique_ptr<WatcherState>> watchers;
};

class LoadRun {
 public:
  LoadRun(const Options& options, const MeshUpload& upload) : options_(options), upload_(upload) {}

  RunResult run();

 private:
  void run_session(SessionState& session);
  bool set_up(SessionState& session);
  bool pick_groups_from_snapshot(SessionState& session, v1::SetHandlesRequest& request);
  void start_watchers(SessionState& session);
  void run_watcher(SessionState& session, WatcherState& watcher);
  void drive(SessionState& session);
  // --settle-seconds: waits for a converged revision at or past the last own move.
  void settle(SessionState& session);
  // Sends one move aimed at the drag pose at `drag_seconds`; blocks until it returns.
  void send_move(SessionState& session, const ScriptedDrag& drag, double drag_seconds);
  void close_session(SessionState& session);
  void finish_watchers(SessionState& session);
  ServerStatsSample fetch_stats();
  void note_setup_failure(SessionState& session, const std::string& call,
                          const grpc::Status& status);

  const Options& options_;
  const MeshUpload& upload_;
  std::vector<std::shared_ptr<grpc::Channel>> channels_;
  std::vector<std::unique_ptr<v1::DeformationService::Stub>> stubs_;
  Clock::time_point start_;
  Clock::time_point run_end_;   //< start + duration: no move is sent after it
  Clock::time_point hard_end_;  //< run_end + drain + settle + backstop: no call outlives it
  Clock::time_point settle_end_;  //< run_end + drain + settle: every settle wait ends by then
  Clock::time_point last_drive_end_;  //< guarded by phase_mutex_: when the last drag ended

  std::mutex phase_mutex_;
  std::condition_variable phase_changed_;
  int setups_done_ = 0;
  int drives_done_ = 0;
  bool is_go_ = false;
  bool is_close_ = false;
  Clock::time_point go_time_;
};

ServerStatsSample LoadRun::fetch_stats() {
  ServerStatsSample sample;
  grpc::ClientContext context;
  set_deadline(context, Clock::now() + kShortCallDeadline);
  v1::GetServerStatsResponse response;
  const grpc::Status status =
      stubs_.front()->GetServerStats(&context, v1::GetServerStatsRequest{}, &response);
  sample.status = code_name(status.error_code());
  if (!status.ok()) {
    // UNIMPLEMENTED (an older server) means "unknown", not a failed run.
    sample.message = truncated(status.error_message());
    return sample;
  }
  sample.is_available = true;
  sample.sessions = response.sessions();
  sample.estimated_bytes = response.estimated_bytes();
  sample.resident_bytes = response.resident_bytes();
  sample.moves_committed = response.moves_committed();
  sample.moves_cancelled = response.moves_cancelled();
  sample.refinements_committed = response.refinements_committed();
  sample.deformer_constructions = response.deformer_constructions();
  sample.evicted_lru = response.evicted_lru();
  sample.evicted_idle = response.evicted_idle();
  sample.workers = response.workers();
  sample.uptime_seconds = response.uptime_seconds();
  return sample;
}

void LoadRun::note_setup_failure(SessionState& session, const std::string& call,
                                 const grpc::Status& status) {
  session.result.setup_status = call + ": " + code_name(status.error_code());
  session.result.setup_error = truncated(status.error_message());
}

// Runs one setup call, retrying while the server refuses it as RESOURCE_EXHAUSTED (heavy-work
// admission or a rate limit: N sessions set up at once are a burst of uploads and precomputes),
// waiting as the retry-after-ms trailer says (else 50 ms, doubling to 1 s), until the deadline.
template <typename Call>
grpc::Status call_with_retry(Clock::time_point deadline, Call&& call) {
  std::chrono::milliseconds backoff(50);
  while (true) {
    grpc::ClientContext context;
    set_deadline(context, deadline);
    grpc::Status status = call(context);
    if (status.error_code() != grpc::StatusCode::RESOURCE_EXHAUSTED) return status;
    std::chrono::milliseconds wait = backoff;
    const auto& trailers = context.GetServerTrailingMetadata();
    if (const auto it = trailers.find("retry-after-ms"); it != trailers.end()) {
      wait = std::chrono::milliseconds(std::atoll(std::string(it->second.data(), it->second.size()).c_str()));
    }
    wait = std::clamp(wait, std::chrono::milliseconds(10), std::chrono::milliseconds(1000));
    if (Clock::now() + wait >= deadline) return status;
    std::this_thread::sleep_for(wait);
    backoff = std::min(backoff * 2, std::chrono::milliseconds(1000));
  }
}

bool LoadRun::set_up(SessionState& session) {
  SessionResult& result = session.result;
  const Clock::time_point setup_deadline = std::min(Clock::now() + kSetupCallDeadline, run_end_);

  v1::CreateSessionRequest create;
  if (options_.mesh_path.empty()) {
    create.set_sample(options_.sample);
  } else {
    create.set_mesh_bytes(upload_.bytes);
    create.set_format(static_cast<v1::MeshFormat>(upload_.format));
  }
  v1::CreateSessionResponse created;
  {
    const Clock::time_point sent = Clock::now();
    const grpc::Status status = call_with_retry(setup_deadline, [&](grpc::ClientContext& context) {
      return session.stub->CreateSession(&context, create, &created);
    });
    result.create_ms = ms_between(sent, Clock::now());
    if (!status.ok()) {
      note_setup_failure(session, "CreateSession", status);
      return false;
    }
  }
  session.session_id = created.session_id();
  session.edit_token = created.edit_token();
  session.view_token = created.view_token();
  result.vertices = created.info().vertices();
  result.faces = created.info().faces();
  session.bbox_min = {created.info().bbox_min().x(), created.info().bbox_min().y(),
                      created.info().bbox_min().z()};
  session.bbox_max = {created.info().bbox_max().x(), created.info().bbox_max().y(),
                      created.info().bbox_max().z()};

  v1::SetHandlesRequest set_handles;
  set_handles.set_session_id(session.session_id);
  set_handles.set_token(session.edit_token);
  set_handles.set_prepare(wire::method_to_proto(options_.method));
  if (created.suggested_groups_size() > 0) {
    *set_handles.mutable_groups() = created.suggested_groups();
  } else if (!pick_groups_from_snapshot(session, set_handles)) {
    return false;
  }
  bool has_handle = false;
  for (int g = 0; g < set_handles.groups_size(); ++g) {
    const v1::HandleGroup& group = set_handles.groups(g);
    if (group.role() == v1::HANDLE_ROLE_FIXED) result.fixed_vertices += group.vertices_size();
    if (group.role() == v1::HANDLE_ROLE_HANDLE) {
      result.handle_vertices += group.vertices_size();
      if (!has_handle) session.handle_group = static_cast<std::uint32_t>(g);
      has_handle = true;
    }
  }
  if (!has_handle) {
    result.setup_status = "SetHandles: no HANDLE group";
    result.setup_error = "the suggested groups contain no HANDLE group to drag";
    return false;
  }
  {
    v1::SetHandlesResponse response;
    const Clock::time_point sent = Clock::now();
    const grpc::Status status = call_with_retry(setup_deadline, [&](grpc::ClientContext& context) {
      context.AddMetadata("x-session-id", session.session_id);
      return session.stub->SetHandles(&context, set_handles, &response);
    });
    result.set_handles_ms = ms_between(sent, Clock::now());
    if (!status.ok()) {
      note_setup_failure(session, "SetHandles", status);
      return false;
    }
    result.last_revision = response.info().revision();
  }
  result.is_set_up = true;
  result.setup_status = "OK";
  return true;
}

// An uploaded mesh has no suggested groups: take the rest positions from a watch's join
// snapshot (doubles, the cleaned mesh's indices) and use the lowest / highest slab along the
// longest bounding-box axis as the fixed / handle group.
bool LoadRun::pick_groups_from_snapshot(SessionState& session, v1::SetHandlesRequest& request) {
  grpc::ClientContext context;
  context.AddMetadata("x-session-id", session.session_id);
  set_deadline(context, std::min(Clock::now() + kSetupCallDeadline, run_end_));
  v1::WatchRequest watch;
  watch.set_session_id(session.session_id);
  watch.set_token(session.view_token);
  std::unique_ptr<grpc::ClientReader<v1::DeformUpdate>> reader =
      session.stub->Watch(&context, watch);
  v1::DeformUpdate update;
  const bool has_update = reader->Read(&update);
  context.TryCancel();  // only the snapshot is needed
  const grpc::Status status = reader->Finish();
  if (!has_update) {
    note_setup_failure(session, "Watch (rest positions)", status);
    return false;
  }
  const auto& positions = update.result().positions();
  int axis = 0;
  for (int k = 1; k < 3; ++k) {
    if (session.bbox_max[k] - session.bbox_min[k] >
        session.bbox_max[axis] - session.bbox_min[axis]) {
      axis = k;
    }
  }
  const double low = session.bbox_min[axis];
  const double high = session.bbox_max[axis];
  const double slab = kSlabFraction * (high - low);
  v1::HandleGroup* fixed = request.add_groups();
  fixed->set_role(v1::HANDLE_ROLE_FIXED);
  v1::HandleGroup* handle = request.add_groups();
  handle->set_role(v1::HANDLE_ROLE_HANDLE);
  const int vertex_count = positions.size() / 3;
  for (int v = 0; v < vertex_count; ++v) {
    const double coordinate = positions[3 * v + axis];
    if (coordinate <= low + slab) {
      fixed->add_vertices(static_cast<std::uint32_t>(v));
    } else if (coordinate >= high - slab) {
      handle->add_vertices(static_cast<std::uint32_t>(v));
    }
  }
  if (fixed->vertices_size() == 0 || handle->vertices_size() == 0) {
    session.result.setup_status = "SetHandles: no groups";
    session.result.setup_error = "the uploaded mesh has no vertices in its lowest or highest slab";
    return false;
  }
  return true;
}

void LoadRun::start_watchers(SessionState& session) {
  for (int w = 0; w < options_.watchers; ++w) {
    auto watcher = std::make_unique<WatcherState>();
    watcher->result.index = w;
    watcher->context->AddMetadata("x-session-id", session.session_id);
    set_deadline(*watcher->context, hard_end_);
    WatcherState& raw = *watcher;
    session.watchers.push_back(std::move(watcher));
    raw.thread = std::thread([this, &session, &raw] { run_watcher(session, raw); });
  }
  // Move only once every watcher holds its join snapshot, so that each sees every revision.
  std::unique_lock lock(session.mutex);
  session.changed.wait_until(lock, std::min(Clock::now() + kWatchJoinWait, run_end_),
                             [&] { return session.watchers_joined == options_.watchers; });
}

void LoadRun::run_watcher(SessionState& session, WatcherState& watcher) {
  WatcherResult& result = watcher.result;
  bool has_joined = false;
  const auto mark_joined = [&] {
    if (has_joined) return;
    has_joined = true;
    const std::lock_guard lock(session.mutex);
    ++session.watchers_joined;
    session.changed.notify_all();
  };
  try {
    v1::WatchRequest request;
    request.set_session_id(session.session_id);
    request.set_token(session.view_token);  // a viewer, as in a shared editing session
    request.set_encoding(encoding_to_proto(options_.encoding));
    if (options_.updates != Updates::Off) {
      v1::UpdateOptions* updates = request.mutable_updates();
      updates->set_mode(options_.updates == Updates::Lossless ? v1::DELTA_MODE_LOSSLESS
                                                              : v1::DELTA_MODE_QUANTIZED);
      updates->set_tolerance(options_.tolerance);
      updates->set_relative_tolerance(options_.relative_tolerance);
      updates->set_max_update_bytes(options_.max_update_bytes);
      updates->set_lossless_settled(options_.lossless_settled);
    }
    request.set_coarse_preview(options_.coarse_preview);
    codec::StreamDecoder decoder;
    std::uint64_t coarse_key = 0;  // the level whose mesh this stream has received
    const Clock::time_point started = Clock::now();
    std::unique_ptr<grpc::ClientReader<v1::DeformUpdate>> reader =
        session.stub->Watch(watcher.context.get(), request);
    v1::DeformUpdate update;
    while (reader->Read(&update)) {
      const v1::DeformResult& deform = update.result();
      if (update.has_delta()) {
        // A link-sized update counts as arrived once it is applied (what a viewer shows).
        const Clock::time_point decode_start = Clock::now();
        const Result<codec::UpdateHeader> header =
            wire::delta_header_from_proto(update.delta(), deform.revision());
        const Status applied =
            header.ok() ? decoder.apply(*header, update.delta().payload()) : header.status();
        if (!applied.ok()) {
          ++result.decode_failures;
          result.end_message = truncated(applied.message());
          watcher.context->TryCancel();
          break;
        }
        if (update.delta().mode() == v1::DELTA_MODE_LOSSLESS) ++result.lossless_updates;
        if (result.updates > 0) {
          result.decode_ms.push_back(ms_between(decode_start, Clock::now()));
          result.update_bytes.push_back(static_cast<double>(update.ByteSizeLong()));
          result.max_error.push_back(update.delta().max_error());
          if (update.continuation()) {
            ++result.continuations;
          } else {
            ++result.revision_updates;
          }
          if (update.delta().pending_vertices() == 0) ++result.complete_updates;
        } else {
          result.join_bytes = static_cast<double>(update.ByteSizeLong());
        }
      }
      if (update.has_coarse()) {
        const v1::CoarseLevel& coarse = update.coarse();
        ++result.coarse_updates;
        result.coarse_bytes.push_back(static_cast<double>(coarse.ByteSizeLong()));
        const bool has_mesh = coarse.triangles_size() > 0 &&
                              coarse.to_fine_size() == static_cast<int>(coarse.vertex_count());
        if (coarse.positions().size() != 12 * static_cast<std::size_t>(coarse.vertex_count()) ||
            (coarse.key() != coarse_key && !has_mesh)) {
          ++result.coarse_malformed;
        }
        if (has_mesh) coarse_key = coarse.key();
      }
      const Clock::time_point at = Clock::now();
      if (result.updates == 0) {
        result.has_join_snapshot = update.is_snapshot();
        result.join_ms = ms_between(started, at);
      }
      ++result.updates;
      if (update.is_snapshot()) {
        ++result.snapshots;
      } else {
        ++result.deltas;
        result.delta_bytes += update.ByteSizeLong();
      }
      if (deform.refinement()) ++result.refinements;
      result.skipped_revisions += static_cast<std::int64_t>(update.skipped_revisions());
      if (deform.revision() >= result.last_revision) {
        result.last_e_theta = deform.e_theta();
        result.last_e_phi = deform.e_phi();
      }
      result.last_revision = deform.revision();
      if (watcher.seen.size() < kMaxSeenPerWatcher) {
        watcher.seen.push_back(Seen{deform.revision(), at, deform.refinement()});
      }
      if (deform.settled() || deform.converged()) {
        // Both under one lock: settle() must not see a converged revision as settled only.
        const std::lock_guard lock(session.mutex);
        if (deform.settled() && deform.revision() > session.settled_revision) {
          session.settled_revision = deform.revision();
          session.settled_at = at;
          session.settled_lossless =
              update.has_delta() && update.delta().mode() == v1::DELTA_MODE_LOSSLESS;
        }
        if (deform.converged() && deform.revision() > session.converged_revision) {
          session.converged_revision = deform.revision();
          session.converged_at = at;
        }
        session.changed.notify_all();
      }
      mark_joined();
    }
    const grpc::Status status = reader->Finish();
    result.end_status = result.decode_failures > 0 ? "DECODE_FAILED" : code_name(status.error_code());
    if (result.decode_failures == 0) result.end_message = truncated(status.error_message());
  } catch (const std::exception& e) {
    result.end_status = "CLIENT_EXCEPTION";
    result.end_message = truncated(e.what());
  }
  mark_joined();
  const std::lock_guard lock(session.mutex);
  ++session.watchers_finished;
  session.changed.notify_all();
}

void LoadRun::send_move(SessionState& session, const ScriptedDrag& drag, double drag_seconds) {
  SessionResult& result = session.result;
  const DragPose pose = drag.pose_at(drag_seconds);
  v1::MoveHandlesRequest request;
  request.set_session_id(session.session_id);
  request.set_token(session.edit_token);
  request.set_method(wire::method_to_proto(options_.method));
  request.set_max_iterations(static_cast<std::uint32_t>(options_.iterations));
  request.set_encoding(encoding_to_proto(options_.encoding));
  // Link-sized updates: the editor's geometry comes from its watch stream, the response carries
  // only the result's figures.
  request.set_omit_positions(options_.updates != Updates::Off);
  request.set_editor("loadtest-" + std::to_string(result.index));
  v1::GroupMove* move = request.add_moves();
  move->set_group(session.handle_group);
  move->mutable_translation()->set_x(pose.translation[0]);
  move->mutable_translation()->set_y(pose.translation[1]);
  move->mutable_translation()->set_z(pose.translation[2]);
  move->mutable_rotation()->set_w(pose.rotation[0]);
  move->mutable_rotation()->set_x(pose.rotation[1]);
  move->mutable_rotation()->set_y(pose.rotation[2]);
  move->mutable_rotation()->set_z(pose.rotation[3]);

  grpc::ClientContext context;
  context.AddMetadata("x-session-id", session.session_id);
  const Clock::time_point sent = Clock::now();
  set_deadline(context, std::min(sent + std::chrono::milliseconds(options_.move_deadline_ms),
                                 run_end_ + kDrain));
  v1::MoveHandlesResponse response;
  ++result.moves_sent;
  const grpc::Status status = session.stub->MoveHandles(&context, request, &response);
  const Clock::time_point returned = Clock::now();
  if (!status.ok()) {
    const std::string code = code_name(status.error_code());
    ++result.errors_by_code[code];
    result.first_error.try_emplace(code, truncated(status.error_message()));
    return;
  }
  ++result.moves_ok;
  result.response_bytes += response.ByteSizeLong();
  const v1::DeformResult& deform = response.result();
  if (result.latencies_ms.size() < kMaxSamplesPerSession) {
    result.latencies_ms.push_back(ms_between(sent, returned));
    result.solve_ms.push_back(1000.0 * deform.solve_seconds());
    result.queue_ms.push_back(1000.0 * deform.queue_seconds());
  }
  result.iterations += deform.iterations();
  if (deform.converged()) ++result.converged;
  if (deform.built_deformer()) ++result.built_deformer;
  if (deform.revision() > result.last_revision + 1) {
    result.revision_gaps += static_cast<std::int64_t>(deform.revision() - result.last_revision - 1);
  }
  result.last_revision = std::max(result.last_revision, deform.revision());
  if (session.move_times.size() < kMaxSamplesPerSession) {
    session.move_times.emplace(deform.revision(), std::make_pair(sent, returned));
  }
  if (deform.revision() >= session.last_own_revision) {
    session.last_own_revision = deform.revision();
    session.last_own_response = returned;
  }
}

// The scripted drag. At a rate, ticks come every 1/rate s (staggered per session); one move is
// in flight at a time; a tick that comes while a move is in flight is skipped (newest target
// wins), and the next move goes at the first tick after the response. At rate 0 the moves go
// back to back.
void LoadRun::drive(SessionState& session) {
  SessionResult& result = session.result;
  const int count = options_.sessions;
  const ScriptedDrag drag(session.bbox_min, session.bbox_max,
                          static_cast<double>(result.index) / std::max(count, 1));
  const auto has_budget = [&] { return options_.moves == 0 || result.moves_sent < options_.moves; };
  if (options_.rate_hz <= 0.0) {
    while (has_budget() && Clock::now() < run_end_) {
      send_move(session, drag, static_cast<double>(result.moves_sent) / kNominalRateHz);
    }
    return;
  }
  const double period_s = 1.0 / options_.rate_hz;
  const auto period =
      std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(period_s));
  // Stagger the sessions over one period so that their ticks do not all land together.
  const Clock::time_point first_tick =
      go_time_ + std::chrono::duration_cast<Clock::duration>(
                     std::chrono::duration<double>(period_s * result.index / std::max(count, 1)));
  const auto tick_time = [&](std::int64_t k) { return first_tick + k * period; };
  std::int64_t tick = 0;
  while (has_budget() && tick_time(tick) < run_end_) {
    std::this_thread::sleep_until(tick_time(tick));
    ++result.ticks;
    send_move(session, drag, seconds_between(first_tick, tick_time(tick)));
    // The first tick at or after the response; the ones before it came while the move was in
    // flight and are skipped (only those before the end of the run count).
    Clock::time_point now = Clock::now();
    std::int64_t next = tick + 1;
    if (tick_time(next) < now) {
      next = std::max(next, static_cast<std::int64_t>((now - first_tick) / period));
      while (tick_time(next) < now) ++next;
    }
    for (std::int64_t k = tick + 1; k < next; ++k) {
      if (tick_time(k) >= run_end_) break;
      ++result.ticks;
      ++result.skipped_ticks;
    }
    // --send-on-response: a tick that came while the move was in flight is not lost: its
    // newest target goes at once (as the viewer's drag does), then the schedule resumes.
    while (options_.send_on_response && next > tick + 1 && has_budget() && now < run_end_) {
      send_move(session, drag, seconds_between(first_tick, now));
      ++result.sent_on_response;
      const std::int64_t missed_before = next;
      now = Clock::now();
      while (tick_time(next) < now) ++next;
      for (std::int64_t k = missed_before; k < next; ++k) {
        if (tick_time(k) >= run_end_) break;
        ++result.ticks;
        ++result.skipped_ticks;
      }
      if (next == missed_before) break;  // the response came before the next tick
      tick = missed_before - 1;  // ticks were missed again: loop with the newest target
    }
    tick = next;
  }
}

void LoadRun::settle(SessionState& session) {
  SessionResult& result = session.result;
  // The last own move (the newest revision this session committed) and its response.
  const std::uint64_t revision = session.last_own_revision;
  if (revision == 0) return;  // no own move: nothing to settle
  const Clock::time_point responded = session.last_own_response;
  const Clock::time_point bound =
      responded + std::chrono::duration_cast<Clock::duration>(
                      std::chrono::duration<double>(options_.settle_seconds));
  std::unique_lock lock(session.mutex);
  // A converged revision is settled too (nothing refines it further); a settled one need not
  // be converged (refinement's budget ended it).
  if (session.changed.wait_until(lock, std::min(bound, settle_end_), [&] {
        return session.converged_revision >= revision || session.settled_revision >= revision;
      })) {
    if (session.converged_revision >= revision) {
      result.settle_ms = ms_between(responded, session.converged_at);
    }
    if (session.settled_revision >= revision) {
      result.settled_ms = ms_between(responded, session.settled_at);
      result.settled_lossless = session.settled_lossless;
    }
  }
}

void LoadRun::close_session(SessionState& session) {
  grpc::ClientContext context;
  context.AddMetadata("x-session-id", session.session_id);
  set_deadline(context, Clock::now() + kShortCallDeadline);
  v1::CloseSessionRequest request;
  request.set_session_id(session.session_id);
  request.set_token(session.edit_token);
  v1::CloseSessionResponse response;
  const grpc::Status status = session.stub->CloseSession(&context, request, &response);
  session.result.close_status = code_name(status.error_code());
}

void LoadRun::finish_watchers(SessionState& session) {
  {
    std::unique_lock lock(session.mutex);
    session.changed.wait_for(lock, kWatcherEndWait, [&] {
      return session.watchers_finished == static_cast<int>(session.watchers.size());
    });
  }
  // Streams the close did not end (e.g. the close failed) are cancelled; TryCancel is a no-op
  // on a finished call.
  for (auto& watcher : session.watchers) watcher->context->TryCancel();
  for (auto& watcher : session.watchers) {
    if (watcher->thread.joinable()) watcher->thread.join();
  }
}

void LoadRun::run_session(SessionState& session) {
  bool is_set_up = false;
  try {
    is_set_up = set_up(session);
    if (is_set_up) start_watchers(session);
  } catch (const std::exception& e) {
    session.result.setup_status = "CLIENT_EXCEPTION";
    session.result.setup_error = truncated(e.what());
    is_set_up = false;
  }
  session.result.is_set_up = is_set_up;
  bool is_go = false;
  {
    std::unique_lock lock(phase_mutex_);
    ++setups_done_;
    phase_changed_.notify_all();
    // The main thread always sets is_go by run_end_; the bound is a second guard.
    is_go = phase_changed_.wait_until(lock, run_end_ + kDrain, [&] { return is_go_; });
  }
  if (is_set_up && is_go) {
    try {
      drive(session);
      {
        const std::lock_guard lock(phase_mutex_);
        last_drive_end_ = std::max(last_drive_end_, Clock::now());
      }
      if (options_.settle_seconds > 0) settle(session);
    } catch (const std::exception& e) {
      ++session.result.errors_by_code["CLIENT_EXCEPTION"];
      session.result.first_error.try_emplace("CLIENT_EXCEPTION", truncated(e.what()));
    }
  }
  {
    std::unique_lock lock(phase_mutex_);
    ++drives_done_;
    phase_changed_.notify_all();
    phase_changed_.wait_until(lock, hard_end_, [&] { return is_close_; });
  }
  try {
    if (!session.session_id.empty()) close_session(session);
  } catch (const std::exception&) {
    session.result.close_status = "CLIENT_EXCEPTION";
  }
  finish_watchers(session);
}

RunResult LoadRun::run() {
  RunResult run;
  run.options = options_;
  run.machine = collect_machine_facts();
  run.mesh_label = options_.mesh_path.empty() ? options_.sample : upload_.name;
  start_ = Clock::now();
  run_end_ = start_ + std::chrono::duration_cast<Clock::duration>(
                          std::chrono::duration<double>(options_.duration_seconds));
  const auto settle = std::chrono::duration_cast<Clock::duration>(
      std::chrono::duration<double>(options_.settle_seconds));
  settle_end_ = run_end_ + kDrain + settle;
  hard_end_ = settle_end_ + kWatchBackstop;

  std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::InsecureChannelCredentials();
  if (!options_.tls_root_certs.empty()) {
    grpc::SslCredentialsOptions ssl;
    ssl.pem_root_certs = options_.tls_root_certs;
    credentials = grpc::SslCredentials(ssl);
  }
  // --via-link: one emulator in front of the server; each channel is its own TCP connection and
  // so its own emulated line (the watchers of a session share their editor's).
  std::unique_ptr<linkemu::LinkEmulator> link;
  std::string target = options_.server;
  if (!options_.via_link.empty()) {
    std::string error, host;
    int port = 0;
    const std::optional<linkemu::LinkSettings> settings =
        linkemu::parse_link_spec(options_.via_link, error);
    std::string server = options_.server;
    for (const char* scheme : {"dns:///", "ipv4:", "ipv6:"}) {
      if (server.rfind(scheme, 0) == 0) server = server.substr(std::string(scheme).size());
    }
    if (settings && linkemu::split_host_port(server, host, port)) {
      link = linkemu::LinkEmulator::start(*settings, host, port, error);
    } else if (settings) {
      error = "--via-link needs --server as HOST:PORT, got '" + options_.server + "'";
    }
    run.link.used = true;
    run.link.spec = options_.via_link;
    if (!link) {
      run.link.description = "not started: " + error;
      run.total_seconds = seconds_between(start_, Clock::now());
      return run;  // no session is set up: the run fails with the reason in the report
    }
    target = link->address();
    run.link.description = linkemu::describe_link(*settings);
    const linkemu::LinkSummary m = linkemu::summarize_link(*settings);
    run.link.down_mbit = m.down_mbit;
    run.link.up_mbit = m.up_mbit;
    run.link.rtt_ms = m.rtt_ms;
    run.link.jitter_ms = m.jitter_ms;
    run.link.loss = m.loss;
    run.link.queue_bytes_down = m.queue_bytes_down;
    run.link.queue_bytes_up = m.queue_bytes_up;
  }
  const int channel_count = options_.channel_count();
  for (int c = 0; c < channel_count; ++c) {
    grpc::ChannelArguments arguments;
    const int limit = options_.max_message_mib * 1024 * 1024;
    arguments.SetMaxReceiveMessageSize(limit);
    arguments.SetMaxSendMessageSize(limit);
    // Separate connections: without these, channels with equal arguments share one subchannel.
    arguments.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
    if (options_.fixed_receive_window) arguments.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
    arguments.SetInt("meshdeform.loadtest.channel", c);
    if (!options_.tls_server_name.empty()) {
      arguments.SetSslTargetNameOverride(options_.tls_server_name);
    }
    channels_.push_back(grpc::CreateCustomChannel(target, credentials, arguments));
    stubs_.push_back(v1::DeformationService::NewStub(channels_.back()));
  }
  run.stats_before = fetch_stats();

  std::vector<std::unique_ptr<SessionState>> sessions;
  for (int i = 0; i < options_.sessions; ++i) {
    auto session = std::make_unique<SessionState>();
    session->result.index = i;
    session->result.channel = i % channel_count;
    session->stub = stubs_[static_cast<std::size_t>(session->result.channel)].get();
    sessions.push_back(std::move(session));
  }
  std::vector<std::thread> threads;
  threads.reserve(sessions.size());
  try {
    for (auto& session : sessions) {
      threads.emplace_back([this, raw = session.get()] { run_session(*raw); });
    }
  } catch (const std::exception& e) {
    // Out of threads: the sessions that did start run as usual; the rest report the reason.
    for (std::size_t i = threads.size(); i < sessions.size(); ++i) {
      sessions[i]->result.setup_status = "CLIENT_EXCEPTION";
      sessions[i]->result.setup_error = truncated(std::string("cannot start thread: ") + e.what());
    }
  }
  const int started = static_cast<int>(threads.size());
  {
    std::unique_lock lock(phase_mutex_);
    phase_changed_.wait_until(lock, run_end_, [&] { return setups_done_ == started; });
    go_time_ = Clock::now();
    is_go_ = true;
    phase_changed_.notify_all();
    // Every drive ends by run_end_ + kDrain (move deadlines are capped), and its settle wait
    // by settle_end_; one more second of slack.
    phase_changed_.wait_until(lock, settle_end_ + std::chrono::seconds(1),
                              [&] { return drives_done_ == started; });
  }
  Clock::time_point moves_end = Clock::now();
  if (options_.settle_seconds > 0) {  // the rates are over the drags, not the settle waits
    const std::lock_guard lock(phase_mutex_);
    if (last_drive_end_ > go_time_) moves_end = std::min(moves_end, last_drive_end_);
  }
  run.setup_phase_seconds = seconds_between(start_, go_time_);
  run.move_phase_seconds = seconds_between(go_time_, moves_end);
  run.stats_loaded = fetch_stats();
  {
    const std::lock_guard lock(phase_mutex_);
    is_close_ = true;
    phase_changed_.notify_all();
  }
  for (std::thread& thread : threads) thread.join();
  run.stats_after_close = fetch_stats();
  if (link) {
    const linkemu::LinkCounters counters = link->counters();
    run.link.bytes_down = counters.down.bytes_delivered;
    run.link.bytes_up = counters.up.bytes_delivered;
    run.link.losses = counters.down.losses + counters.up.losses;
    run.link.full_queue_waits_down = counters.down.full_queue_waits;
    run.link.connections = counters.connections_accepted;
  }
  run.total_seconds = seconds_between(start_, Clock::now());
  run.machine.load_average_end = load_average();

  for (auto& session : sessions) {
    SessionResult& result = session->result;
    for (auto& watcher : session->watchers) {
      for (const Seen& seen : watcher->seen) {
        if (seen.is_refinement || seen.revision == 0) continue;
        const auto found = session->move_times.find(seen.revision);
        if (found == session->move_times.end()) continue;
        const double delay = ms_between(found->second.second, seen.at);
        if (delay < 0.0) ++watcher->result.seen_before_response;
        watcher->result.delays_ms.push_back(delay);
        watcher->result.delays_after_send_ms.push_back(ms_between(found->second.first, seen.at));
      }
      // Every own move, skipped revisions included: the first update at or past its revision.
      std::size_t next_seen = 0;
      for (const auto& [revision, times] : session->move_times) {
        while (next_seen < watcher->seen.size() && watcher->seen[next_seen].revision < revision) {
          ++next_seen;
        }
        if (next_seen == watcher->seen.size()) break;
        watcher->result.applied_after_send_ms.push_back(
            ms_between(times.first, watcher->seen[next_seen].at));
      }
      result.watchers.push_back(std::move(watcher->result));
    }
    if (result.is_set_up) ++run.sessions_set_up;
    run.sessions.push_back(std::move(result));
  }
  run.completed = true;
  return run;
}

}  // namespace

bool load_mesh_upload(const std::string& path, MeshUpload& upload, std::string& error) {
  std::string extension = std::filesystem::path(path).extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  static const std::map<std::string, v1::MeshFormat> kFormats = {
      {".obj", v1::MESH_FORMAT_OBJ}, {".off", v1::MESH_FORMAT_OFF},
      {".ply", v1::MESH_FORMAT_PLY}, {".stl", v1::MESH_FORMAT_STL},
      {".glb", v1::MESH_FORMAT_GLB}, {".gltf", v1::MESH_FORMAT_GLTF}};
  const auto format = kFormats.find(extension);
  if (format == kFormats.end()) {
    error = "--mesh " + path + ": unknown extension (use .obj .off .ply .stl .glb or .gltf)";
    return false;
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    error = "--mesh " + path + ": cannot open";
    return false;
  }
  upload.bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  if (in.bad() || upload.bytes.empty()) {
    error = "--mesh " + path + ": cannot read, or empty";
    return false;
  }
  upload.format = format->second;
  upload.name = std::filesystem::path(path).filename().string();
  return true;
}

RunResult run_load_test(const Options& options, const MeshUpload& upload) {
  LoadRun run(options, upload);
  return run.run();
}

}  // namespace meshdeform::loadtest
