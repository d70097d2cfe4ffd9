#pragma once
/// @file options.h
/// Command-line flags of meshdeform-loadtest, their validation, and the loopback check that keeps
/// the tool from loading a remote server by accident.

#include <cstdint>
#include <string>
#include <string_view>
#include <vector>

namespace meshdeform::loadtest {

/// Exit codes of meshdeform-loadtest.
constexpr int kExitOk = 0;         ///< the run completed (move errors, if any, are reported)
constexpr int kExitRunFailed = 1;  ///< setup failed for every session, or --fail-on-errors saw one
constexpr int kExitUsage = 2;      ///< bad flag or value, or a remote target without --allow-remote

/// The solver a session uses (MoveHandlesRequest.method and SetHandlesRequest.prepare).
enum class Method { ScaleAware, Arap, Laplacian };

/// "scale_aware", "arap" or "laplacian".
std::string_view method_name(Method method);

/// How moves and watch updates carry positions (PositionEncoding in the proto).
enum class Encoding { Doubles, Float32, Meshopt };

/// "doubles", "float32" or "meshopt".
std::string_view encoding_name(Encoding encoding);

/// Link-sized Watch updates (UpdateOptions in the proto): off, quantized or lossless.
enum class Updates { Off, Quantized, Lossless };

/// "off", "quantized" or "lossless".
std::string_view updates_name(Updates updates);

/// Everything the command line configures. Defaults are the documented ones.
struct Options {
  std::string server;               ///< gRPC target, e.g. "127.0.0.1:50051"
  int sessions = 1;                 ///< concurrent sessions, each with its own mesh
  std::string sample = "cylinder";  ///< built-in sample (ignored when mesh_path is set)
  std::string mesh_path;            ///< a mesh file to upload instead of a sample
  std::int64_t moves = 0;           ///< moves per session; 0 = until the duration ends
  double rate_hz = 10.0;            ///< moves per second per session; 0 = as fast as possible
  double duration_seconds = 60.0;   ///< hard bound for the whole run (setup included)
  int watchers = 0;                 ///< Watch streams per session
  int iterations = 2;               ///< MoveHandlesRequest.max_iterations
  Method method = Method::ScaleAware;
  Encoding encoding = Encoding::Doubles;  ///< MoveHandlesRequest / WatchRequest.encoding
  std::string json_path;          ///< write the JSON report here (empty: do not)
  std::string markdown_path;      ///< write the Markdown summary here (empty: do not)
  int connections = 0;            ///< gRPC channels; 0 = one per session
  bool allow_remote = false;      ///< permit a target that is not loopback
  bool fail_on_errors = false;    ///< exit kExitRunFailed when any move failed
  bool fixed_receive_window = false;  ///< --fixed-receive-window: no BDP probing (64 KiB)
  /// --send-on-response: when ticks came while a move was in flight, send the newest target
  /// as soon as the response arrives instead of waiting for the next tick (the viewer's drag).
  bool send_on_response = false;
  /// --coarse-preview: watchers ask for the coarse level of multiresolution moves
  /// (WatchRequest.coarse_preview) and the report counts and sizes it.
  bool coarse_preview = false;
  /// --settle-seconds: after its drag, each session waits up to this long for its watchers to
  /// see a converged revision at or past its last move (the server's background refinement),
  /// and the report gives that time from the last move's response. 0: no wait.
  double settle_seconds = 0.0;
  int move_deadline_ms = 10'000;  ///< deadline of each MoveHandles call
  int max_message_mib = 64;       ///< client send/receive limit (snapshots of big meshes)
  std::string tls_ca_path;        ///< --tls-ca: TLS trusting these PEM roots (empty: plaintext)
  std::string tls_root_certs;     ///< the text of tls_ca_path, read by parse_options
  std::string tls_server_name;    ///< --tls-server-name: the name the certificate must carry
  /// --via-link: run every connection through an emulated link (linkemu, e.g. "20mbit,40ms"),
  /// each channel on a line of its own; empty: direct.
  std::string via_link;
  /// --updates: link-sized Watch updates; with them moves ask for no positions
  /// (omit_positions: the editor's geometry comes from its watch stream).
  Updates updates = Updates::Off;
  double tolerance = 0.0;           ///< --tolerance (model units; 0: relative)
  double relative_tolerance = 0.0;  ///< --relative-tolerance (0: the server's default 1e-4)
  std::uint32_t max_update_bytes = 0;  ///< --max-update-bytes (0: no budget)
  /// --lossless-settled (with --updates quantized): settled revisions come lossless
  /// (UpdateOptions.lossless_settled); --settle-seconds then also waits for a settled one.
  bool lossless_settled = false;

  /// Channels actually used: `connections`, or one per session when 0 (never more than sessions).
  int channel_count() const;
};

/// What parse_options decided.
struct ParseOutcome {
  enum class Kind { Run, Help, UsageError } kind = Kind::UsageError;
  std::string message;  ///< for UsageError: what was wrong (one line)
};

/// The --help text.
std::string usage_text();

/// Parses `args` (argv without the program name) into `options`.
/// Accepts "--flag value" and "--flag=value" (CLI11). Checks ranges, that --server is given, that
/// --sample and --mesh are not both given, and that the target is loopback unless --allow-remote.
/// @return Run, Help, or UsageError with the reason.
ParseOutcome parse_options(const std::vector<std::string>& args, Options& options);

/// Whether a gRPC target names this machine: 127.0.0.0/8, ::1 or "localhost" (with an optional
/// "dns:///", "ipv4:" or "ipv6:" scheme and a port), or a unix socket.
bool is_loopback_target(std::string_view target);

}  // namespace meshdeform::loadtest
