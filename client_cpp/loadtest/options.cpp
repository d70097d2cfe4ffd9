#include "client_cpp/loadtest/options.h"

#include "linkemu/link_emulator.h"

#include <arpa/inet.h>

#include <algorithm>
#include <cctype>
#include <charconv>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <optional>
#include <string>

#include "common/command_line.h"

namespace meshdeform::loadtest {
namespace {

namespace command_line = meshdeform::command_line;

bool parse_int64(std::string_view text, std::int64_t min, std::int64_t max, std::int64_t& out) {
  std::int64_t value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || value < min || value > max) {
    return false;
  }
  out = value;
  return true;
}

bool parse_int(std::string_view text, int min, int max, int& out) {
  std::int64_t value = 0;
  if (!parse_int64(text, min, max, value)) return false;
  out = static_cast<int>(value);
  return true;
}

// A finite decimal in [min, max] (strtod: from_chars for double is not in every libstdc++).
bool parse_double(std::string_view text, double min, double max, double& out) {
  if (text.empty() || text.size() > 64) return false;
  const std::string copy(text);
  char* end = nullptr;
  const double value = std::strtod(copy.c_str(), &end);
  if (end != copy.c_str() + copy.size() || !std::isfinite(value) || value < min || value > max) {
    return false;
  }
  out = value;
  return true;
}

bool parse_method(std::string_view text, Method& out) {
  for (const Method method : {Method::ScaleAware, Method::Arap, Method::Laplacian}) {
    if (text == method_name(method)) {
      out = method;
      return true;
    }
  }
  return false;
}

bool starts_with(std::string_view text, std::string_view prefix) {
  return text.substr(0, prefix.size()) == prefix;
}

bool is_loopback_host(std::string_view host) {
  std::string lower(host);
  std::transform(lower.begin(), lower.end(), lower.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (lower == "localhost") return true;
  unsigned char bytes[16] = {};
  if (inet_pton(AF_INET, lower.c_str(), bytes) == 1) return bytes[0] == 127;
  if (inet_pton(AF_INET6, lower.c_str(), bytes) == 1) {
    static constexpr unsigned char kLoopback6[16] = {0, 0, 0, 0, 0, 0, 0, 0,
                                                     0, 0, 0, 0, 0, 0, 0, 1};
    return std::equal(std::begin(bytes), std::end(bytes), std::begin(kLoopback6));
  }
  return false;
}

}  // namespace

std::string_view method_name(Method method) {
  switch (method) {
    case Method::ScaleAware:
      return "scale_aware";
    case Method::Arap:
      return "arap";
    case Method::Laplacian:
      return "laplacian";
  }
  return "scale_aware";
}

std::string_view updates_name(Updates updates) {
  switch (updates) {
    case Updates::Quantized:
      return "quantized";
    case Updates::Lossless:
      return "lossless";
    case Updates::Off:
      break;
  }
  return "off";
}

std::string_view encoding_name(Encoding encoding) {
  switch (encoding) {
    case Encoding::Doubles:
      return "doubles";
    case Encoding::Float32:
      return "float32";
    case Encoding::Meshopt:
      return "meshopt";
  }
  return "doubles";
}

int Options::channel_count() const {
  return connections == 0 ? sessions : std::min(connections, sessions);
}

std::string usage_text() {
  return "usage: meshdeform-loadtest --server HOST:PORT [flags]\n"
         "Drives a meshdeform-server with scripted interactive clients and reports throughput,\n"
         "latency, watcher propagation and server memory.\n"
         "  --server TARGET        gRPC target, e.g. 127.0.0.1:50051 (required)\n"
         "  --sessions N           concurrent sessions, each with its own mesh (default 1)\n"
         "  --sample NAME          built-in sample to create each session from (default cylinder)\n"
         "  --mesh FILE            upload this mesh (.obj .off .ply .stl .glb .gltf) instead; its\n"
         "                         fixed/handle groups are the lowest/highest 5% along the "
         "longest\n"
         "                         bounding-box axis\n"
         "  --moves M              moves per session (default 0 = until the duration ends)\n"
         "  --rate HZ              move ticks per second per session (default 10; 0 = back to "
         "back)\n"
         "                         Each session keeps ONE move in flight, like a real drag: a "
         "tick\n"
         "                         that comes while the previous move is still in flight is "
         "skipped\n"
         "                         (counted as a skipped tick) and the next move goes at the "
         "first\n"
         "                         tick after the response, aimed at that tick's (newest) target.\n"
         "  --duration S           hard bound for the whole run, setup included (default 60); "
         "moves\n"
         "                         in flight then get at most a 5 s drain\n"
         "  --watchers W           Watch streams per session (default 0)\n"
         "  --iterations K         max_iterations per move (default 2)\n"
         "  --method NAME          scale_aware, arap or laplacian (default scale_aware)\n"
         "  --encoding NAME        positions in move responses and watch updates: doubles,\n"
         "                         float32 or meshopt (default doubles)\n"
         "  --updates MODE         link-sized watch updates: off (default), quantized or\n"
         "                         lossless; moves then carry no positions (the editor's\n"
         "                         geometry comes from its watch stream: use --watchers >= 1)\n"
         "  --tolerance X          quantized: the tolerance in model units (default: relative)\n"
         "  --relative-tolerance X quantized: fraction of the bounding-box diagonal (server\n"
         "                         default 1e-4)\n"
         "  --max-update-bytes N   quantized: payload budget per update (0: none; >= 1024)\n"
         "  --lossless-settled     quantized: settled revisions (no refinement follows: the\n"
         "                         result after a release) come lossless; the report counts the\n"
         "                         lossless updates, and --settle-seconds also times the settled\n"
         "                         revision\n"
         "  --fixed-receive-window keep gRPC's 64 KiB receive window (no BDP probing): HTTP/2\n"
         "                         flow control then bounds what a watch has in flight, and a\n"
         "                         slow line skips to the newest revision (a remote viewer's\n"
         "                         setting; ClientOptions::adaptive_receive_window false)\n"
         "  --send-on-response     when ticks came while a move was in flight, send the newest\n"
         "                         target as soon as the response arrives (the viewer's drag)\n"
         "                         instead of at the next tick; still one move in flight\n"
         "  --coarse-preview       watchers ask for the coarse level of multiresolution moves\n"
         "                         (a server session above --multires-above); the report counts\n"
         "                         the updates that carried one and their coarse bytes\n"
         "  --settle-seconds S     after its drag, each session waits up to S s for a converged\n"
         "                         revision at or past its last move (the server's background\n"
         "                         refinement; needs --watchers) and reports the time from the\n"
         "                         last move's response to a watcher's receipt of it\n"
         "  --via-link SPEC        run every channel through an emulated link, e.g. 20mbit,40ms\n"
         "                         or 100mbit,20ms,jitter=2ms,loss=0.1% (a line per channel;\n"
         "                         see meshdeform-link --help); reports name the link\n"
         "  --connections C        gRPC channels to spread the sessions over (default 0 = one per\n"
         "                         session); a session's watchers share its channel\n"
         "  --move-deadline-ms MS  deadline of each move (default 10000)\n"
         "  --max-message-mib N    client message limit (default 64; raise for huge snapshots)\n"
         "  --tls-ca FILE          connect with TLS (a server with --tls-cert), trusting the PEM\n"
         "                         root certificates in FILE (default: plaintext)\n"
         "  --tls-server-name NAME with --tls-ca: the name the server's certificate must carry\n"
         "                         instead of the --server host\n"
         "  --json FILE            write the full report as JSON\n"
         "  --markdown FILE        write a Markdown summary (for bench/results/)\n"
         "  --allow-remote         allow a target that is not loopback (127.0.0.0/8, ::1,\n"
         "                         localhost); refused otherwise\n"
         "  --fail-on-errors       exit 1 if any move failed (for CI)\n"
         "  --help                 this text\n"
         "Exit codes: 0 the run completed (errors are reported); 1 setup failed for every "
         "session,\n"
         "or --fail-on-errors and a move failed; 2 usage error.\n";
}

ParseOutcome parse_options(const std::vector<std::string>& args, Options& options) {
  const auto usage_error = [](std::string message) {
    return ParseOutcome{ParseOutcome::Kind::UsageError, std::move(message)};
  };
  // CLI11 (common/command_line.h) reads the line; each value is checked as soon as it is read, so
  // the first bad one is reported, and --help/-h stops the parse.
  CLI::App app;
  command_line::configure(app);
  bool help = false;
  command_line::add_help(app, help, true);
  command_line::add_flag(app, "--allow-remote", options.allow_remote);
  command_line::add_flag(app, "--fail-on-errors", options.fail_on_errors);
  command_line::add_flag(app, "--fixed-receive-window", options.fixed_receive_window);
  command_line::add_flag(app, "--send-on-response", options.send_on_response);
  command_line::add_flag(app, "--coarse-preview", options.coarse_preview);
  command_line::add_flag(app, "--lossless-settled", options.lossless_settled);
  bool has_sample = false;
  // The value is refused with the generic message below; no per-flag text.
  const auto check = [](bool ok) { return ok ? std::nullopt : std::optional<std::string>(""); };
  const auto text = [&](const std::string& name, std::string& out) {
    command_line::add_checked(app, name, [&out, check](const std::string& value) {
      out = value;
      return check(!value.empty());
    });
  };
  const auto integer = [&](const std::string& name, int min, int max, int& out) {
    command_line::add_checked(app, name, [min, max, &out, check](const std::string& value) {
      return check(parse_int(value, min, max, out));
    });
  };
  const auto number = [&](const std::string& name, double min, double max, double& out) {
    command_line::add_checked(app, name, [min, max, &out, check](const std::string& value) {
      return check(parse_double(value, min, max, out));
    });
  };
  text("--server", options.server);
  integer("--sessions", 1, 1024, options.sessions);
  command_line::add_checked(app, "--sample", [&](const std::string& value) {
    options.sample = value;
    has_sample = true;
    return check(!value.empty());
  });
  text("--mesh", options.mesh_path);
  command_line::add_checked(app, "--moves", [&](const std::string& value) {
    return check(parse_int64(value, 0, 100'000'000, options.moves));
  });
  number("--rate", 0.0, 10'000.0, options.rate_hz);
  number("--duration", 0.1, 7.0 * 24 * 3600, options.duration_seconds);
  integer("--watchers", 0, 64, options.watchers);
  number("--settle-seconds", 0.0, 3600.0, options.settle_seconds);
  integer("--iterations", 1, 1000, options.iterations);
  command_line::add_checked(app, "--method", [&](const std::string& value) {
    return check(parse_method(value, options.method));
  });
  command_line::add_checked(app, "--encoding", [&](const std::string& value) {
    for (Encoding e : {Encoding::Doubles, Encoding::Float32, Encoding::Meshopt}) {
      if (value == encoding_name(e)) {
        options.encoding = e;
        return check(true);
      }
    }
    return check(false);
  });
  command_line::add_checked(app, "--updates", [&](const std::string& value) {
    for (Updates u : {Updates::Off, Updates::Quantized, Updates::Lossless}) {
      if (value == updates_name(u)) {
        options.updates = u;
        return check(true);
      }
    }
    return check(false);
  });
  number("--tolerance", 0.0, 1e6, options.tolerance);
  number("--relative-tolerance", 0.0, 0.1, options.relative_tolerance);
  command_line::add_checked(app, "--max-update-bytes", [&](const std::string& value) {
    int bytes = 0;
    const bool ok = parse_int(value, 0, 1 << 30, bytes) && (bytes == 0 || bytes >= 1024);
    options.max_update_bytes = static_cast<std::uint32_t>(bytes);
    return check(ok);
  });
  text("--via-link", options.via_link);
  text("--json", options.json_path);
  text("--markdown", options.markdown_path);
  integer("--connections", 0, 1024, options.connections);
  integer("--move-deadline-ms", 1, 3'600'000, options.move_deadline_ms);
  integer("--max-message-mib", 1, 1024, options.max_message_mib);
  text("--tls-ca", options.tls_ca_path);
  text("--tls-server-name", options.tls_server_name);

  const std::optional<command_line::Problem> problem =
      command_line::parse(app, args, command_line::Repeats::LastWins);
  if (help) return ParseOutcome{ParseOutcome::Kind::Help, {}};
  if (problem) {
    using Kind = command_line::Problem::Kind;
    switch (problem->kind) {
      case Kind::BadValue:
        return usage_error("bad value '" + problem->value + "' for " + problem->word);
      case Kind::MissingValue:
        return usage_error(problem->word + " needs a value");
      case Kind::TakesNoValue:
        return usage_error(problem->word + " takes no value");
      case Kind::UnknownOption:
        if (starts_with(problem->word, "--")) return usage_error("unknown flag " + problem->word);
        [[fallthrough]];
      case Kind::Unexpected:
        return usage_error("unexpected argument '" + problem->word + "'");
      case Kind::Repeated:
      case Kind::Other:
        break;
    }
    return usage_error(problem->message);
  }
  if (options.server.empty()) return usage_error("--server is required");
  if (!options.tls_server_name.empty() && options.tls_ca_path.empty()) {
    return usage_error("--tls-server-name needs --tls-ca");
  }
  if (!options.tls_ca_path.empty()) {
    std::ifstream in(options.tls_ca_path, std::ios::binary);
    options.tls_root_certs.assign(std::istreambuf_iterator<char>(in),
                                  std::istreambuf_iterator<char>());
    if (options.tls_root_certs.empty()) {
      return usage_error("cannot read --tls-ca file '" + options.tls_ca_path +
                         "' (missing or empty)");
    }
  }
  if (!options.via_link.empty()) {
    std::string error;
    if (!linkemu::parse_link_spec(options.via_link, error)) {
      return usage_error("--via-link: " + error);
    }
  }
  if (options.updates == Updates::Off &&
      (options.tolerance > 0 || options.relative_tolerance > 0 || options.max_update_bytes > 0)) {
    return usage_error("--tolerance, --relative-tolerance and --max-update-bytes need --updates");
  }
  if (options.lossless_settled && options.updates != Updates::Quantized) {
    return usage_error("--lossless-settled needs --updates quantized");
  }
  if (options.settle_seconds > 0 && options.watchers < 1) {
    return usage_error("--settle-seconds needs --watchers >= 1 (a watcher sees the refinement)");
  }
  if (has_sample && !options.mesh_path.empty()) {
    return usage_error("give --sample or --mesh, not both");
  }
  if (!options.allow_remote && !is_loopback_target(options.server)) {
    return usage_error("refusing to load '" + options.server +
                       "': not a loopback address (127.0.0.0/8, ::1, localhost); pass "
                       "--allow-remote to load a remote server");
  }
  return ParseOutcome{ParseOutcome::Kind::Run, {}};
}

bool is_loopback_target(std::string_view target) {
  if (starts_with(target, "unix:") || starts_with(target, "unix-abstract:")) return true;
  for (const std::string_view scheme : {"dns://", "dns:", "ipv4:", "ipv6:"}) {
    if (starts_with(target, scheme)) {
      target.remove_prefix(scheme.size());
      break;
    }
  }
  std::string_view host;
  if (starts_with(target, "[")) {
    const std::size_t close = target.find(']');
    if (close == std::string_view::npos) return false;
    host = target.substr(1, close - 1);
    const std::string_view rest = target.substr(close + 1);
    if (!rest.empty() && !starts_with(rest, ":")) return false;
  } else {
    const std::size_t colon = target.rfind(':');
    // A bare IPv6 literal has several colons and no port ("::1"); gRPC wants brackets then.
    if (colon != std::string_view::npos && target.find(':') != colon) {
      host = target;
    } else {
      host = colon == std::string_view::npos ? target : target.substr(0, colon);
    }
  }
  return !host.empty() && is_loopback_host(host);
}

}  // namespace meshdeform::loadtest
