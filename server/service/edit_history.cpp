#include "server/service/edit_history.h"

#include <algorithm>
#include <cmath>
#include <string>

namespace meshdeform::service {
namespace {

bool same_move(const GroupMove& a, const GroupMove& b) {
  return a.group == b.group && a.translation == b.translation &&
         a.rotation.coeffs() == b.rotation.coeffs() && a.scale == b.scale && a.pivot == b.pivot;
}

std::size_t target_count(const EditState& state) {
  std::size_t n = 0;
  for (const EditStep& step : state.steps) n += step.targets.size();
  return n;
}

}  // namespace

EditStep merge_step(const EditStep& current, const std::vector<GroupMove>& moves,
                    const std::vector<VertexTarget>& targets,
                    const std::vector<int>& vertex_group, std::uint64_t gesture) {
  EditStep next;
  next.gesture = gesture;
  // Later moves of one group win, as when they are applied in order.
  std::vector<GroupMove> incoming;
  for (const GroupMove& move : moves) {
    GroupMove m = move;
    const double norm = m.rotation.norm();
    if (norm > 0) m.rotation.coeffs() /= norm;
    std::erase_if(incoming, [&m](const GroupMove& x) { return x.group == m.group; });
    incoming.push_back(std::move(m));
  }
  // The identity about any pivot leaves the group at its anchors: stored as no move, so that
  // re-sending the handles as set is the state as set.
  auto identity = [](const GroupMove& m) {
    return m.translation.isZero(0) && m.scale == 1.0 &&
           m.rotation.coeffs() == Eigen::Quaterniond::Identity().coeffs();
  };
  auto moved = [&incoming](int group) {
    return std::any_of(incoming.begin(), incoming.end(),
                       [group](const GroupMove& m) { return m.group == group; });
  };
  for (const GroupMove& m : current.moves) {
    if (!moved(m.group)) next.moves.push_back(m);
  }
  for (const GroupMove& m : incoming) {
    if (!identity(m)) next.moves.push_back(m);
  }
  std::sort(next.moves.begin(), next.moves.end(),
            [](const GroupMove& a, const GroupMove& b) { return a.group < b.group; });

  // A group move sets every target of its group: earlier explicit targets there are overridden.
  for (const VertexTarget& t : current.targets) {
    if (!moved(vertex_group[static_cast<std::size_t>(t.vertex)])) next.targets.push_back(t);
  }
  for (const VertexTarget& t : targets) {
    std::erase_if(next.targets, [&t](const VertexTarget& x) { return x.vertex == t.vertex; });
    next.targets.push_back(t);
  }
  std::sort(next.targets.begin(), next.targets.end(),
            [](const VertexTarget& a, const VertexTarget& b) { return a.vertex < b.vertex; });
  return next;
}

void restart_history(EditState& state) {
  state.steps.assign(1, EditStep{});
  state.steps[0].settings = state.settings;
  state.position = 0;
}

int kept_positions_limit(int vertices) {
  const std::size_t per = 24 * static_cast<std::size_t>(std::max(vertices, 1));
  const std::size_t fit = kKeptPositionsBytes / per;
  return static_cast<int>(std::clamp<std::size_t>(fit, kMinKeptPositions, kMaxKeptPositions));
}

void remember_step(EditState& state, int step, KeptPositions shown, int limit) {
  if (step < 0 || step >= static_cast<int>(state.steps.size()) || !shown.positions) return;
  state.steps[static_cast<std::size_t>(step)].revision = shown.revision;
  std::erase_if(state.kept,
                [&shown](const KeptPositions& k) { return k.revision == shown.revision; });
  state.kept.push_back(std::move(shown));
  while (static_cast<int>(state.kept.size()) > std::max(limit, 1)) {
    const std::uint64_t dropped = state.kept.front().revision;
    state.kept.erase(state.kept.begin());
    for (EditStep& s : state.steps) {
      if (s.revision == dropped) s.revision.reset();
    }
  }
}

std::size_t kept_positions_bytes(const EditState& state) {
  std::size_t bytes = 0;
  for (const KeptPositions& k : state.kept) {
    if (k.positions) bytes += static_cast<std::size_t>(k.positions->size()) * sizeof(double);
  }
  return bytes;
}

std::shared_ptr<const Positions> kept_positions(const EditState& state, std::uint64_t revision) {
  for (const KeptPositions& k : state.kept) {
    if (k.revision == revision) return k.positions;
  }
  return nullptr;
}

bool same_settings(const std::optional<EditSettings>& a, const std::optional<EditSettings>& b) {
  if (!a || !b) return a.has_value() == b.has_value();
  return a->method == b->method && a->ora == b->ora && a->rigidity == b->rigidity &&
         a->max_iterations == b->max_iterations && a->tolerance == b->tolerance &&
         std::equal(a->magnify.begin(), a->magnify.end(), b->magnify.begin(), b->magnify.end(),
                    [](const core::MagnifyRegion& x, const core::MagnifyRegion& y) {
                      return x.scale == y.scale && x.vertices.size() == y.vertices.size() &&
                             x.vertices == y.vertices;
                    });
}

bool same_state(const EditStep& a, const EditStep& b) {
  return std::equal(a.moves.begin(), a.moves.end(), b.moves.begin(), b.moves.end(), same_move) &&
         std::equal(a.targets.begin(), a.targets.end(), b.targets.begin(), b.targets.end(),
                    [](const VertexTarget& x, const VertexTarget& y) {
                      return x.vertex == y.vertex && x.position == y.position;
                    });
}

Recorded record_step(EditState& state, EditStep step, std::size_t max_targets) {
  const auto current = static_cast<std::size_t>(state.position);
  const bool newest = current + 1 == state.steps.size();
  Recorded recorded = Recorded::Added;
  if (step.gesture != 0 && newest && current > 0 && state.steps[current].gesture == step.gesture) {
    state.steps[current] = std::move(step);
    recorded = Recorded::Replaced;
  } else if (same_state(step, state.steps[current]) &&
             same_settings(step.settings, state.steps[current].settings)) {
    return Recorded::Unchanged;
  } else {
    state.steps.resize(current + 1);  // a new edit drops the redo branch
    state.steps.push_back(std::move(step));
    ++state.position;
  }
  while (state.position > 0 && (state.steps.size() > static_cast<std::size_t>(kMaxHistorySteps) ||
                                target_count(state) > max_targets)) {
    state.steps.erase(state.steps.begin());
    --state.position;
  }
  return recorded;
}

Result<int> history_target(const EditState& state, HistoryAction action) {
  if (action == HistoryAction::Undo) {
    if (state.position == 0) {
      return Error(ErrorCode::FailedPrecondition,
                   "nothing to undo (the history starts at the last set_handles)");
    }
    return state.position - 1;
  }
  if (state.position + 1 >= static_cast<int>(state.steps.size())) {
    return Error(ErrorCode::FailedPrecondition, "nothing to redo");
  }
  return state.position + 1;
}

EditSettings settings_of(const MoveRequest& request, double rigidity) {
  EditSettings settings;
  settings.method = request.method;
  settings.ora = request.ora;
  settings.rigidity = rigidity;
  settings.magnify = request.magnify;
  settings.max_iterations = request.max_iterations;
  settings.tolerance = request.tolerance;
  return settings;
}

namespace {

void write_settings(BinaryWriter& out, const EditSettings& s) {
  out.pod<std::int32_t>(static_cast<std::int32_t>(s.method));
  out.pod<std::uint8_t>(s.ora ? 1 : 0);
  out.pod(s.rigidity);
  out.pod<std::int32_t>(s.max_iterations);
  out.pod(s.tolerance);
  out.pod(static_cast<std::uint32_t>(s.magnify.size()));
  for (const core::MagnifyRegion& region : s.magnify) {
    out.pod(region.scale);
    out.pod(static_cast<std::uint32_t>(region.vertices.size()));
    for (const int v : region.vertices) out.pod<std::int32_t>(v);
  }
}

/// Bit 1 of the first byte: every step ends with its settings (issue 44). Without it (bytes
/// written before), steps have none.
constexpr std::uint8_t kStepSettings = 2;

}  // namespace

// Bytes: u8 flags (bit 0: has settings, bit 1: steps carry settings); settings: i32 method,
// u8 ora, f64 rigidity, i32 max_iterations, f64 tolerance, u32 regions x (f64 scale, u32 n,
// i32 vertices); u32 steps x (u64 gesture, u32 moves x (i32 group, f64 x3 translation, f64 x4
// rotation w x y z, f64 scale, u8 has_pivot, f64 x3 pivot), u32 targets x (i32 vertex, f64 x3),
// with bit 1: u8 has settings, settings); i32 position.
void write_edit_state(BinaryWriter& out, const EditState& state) {
  out.pod<std::uint8_t>(static_cast<std::uint8_t>((state.settings ? 1 : 0) | kStepSettings));
  if (state.settings) write_settings(out, *state.settings);
  out.pod(static_cast<std::uint32_t>(state.steps.size()));
  for (const EditStep& step : state.steps) {
    out.pod(step.gesture);
    out.pod(static_cast<std::uint32_t>(step.moves.size()));
    for (const GroupMove& m : step.moves) {
      out.pod<std::int32_t>(m.group);
      for (int c = 0; c < 3; ++c) out.pod(m.translation[c]);
      out.pod(m.rotation.w());
      out.pod(m.rotation.x());
      out.pod(m.rotation.y());
      out.pod(m.rotation.z());
      out.pod(m.scale);
      out.pod<std::uint8_t>(m.pivot ? 1 : 0);
      const Eigen::Vector3d pivot = m.pivot.value_or(Eigen::Vector3d::Zero());
      for (int c = 0; c < 3; ++c) out.pod(pivot[c]);
    }
    out.pod(static_cast<std::uint32_t>(step.targets.size()));
    for (const VertexTarget& t : step.targets) {
      out.pod<std::int32_t>(t.vertex);
      for (int c = 0; c < 3; ++c) out.pod(t.position[c]);
    }
    out.pod<std::uint8_t>(step.settings ? 1 : 0);
    if (step.settings) write_settings(out, *step.settings);
  }
  out.pod<std::int32_t>(state.position);
}

namespace {

Status read_vector(BinaryReader& in, Eigen::Vector3d& v, const char* what) {
  for (int c = 0; c < 3; ++c) MD_RETURN_IF_ERROR(in.pod(v[c], what));
  if (!v.allFinite()) return in.corrupt(std::string(what) + " is not finite");
  return Status::success();
}

Status read_index(BinaryReader& in, int& index, int size, const char* what) {
  std::int32_t value = 0;
  MD_RETURN_IF_ERROR(in.pod(value, what));
  if (value < 0 || value >= size) {
    return in.corrupt(std::string(what) + " " + std::to_string(value) + " out of range");
  }
  index = value;
  return Status::success();
}

Status read_settings(BinaryReader& in, EditSettings& s, int vertices) {
  std::int32_t method = 0;
  std::uint8_t ora = 0;
  std::int32_t iterations = 0;
  MD_RETURN_IF_ERROR(in.pod(method, "settings method"));
  if (method < 0 || method > static_cast<std::int32_t>(core::Method::Laplacian)) {
    return in.corrupt("unknown settings method " + std::to_string(method));
  }
  s.method = static_cast<core::Method>(method);
  MD_RETURN_IF_ERROR(in.pod(ora, "settings ora"));
  s.ora = ora != 0;
  MD_RETURN_IF_ERROR(in.pod(s.rigidity, "settings rigidity"));
  MD_RETURN_IF_ERROR(in.pod(iterations, "settings iterations"));
  s.max_iterations = iterations;
  MD_RETURN_IF_ERROR(in.pod(s.tolerance, "settings tolerance"));
  if (!core::check_rigidity(s.rigidity, kMaxRigidity).ok() || iterations < 1 || iterations > kMaxMoveIterations ||
      !(s.tolerance >= 0) || !std::isfinite(s.tolerance)) {
    return in.corrupt("settings out of range");
  }
  std::uint32_t regions = 0;
  MD_RETURN_IF_ERROR(in.count(regions, "magnify regions", 12));
  s.magnify.resize(regions);
  for (core::MagnifyRegion& region : s.magnify) {
    MD_RETURN_IF_ERROR(in.pod(region.scale, "magnify scale"));
    if (!(region.scale > 0) || !std::isfinite(region.scale)) {
      return in.corrupt("magnify scale is not finite and > 0");
    }
    std::uint32_t n = 0;
    MD_RETURN_IF_ERROR(in.count(n, "magnify vertices", 4));
    region.vertices.resize(static_cast<Eigen::Index>(n));
    for (int& v : region.vertices) MD_RETURN_IF_ERROR(read_index(in, v, vertices, "magnify vertex"));
  }
  return Status::success();
}

Status read_step(BinaryReader& in, EditStep& step, int vertices, int groups, bool with_settings) {
  MD_RETURN_IF_ERROR(in.pod(step.gesture, "step gesture"));
  std::uint32_t moves = 0;
  MD_RETURN_IF_ERROR(in.count(moves, "step moves", 4 + 8 * 8 + 1 + 24));
  step.moves.resize(moves);
  for (GroupMove& m : step.moves) {
    MD_RETURN_IF_ERROR(read_index(in, m.group, groups, "step move group"));
    MD_RETURN_IF_ERROR(read_vector(in, m.translation, "step move translation"));
    double w = 0, x = 0, y = 0, z = 0;
    MD_RETURN_IF_ERROR(in.pod(w, "step move rotation"));
    MD_RETURN_IF_ERROR(in.pod(x, "step move rotation"));
    MD_RETURN_IF_ERROR(in.pod(y, "step move rotation"));
    MD_RETURN_IF_ERROR(in.pod(z, "step move rotation"));
    m.rotation = Eigen::Quaterniond(w, x, y, z);
    MD_RETURN_IF_ERROR(in.pod(m.scale, "step move scale"));
    if (!m.rotation.coeffs().allFinite() || !(m.rotation.norm() > 0) || !(m.scale > 0) ||
        !std::isfinite(m.scale)) {
      return in.corrupt("step move rotation or scale out of range");
    }
    std::uint8_t has_pivot = 0;
    MD_RETURN_IF_ERROR(in.pod(has_pivot, "step move pivot"));
    Eigen::Vector3d pivot;
    MD_RETURN_IF_ERROR(read_vector(in, pivot, "step move pivot"));
    if (has_pivot != 0) m.pivot = pivot;
  }
  std::uint32_t targets = 0;
  MD_RETURN_IF_ERROR(in.count(targets, "step targets", 4 + 24));
  step.targets.resize(targets);
  for (VertexTarget& t : step.targets) {
    MD_RETURN_IF_ERROR(read_index(in, t.vertex, vertices, "step target vertex"));
    MD_RETURN_IF_ERROR(read_vector(in, t.position, "step target position"));
  }
  step.settings.reset();
  if (!with_settings) return Status::success();
  std::uint8_t has_settings = 0;
  MD_RETURN_IF_ERROR(in.pod(has_settings, "step settings"));
  if (has_settings > 1) return in.corrupt("step settings flag " + std::to_string(has_settings));
  if (has_settings != 0) {
    EditSettings settings;
    MD_RETURN_IF_ERROR(read_settings(in, settings, vertices));
    step.settings = std::move(settings);
  }
  return Status::success();
}

}  // namespace

Status read_edit_state(BinaryReader& in, EditState& state, int vertices, int groups) {
  std::uint8_t flags = 0;
  MD_RETURN_IF_ERROR(in.pod(flags, "settings"));
  if ((flags & ~(1 | kStepSettings)) != 0) {
    return in.corrupt("edit state flags " + std::to_string(flags));
  }
  state.settings.reset();
  state.kept.clear();
  if ((flags & 1) != 0) {
    EditSettings settings;
    MD_RETURN_IF_ERROR(read_settings(in, settings, vertices));
    state.settings = std::move(settings);
  }
  std::uint32_t steps = 0;
  MD_RETURN_IF_ERROR(in.count(steps, "history steps", 16));
  if (steps == 0 || steps > static_cast<std::uint32_t>(kMaxHistorySteps)) {
    return in.corrupt("history of " + std::to_string(steps) + " steps");
  }
  state.steps.assign(steps, EditStep{});
  for (EditStep& step : state.steps) {
    MD_RETURN_IF_ERROR(read_step(in, step, vertices, groups, (flags & kStepSettings) != 0));
  }
  std::int32_t position = 0;
  MD_RETURN_IF_ERROR(in.pod(position, "history position"));
  if (position < 0 || position >= static_cast<std::int32_t>(steps)) {
    return in.corrupt("history position " + std::to_string(position) + " out of range");
  }
  state.position = position;
  return Status::success();
}

}  // namespace meshdeform::service
