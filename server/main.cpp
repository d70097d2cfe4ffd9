// meshdeform-server: flags, ServerBuilder, health, reflection and signal handling; no logic.
#include <grpcpp/security/server_credentials.h>
#include <grpcpp/server.h>
#include <grpcpp/server_builder.h>

#include <pthread.h>
#include <signal.h>

#include <algorithm>
#include <charconv>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <iostream>
#include <memory>
#include <mutex>
#include <stop_token>
#include <string>
#include <string_view>
#include <thread>

#include "server/service/deformation_service.h"
#include "server/transport/deform_service_impl.h"
#include "server/transport/server_setup.h"

namespace {

struct Flags {
  std::string listen = "127.0.0.1:50051";
  int max_sessions = 64;
  int max_vertices = 250'000;
  int idle_ttl_seconds = 30 * 60;
  int max_message_mib = 64;
  int workers = 0;
  int shutdown_grace_seconds = 10;
};

constexpr const char* kUsage =
    "usage: meshdeform-server [flags]\n"
    "  --listen ADDR               host:port to serve on (default 127.0.0.1:50051; 0.0.0.0:PORT\n"
    "                              for every interface; the connection is plaintext)\n"
    "  --max-sessions N            open sessions (default 64)\n"
    "  --max-vertices N            vertices per mesh (default 250000)\n"
    "  --idle-ttl-seconds N        sessions idle for longer are closed (default 1800)\n"
    "  --max-message-mib N         largest request/response, e.g. a mesh upload (default 64)\n"
    "  --workers N                 solver threads (default 0 = one per core)\n"
    "  --shutdown-grace-seconds N  on SIGTERM/SIGINT, time to finish calls (default 10)\n";

bool parse_int(std::string_view text, int min, int max, int& out) {
  int value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || value < min || value > max) {
    return false;
  }
  out = value;
  return true;
}

/// @return false (after printing why) for an unknown flag or a bad value.
bool parse_flags(int argc, char** argv, Flags& flags, bool& help) {
  for (int i = 1; i < argc; ++i) {
    std::string_view arg = argv[i], value;
    if (arg == "--help" || arg == "-h") {
      help = true;
      return true;
    }
    if (const std::size_t eq = arg.find('='); eq != std::string_view::npos) {
      value = arg.substr(eq + 1);
      arg = arg.substr(0, eq);
    } else if (i + 1 < argc) {
      value = argv[++i];
    } else {
      std::cerr << "meshdeform-server: " << arg << " needs a value\n" << kUsage;
      return false;
    }
    bool ok = true;
    if (arg == "--listen") {
      flags.listen = std::string(value);
      ok = !value.empty();
    } else if (arg == "--max-sessions") {
      ok = parse_int(value, 1, 1'000'000, flags.max_sessions);
    } else if (arg == "--max-vertices") {
      ok = parse_int(value, 3, 100'000'000, flags.max_vertices);
    } else if (arg == "--idle-ttl-seconds") {
      ok = parse_int(value, 1, 365 * 24 * 3600, flags.idle_ttl_seconds);
    } else if (arg == "--max-message-mib") {
      ok = parse_int(value, 1, 2047, flags.max_message_mib);
    } else if (arg == "--workers") {
      ok = parse_int(value, 0, 1024, flags.workers);
    } else if (arg == "--shutdown-grace-seconds") {
      ok = parse_int(value, 0, 3600, flags.shutdown_grace_seconds);
    } else {
      std::cerr << "meshdeform-server: unknown flag " << arg << "\n" << kUsage;
      return false;
    }
    if (!ok) {
      std::cerr << "meshdeform-server: bad value '" << value << "' for " << arg << "\n";
      return false;
    }
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  Flags flags;
  bool help = false;
  if (!parse_flags(argc, argv, flags, help)) return 2;
  if (help) {
    std::cout << kUsage;
    return 0;
  }

  // Block the shutdown signals before any thread starts, so every thread inherits the mask and
  // only sigwait below receives them.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGTERM);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  meshdeform::service::ServiceOptions options;
  options.workers = flags.workers;
  options.max_sessions = flags.max_sessions;
  options.max_vertices = flags.max_vertices;
  options.idle_ttl = std::chrono::seconds(flags.idle_ttl_seconds);
  meshdeform::service::DeformationService service(options);
  meshdeform::transport::DeformServiceImpl impl(service);

  meshdeform::transport::enable_health_and_reflection();
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort(flags.listen, grpc::InsecureServerCredentials(), &port);
  meshdeform::transport::configure_builder(builder, impl, flags.max_message_mib);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (!server || port == 0) {
    std::cerr << "meshdeform-server: cannot listen on " << flags.listen << "\n";
    return 1;
  }
  std::cerr << "meshdeform-server: listening on " << flags.listen << " (port " << port << "), "
            << service.stats().workers << " workers\n";

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
  sigwait(&signals, &received);
  std::cerr << "meshdeform-server: signal " << received << ", shutting down (grace "
            << flags.shutdown_grace_seconds << " s)\n";
  // Stops accepting calls; after the grace period, cancels what is left (running solves see
  // the cancellation through their stop token and end quickly).
  server->Shutdown(std::chrono::system_clock::now() +
                   std::chrono::seconds(flags.shutdown_grace_seconds));
  sweeper.request_stop();
  return 0;
}
