// meshdeform-server: flags, ServerBuilder, health, reflection and signal handling; no logic.
#include <grpcpp/security/server_credentials.h>
#include <grpcpp/server.h>
#include <grpcpp/server_builder.h>

#include <pthread.h>
#include <signal.h>

#include <algorithm>
#include <atomic>
#include <charconv>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iostream>
#include <memory>
#include <mutex>
#include <optional>
#include <stop_token>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "common/command_line.h"
#include "core/base/allocator.h"
#include "server/service/deformation_service.h"
#include "server/service/log.h"
#include "server/service/persistence.h"
#include "server/redis/redis_store.h"
#include "server/transport/deform_service_impl.h"
#include "server/transport/connection_gate.h"
#include "server/transport/grpc_front_door.h"
#include "server/transport/grpc_web_gateway.h"
#include "server/transport/http_router.h"
#include "server/transport/http_server.h"
#include "server/transport/ops_endpoints.h"
#include "server/transport/server_setup.h"
#include "server/transport/static_files.h"

namespace {

struct Flags {
  std::string listen = "127.0.0.1:50051";
  int max_sessions = 64;
  int max_vertices = 1'000'000;
  int idle_ttl_seconds = 30 * 60;
  int max_message_mib = 64;
  int memory_budget_mib = 2048;
  int workers = 0;
  int shutdown_grace_seconds = 10;
  int refine_budget = 30;
  int refine_delay_ms = 150;
  int multires_above = 100'000;
  int multires_coarse_vertices = 10'000;
  int solver_threads = 0;
  int parallel_solve_above = 20'000;
  std::string http_listen;
  std::string web_root;
  std::vector<std::string> cors_origins;
  std::string state_dir;
  std::string redis_url;            // --redis: sessions on Redis (issue 16)
  std::string redis_password_file;  // the password never comes from the command line
  std::string redis_ca_file;        // rediss://: CA the server's certificate chains to
  int redis_lease_ms = 5000;
  int redis_log_length = 32;
  std::string tls_cert;       // PEM files; both or neither
  std::string tls_key;
  std::string tls_client_ca;  // optional: require client certificates (mTLS)
  std::string log_level = "info";
  double create_rate = 2.0;   // per client, sessions per second (0 = unlimited)
  double create_burst = 30;
  double move_rate = 200.0;   // per client, moves per second (0 = unlimited)
  double move_burst = 400;
  bool trust_forwarded_for = false;
  int heavy_per_client = 4;   // uploads/precomputes admitted at once per client
  int heavy_total = 16;       // ... and over all clients
  int heavy_lanes = 0;        // workers that may run them (0 = workers - 1)
  int max_sessions_per_client = 0;       // 0 = a quarter of --max-sessions
  int memory_budget_per_client_mib = 0;  // 0 = three quarters of --memory-budget-mib
  int max_connections = 1024;            // per port
  int max_connections_per_address = 64;  // per port and client address
  int header_timeout_seconds = 10;       // first bytes of a connection / a request's header
  bool test_hooks = false;    // SIGUSR1 expires every idle session now (tests only)
};

constexpr const char* kUsage =
    "usage: meshdeform-server [flags]\n"
    "  --listen ADDR               host:port to serve on (default 127.0.0.1:50051; 0.0.0.0:PORT\n"
    "                              for every interface; plaintext unless --tls-cert is given)\n"
    "  --max-sessions N            open sessions (default 64)\n"
    "  --max-vertices N            vertices per mesh (default 1000000; --memory-budget-mib\n"
    "                              bounds what is solved: a session's deformer is charged\n"
    "                              5.2 KB per vertex, e.g. 3.9 GB at 750k vertices)\n"
    "  --idle-ttl-seconds N        sessions idle for longer are closed (default 1800)\n"
    "  --memory-budget-mib N       estimated memory for all sessions; least recently used idle\n"
    "                              sessions are evicted to make room (default 2048)\n"
    "  --max-message-mib N         largest request/response, e.g. a mesh upload (default 64)\n"
    "  --workers N                 solver threads (default 0 = one per core, at least 2)\n"
    "  --shutdown-grace-seconds N  on SIGTERM/SIGINT, time to finish calls (default 10)\n"
    "  --refine-budget N           outer iterations the server keeps refining a session in the\n"
    "                              background after a move while its handles rest, publishing\n"
    "                              each improvement as a revision (default 30; 0 = off)\n"
    "  --refine-delay-ms N         ... starting once the handles have rested N ms (default 150:\n"
    "                              no refinement revisions between the moves of a drag), or\n"
    "                              twice the pause between the drag's last two moves if that is\n"
    "                              longer (a drag over a slow line), at most 1 s\n"
    "  --multires-above N          scale-aware sessions on meshes of more than N vertices move\n"
    "                              on a coarse level of a mesh hierarchy (answered at once) and\n"
    "                              the background refinement converges the full mesh (default\n"
    "                              100000; 0 = always full resolution)\n"
    "  --multires-coarse-vertices N  the coarse level's size (default 10000)\n"
    "  --solver-threads N          threads inside one solve of a session on a mesh of at least\n"
    "                              --parallel-solve-above vertices (default 0 = one per core;\n"
    "                              1 = every solve on one thread)\n"
    "  --parallel-solve-above N    ... smaller sessions solve on one thread and share the cores\n"
    "                              through the workers (default 20000)\n"
    "  --http-listen ADDR          also serve HTTP/1.1 on ADDR (e.g. 127.0.0.1:8080): the service\n"
    "                              over gRPC-Web (for browsers), GET /metrics (Prometheus text\n"
    "                              format), GET /healthz, and --web-root files (default: off)\n"
    "  --web-root DIR              static files (the built viewer) served on --http-listen\n"
    "  --cors-origin ORIGIN        allow gRPC-Web calls from this browser origin (repeatable;\n"
    "                              '*' for any; default: same origin only)\n"
    "  --state-dir DIR             keep every session's state in DIR (written atomically before\n"
    "                              each edit is acknowledged) and resume sessions from it after a\n"
    "                              restart or on another replica sharing DIR (default: memory only)\n"
    "  --redis URL                 keep sessions in Redis (redis://[user@]host[:port][/db]) so\n"
    "                              that any replica on the same Redis serves any session: edits\n"
    "                              take a per-session lease, commit by compare-and-set and are\n"
    "                              acknowledged only once Redis accepted them; watchers see the\n"
    "                              edits of every replica (default: off; not with --state-dir;\n"
    "                              rediss://... for TLS: the server's certificate and host name\n"
    "                              are verified)\n"
    "  --redis-ca-file FILE        rediss://: PEM CA certificate(s) the Redis server's\n"
    "                              certificate must chain to (default: the system's CAs)\n"
    "  --redis-password-file FILE  the Redis password (first line of FILE; else the environment\n"
    "                              variable MESHDEFORM_REDIS_PASSWORD; never on the command line)\n"
    "  --redis-lease-ms N          how long a replica's edit lease on a session lasts unrenewed:\n"
    "                              after a crash, other replicas take the session over within N\n"
    "                              ms (default 5000)\n"
    "  --redis-log-length N        committed revisions kept per session in Redis for replicas\n"
    "                              and watchers catching up (each holds the positions, 24 bytes\n"
    "                              a vertex; further behind, they load the whole state; default\n"
    "                              32)\n"
    "  --tls-cert FILE             serve TLS (1.2+) on --listen and HTTPS on --http-listen with\n"
    "                              this PEM certificate chain (needs --tls-key; default: off)\n"
    "  --tls-key FILE              the certificate's PEM private key (unencrypted)\n"
    "  --tls-client-ca FILE        with --tls-cert: require client certificates issued by these\n"
    "                              PEM CAs on both ports (mutual TLS; default: not requested)\n"
    "  --log-level LEVEL           debug, info, warn or error (default info); logs are JSON lines\n"
    "                              on stderr\n"
    "  --create-rate R             sessions each client may create per second, sustained\n"
    "                              (default 2; 0 = unlimited); over it: RESOURCE_EXHAUSTED with\n"
    "                              the wait in the message and the retry-after-ms trailer\n"
    "  --create-burst N            ... and at once after a quiet spell (default 30)\n"
    "  --move-rate R               moves each client may make per second (default 200; 0 =\n"
    "                              unlimited)\n"
    "  --move-burst N              ... and at once (default 400)\n"
    "  --heavy-per-client N        uploads (CreateSession parses) and SetHandles precomputes each\n"
    "                              client may have queued or running at once (default 4); over\n"
    "                              it, or over --heavy-total: RESOURCE_EXHAUSTED at once\n"
    "  --heavy-total N             ... over all clients (default 16)\n"
    "  --heavy-lanes N             workers that may run that heavy work (default 0 = workers - 1,\n"
    "                              at least 1): the others keep serving moves and reads\n"
    "  --max-sessions-per-client N sessions one client may hold open (default 0 = a quarter of\n"
    "                              --max-sessions); over it: RESOURCE_EXHAUSTED\n"
    "  --memory-budget-per-client-mib N  what one client's sessions may hold of the memory\n"
    "                              budget (default 0 = three quarters of it). Room is made by\n"
    "                              evicting the client's own idle sessions, then those of\n"
    "                              clients over this quota, then (with --state-dir or --redis\n"
    "                              only, where eviction loses nothing) any idle session; in\n"
    "                              memory only, another client's session within its quota is\n"
    "                              never evicted\n"
    "  --max-connections N         open connections per port (gRPC and HTTP each; default 1024;\n"
    "                              lowered at start to fit the descriptor limit, which the\n"
    "                              server first raises to its hard limit); more are closed at once\n"
    "  --max-connections-per-address N  ... from one client address (default 64; behind a\n"
    "                              proxy every client has the proxy's address: raise it)\n"
    "  --header-timeout-seconds N  a connection's first bytes (gRPC) or a request's header\n"
    "                              (HTTP), and a TLS handshake, must arrive within N s (default\n"
    "                              10): silent sockets are closed\n"
    "  --test-hooks                for tests only: SIGUSR1 expires every idle session at once (as\n"
    "                              if --idle-ttl-seconds had passed) and logs \"expired_by_signal\"\n"
    "  --trust-forwarded-for       name clients by the x-forwarded-for header for those limits;\n"
    "                              only behind a proxy that sets it (nginx: grpc_set_header\n"
    "                              X-Forwarded-For $remote_addr), else clients pick their name\n";

/// Parses all of `text` as a number in [min, max] (int or double: from_chars takes both).
template <typename T>
bool parse_number(std::string_view text, T min, T max, T& out) {
  T value{};
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || !(value >= min && value <= max)) {
    return false;
  }
  out = value;
  return true;
}

/// Parses the flags with CLI11 (common/command_line.h); each value is checked as soon as it is
/// read, so the first bad one on the line is reported, and --help/-h stops the parse.
/// @return false (after printing why) for an unknown flag or a bad value.
bool parse_flags(int argc, char** argv, Flags& flags, bool& help) {
  namespace command_line = meshdeform::command_line;
  CLI::App app;
  command_line::configure(app);
  command_line::add_help(app, help, true);
  command_line::add_flag(app, "--trust-forwarded-for", flags.trust_forwarded_for);
  command_line::add_flag(app, "--test-hooks", flags.test_hooks);
  // The value is refused with the generic message below; no per-flag text.
  const auto check = [](bool ok) { return ok ? std::nullopt : std::optional<std::string>(""); };
  const auto text = [&](const std::string& name, std::string& out) {
    command_line::add_checked(app, name, [&out, check](const std::string& value) {
      out = value;
      return check(!value.empty());
    });
  };
  const auto number = [&](const std::string& name, auto min, auto max, auto& out) {
    command_line::add_checked(app, name, [min, max, &out, check](const std::string& value) {
      return check(parse_number(value, min, max, out));
    });
  };
  text("--listen", flags.listen);
  number("--max-sessions", 1, 1'000'000, flags.max_sessions);
  number("--max-vertices", 3, 100'000'000, flags.max_vertices);
  number("--idle-ttl-seconds", 1, 365 * 24 * 3600, flags.idle_ttl_seconds);
  number("--memory-budget-mib", 1, 1'000'000, flags.memory_budget_mib);
  number("--max-message-mib", 1, 2047, flags.max_message_mib);
  number("--workers", 0, 1024, flags.workers);
  number("--refine-budget", 0, 100'000, flags.refine_budget);
  number("--refine-delay-ms", 0, 60'000, flags.refine_delay_ms);
  number("--multires-above", 0, 100'000'000, flags.multires_above);
  number("--multires-coarse-vertices", 100, 10'000'000, flags.multires_coarse_vertices);
  number("--solver-threads", 0, 1024, flags.solver_threads);
  number("--parallel-solve-above", 0, 100'000'000, flags.parallel_solve_above);
  text("--http-listen", flags.http_listen);
  text("--web-root", flags.web_root);
  command_line::add_checked(app, "--cors-origin", [&flags, check](const std::string& value) {
    flags.cors_origins.push_back(value);  // repeatable
    return check(!value.empty());
  });
  text("--state-dir", flags.state_dir);
  text("--redis", flags.redis_url);
  text("--redis-password-file", flags.redis_password_file);
  text("--redis-ca-file", flags.redis_ca_file);
  number("--redis-lease-ms", 100, 600'000, flags.redis_lease_ms);
  number("--redis-log-length", 1, 100'000, flags.redis_log_length);
  text("--tls-cert", flags.tls_cert);
  text("--tls-key", flags.tls_key);
  text("--tls-client-ca", flags.tls_client_ca);
  command_line::add_checked(app, "--log-level", [&flags, check](const std::string& value) {
    flags.log_level = value;
    return check(value == "debug" || value == "info" || value == "warn" || value == "error");
  });
  number("--create-rate", 0.0, 1e6, flags.create_rate);
  number("--create-burst", 1.0, 1e6, flags.create_burst);
  number("--move-rate", 0.0, 1e6, flags.move_rate);
  number("--move-burst", 1.0, 1e6, flags.move_burst);
  number("--heavy-per-client", 1, 1024, flags.heavy_per_client);
  number("--heavy-total", 1, 4096, flags.heavy_total);
  number("--heavy-lanes", 0, 1024, flags.heavy_lanes);
  number("--max-sessions-per-client", 0, 1'000'000, flags.max_sessions_per_client);
  number("--memory-budget-per-client-mib", 0, 1'000'000, flags.memory_budget_per_client_mib);
  number("--max-connections", 1, 1'000'000, flags.max_connections);
  number("--max-connections-per-address", 1, 1'000'000, flags.max_connections_per_address);
  number("--header-timeout-seconds", 1, 3600, flags.header_timeout_seconds);
  number("--shutdown-grace-seconds", 0, 3600, flags.shutdown_grace_seconds);

  const std::optional<command_line::Problem> problem = command_line::parse(
      app, std::vector<std::string>(argv + 1, argv + argc), command_line::Repeats::LastWins);
  if (help || !problem) return true;
  using Kind = command_line::Problem::Kind;
  switch (problem->kind) {
    case Kind::BadValue:
      std::cerr << "meshdeform-server: bad value '" << problem->value << "' for " << problem->word
                << "\n";
      return false;
    case Kind::MissingValue:
      std::cerr << "meshdeform-server: " << problem->word << " needs a value\n" << kUsage;
      return false;
    case Kind::TakesNoValue:
      std::cerr << "meshdeform-server: " << problem->word << " takes no value\n" << kUsage;
      return false;
    case Kind::UnknownOption:
    case Kind::Unexpected:
      std::cerr << "meshdeform-server: unknown flag " << problem->word << "\n" << kUsage;
      return false;
    case Kind::Repeated:
    case Kind::Other:
      break;
  }
  std::cerr << "meshdeform-server: " << problem->message << "\n" << kUsage;
  return false;
}

}  // namespace

int main(int argc, char** argv) {
  meshdeform::core::keep_freed_heap_for_solver_arrays();
  using meshdeform::service::log_event;
  using meshdeform::service::LogFields;
  using meshdeform::service::LogLevel;
  Flags flags;
  bool help = false;
  if (!parse_flags(argc, argv, flags, help)) return 2;
  if (help) {
    std::cout << kUsage;
    return 0;
  }
  meshdeform::service::set_log_level(flags.log_level == "debug"  ? LogLevel::Debug
                                     : flags.log_level == "warn" ? LogLevel::Warn
                                     : flags.log_level == "error" ? LogLevel::Error
                                                                  : LogLevel::Info);

  // Block the shutdown signals before any thread starts, so every thread inherits the mask and
  // only sigwait below receives them.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  if (flags.test_hooks) sigaddset(&signals, SIGUSR1);  // see --test-hooks
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  meshdeform::service::ServiceOptions options;
  options.workers = flags.workers;
  options.max_sessions = flags.max_sessions;
  options.max_vertices = flags.max_vertices;
  options.idle_ttl = std::chrono::seconds(flags.idle_ttl_seconds);
  options.refine_budget = flags.refine_budget;
  options.refine_delay = std::chrono::milliseconds(flags.refine_delay_ms);
  options.multires_above = flags.multires_above;
  options.multires_coarse_vertices = flags.multires_coarse_vertices;
  options.solver_threads = flags.solver_threads;
  options.parallel_solve_above = flags.parallel_solve_above;
  options.memory_budget_bytes = static_cast<std::size_t>(flags.memory_budget_mib) << 20;
  options.state_dir = flags.state_dir;
  options.create_rate = {flags.create_rate, flags.create_burst};
  options.move_rate = {flags.move_rate, flags.move_burst};
  options.heavy_work = {flags.heavy_per_client, flags.heavy_total};
  options.heavy_lanes = flags.heavy_lanes;
  options.max_sessions_per_client = flags.max_sessions_per_client;
  options.memory_budget_per_client_bytes =
      static_cast<std::size_t>(flags.memory_budget_per_client_mib) << 20;
  if (!flags.state_dir.empty()) {
    if (auto dir = meshdeform::service::StateDirectory::open(flags.state_dir); !dir.ok()) {
      log_event(LogLevel::Error, "state_dir_unusable",
                LogFields().add("path", flags.state_dir).add("message", dir.status().message()));
      return 2;
    }
  }
  // Redis is checked before anything listens: a wrong URL, password or an unreachable server
  // stops the server with one line naming the cause.
  std::shared_ptr<meshdeform::service::SharedStateStore> shared;
  if (!flags.redis_url.empty()) {
    auto redis_error = [&](const std::string& message) {
      log_event(LogLevel::Error, "redis_unusable", LogFields().add("message", message));
      return 2;
    };
    if (!flags.state_dir.empty()) {
      return redis_error("--redis and --state-dir exclude each other: Redis holds the state");
    }
    auto config = meshdeform::redis::parse_redis_url(flags.redis_url);
    if (!config.ok()) return redis_error(config.status().message());
    if (!flags.redis_password_file.empty()) {
      std::ifstream file(flags.redis_password_file);
      if (!file) return redis_error("cannot read --redis-password-file " + flags.redis_password_file);
      std::getline(file, config->password);
      if (!config->password.empty() && config->password.back() == '\r') config->password.pop_back();
    } else if (const char* env = std::getenv("MESHDEFORM_REDIS_PASSWORD"); env != nullptr) {
      config->password = env;
    }
    if (!flags.redis_ca_file.empty()) {
      if (!config->tls) return redis_error("--redis-ca-file needs a rediss:// (TLS) --redis URL");
      config->tls_ca_file = flags.redis_ca_file;
    }
    config->lease = std::chrono::milliseconds(flags.redis_lease_ms);
    config->log_length = flags.redis_log_length;
    config->idle_ttl = std::chrono::seconds(flags.idle_ttl_seconds);
    auto connected = meshdeform::redis::RedisStateStore::connect(std::move(config).value());
    if (!connected.ok()) return redis_error(connected.status().message());
    shared = std::move(connected).value();
    log_event(LogLevel::Info, "redis",
              LogFields().add("url", flags.redis_url).add("lease_ms", flags.redis_lease_ms));
  } else if (!flags.redis_password_file.empty() || !flags.redis_ca_file.empty()) {
    log_event(LogLevel::Error, "redis_unusable",
              LogFields().add("message", !flags.redis_password_file.empty()
                                             ? "--redis-password-file needs --redis"
                                             : "--redis-ca-file needs --redis"));
    return 2;
  }
  // TLS files are checked before anything listens, so that a typo stops the server with a
  // message naming the file (gRPC itself would only report a failed listen).
  std::optional<meshdeform::transport::TlsConfig> tls;
  if (flags.tls_cert.empty() != flags.tls_key.empty() ||
      (!flags.tls_client_ca.empty() && flags.tls_cert.empty())) {
    log_event(LogLevel::Error, "tls_unusable",
              LogFields().add("message", flags.tls_cert.empty() && flags.tls_key.empty()
                                             ? "--tls-client-ca needs --tls-cert and --tls-key"
                                             : "--tls-cert and --tls-key go together"));
    return 2;
  }
  if (!flags.tls_cert.empty()) {
    auto loaded =
        meshdeform::transport::load_tls_config(flags.tls_cert, flags.tls_key, flags.tls_client_ca);
    if (!loaded.ok()) {
      log_event(LogLevel::Error, "tls_unusable",
                LogFields().add("message", loaded.status().message()));
      return 2;
    }
    tls = std::move(loaded).value();
  }
  // Connection caps that fit the descriptors this process may open (raised to the hard limit
  // first): a flood of idle connections is refused before it starves state files of
  // descriptors.
  meshdeform::transport::ConnectionLimits grpc_limits{
      static_cast<std::size_t>(flags.max_connections_per_address),
      static_cast<std::size_t>(flags.max_connections)};
  meshdeform::transport::ConnectionLimits http_limits = grpc_limits;
  const long descriptors = meshdeform::transport::raise_descriptor_limit();
  if (meshdeform::transport::fit_connection_limits(
          descriptors, /*reserve=*/128, grpc_limits,
          flags.http_listen.empty() ? nullptr : &http_limits)) {
    log_event(LogLevel::Warn, "connection_caps_lowered",
              LogFields()
                  .add("descriptors", static_cast<std::int64_t>(descriptors))
                  .add("grpc_total", static_cast<std::uint64_t>(grpc_limits.total))
                  .add("http_total", static_cast<std::uint64_t>(http_limits.total)));
  }
  meshdeform::service::DeformationService service(options, shared);
  std::unique_ptr<meshdeform::transport::GrpcFrontDoor> front_door;  // outlives impl
  meshdeform::transport::ClientIdentityOptions identity;
  identity.trust_forwarded_for = flags.trust_forwarded_for;
  identity.resolve_peer = [&front_door](std::string_view peer) -> std::optional<std::string> {
    return front_door ? front_door->client_of(peer) : std::nullopt;
  };
  meshdeform::transport::DeformServiceImpl impl(service, identity);

  meshdeform::transport::enable_health_and_reflection();
  grpc::ServerBuilder builder;
  std::shared_ptr<grpc::ServerCredentials> credentials = grpc::InsecureServerCredentials();
  if (tls) {
    grpc::SslServerCredentialsOptions ssl(
        tls->client_ca_pem.empty() ? GRPC_SSL_DONT_REQUEST_CLIENT_CERTIFICATE
                                   : GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY);
    ssl.pem_root_certs = tls->client_ca_pem;
    ssl.pem_key_cert_pairs.push_back({tls->private_key_pem, tls->cert_chain_pem});
    credentials = grpc::SslServerCredentials(ssl);
  }
  // gRPC listens on a loopback port of its own; the front door takes the public address.
  int upstream_port = 0;
  builder.AddListeningPort("127.0.0.1:0", credentials, &upstream_port);
  builder.AddChannelArgument(GRPC_ARG_SERVER_HANDSHAKE_TIMEOUT_MS,
                             flags.header_timeout_seconds * 1000);
  meshdeform::transport::configure_builder(builder, impl, flags.max_message_mib);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (!server || upstream_port == 0) {
    log_event(LogLevel::Error, "listen_failed", LogFields().add("address", "127.0.0.1:0"));
    return 1;
  }
  {
    meshdeform::transport::FrontDoorOptions door;
    door.limits = grpc_limits;
    door.first_bytes_timeout_seconds = flags.header_timeout_seconds;
    auto opened = meshdeform::transport::GrpcFrontDoor::start(
        flags.listen, "127.0.0.1:" + std::to_string(upstream_port), door);
    if (!opened.ok()) {
      log_event(LogLevel::Error, "listen_failed",
                LogFields().add("address", flags.listen).add("message", opened.status().message()));
      return 1;
    }
    front_door = std::move(opened).value();
  }
  const int port = front_door->port();
  log_event(LogLevel::Info, "listening",
            LogFields()
                .add("address", flags.listen)
                .add("port", port)
                .add("tls", tls.has_value())
                .add("workers", service.stats().workers)
                .add("refine_budget", flags.refine_budget)
                .add("multires_above", flags.multires_above)
                .add("solver_threads", flags.solver_threads)
                .add("parallel_solve_above", flags.parallel_solve_above));

  std::atomic<bool> serving{true};
  auto http_gate = std::make_shared<meshdeform::transport::ConnectionGate>(http_limits);
  service.metrics().add_section([&front_door, http_gate, has_http = !flags.http_listen.empty()](
                                    std::string& out) {
    std::vector<std::pair<std::string, meshdeform::transport::ConnectionStats>> ports;
    if (front_door) ports.emplace_back("grpc", front_door->stats());
    if (has_http) ports.emplace_back("http", http_gate->stats());
    meshdeform::transport::render_connection_metrics(ports, out);
  });
  // Declared in this order so that the gateway and the files outlive the listener using them.
  std::unique_ptr<meshdeform::transport::GrpcWebGateway> gateway;
  std::optional<meshdeform::transport::StaticFileServer> files;
  std::unique_ptr<meshdeform::transport::HttpServer> http;
  if (!flags.http_listen.empty()) {
    meshdeform::transport::GrpcWebGatewayOptions web_options;
    web_options.allowed_origins = flags.cors_origins;
    gateway = std::make_unique<meshdeform::transport::GrpcWebGateway>(
        *server, static_cast<std::size_t>(flags.max_message_mib) << 20, web_options,
        &service.metrics());
    if (!flags.web_root.empty()) {
      auto opened = meshdeform::transport::StaticFileServer::open(flags.web_root);
      if (!opened.ok()) {
        log_event(LogLevel::Error, "web_root_unusable",
                  LogFields().add("path", flags.web_root).add("message", opened.status().message()));
        return 2;
      }
      files.emplace(std::move(opened).value());
    }
    meshdeform::transport::HttpServerOptions http_options;
    http_options.threads = 2;
    http_options.header_timeout_seconds = flags.header_timeout_seconds;
    http_options.gate = http_gate;
    http_options.body_limit = meshdeform::transport::make_body_limit(*gateway);
    http_options.tls = tls;
    auto started = meshdeform::transport::HttpServer::start_async(
        flags.http_listen,
        meshdeform::transport::make_http_router(
            *gateway, files ? &*files : nullptr,
            [&service, &serving](const meshdeform::transport::HttpRequest& request) {
              return meshdeform::transport::handle_ops_request(request, service, serving.load());
            }),
        http_options);
    if (!started.ok()) {
      log_event(LogLevel::Error, "listen_failed",
                LogFields().add("address", flags.http_listen).add("message", started.status().message()));
      return 1;
    }
    http = std::move(started).value();
    log_event(LogLevel::Info, "http_listening",
              LogFields().add("address", flags.http_listen).add("port", http->port())
                  .add("tls", tls.has_value()).add("web_root", flags.web_root));
  }

  // Sweeps idle sessions (create_session also sweeps, but a quiet server should free memory too).
  std::jthread sweeper([&service, ttl = std::chrono::seconds(flags.idle_ttl_seconds)](
                           std::stop_token stop) {
    std::mutex mutex;
    std::condition_variable_any cv;
    const auto period = std::clamp<std::chrono::seconds>(ttl / 4, std::chrono::seconds(1),
                                                         std::chrono::seconds(60));
    std::unique_lock lock(mutex);
    while (!cv.wait_for(lock, stop, period, [] { return false; })) {
      if (stop.stop_requested()) break;
      service.evict_expired();
    }
  });

  int received = 0;
  while (true) {
    sigwait(&signals, &received);
    if (received != SIGUSR1) break;
    // Test hook: an explicit expiry instead of a short TTL, so that tests do not depend on how
    // fast this machine runs them.
    const std::size_t removed = service.evict_expired(
        std::chrono::steady_clock::now() + std::chrono::seconds(flags.idle_ttl_seconds) +
        std::chrono::seconds(1));
    log_event(LogLevel::Info, "expired_by_signal",
              LogFields().add("removed", static_cast<std::uint64_t>(removed)));
  }
  log_event(LogLevel::Info, "shutdown",
            LogFields().add("signal", received).add("grace_seconds", flags.shutdown_grace_seconds));
  // Health checks say NOT_SERVING at once (balancers stop sending); then stop accepting calls and,
  // after the grace period, cancel what is left (running solves see the cancellation through
  // their stop token and end quickly).
  serving.store(false);
  server->GetHealthCheckService()->SetServingStatus(false);
  service.end_watches();  // Watch streams never end on their own: finish them OK now
  server->Shutdown(std::chrono::system_clock::now() +
                   std::chrono::seconds(flags.shutdown_grace_seconds));
  sweeper.request_stop();
  front_door->stop();  // the gRPC server has drained: close the relayed connections
  if (gateway) gateway->stop();  // quick by now: the gRPC server has drained
  if (http) http->stop();
  log_event(LogLevel::Info, "stopped");
  return 0;
}
