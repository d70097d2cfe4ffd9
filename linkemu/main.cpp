// meshdeform-link: the link emulator as a process, for bench scripts and by hand: relays every
// connection to --target through an emulated link (linkemu/link_emulator.h) until SIGINT or
// SIGTERM, then prints the counters as one JSON line on stdout.
#include <csignal>
#include <cstdio>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include <unistd.h>

#include "common/command_line.h"
#include "linkemu/link_emulator.h"

namespace {

using namespace meshdeform::linkemu;

constexpr const char* kUsage =
    "usage: meshdeform-link --target HOST:PORT --link SPEC [--listen HOST:PORT]\n"
    "\n"
    "Relays every TCP connection accepted on --listen (default 127.0.0.1:0, any free port) to\n"
    "--target through an emulated link, until SIGINT or SIGTERM. Prints\n"
    "  {\"event\":\"listening\",\"port\":N,\"link\":\"...\"}\n"
    "on stderr once it listens, and the byte and stall counters as JSON on stdout at exit.\n"
    "\n"
    "SPEC: comma-separated items, e.g. 20mbit,40ms or 100mbit,20ms,jitter=2ms,loss=0.1%\n"
    "  RATE (20mbit, 512kbit, 1gbit)  both directions' bottleneck rate\n"
    "  DURATION (40ms, 0.04s)         round-trip time, half each way\n"
    "  up=RATE, down=RATE             one direction's rate (down: target to client)\n"
    "  delay-up=DUR, delay-down=DUR   one direction's one-way delay\n"
    "  jitter=DUR                     extra delay per chunk, uniform in [0, DUR] (never reorders)\n"
    "  loss=P (0.01 or 1%)            packet loss, seen as a stall of stall=DUR (default 200ms)\n"
    "  queue=BYTES (256kb, 1mb)       bytes a direction holds (default: rate x delay + 64 KiB,\n"
    "                                 at least 256 KiB); a full queue pushes back on the sender\n";

volatile std::sig_atomic_t g_stop = 0;
void on_signal(int) { g_stop = 1; }

std::string counters_json(const LinkCounters& c) {
  auto direction = [](const DirectionCounters& d) {
    const double mean_ms =
        d.chunks == 0 ? 0.0 : static_cast<double>(d.queue_delay_ns_sum) / 1e6 / static_cast<double>(d.chunks);
    return "{\"bytes_in\":" + std::to_string(d.bytes_in) +
           ",\"bytes_delivered\":" + std::to_string(d.bytes_delivered) +
           ",\"chunks\":" + std::to_string(d.chunks) + ",\"losses\":" + std::to_string(d.losses) +
           ",\"full_queue_waits\":" + std::to_string(d.full_queue_waits) +
           ",\"mean_chunk_delay_ms\":" + std::to_string(mean_ms) +
           ",\"max_chunk_delay_ms\":" + std::to_string(static_cast<double>(d.queue_delay_ns_max) / 1e6) + "}";
  };
  return "{\"connections_accepted\":" + std::to_string(c.connections_accepted) +
         ",\"connect_failures\":" + std::to_string(c.connect_failures) +
         ",\"down\":" + direction(c.down) + ",\"up\":" + direction(c.up) + "}";
}

int run(const std::vector<std::string>& args) {
  namespace cl = meshdeform::command_line;
  CLI::App app;
  cl::configure(app);
  bool help = false;
  std::optional<std::string> target, link, listen;
  cl::add_help(app, help, true);
  cl::add_text(app, "--target", target);
  cl::add_text(app, "--link", link);
  cl::add_text(app, "--listen", listen);
  if (const std::optional<cl::Problem> problem = cl::parse(app, args, cl::Repeats::LastWins)) {
    std::cerr << "meshdeform-link: " << (problem->word.empty() ? problem->message : problem->word + ": " + problem->message)
              << "\n" << kUsage;
    return 2;
  }
  if (help) {
    std::cout << kUsage;
    return 0;
  }
  if (!target || !link) {
    std::cerr << "meshdeform-link: --target and --link are required\n" << kUsage;
    return 2;
  }
  std::string error;
  const std::optional<LinkSettings> settings = parse_link_spec(*link, error);
  if (!settings) {
    std::cerr << "meshdeform-link: --link: " << error << "\n";
    return 2;
  }
  std::string target_host, listen_host = "127.0.0.1";
  int target_port = 0, listen_port = 0;
  if (!split_host_port(*target, target_host, target_port) || target_port == 0) {
    std::cerr << "meshdeform-link: --target must be HOST:PORT, got '" << *target << "'\n";
    return 2;
  }
  if (listen && !split_host_port(*listen, listen_host, listen_port)) {
    std::cerr << "meshdeform-link: --listen must be HOST:PORT, got '" << *listen << "'\n";
    return 2;
  }
  std::unique_ptr<LinkEmulator> emulator =
      LinkEmulator::start(*settings, target_host, target_port, error, listen_host, listen_port);
  if (!emulator) {
    std::cerr << "meshdeform-link: " << error << "\n";
    return 1;
  }
  std::signal(SIGINT, on_signal);
  std::signal(SIGTERM, on_signal);
  std::cerr << "{\"event\":\"listening\",\"port\":" << emulator->port() << ",\"link\":\""
            << describe_link(*settings) << "\"}" << std::endl;
  while (g_stop == 0) ::usleep(50'000);
  const LinkCounters counters = emulator->counters();
  emulator.reset();
  std::cout << counters_json(counters) << std::endl;
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(std::vector<std::string>(argv + 1, argv + argc));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "meshdeform-link: error: %s\n", e.what());
  }
  return 1;
}
