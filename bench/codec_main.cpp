// meshdeform-bench-codec (issue 45): what a link-sized update costs, per mesh size: a smooth
// drag of N revisions (the upper part of the mesh bent about its base, a little more each
// revision, every vertex moving as a drag's do) encoded by one stream's StreamEncoder and
// decoded by a StreamDecoder, in three modes: quantized at the default tolerance (1e-4 of the
// bounding-box diagonal) without a budget, the same within 149,000 bytes per update, and
// lossless. Prints and writes (--markdown, --json) the join size and, per drag update, bytes,
// encode and decode times. Bytes are exact for the input; times depend on the machine's load,
// which the report states. The load tester's runs through the link emulator (bench/run_link.sh)
// measure the same on the solver's own revisions.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "codec/update_codec.h"
#include "common/command_line.h"
#include "core/io/mesh_io.h"
#include "machine_info.h"

namespace {

using namespace meshdeform;
using namespace meshdeform::bench;
using Clock = std::chrono::steady_clock;

double p50(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v[(v.size() - 1) / 2];
}
double maximum(const std::vector<double>& v) {
  return v.empty() ? 0 : *std::max_element(v.begin(), v.end());
}

/// The mesh bent by `degrees` about the bottom of its longest axis, growing with height squared.
Positions bent(const Positions& V, double degrees) {
  const Eigen::Vector3d lo = V.colwise().minCoeff(), hi = V.colwise().maxCoeff();
  int axis = 0;
  for (int k = 1; k < 3; ++k) {
    if (hi[k] - lo[k] > hi[axis] - lo[axis]) axis = k;
  }
  const int across = (axis + 1) % 3, other = (axis + 2) % 3;
  Positions out = V;
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    const double t = (V(i, axis) - lo[axis]) / (hi[axis] - lo[axis]);
    const double a = degrees * M_PI / 180.0 * t * t;
    const double y = V(i, axis) - lo[axis], x = V(i, across) - 0.5 * (lo[across] + hi[across]);
    out(i, axis) = lo[axis] + y * std::cos(a) - x * std::sin(a);
    out(i, across) = 0.5 * (lo[across] + hi[across]) + y * std::sin(a) + x * std::cos(a);
    out(i, other) = V(i, other);
  }
  return out;
}

struct Row {
  std::string mesh, mode;
  int vertices = 0;
  double join_bytes = 0, bytes_p50 = 0, bytes_max = 0, encode_ms = 0, decode_ms = 0;
  int updates = 0, continuations = 0;
  double max_error = 0;
};

Row run(const std::string& name, const Positions& V, codec::StreamSettings settings,
        const std::string& mode, int revisions) {
  Row row;
  row.mesh = name;
  row.mode = mode;
  row.vertices = static_cast<int>(V.rows());
  auto encoder = codec::StreamEncoder::create(settings, row.vertices);
  if (!encoder.ok()) throw std::runtime_error(encoder.status().message());
  codec::StreamDecoder decoder;
  std::vector<double> bytes, encode, decode;
  auto one = [&](const std::function<Result<codec::EncodedUpdate>()>& make, bool join) {
    const auto t0 = Clock::now();
    Result<codec::EncodedUpdate> u = make();
    const auto t1 = Clock::now();
    if (!u.ok()) throw std::runtime_error(u.status().message());
    const Status applied = decoder.apply(u->header, u->payload);
    const auto t2 = Clock::now();
    if (!applied.ok()) throw std::runtime_error(applied.message());
    if (join) {
      row.join_bytes += static_cast<double>(u->payload.size());
    } else {
      bytes.push_back(static_cast<double>(u->payload.size()));
      encode.push_back(std::chrono::duration<double, std::milli>(t1 - t0).count());
      decode.push_back(std::chrono::duration<double, std::milli>(t2 - t1).count());
      row.max_error = std::max(row.max_error, u->header.max_error);
    }
  };
  one([&] { return encoder->encode(V, 0); }, true);
  while (encoder->pending()) one([&] { return encoder->encode_pending(); }, true);
  for (int r = 1; r <= revisions; ++r) {
    const Positions target = bent(V, 1.5 * r);
    one([&] { return encoder->encode(target, static_cast<std::uint64_t>(r)); }, false);
    ++row.updates;
  }
  // After the drag: continuations until the last revision is complete (bounded).
  for (int i = 0; i < 1000 && encoder->pending(); ++i) {
    one([&] { return encoder->encode_pending(); }, false);
    ++row.continuations;
  }
  row.bytes_p50 = p50(bytes);
  row.bytes_max = maximum(bytes);
  row.encode_ms = p50(encode);
  row.decode_ms = p50(decode);
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  namespace cl = meshdeform::command_line;
  CLI::App app;
  cl::configure(app);
  bool help = false;
  std::vector<std::string> meshes;
  std::optional<std::string> markdown, json_path;
  int revisions = 20;
  cl::add_help(app, help, true);
  app.add_option("--mesh", meshes);
  cl::add_text(app, "--markdown", markdown);
  cl::add_text(app, "--json", json_path);
  app.add_option("--revisions", revisions);
  if (auto problem = cl::parse(app, std::vector<std::string>(argv + 1, argv + argc),
                               cl::Repeats::LastWins)) {
    std::cerr << "meshdeform-bench-codec: " << problem->word << " " << problem->message << "\n";
    return 2;
  }
  if (help || meshes.empty()) {
    std::cout << "usage: meshdeform-bench-codec --mesh FILE [--mesh FILE ...] [--revisions N]\n"
                 "       [--markdown FILE] [--json FILE]\n";
    return help ? 0 : 2;
  }
  const MachineInfo machine = collect_machine_info();
  std::vector<Row> rows;
  try {
    for (const std::string& path : meshes) {
      Result<MeshData> mesh = io::read_mesh(path);
      if (!mesh.ok()) throw std::runtime_error(path + ": " + mesh.status().message());
      const Positions& V = mesh->V;
      const Eigen::Vector3d lo = V.colwise().minCoeff(), hi = V.colwise().maxCoeff();
      const std::string name = std::filesystem::path(path).filename().string();
      codec::StreamSettings q;
      q.tolerance = 1e-4 * (hi - lo).norm();
      q.origin = lo;
      rows.push_back(run(name, V, q, "quantized 1e-4", revisions));
      codec::StreamSettings b = q;
      b.max_update_bytes = 149'000;
      rows.push_back(run(name, V, b, "quantized 1e-4, 149 kB budget", revisions));
      codec::StreamSettings l;
      l.mode = codec::DeltaMode::Lossless;
      rows.push_back(run(name, V, l, "lossless", revisions));
    }
  } catch (const std::exception& e) {
    std::cerr << "meshdeform-bench-codec: " << e.what() << "\n";
    return 1;
  }
  std::ostringstream md;
  md << "# Link-sized updates: what an update costs (meshdeform-bench-codec)\n\n"
     << "A smooth drag of " << revisions
     << " revisions per mesh (the upper part bent 1.5 degrees more each revision: every vertex "
        "moves), one stream, payload bytes (zstd) per drag update; continuations are the "
        "updates after the drag that complete a budget-limited revision. Times: one thread, "
        "p50. Machine: "
     << machine.cpu_model << ", " << machine.hardware_threads << " threads, load "
     << machine.load_average << " at start, " << read_load_average() << " at end.\n\n"
     << "| mesh | vertices | mode | join bytes | bytes/update p50 | max | continuations | "
        "max error | encode ms | decode ms |\n|---|---:|---|---:|---:|---:|---:|---:|---:|---:|\n";
  nlohmann::json out = nlohmann::json::array();
  for (const Row& r : rows) {
    char line[512];
    std::snprintf(line, sizeof line, "| %s | %d | %s | %.0f | %.0f | %.0f | %d | %.3g | %.2f | %.2f |\n",
                  r.mesh.c_str(), r.vertices, r.mode.c_str(), r.join_bytes, r.bytes_p50,
                  r.bytes_max, r.continuations, r.max_error, r.encode_ms, r.decode_ms);
    md << line;
    out.push_back({{"mesh", r.mesh}, {"vertices", r.vertices}, {"mode", r.mode},
                   {"join_bytes", r.join_bytes}, {"bytes_p50", r.bytes_p50},
                   {"bytes_max", r.bytes_max}, {"continuations", r.continuations},
                   {"max_error", r.max_error}, {"encode_ms_p50", r.encode_ms},
                   {"decode_ms_p50", r.decode_ms}});
  }
  std::cout << md.str();
  if (markdown) std::ofstream(*markdown) << md.str();
  if (json_path) {
    std::ofstream(*json_path) << nlohmann::json{{"tool", "meshdeform-bench-codec"},
                                                {"machine", machine_json(machine, read_load_average())},
                                                {"rows", out}}.dump(2)
                              << "\n";
  }
  return 0;
}
