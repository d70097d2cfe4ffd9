#pragma once
/// @file client.h
/// The C++ client of the meshdeform.v1 deformation service: what any C++ application links
/// (`meshdeform::client`). Plain C++ / Eigen types in, `Status` / `Result<T>` out; no protobuf
/// or gRPC type appears in this header.
///
/// Conventions (see proto/meshdeform/v1/deformation.proto):
/// - Every call gets a deadline (ClientOptions::default_timeout, or CallOptions::timeout).
/// - Every per-session call sends the session id as the `x-session-id` metadata header, so a
///   balancer can route a session's calls to one replica.
/// - Positions travel as IEEE doubles: results are bit-identical to the server's.
/// - gRPC status codes are mapped back to ErrorCode by to_error_code(); error messages read
///   "<Rpc>: <GRPC_CODE>: <server message>" and never contain a token.
///
/// Paper: Liu et al., "Scale-aware shape manipulation" (the server's default method).

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <functional>
#include <memory>
#include <optional>
#include <stop_token>
#include <string>
#include <vector>

#include "core/methods/deformer.h"
#include "core/methods/edit_types.h"
#include "core/io/mesh_io.h"
#include "core/mesh/mesh_data.h"
#include "core/base/status.h"

namespace meshdeform::client {

// ------------------------------------------------------------------------------------ options

/// TLS towards a server started with --tls-cert (gRPC's SslCredentials).
struct TlsOptions {
  /// PEM root certificates that the server's certificate must chain to. When this and
  /// root_certs_file are both empty, gRPC's default roots (the system's) are used.
  std::string root_certs_pem;
  /// A PEM file to read root_certs_pem from at connect(); only when root_certs_pem is empty.
  std::filesystem::path root_certs_file;
  /// The name checked against the server's certificate instead of the target's host (gRPC's
  /// grpc.ssl_target_name_override), e.g. "localhost" when dialling 127.0.0.1 with a certificate
  /// for localhost only; empty: the target's host.
  std::string server_name;
  /// A client certificate chain and its unencrypted key (PEM text), both or neither: for a server
  /// that requires client certificates (--tls-client-ca).
  std::string client_cert_chain_pem;
  std::string client_private_key_pem;
};

/// How to reach the server.
struct ClientOptions {
  /// "host:port"; plaintext unless `tls` is set.
  std::string target = "127.0.0.1:50051";
  /// Set: connect with TLS (the server runs with --tls-cert); unset: plaintext. A plaintext
  /// client of a TLS server (or the reverse) gets Unavailable on its first call.
  std::optional<TlsOptions> tls;
  /// Deadline of every unary call that does not set CallOptions::timeout; > 0.
  std::chrono::milliseconds default_timeout{30'000};
  /// Deadline of a Watch stream that does not set CallOptions::timeout (a stream lasts as long as
  /// the session is edited, but never forever); > 0.
  std::chrono::milliseconds watch_timeout{std::chrono::hours(1)};
  /// The channel's receive and send limits in MiB (match the server's --max-message-mib to read
  /// big GetMesh / Watch messages of large meshes); in [1, 2047].
  int max_message_mib = 64;
  /// gRPC's adaptive flow control (BDP probing), which grows each stream's receive window to
  /// megabytes on a fast link: best for big downloads. A Watch reader that is slower than the
  /// editor then has many updates buffered on its side before the server notices and skips it to
  /// the newest snapshot. false keeps the window at gRPC's default 64 KiB, so a slow viewer is
  /// skipped ahead sooner (fresher, with fewer buffered updates) at some cost in throughput:
  /// one window per round trip, 13 Mbit/s at 40 ms (over 20 Mbit/s, 40 ms the 187k drag's
  /// updates arrived p50 50 ms later than with the adaptive window; docs/remote-editing.md).
  bool adaptive_receive_window = true;
};

/// Per-call overrides.
/// A phase of the server's work on a CreateSession or SetHandles call (meshdeform.v1.Progress:
/// "queued", "parse", "session", "validate", "rigid_start", "step_two", "factorize",
/// "decimate", "prolongation", "coarse_precompute", ...). Each phase is reported at fraction 0
/// and 1, long ones also in between; every phase arrives, fractions a slow reader could not take
/// may be skipped.
struct Progress {
  std::string phase;
  double fraction = 0;         ///< of the phase, in [0, 1]
  double elapsed_seconds = 0;  ///< since the server admitted the call
};

struct CallOptions {
  /// This call's deadline instead of the client's default; > 0 when set.
  std::optional<std::chrono::milliseconds> timeout;
  /// Requesting a stop cancels the call (ClientContext::TryCancel): the server stops a running
  /// solve and commits nothing; the call returns Cancelled.
  std::stop_token stop;
  /// create_session_* and set_handles only: when set, the call uses its streaming form
  /// (CreateSessionWithProgress / SetHandlesWithProgress) and calls this on the calling thread
  /// for every Progress event before it returns; results and errors are the plain call's. A
  /// server without the streaming form (UNIMPLEMENTED before any event) gets the plain call.
  std::function<void(const Progress&)> on_progress;
};

// ------------------------------------------------------------------------------- domain types

// The edit vocabulary (core/methods/edit_types.h: one definition, shared with the server): handle
// groups and roles, similarity moves of a group (GroupMove: absolute, relative to the group's
// anchors, i.e. its positions when SetHandles was called), explicit vertex targets, undo/redo.
using core::GroupMove;
using core::HandleGroup;
using core::HandleRole;
using core::HistoryAction;
using core::VertexTarget;

/// A summary of a session (GetSessionInfo).
struct SessionInfo {
  std::string session_id;
  int vertices = 0;
  int faces = 0;
  int boundary_loops = 0;
  int components = 0;
  Eigen::Vector3d bbox_min = Eigen::Vector3d::Zero();  ///< of the rest mesh
  Eigen::Vector3d bbox_max = Eigen::Vector3d::Zero();
  std::uint64_t revision = 0;  ///< 0 is the rest mesh
  std::vector<HandleGroup> groups;
  std::optional<core::Method> last_method;  ///< nullopt before the first committed move
  std::uint64_t estimated_bytes = 0;        ///< what the server's memory budget charges
  int cached_deformers = 0;
  int watchers = 0;
  /// The session's undo history (SessionInfo.edit): steps kept (at least 1: the handles as set)
  /// and the current one. MoveSpec::history Undo applies step history_position - 1.
  int history_steps = 1;
  int history_position = 0;
  /// The method of the session's last move as stored with the session (nullopt before any).
  std::optional<core::Method> settings_method;
};

/// Which session a call is about, and the token that authorises it (edit or view). Build one
/// from the values printed by `meshdeform-client create`, or with Session::edit() / view().
struct SessionRef {
  std::string id;
  std::string token;  ///< a secret: never logged or put in an error message
};

/// A created session (CreateSession).
struct Session {
  std::string id;
  std::string edit_token;  ///< needed to edit (set handles, move, close)
  std::string view_token;  ///< enough to watch and to read the mesh and the info
  SessionInfo info;
  int welded_vertices = 0;  ///< cleaning changed the indices: they refer to the cleaned mesh
  int dropped_unreferenced = 0;
  std::vector<HandleGroup> suggested_groups;  ///< samples: group 0 fixed, group 1 handle

  SessionRef edit() const { return {id, edit_token}; }
  SessionRef view() const { return {id, view_token}; }
};

/// How CreateSession treats the mesh.
struct CreateOptions {
  bool weld = false;             ///< weld coincident vertices (STL always is)
  std::optional<double> lambda;  ///< soft handle weight, > 0 (server default 100)
  /// Scale control of the session's moves that set none (server default 100; see MoveSpec).
  std::optional<double> rigidity;
};

/// One MoveHandles request.
struct MoveSpec {
  std::vector<GroupMove> moves;
  std::vector<VertexTarget> targets;
  core::Method method = core::Method::ScaleAware;
  bool ora = false;                 ///< optimal rigidity approximation (scale-aware only)
  /// Scale control of the scale-aware method in [0, 10000] (0 = the paper's pure method;
  /// larger = more ARAP-like area); unset: the session's.
  std::optional<double> rigidity;
  int max_iterations = 0;           ///< 0: the server's default (2); at most 1000
  std::optional<double> tolerance;  ///< relative energy change that stops early (default 1e-4)
  std::string editor;               ///< free-form label forwarded to watchers
  bool full_positions = false;      ///< also return every vertex position
  HistoryAction history = HistoryAction::Record;
  /// Moves of one gesture (a drag) make one undo step: give them the same non-zero id.
  std::uint64_t gesture = 0;
  bool keep_settings = false;  ///< a one-off solve: the session's stored settings stay
  /// The result carries its figures only, no positions or changed lists (an editor that takes
  /// its geometry from a Watch stream with UpdateOptions).
  bool omit_positions = false;
};

/// Link-sized Watch updates (meshdeform.v1.UpdateOptions, issue 45): every update is a delta
/// against what the stream already delivered, zstd-compressed; the client reconstructs the
/// positions (WatchUpdate::result.positions).
struct UpdateOptions {
  enum class Mode {
    Off,        ///< the plain updates (doubles, snapshots and changed lists)
    Quantized,  ///< positions within `tolerance` of the solver's once an update is complete
    Lossless,   ///< bit-exact (the byte budget does not apply)
  };
  Mode mode = Mode::Off;
  /// Quantized: in model units (> 0); 0: relative_tolerance x the rest bounding-box diagonal.
  double tolerance = 0;
  /// Quantized, when tolerance is 0: a fraction of the diagonal in (0, 0.1]; 0: 1e-4.
  double relative_tolerance = 0;
  /// Quantized: most payload bytes per update (0: no limit; else >= 1024). The server sends a
  /// coarser or partial update and continues toward the same revision (continuation updates).
  std::uint32_t max_update_bytes = 0;
  /// Quantized: settled revisions (DeformResult::settled: the result after a release, once
  /// refinement is done) come lossless, so positions then equal the server's bit for bit; the
  /// stream goes on quantized after them.
  bool lossless_settled = false;
};

/// What a Watch stream asks for besides the session (meshdeform.v1.WatchRequest).
struct WatchOptions {
  UpdateOptions updates;  ///< link-sized updates (default off)
  /// Updates of a multiresolution session's moves also carry the coarse level they were solved
  /// on (WatchUpdate::coarse), for a client that draws the coarse mesh during a drag: a fraction
  /// of the vertices. The full positions come as usual.
  bool coarse_preview = false;
};

/// The coarse level of a multiresolution move (meshdeform.v1.CoarseLevel, WatchOptions::
/// coarse_preview). The server sends a level's mesh once per stream; the client fills it in on
/// every update of that level.
struct CoarseLevel {
  std::uint64_t key = 0;      ///< identifies the level's mesh
  Positions positions;        ///< #Vc x 3, the full result's positions at the coarse vertices
  Triangles triangles;        ///< #Fc x 3 coarse vertex indices
  std::vector<int> to_fine;   ///< #Vc: the full-resolution vertex of each coarse vertex
};

/// What a link-sized update cost and how close it brought the client (VertexDelta).
struct DeltaStats {
  std::uint64_t sequence = 0;
  std::uint32_t vertices_sent = 0;
  std::uint32_t shift = 0;             ///< values in units of 2^shift grid steps
  double max_error = 0;                ///< largest distance left to the revision's positions
  std::uint32_t pending_vertices = 0;  ///< still farther than the tolerance (0: complete)
  std::size_t payload_bytes = 0;       ///< compressed
  std::uint64_t raw_bytes = 0;         ///< before compression
  bool continuation = false;           ///< the same revision as the update before, further on
  /// Sent lossless (a lossless stream, or a settled revision with lossless_settled): the
  /// positions are the server's bit for bit.
  bool lossless = false;
  bool complete() const { return pending_vertices == 0; }
};

/// A committed revision (a MoveHandles result or a Watch update's payload).
struct DeformResult {
  std::uint64_t revision = 0;
  core::Method method = core::Method::ScaleAware;
  /// Vertices whose position changed (exactly) since the previous revision, ascending.
  std::vector<int> changed_indices;
  Positions changed_positions;         ///< #changed x 3, their new positions
  std::optional<Positions> positions;  ///< #V x 3: in snapshots and when full_positions was asked
  double e_theta = 0;                  ///< RMS corner-angle error against the rest mesh (radians)
  double e_phi = 0;                    ///< RMS dihedral-angle error (radians)
  double area_log_rms = 0;             ///< RMS of log(area'/area) over faces
  double rigidity = 0;                 ///< scale control the solve used (0: ARAP, Laplacian)
  int iterations = 0;
  bool converged = false;
  double solve_seconds = 0;
  /// A move's response only (0 in watch updates): its wait on the server before the solve began.
  double queue_seconds = 0;
  bool built_deformer = false;  ///< this move factored a new system
  std::string editor;
  bool refinement = false;  ///< committed by the server's background refinement
  /// No refinement revision follows until the next edit (converged, refinement off, or its
  /// last slice).
  bool settled = false;
};

/// One message of a Watch stream.
struct WatchUpdate {
  DeformResult result;
  /// True on join and after a gap: result.positions holds every vertex and the changed lists
  /// are empty.
  bool is_snapshot = false;
  std::uint64_t skipped_revisions = 0;  ///< revisions this watcher never saw (0 unless a gap)
  /// Streams with UpdateOptions: what the update cost. result.positions then always holds the
  /// reconstructed positions (is_snapshot is true for the stream's first update only).
  std::optional<DeltaStats> delta;
  /// Streams with WatchOptions::coarse_preview, on an update of a move solved on a coarse level.
  std::optional<CoarseLevel> coarse;
  /// The message's size on the wire (serialized bytes), for reports.
  std::size_t wire_bytes = 0;
};

/// Process-wide figures (GetServerStats).
struct ServerStats {
  std::uint32_t sessions = 0;
  std::uint64_t estimated_bytes = 0;
  std::uint64_t resident_bytes = 0;  ///< 0 if unknown
  std::uint64_t moves_committed = 0;
  std::uint64_t moves_cancelled = 0;  ///< Cancelled or DeadlineExceeded
  std::uint64_t refinements_committed = 0;
  std::uint64_t deformer_constructions = 0;
  std::uint64_t evicted_lru = 0;
  std::uint64_t evicted_idle = 0;
  std::uint32_t workers = 0;
  double uptime_seconds = 0;
};

/// How a watch() ended without an error.
enum class WatchEnd {
  StreamEnded,        ///< the server ended the stream OK (session closed or expired)
  StoppedByCallback,  ///< the callback returned false
  StoppedByToken,     ///< the stop token was requested
};

// -------------------------------------------------------------------------------- the client

class WatchStream;

/// A connection to one server. Cheap to copy (copies share the channel) and safe to use from
/// several threads at once.
class Client {
 public:
  /// Creates the channel (lazily connected: an unreachable server shows up as an error of the
  /// first call).
  /// @param[in] options  see ClientOptions.
  /// @return the client; InvalidArgument for an empty target, a timeout <= 0, max_message_mib
  ///         outside [1, 2047], or TlsOptions with both root_certs_pem and root_certs_file set
  ///         or a root_certs_file that cannot be read (its path in the message), or only one
  ///         of client_cert_chain_pem and client_private_key_pem.
  [[nodiscard]] static Result<Client> connect(const ClientOptions& options);

  const ClientOptions& options() const;

  /// Creates a session from a mesh file; the format comes from the extension (mesh_io.h).
  /// @param[in] path  OBJ, OFF, PLY, STL, GLB or glTF (embedded buffers) file.
  /// @return the session; NotFound if the file does not exist; InvalidArgument for an unknown
  ///         extension, or from the server for a malformed mesh; Internal if the file cannot be
  ///         read; ResourceExhausted over the server's limits (sessions, vertices, memory, or the
  ///         message size); the transport errors of to_error_code().
  [[nodiscard]] Result<Session> create_session_from_file(const std::filesystem::path& path,
                                                         const CreateOptions& create = {},
                                                         const CallOptions& call = {}) const;

  /// Creates a session from the bytes of a mesh file.
  /// @param[in] bytes   whole file contents (non-empty).
  /// @param[in] format  how the server must read them.
  /// @return the session; InvalidArgument for empty or malformed bytes (server);
  ///         ResourceExhausted over the server's limits; the transport errors of to_error_code().
  [[nodiscard]] Result<Session> create_session_from_bytes(std::string bytes, io::MeshFormat format,
                                                          const CreateOptions& create = {},
                                                          const CallOptions& call = {}) const;

  /// Creates a session from a built-in sample ("cylinder_small", "bar", ...), which comes with
  /// suggested_groups (group 0 fixed, group 1 handle).
  /// @return the session; InvalidArgument for an unknown name (the message lists the known
  ///         ones); ResourceExhausted over the server's limits; the transport errors.
  [[nodiscard]] Result<Session> create_session_from_sample(const std::string& name,
                                                           const CreateOptions& create = {},
                                                           const CallOptions& call = {}) const;

  /// Sets the handle groups (anchored at the current positions) and builds the factorization of
  /// `prepare`. Needs the edit token.
  /// @param[in] groups   non-empty, no vertex in two groups.
  /// @return the new info; InvalidArgument for a negative index (checked here) or, from the
  ///         server, no/empty groups, an index out of range or a vertex in two groups;
  ///         FailedPrecondition for a component the method cannot pin; PermissionDenied for a
  ///         wrong or view token; NotFound for an unknown session; the transport errors.
  [[nodiscard]] Result<SessionInfo> set_handles(const SessionRef& session,
                                                const std::vector<HandleGroup>& groups,
                                                core::Method prepare = core::Method::ScaleAware,
                                                const CallOptions& call = {}) const;

  /// Moves handles and solves; the server commits a new revision. Needs the edit token.
  /// Honours the deadline and `call.stop` mid-solve (nothing is committed then).
  /// @return the result; InvalidArgument for a negative group/vertex index or max_iterations
  ///         outside [0, 1000] (checked here) or, from the server, a bad group, a fixed group,
  ///         an index out of range, a non-finite value, scale <= 0, ORA with ARAP/Laplacian;
  ///         FailedPrecondition before set_handles; PermissionDenied; NotFound; Cancelled;
  ///         DeadlineExceeded; Internal for a solver breakdown; the transport errors.
  [[nodiscard]] Result<DeformResult> move(const SessionRef& session, const MoveSpec& spec,
                                          const CallOptions& call = {}) const;

  /// Streams the session's revisions to `on_update` (on this thread) until the stream ends, the
  /// callback returns false or `call.stop` is requested. The first update is a full snapshot.
  /// The deadline is call.timeout or ClientOptions::watch_timeout. View or edit token.
  /// @param[in] on_update  returns whether to keep watching.
  /// @return how it ended; PermissionDenied, NotFound, DeadlineExceeded, the transport errors
  ///         (e.g. Unavailable when the server goes away), InvalidArgument for a
  ///         malformed update.
  /// @param[in] updates  link-sized updates (default off); InvalidArgument from the server for
  ///                      a bad tolerance or budget, DataLoss-like InvalidArgument for an
  ///                      update that does not decode or is out of sequence.
  [[nodiscard]] Result<WatchEnd> watch(const SessionRef& session,
                                       const std::function<bool(const WatchUpdate&)>& on_update,
                                       const CallOptions& call = {},
                                       const UpdateOptions& updates = {}) const;
  /// The same with every Watch option (link-sized updates, the coarse preview). (A bare `{}` as
  /// the fourth argument is ambiguous between the two: write UpdateOptions{} or WatchOptions{}.)
  /// @return as above; InvalidArgument for a coarse level that does not decode (positions of
  ///         the wrong size, a level whose mesh never came, indices out of range).
  [[nodiscard]] Result<WatchEnd> watch(const SessionRef& session,
                                       const std::function<bool(const WatchUpdate&)>& on_update,
                                       const CallOptions& call, const WatchOptions& options) const;

  /// Opens a Watch stream to read update by update (see WatchStream).
  /// @return the stream (errors such as NotFound surface from its first next()).
  [[nodiscard]] WatchStream open_watch(const SessionRef& session,
                                       const CallOptions& call = {},
                                       const UpdateOptions& updates = {}) const;
  /// The same with every Watch option.
  [[nodiscard]] WatchStream open_watch(const SessionRef& session, const CallOptions& call,
                                       const WatchOptions& options) const;

  /// The mesh at `revision` (default: current) as file bytes. View or edit token.
  /// @return the bytes; NotFound for an unknown session or a revision no longer kept;
  ///         InvalidArgument for a coordinate the format cannot store; PermissionDenied; the
  ///         transport errors.
  [[nodiscard]] Result<std::string> get_mesh(const SessionRef& session,
                                             io::MeshFormat format = io::MeshFormat::Glb,
                                             std::optional<std::uint64_t> revision = {},
                                             const CallOptions& call = {}) const;

  /// The session's summary. View or edit token.
  /// @return the info; NotFound; PermissionDenied; the transport errors.
  [[nodiscard]] Result<SessionInfo> session_info(const SessionRef& session,
                                                 const CallOptions& call = {}) const;

  /// Closes the session (its watchers' streams end OK). Needs the edit token.
  /// @return success; NotFound; PermissionDenied; the transport errors.
  [[nodiscard]] Status close_session(const SessionRef& session, const CallOptions& call = {}) const;

  /// Process-wide figures; no token.
  /// @return the stats; FailedPrecondition "UNIMPLEMENTED" from a server without it; the
  ///         transport errors.
  [[nodiscard]] Result<ServerStats> server_stats(const CallOptions& call = {}) const;

 private:
  struct Impl;
  explicit Client(std::shared_ptr<const Impl> impl) : impl_(std::move(impl)) {}
  std::shared_ptr<const Impl> impl_;
};

/// A Watch stream read update by update (the pull form of Client::watch). Move-only; the
/// destructor cancels the stream if it is still open. next() must not be called from two
/// threads at once; cancel() may be called from any thread.
class WatchStream {
 public:
  WatchStream(WatchStream&&) noexcept;
  WatchStream& operator=(WatchStream&&) noexcept;
  ~WatchStream();

  /// Blocks for the next update.
  /// @return the update; nullopt once the stream ended OK (session closed, or cancel() / the
  ///         stop token ended it); the stream's error otherwise (PermissionDenied, NotFound,
  ///         DeadlineExceeded, the transport errors, InvalidArgument for a malformed update).
  [[nodiscard]] Result<std::optional<WatchUpdate>> next();

  /// Ends the stream (best effort, thread-safe): a blocked next() returns nullopt.
  void cancel();

 private:
  struct State;
  friend class Client;
  explicit WatchStream(std::unique_ptr<State> state);
  std::unique_ptr<State> state_;
};

// ----------------------------------------------------------------------------------- helpers

/// A local copy of a session's positions kept current by Watch updates (and the editor's own
/// move results): a snapshot replaces every position, a delta writes the changed rows.
class SessionMirror {
 public:
  /// Applies a Watch update (a link-sized one, WatchUpdate::delta, as the full positions it
  /// carries).
  /// @return success; FailedPrecondition for a delta before any snapshot or a delta whose
  ///         revision does not follow the mirrored one; InvalidArgument for a snapshot without
  ///         positions, a row count that changes, mismatched changed lists or an index out of
  ///         range.
  [[nodiscard]] Status apply(const WatchUpdate& update);
  /// Applies a MoveHandles result: its full positions when present, else its delta (which must
  /// follow the mirrored revision). Errors as for apply(WatchUpdate).
  [[nodiscard]] Status apply(const DeformResult& result);

  bool has_snapshot() const { return has_snapshot_; }
  std::uint64_t revision() const { return revision_; }
  /// #V x 3 positions at revision() (empty before the first snapshot).
  const Positions& positions() const { return positions_; }

 private:
  Status apply_delta(const DeformResult& result);
  Status apply_snapshot(const DeformResult& result);

  bool has_snapshot_ = false;
  std::uint64_t revision_ = 0;
  Positions positions_;
};

/// The ErrorCode of a gRPC status code (given as its integer value, grpc::StatusCode). Codes
/// without an equivalent map to the nearest: UNAUTHENTICATED -> PermissionDenied;
/// OUT_OF_RANGE -> InvalidArgument; ALREADY_EXISTS, UNIMPLEMENTED -> FailedPrecondition;
/// ABORTED -> Aborted and UNAVAILABLE -> Unavailable (retrying may succeed); UNKNOWN,
/// DATA_LOSS -> Internal. Messages keep the gRPC code name ("UNAVAILABLE"), see
/// grpc_code_name().
ErrorCode to_error_code(int grpc_code);

/// The gRPC name of a status code ("DEADLINE_EXCEEDED"); "CODE_<n>" for an unknown value.
std::string grpc_code_name(int grpc_code);

}  // namespace meshdeform::client
