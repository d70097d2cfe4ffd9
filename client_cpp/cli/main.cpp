// meshdeform-client: a command-line front end of meshdeform::client (create a session, set
// handles, move, watch, download, inspect, close, server stats). Output is JSON on stdout (one
// line per object); errors go to stderr. Exit codes: 0 ok, 1 the server (or the connection)
// returned an error, 2 usage or unreadable/malformed local input.
#include <Eigen/Dense>
#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <map>
#include <mutex>
#include <nlohmann/json.hpp>
#include <optional>
#include <set>
#include <stop_token>
#include <string>
#include <string_view>
#include <thread>
#include <vector>

#include "client_cpp/client.h"
#include "common/command_line.h"
#include "core/io/deform_spec.h"
#include "core/io/mesh_io.h"
#include "core/methods/similarity.h"

namespace {

namespace mc = meshdeform::client;
using meshdeform::ErrorCode;
using meshdeform::Result;
using meshdeform::Status;
using nlohmann::json;

constexpr int kExitOk = 0;
constexpr int kExitServer = 1;
constexpr int kExitUsage = 2;

constexpr const char* kUsage = R"(usage: meshdeform-client [global options] COMMAND [options]

Global options (anywhere on the line):
  --server HOST:PORT     the server (default 127.0.0.1:50051)
  --timeout SECONDS      deadline of each call (default 30; watch: see --seconds)
  --max-message-mib N    the channel's message limit (default 64; match the server's)
  --tls-ca FILE          connect with TLS (a server with --tls-cert), trusting the PEM root
                         certificates in FILE (default: plaintext)
  --tls-server-name NAME with TLS: the name the server's certificate must carry, instead of
                         the --server host (alone: TLS with the system's root certificates)
  --tls-cert FILE        with TLS: present this PEM client certificate (and --tls-key FILE, its
                         key) to a server that requires one (--tls-client-ca)
  --help                 this text

Commands (the token may also come from the MESHDEFORM_TOKEN environment variable, which keeps
it out of the process list):
  create (--mesh FILE [--weld] | --sample NAME) [--lambda X] [--rigidity X] [--progress]
      Creates a session; prints {"session_id", "edit_token", "view_token", ...,
      "suggested_groups"}. The mesh format comes from the extension (obj off ply stl glb gltf).
      --progress: one JSON line per phase of the server's work on stderr ({"phase", "fraction",
      "elapsed_seconds"}; phases in deformation.proto's Progress), for big meshes.
  handles --session ID --token T (--sel FILE | --groups JSON|FILE) [--prepare METHOD]
          [--progress]
      Sets the handle groups. A .sel file gives one role per vertex (0 fixed, 1 free, 2 handle):
      group 0 = fixed, group 1 = handle. --groups takes
      [{"role":"fixed","vertices":[...]},{"role":"handle","vertices":[...]}] inline or in a file
      (the "suggested_groups" printed by create).
  move --session ID --token T (--def FILE | --edit JSON|FILE) [--method M] [--ora]
       [--rigidity X] [--iterations N] [--tolerance X] [--editor NAME] [--timeout SECONDS]
      Moves handles and solves; prints the result summary. A .def 4x4 transform moves every
      handle group from its anchors (its positions when 'handles' ran); it must be a similarity
      (rotation, uniform scale, translation). A JSON edit
      spec (see core/io/deform_spec.h) sets its own groups (fixed first, then one per handle
      entry) when they differ from the session's. METHOD: scale_aware, arap, laplacian.
      --rigidity X: scale control of the scale-aware method, 0..10000 (0 = the paper's pure
      method; default: the session's, set by create --rigidity, else 30).
  watch --session ID --token T [--max-updates N] [--seconds S]
        [--updates quantized|lossless [--tolerance X | --relative-tolerance X]
         [--max-update-bytes N] [--lossless-settled]] [--coarse-preview]
      Prints one JSON line per committed revision (the first is a snapshot) until the session
      closes, N updates were printed or S seconds passed. --updates asks for link-sized updates
      (deltas against what this stream delivered, zstd; quantized within the tolerance, default
      1e-4 of the bounding-box diagonal, or lossless); each line then also has "delta" (bytes,
      vertices sent, max error, pending vertices, continuation, lossless). --lossless-settled
      (quantized): the settled revision (no refinement follows: the result after a release)
      comes lossless, bit for bit the server's. --coarse-preview: the lines of
      a multiresolution session's moves also have "coarse" (the level the move was solved on:
      key, vertices, faces, its centroid).
  get --session ID --token T --out FILE [--revision N]
      Downloads the mesh; the format comes from the extension.
  info --session ID --token T       Prints the session summary.
  close --session ID --token T      Closes the session (needs the edit token).
  stats                             Prints the server's process-wide figures.

Exit codes: 0 ok, 1 server or connection error (its code is printed), 2 usage or bad local input.
)";

/// A usage problem or unreadable local input: exit code 2.
struct UsageError {
  std::string message;
};

// ----------------------------------------------------------------------------- argument parsing

struct Args {
  std::string command;
  std::map<std::string, std::string> values;  // option name (without "--") -> value
  std::set<std::string> flags;                // boolean options given

  bool has(const std::string& name) const { return values.count(name) || flags.count(name); }
  std::optional<std::string> get(const std::string& name) const {
    auto it = values.find(name);
    if (it == values.end()) return std::nullopt;
    return it->second;
  }
};

const std::set<std::string> kGlobalValues = {"server",   "timeout",         "max-message-mib",
                                             "tls-ca",   "tls-server-name", "tls-cert",
                                             "tls-key"};
const std::map<std::string, std::set<std::string>> kCommandValues = {
    {"create", {"mesh", "sample", "lambda", "rigidity"}},
    {"handles", {"session", "token", "sel", "groups", "prepare"}},
    {"move",
     {"session", "token", "def", "edit", "method", "rigidity", "iterations", "tolerance", "editor"}},
    {"watch", {"session", "token", "max-updates", "seconds", "updates", "tolerance",
               "relative-tolerance", "max-update-bytes"}},
    {"get", {"session", "token", "out", "revision"}},
    {"info", {"session", "token"}},
    {"close", {"session", "token"}},
    {"stats", {}},
};
const std::map<std::string, std::set<std::string>> kCommandFlags = {
    {"create", {"weld", "progress"}},
    {"handles", {"progress"}},
    {"move", {"ora"}},
    {"watch", {"coarse-preview", "lossless-settled"}},
};

/// Parses the command line with CLI11: the commands are subcommands, the global options are the
/// top level's and may also come after the command (fallthrough).
std::optional<UsageError> parse_args(int argc, char** argv, Args& out) {
  namespace command_line = meshdeform::command_line;
  const std::vector<std::string> words(argv + 1, argv + argc);
  CLI::App app;
  command_line::configure(app);
  app.require_subcommand(0, 1);
  bool help = false;
  command_line::add_help(app, help, false);
  // std::map: the bound values keep their addresses while the App holds references to them.
  std::map<std::string, std::optional<std::string>> global_values;
  for (const std::string& name : kGlobalValues) {
    command_line::add_text(app, "--" + name, global_values[name]);
  }
  std::map<std::string, std::map<std::string, std::optional<std::string>>> command_values;
  std::map<std::string, std::map<std::string, bool>> command_flags;
  for (const auto& [command, names] : kCommandValues) {
    CLI::App* sub = app.add_subcommand(command);
    command_line::configure(*sub);
    sub->fallthrough();  // global options after the command
    for (const std::string& name : names) {
      command_line::add_text(*sub, "--" + name, command_values[command][name]);
    }
    if (const auto flags = kCommandFlags.find(command); flags != kCommandFlags.end()) {
      for (const std::string& name : flags->second) {
        command_line::add_flag(*sub, "--" + name, command_flags[command][name]);
      }
    }
  }
  const std::optional<command_line::Problem> problem =
      command_line::parse(app, words, command_line::Repeats::RefuseValues);
  const std::vector<CLI::App*> given = app.get_subcommands();
  if (!given.empty()) out.command = given.front()->get_name();
  if (problem) {
    using Kind = command_line::Problem::Kind;
    const std::string& word = problem->word;
    // Whether `word` came before the command on the line (or there is no command).
    const auto before_command = [&] {
      if (out.command.empty()) return true;
      const auto at = [&](const std::string& w) {
        return std::find_if(words.begin(), words.end(), [&](const std::string& x) {
          return x == w || x.rfind(w + "=", 0) == 0;
        });
      };
      return at(word) < at(out.command);
    };
    switch (problem->kind) {
      case Kind::UnknownOption:
        if (word.rfind("--", 0) == 0) {
          return UsageError{"unknown option " + word +
                            (before_command() ? std::string(" (options follow the command)")
                                              : " for '" + out.command + "'")};
        }
        [[fallthrough]];
      case Kind::Unexpected:
        if (before_command()) return UsageError{"unknown command '" + word + "'"};
        return UsageError{"unexpected argument '" + word + "'"};
      case Kind::MissingValue:
        return UsageError{word + " needs a value"};
      case Kind::Repeated:
        return UsageError{word + " given twice"};
      case Kind::TakesNoValue:
        return UsageError{word + " takes no value"};
      case Kind::BadValue:  // no add_checked() options here
      case Kind::Other:
        break;
    }
    return UsageError{problem->message};
  }
  if (help) out.flags.insert("help");
  for (const auto& [name, value] : global_values) {
    if (value) out.values[name] = *value;
  }
  if (!out.command.empty()) {
    for (const auto& [name, value] : command_values[out.command]) {
      if (value) out.values[name] = *value;
    }
    for (const auto& [name, is_given] : command_flags[out.command]) {
      if (is_given) out.flags.insert(name);
    }
  }
  return std::nullopt;
}

long long parse_int_or_throw(const std::string& name, const std::string& text, long long min,
                             long long max) {
  long long value = 0;
  const auto [end, ec] = std::from_chars(text.data(), text.data() + text.size(), value);
  if (ec != std::errc() || end != text.data() + text.size() || value < min || value > max) {
    throw UsageError{"--" + name + " '" + text + "' is not an integer in [" + std::to_string(min) +
                     ", " + std::to_string(max) + "]"};
  }
  return value;
}

double parse_double_or_throw(const std::string& name, const std::string& text) {
  char* end = nullptr;
  const double value = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size() || !std::isfinite(value)) {
    throw UsageError{"--" + name + " '" + text + "' is not a finite number"};
  }
  return value;
}

std::string required(const Args& args, const std::string& name) {
  if (auto v = args.get(name)) return *v;
  throw UsageError{"'" + args.command + "' needs --" + name};
}

mc::SessionRef session_ref(const Args& args) {
  mc::SessionRef ref;
  ref.id = required(args, "session");
  if (auto token = args.get("token")) {
    ref.token = *token;
  } else if (const char* env = std::getenv("MESHDEFORM_TOKEN"); env && *env) {
    ref.token = env;
  } else {
    throw UsageError{"'" + args.command + "' needs --token (or MESHDEFORM_TOKEN)"};
  }
  return ref;
}

std::string read_text_file(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) throw UsageError{"no such file: " + path};
  std::ifstream in(path, std::ios::binary);
  std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  if (!in.good() && !in.eof()) throw UsageError{"cannot read " + path};
  return bytes;
}

/// Inline JSON (starting with '{' or '[') or the contents of a file.
std::string inline_or_file(const std::string& value) {
  const auto first = value.find_first_not_of(" \t\r\n");
  if (first != std::string::npos && (value[first] == '{' || value[first] == '[')) return value;
  return read_text_file(value);
}

template <typename T>
T value_or_usage(Result<T> result) {
  if (!result.ok()) throw UsageError{result.status().to_string()};
  return std::move(result).value();
}

meshdeform::core::Method method_or_usage(const std::string& name) {
  return value_or_usage(meshdeform::core::parse_method(name));
}

// ------------------------------------------------------------------------------------- output

const char* role_name(mc::HandleRole role) {
  switch (role) {
    case mc::HandleRole::Fixed:
      return "fixed";
    case mc::HandleRole::Handle:
      return "handle";
  }
  return "?";
}

json groups_json(const std::vector<mc::HandleGroup>& groups) {
  json out = json::array();
  for (const mc::HandleGroup& g : groups) {
    out.push_back({{"role", role_name(g.role)}, {"vertices", g.vertices}});
  }
  return out;
}

json vec_json(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }

json info_json(const mc::SessionInfo& info) {
  json out = {{"session_id", info.session_id},
              {"vertices", info.vertices},
              {"faces", info.faces},
              {"boundary_loops", info.boundary_loops},
              {"components", info.components},
              {"bbox_min", vec_json(info.bbox_min)},
              {"bbox_max", vec_json(info.bbox_max)},
              {"revision", info.revision},
              {"groups", groups_json(info.groups)},
              {"estimated_bytes", info.estimated_bytes},
              {"cached_deformers", info.cached_deformers},
              {"watchers", info.watchers}};
  out["last_method"] =
      info.last_method ? json(meshdeform::core::method_name(*info.last_method)) : json(nullptr);
  return out;
}

json result_json(const mc::DeformResult& r) {
  return {{"revision", r.revision},
          {"method", meshdeform::core::method_name(r.method)},
          {"changed", r.changed_indices.size()},
          {"e_theta", r.e_theta},
          {"e_phi", r.e_phi},
          {"area_log_rms", r.area_log_rms},
          {"rigidity", r.rigidity},
          {"iterations", r.iterations},
          {"converged", r.converged},
          {"solve_seconds", r.solve_seconds},
          {"queue_seconds", r.queue_seconds},
          {"built_deformer", r.built_deformer},
          {"editor", r.editor},
          {"refinement", r.refinement},
          {"settled", r.settled}};
}

/// A failed call: exit code 1 with the error code's name.
int server_error(const std::string& command, const Status& status) {
  std::cerr << "meshdeform-client: " << command << ": " << status.to_string() << "\n";
  return kExitServer;
}

// ----------------------------------------------------------------------------------- commands

/// With --progress: the call reports the server's phases as JSON lines on stderr.
mc::CallOptions progress_call(const Args& args) {
  mc::CallOptions call;
  if (args.flags.count("progress") > 0) {
    call.on_progress = [](const mc::Progress& p) {
      std::cerr << json{{"phase", p.phase}, {"fraction", p.fraction},
                        {"elapsed_seconds", p.elapsed_seconds}}
                       .dump()
                << "\n";
    };
  }
  return call;
}

int cmd_create(const mc::Client& client, const Args& args) {
  const bool has_mesh = args.has("mesh"), has_sample = args.has("sample");
  if (has_mesh == has_sample) throw UsageError{"'create' needs exactly one of --mesh and --sample"};
  mc::CreateOptions create;
  create.weld = args.flags.count("weld") > 0;
  if (auto lambda = args.get("lambda")) create.lambda = parse_double_or_throw("lambda", *lambda);
  if (auto rigidity = args.get("rigidity")) {
    create.rigidity = parse_double_or_throw("rigidity", *rigidity);
  }
  Result<mc::Session> session = Error(ErrorCode::Internal, "unreachable");
  if (has_mesh) {
    const std::string path = *args.get("mesh");
    const meshdeform::io::MeshFormat format =
        value_or_usage(meshdeform::io::format_from_path(path));
    session =
        client.create_session_from_bytes(read_text_file(path), format, create, progress_call(args));
  } else {
    if (create.weld) throw UsageError{"--weld applies to --mesh only"};
    session = client.create_session_from_sample(*args.get("sample"), create, progress_call(args));
  }
  if (!session.ok()) return server_error("create", session.status());
  json out = {{"session_id", session->id},
              {"edit_token", session->edit_token},
              {"view_token", session->view_token},
              {"vertices", session->info.vertices},
              {"faces", session->info.faces},
              {"components", session->info.components},
              {"boundary_loops", session->info.boundary_loops},
              {"welded_vertices", session->welded_vertices},
              {"dropped_unreferenced", session->dropped_unreferenced},
              {"suggested_groups", groups_json(session->suggested_groups)}};
  std::cout << out.dump() << std::endl;
  return kExitOk;
}

std::vector<mc::HandleGroup> groups_from_json(const std::string& text) {
  json doc;
  try {
    doc = json::parse(text);
  } catch (const json::exception& e) {
    throw UsageError{std::string("--groups: malformed JSON: ") + e.what()};
  }
  if (doc.is_object() && doc.contains("groups")) doc = doc["groups"];
  if (doc.is_object() && doc.contains("suggested_groups")) doc = doc["suggested_groups"];
  if (!doc.is_array() || doc.empty()) throw UsageError{"--groups: expected a non-empty array"};
  std::vector<mc::HandleGroup> groups;
  for (std::size_t g = 0; g < doc.size(); ++g) {
    const json& item = doc[g];
    const std::string where = "--groups[" + std::to_string(g) + "]";
    if (!item.is_object() || !item.contains("role") || !item.contains("vertices")) {
      throw UsageError{where + ": expected {\"role\": ..., \"vertices\": [...]}"};
    }
    mc::HandleGroup group;
    const json& role = item["role"];
    if (role == "fixed") {
      group.role = mc::HandleRole::Fixed;
    } else if (role == "handle") {
      group.role = mc::HandleRole::Handle;
    } else {
      throw UsageError{where + ".role: expected \"fixed\" or \"handle\""};
    }
    if (!item["vertices"].is_array()) throw UsageError{where + ".vertices: expected an array"};
    for (const json& v : item["vertices"]) {
      if (!v.is_number_integer() || v.get<long long>() < 0 || v.get<long long>() > INT32_MAX) {
        throw UsageError{where + ".vertices: expected non-negative integers"};
      }
      group.vertices.push_back(v.get<int>());
    }
    groups.push_back(std::move(group));
  }
  return groups;
}

int cmd_handles(const mc::Client& client, const Args& args) {
  const mc::SessionRef ref = session_ref(args);
  if (args.has("sel") == args.has("groups")) {
    throw UsageError{"'handles' needs exactly one of --sel and --groups"};
  }
  meshdeform::core::Method prepare = meshdeform::core::Method::ScaleAware;
  if (auto m = args.get("prepare")) prepare = method_or_usage(*m);
  std::vector<mc::HandleGroup> groups;
  if (auto sel = args.get("sel")) {
    Result<mc::SessionInfo> info = client.session_info(ref);
    if (!info.ok()) return server_error("handles", info.status());
    const Eigen::VectorXi roles =
        value_or_usage(meshdeform::io::parse_sel(read_text_file(*sel), info->vertices));
    mc::HandleGroup fixed{mc::HandleRole::Fixed, {}}, handle{mc::HandleRole::Handle, {}};
    for (Eigen::Index v = 0; v < roles.size(); ++v) {
      if (roles(v) == 0) fixed.vertices.push_back(static_cast<int>(v));
      if (roles(v) == 2) handle.vertices.push_back(static_cast<int>(v));
    }
    if (!fixed.vertices.empty()) groups.push_back(std::move(fixed));
    if (!handle.vertices.empty()) groups.push_back(std::move(handle));
    if (groups.empty()) throw UsageError{*sel + ": no fixed (0) or handle (2) vertex"};
  } else {
    groups = groups_from_json(inline_or_file(*args.get("groups")));
  }
  Result<mc::SessionInfo> info = client.set_handles(ref, groups, prepare, progress_call(args));
  if (!info.ok()) return server_error("handles", info.status());
  json out = info_json(*info);
  out.erase("groups");  // echoing every index adds nothing
  json sizes = json::array();
  for (const mc::HandleGroup& g : info->groups) {
    sizes.push_back({{"role", role_name(g.role)}, {"size", g.vertices.size()}});
  }
  out["groups"] = sizes;
  std::cout << out.dump() << std::endl;
  return kExitOk;
}

/// A 4x4 affine transform as a group move about the origin, if its linear part is a rotation
/// times a positive uniform scale (the only transforms GroupMove expresses).
std::optional<mc::GroupMove> similarity_move(const Eigen::Matrix4d& T, int group) {
  const std::optional<meshdeform::core::GroupSimilarity> similarity =
      meshdeform::core::similarity_from_matrix(T);
  if (!similarity) return std::nullopt;
  mc::GroupMove move;
  move.group = group;
  move.rotation = Eigen::Quaterniond(similarity->rotation).normalized();
  move.scale = similarity->scale;
  move.pivot = similarity->pivot;  // the origin: target = s R anchor + t
  move.translation = similarity->translation;
  return move;
}

int cmd_move(const mc::Client& client, const Args& args) {
  const mc::SessionRef ref = session_ref(args);
  if (args.has("def") == args.has("edit")) {
    throw UsageError{"'move' needs exactly one of --def and --edit"};
  }
  mc::MoveSpec spec;
  std::optional<std::vector<mc::HandleGroup>> spec_groups;  // the groups an edit spec defines
  if (auto def = args.get("def")) {
    const Eigen::Matrix4d T = value_or_usage(meshdeform::io::parse_def(read_text_file(*def)));
    Result<mc::SessionInfo> info = client.session_info(ref);
    if (!info.ok()) return server_error("move", info.status());
    for (std::size_t g = 0; g < info->groups.size(); ++g) {
      if (info->groups[g].role != mc::HandleRole::Handle) continue;
      std::optional<mc::GroupMove> move = similarity_move(T, static_cast<int>(g));
      if (!move) {
        throw UsageError{*def +
                         ": not a similarity (rotation x uniform scale + translation); "
                         "give explicit targets with --edit"};
      }
      spec.moves.push_back(*move);
    }
    if (spec.moves.empty())
      throw UsageError{"the session has no handle group: run 'handles' first"};
  } else {
    const meshdeform::io::EditSpec edit =
        value_or_usage(meshdeform::io::parse_edit_spec(inline_or_file(*args.get("edit"))));
    if (!edit.magnify.empty())
      throw UsageError{"--edit: \"magnify\" is not supported by the service"};
    if (edit.handles.empty()) throw UsageError{"--edit: no handle group to move"};
    std::vector<mc::HandleGroup> groups;
    if (!edit.fixed.empty()) groups.push_back({mc::HandleRole::Fixed, edit.fixed});
    const int first_handle = static_cast<int>(groups.size());
    for (const meshdeform::io::HandleMotion& h : edit.handles) {
      groups.push_back({mc::HandleRole::Handle, h.vertices});
    }
    if (edit.options.method) spec.method = method_or_usage(*edit.options.method);
    if (edit.options.iterations) spec.max_iterations = *edit.options.iterations;
    if (edit.options.tolerance) spec.tolerance = *edit.options.tolerance;
    if (edit.options.ora) spec.ora = *edit.options.ora;
    if (edit.options.rigidity) spec.rigidity = *edit.options.rigidity;
    if (edit.options.inner_iterations) {
      std::cerr << "meshdeform-client: move: warning: options.inner_iterations is not a service "
                   "option; ignored\n";
    }
    for (std::size_t i = 0; i < edit.handles.size(); ++i) {
      const meshdeform::io::HandleMotion& h = edit.handles[i];
      const int g = first_handle + static_cast<int>(i);
      const std::string where = "--edit: handles[" + std::to_string(i) + "]";
      switch (h.form) {
        case meshdeform::io::HandleForm::Rigid: {
          mc::GroupMove move;
          move.group = g;
          move.translation = h.translation;
          move.scale = h.scale;
          move.pivot = h.pivot;
          if (h.rotation) {
            if (h.rotation->axis.norm() == 0) throw UsageError{where + ".rotation: zero axis"};
            move.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(
                h.rotation->angle_deg * M_PI / 180.0, h.rotation->axis.normalized()));
          } else if (h.quaternion) {
            const Eigen::Vector4d& q = *h.quaternion;
            move.rotation = Eigen::Quaterniond(q(0), q(1), q(2), q(3));
          }
          spec.moves.push_back(move);
          break;
        }
        case meshdeform::io::HandleForm::Matrix: {
          std::optional<mc::GroupMove> move = similarity_move(h.matrix, g);
          if (!move) {
            throw UsageError{where + ".matrix: not a similarity; give \"targets\" instead"};
          }
          spec.moves.push_back(*move);
          break;
        }
        case meshdeform::io::HandleForm::Targets: {
          if (h.targets.rows() != static_cast<Eigen::Index>(h.vertices.size())) {
            throw UsageError{where + ": " + std::to_string(h.targets.rows()) + " targets for " +
                             std::to_string(h.vertices.size()) + " vertices"};
          }
          for (std::size_t j = 0; j < h.vertices.size(); ++j) {
            spec.targets.push_back(
                {h.vertices[j], h.targets.row(static_cast<Eigen::Index>(j)).transpose()});
          }
          break;
        }
      }
    }
    spec_groups = std::move(groups);
  }
  // Flags override the spec's options.
  if (auto m = args.get("method")) spec.method = method_or_usage(*m);
  if (args.flags.count("ora")) spec.ora = true;
  if (auto rigidity = args.get("rigidity")) {
    spec.rigidity = parse_double_or_throw("rigidity", *rigidity);
  }
  if (auto it = args.get("iterations")) {
    spec.max_iterations = static_cast<int>(parse_int_or_throw("iterations", *it, 1, 1000));
  }
  if (auto tol = args.get("tolerance")) spec.tolerance = parse_double_or_throw("tolerance", *tol);
  if (auto editor = args.get("editor")) spec.editor = *editor;
  if (spec_groups) {
    // Set the spec's groups only when they differ: SetHandles re-anchors the handles at the
    // current positions, which would change what the spec's transforms mean.
    Result<mc::SessionInfo> info = client.session_info(ref);
    if (!info.ok()) return server_error("move", info.status());
    if (info->groups != *spec_groups) {
      Result<mc::SessionInfo> set = client.set_handles(ref, *spec_groups, spec.method);
      if (!set.ok()) return server_error("move", set.status());
    }
  }
  Result<mc::DeformResult> result = client.move(ref, spec);
  if (!result.ok()) return server_error("move", result.status());
  std::cout << result_json(*result).dump() << std::endl;
  return kExitOk;
}

int cmd_watch(const mc::Client& client, const Args& args) {
  const mc::SessionRef ref = session_ref(args);
  std::optional<long long> max_updates;
  if (auto n = args.get("max-updates")) {
    max_updates = parse_int_or_throw("max-updates", *n, 1, 1'000'000'000);
  }
  std::optional<double> seconds;
  if (auto s = args.get("seconds")) {
    seconds = parse_double_or_throw("seconds", *s);
    if (*seconds <= 0) throw UsageError{"--seconds must be positive"};
  }
  // --seconds ends the watch normally (a stop, not a deadline error).
  std::stop_source stop;
  std::jthread timer;
  if (seconds) {
    const auto period = std::chrono::duration_cast<std::chrono::milliseconds>(
        std::chrono::duration<double>(*seconds));
    timer = std::jthread([period, &stop](std::stop_token cancelled) {
      std::mutex mutex;
      std::condition_variable_any cv;
      std::unique_lock lock(mutex);
      cv.wait_for(lock, cancelled, period, [] { return false; });
      stop.request_stop();
    });
  }
  mc::CallOptions call;
  call.stop = stop.get_token();
  if (seconds) {
    // The stream's deadline is a safety bound a little past the requested time.
    call.timeout = std::chrono::duration_cast<std::chrono::milliseconds>(
                       std::chrono::duration<double>(*seconds)) +
                   std::chrono::seconds(30);
  }
  mc::WatchOptions options;
  options.coarse_preview = args.has("coarse-preview");
  mc::UpdateOptions& updates = options.updates;
  if (auto mode = args.get("updates")) {
    if (*mode == "quantized") {
      updates.mode = mc::UpdateOptions::Mode::Quantized;
    } else if (*mode == "lossless") {
      updates.mode = mc::UpdateOptions::Mode::Lossless;
    } else if (*mode != "off") {
      throw UsageError{"--updates must be off, quantized or lossless, got '" + *mode + "'"};
    }
  }
  for (const char* flag :
       {"tolerance", "relative-tolerance", "max-update-bytes", "lossless-settled"}) {
    if (args.has(flag) && updates.mode != mc::UpdateOptions::Mode::Quantized) {
      throw UsageError{std::string("--") + flag + " needs --updates quantized"};
    }
  }
  if (auto t = args.get("tolerance")) updates.tolerance = parse_double_or_throw("tolerance", *t);
  if (auto t = args.get("relative-tolerance")) {
    updates.relative_tolerance = parse_double_or_throw("relative-tolerance", *t);
  }
  if (auto b = args.get("max-update-bytes")) {
    updates.max_update_bytes =
        static_cast<std::uint32_t>(parse_int_or_throw("max-update-bytes", *b, 0, 1 << 30));
  }
  updates.lossless_settled = args.has("lossless-settled");
  mc::SessionMirror mirror;
  Status mirror_error;
  long long printed = 0;
  Result<mc::WatchEnd> end = client.watch(
      ref,
      [&](const mc::WatchUpdate& update) {
        mirror_error = mirror.apply(update);
        if (!mirror_error.ok()) return false;
        json line = result_json(update.result);
        line["is_snapshot"] = update.is_snapshot;
        line["skipped_revisions"] = update.skipped_revisions;
        line["vertices"] = mirror.positions().rows();
        const Eigen::RowVector3d centroid = mirror.positions().colwise().mean();
        line["centroid"] = vec_json(centroid.transpose());
        if (update.delta) {
          const mc::DeltaStats& d = *update.delta;
          line["delta"] = json{{"sequence", d.sequence},
                               {"payload_bytes", d.payload_bytes},
                               {"wire_bytes", update.wire_bytes},
                               {"vertices_sent", d.vertices_sent},
                               {"shift", d.shift},
                               {"max_error", d.max_error},
                               {"pending_vertices", d.pending_vertices},
                               {"continuation", d.continuation},
                               {"lossless", d.lossless}};
        }
        if (update.coarse) {
          const mc::CoarseLevel& c = *update.coarse;
          line["coarse"] = json{{"key", c.key},
                                {"vertices", c.positions.rows()},
                                {"faces", c.triangles.rows()}};
          if (c.positions.rows() > 0) {
            line["coarse"]["centroid"] = vec_json(c.positions.colwise().mean().transpose());
          }
        }
        std::cout << line.dump() << std::endl;
        ++printed;
        return !(max_updates && printed >= *max_updates);
      },
      call, options);
  timer.request_stop();
  if (!mirror_error.ok()) return server_error("watch", mirror_error);
  if (!end.ok()) return server_error("watch", end.status());
  return kExitOk;
}

int cmd_get(const mc::Client& client, const Args& args) {
  const mc::SessionRef ref = session_ref(args);
  const std::string out = required(args, "out");
  const meshdeform::io::MeshFormat format = value_or_usage(meshdeform::io::format_from_path(out));
  std::optional<std::uint64_t> revision;
  if (auto r = args.get("revision")) {
    revision = static_cast<std::uint64_t>(parse_int_or_throw("revision", *r, 0, INT64_MAX));
  }
  Result<std::string> bytes = client.get_mesh(ref, format, revision);
  if (!bytes.ok()) return server_error("get", bytes.status());
  std::ofstream file(out, std::ios::binary | std::ios::trunc);
  file.write(bytes->data(), static_cast<std::streamsize>(bytes->size()));
  file.close();
  if (!file) throw UsageError{"cannot write " + out};
  std::cout << json{{"out", out},
                    {"format", meshdeform::io::format_name(format)},
                    {"bytes", bytes->size()}}
                   .dump()
            << std::endl;
  return kExitOk;
}

int cmd_info(const mc::Client& client, const Args& args) {
  Result<mc::SessionInfo> info = client.session_info(session_ref(args));
  if (!info.ok()) return server_error("info", info.status());
  std::cout << info_json(*info).dump() << std::endl;
  return kExitOk;
}

int cmd_close(const mc::Client& client, const Args& args) {
  const mc::SessionRef ref = session_ref(args);
  const Status status = client.close_session(ref);
  if (!status.ok()) return server_error("close", status);
  std::cout << json{{"closed", ref.id}}.dump() << std::endl;
  return kExitOk;
}

int cmd_stats(const mc::Client& client) {
  Result<mc::ServerStats> stats = client.server_stats();
  if (!stats.ok()) return server_error("stats", stats.status());
  const mc::ServerStats& s = *stats;
  std::cout << json{{"sessions", s.sessions},
                    {"estimated_bytes", s.estimated_bytes},
                    {"resident_bytes", s.resident_bytes},
                    {"moves_committed", s.moves_committed},
                    {"moves_cancelled", s.moves_cancelled},
                    {"refinements_committed", s.refinements_committed},
                    {"deformer_constructions", s.deformer_constructions},
                    {"evicted_lru", s.evicted_lru},
                    {"evicted_idle", s.evicted_idle},
                    {"workers", s.workers},
                    {"uptime_seconds", s.uptime_seconds}}
                   .dump()
            << std::endl;
  return kExitOk;
}

int run(int argc, char** argv) {
  Args args;
  if (std::optional<UsageError> error = parse_args(argc, argv, args)) throw *error;
  if (args.flags.count("help")) {
    std::cout << kUsage;
    return kExitOk;
  }
  if (args.command.empty()) throw UsageError{"no command given"};
  mc::ClientOptions options;
  if (auto server = args.get("server")) options.target = *server;
  if (auto timeout = args.get("timeout")) {
    const double s = parse_double_or_throw("timeout", *timeout);
    if (s <= 0) throw UsageError{"--timeout must be positive"};
    options.default_timeout =
        std::chrono::duration_cast<std::chrono::milliseconds>(std::chrono::duration<double>(s));
    if (options.default_timeout.count() < 1) options.default_timeout = std::chrono::milliseconds(1);
  }
  if (auto mib = args.get("max-message-mib")) {
    options.max_message_mib =
        static_cast<int>(parse_int_or_throw("max-message-mib", *mib, 1, 2047));
  }
  if (args.has("tls-ca") || args.has("tls-server-name")) {
    options.tls.emplace();
    if (auto ca = args.get("tls-ca")) options.tls->root_certs_file = *ca;
    if (auto name = args.get("tls-server-name")) options.tls->server_name = *name;
  }
  if (args.has("tls-cert") || args.has("tls-key")) {
    if (!options.tls) {
      throw UsageError{"--tls-cert and --tls-key need --tls-ca or --tls-server-name"};
    }
    if (!args.has("tls-cert") || !args.has("tls-key")) {
      throw UsageError{"--tls-cert and --tls-key go together"};
    }
    options.tls->client_cert_chain_pem = read_text_file(*args.get("tls-cert"));
    options.tls->client_private_key_pem = read_text_file(*args.get("tls-key"));
  }
  const mc::Client client = value_or_usage(mc::Client::connect(options));
  if (args.command == "create") return cmd_create(client, args);
  if (args.command == "handles") return cmd_handles(client, args);
  if (args.command == "move") return cmd_move(client, args);
  if (args.command == "watch") return cmd_watch(client, args);
  if (args.command == "get") return cmd_get(client, args);
  if (args.command == "info") return cmd_info(client, args);
  if (args.command == "close") return cmd_close(client, args);
  if (args.command == "stats") return cmd_stats(client);
  throw UsageError{"unknown command '" + args.command + "'"};
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(argc, argv);
  } catch (const UsageError& error) {
    std::cerr << "meshdeform-client: " << error.message << "\n"
              << "run 'meshdeform-client --help' for usage\n";
    return kExitUsage;
  } catch (const std::exception& error) {
    std::cerr << "meshdeform-client: unexpected error: " << error.what() << "\n";
    return kExitServer;
  }
}
