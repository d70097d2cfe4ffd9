#pragma once
/// @file edit_history.h
/// A session's undo history and edit settings (issue 17): the rules that change them and their
/// stored bytes. Kept with the session (in memory, the state file and the shared store) so that
/// any client opening the session later continues where the last one left it.
///
/// Model: every recorded move makes the session's *state* (EditStep: the handle groups' moves
/// and explicit vertex targets, applied to the anchors) a new step; undo and redo apply the
/// previous or next step as a move. A step is the whole state, not a delta: a move that names
/// only some groups is merged with the current step (merge_step), so any step can be applied on
/// its own. Moves of one gesture (a drag) replace their own step instead of adding one.
///
/// Exact undo (issue 44): each step also carries the settings it was solved with (a settings
/// change alone is a step), and a step the session leaves remembers the revision that showed it,
/// whose positions are kept (in memory, bounded: kept_positions_limit), so that undo and redo
/// commit them again instead of solving.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

#include "core/base/status.h"
#include "server/service/binary_codec.h"
#include "server/service/types.h"

namespace meshdeform::service {

/// Steps kept per session (the oldest are dropped first).
inline constexpr int kMaxHistorySteps = 100;

/// Exact undo (issue 44): a step the session leaves keeps the positions that showed it, so that
/// undo and redo commit them again instead of solving (a solve from another start lands
/// elsewhere: the viewer measured 0.02 of a tube's size). Positions are shared with the
/// revisions (no copy) but may outlive them, so they are bounded: at most this many bytes of
/// them per session (24 bytes per vertex each), at least kMinKeptPositions and at most
/// kMaxKeptPositions revisions. Steps beyond keep no positions and are solved again.
inline constexpr std::size_t kKeptPositionsBytes = std::size_t{32} << 20;
inline constexpr int kMinKeptPositions = 4;
inline constexpr int kMaxKeptPositions = 32;

/// How many revisions' positions a session of `vertices` keeps for exact undo.
int kept_positions_limit(int vertices);

/// Remembers that steps[step] is shown by `shown` (the session is about to leave it): the step
/// names the revision, whose positions join EditState::kept (or move to its newest end). The
/// oldest kept are dropped beyond `limit`, and the steps naming them forget their revision.
void remember_step(EditState& state, int step, KeptPositions shown, int limit);

/// What the kept positions hold (24 bytes per vertex each): charged to the session's memory
/// estimate as they are kept (Session::estimated_bytes), at most kept_positions_limit of them.
std::size_t kept_positions_bytes(const EditState& state);

/// The kept positions of `revision`; null when the state keeps none.
std::shared_ptr<const Positions> kept_positions(const EditState& state, std::uint64_t revision);

/// True when both are unset, or both set and equal.
bool same_settings(const std::optional<EditSettings>& a, const std::optional<EditSettings>& b);

/// The current state `current` after a move of `moves` and `targets`: each moved group's move
/// replaces that group's (and drops the explicit targets of its vertices, which the move
/// overrides), each target replaces that vertex's. Moves are stored with a unit rotation.
/// @param vertex_group  the group of each vertex (-1: unconstrained); indices already checked.
EditStep merge_step(const EditStep& current, const std::vector<GroupMove>& moves,
                    const std::vector<VertexTarget>& targets,
                    const std::vector<int>& vertex_group, std::uint64_t gesture);

/// New anchors (set_handles): the history restarts at the state as set (one step, no moves,
/// the session's settings); the settings and the kept positions stay.
void restart_history(EditState& state);

/// True when both steps give the same targets (equal moves and targets; gestures, settings and
/// revisions ignored).
bool same_state(const EditStep& a, const EditStep& b);

/// What record_step did.
enum class Recorded {
  Unchanged,  ///< equal to the current step (state and settings): nothing recorded
  Replaced,   ///< the current step, of the same gesture, was replaced
  Added,      ///< added after the step that was current (now position - 1)
};

/// Records `step` as the new current step: it replaces the current step when both belong to the
/// same non-zero gesture and nothing was undone since; it is not recorded when it equals the
/// current state with the same settings; otherwise it is added after the current step (dropping
/// the redo branch). A settings change alone is a step (issue 44). Then the oldest steps are
/// dropped while there are more than kMaxHistorySteps or the steps hold more than `max_targets`
/// explicit vertex targets in all (the current step is kept).
Recorded record_step(EditState& state, EditStep step, std::size_t max_targets);

/// The index of the step an Undo or Redo applies.
/// @return the index; FailedPrecondition saying there is nothing to undo (redo).
/// @pre action is Undo or Redo.
[[nodiscard]] Result<int> history_target(const EditState& state, HistoryAction action);

/// The settings a move solves with, as the session keeps them.
EditSettings settings_of(const MoveRequest& request, double rigidity);

/// The edit state's stored bytes (state file and shared store): see edit_history.cpp. Steps'
/// revisions and the kept positions are not stored (they live in memory only).
void write_edit_state(BinaryWriter& out, const EditState& state);
/// @param vertices, groups  the session's sizes: indices are checked against them.
/// @return success; InvalidArgument (BinaryReader::corrupt) naming the field.
[[nodiscard]] Status read_edit_state(BinaryReader& in, EditState& state, int vertices,
                                     int groups);

}  // namespace meshdeform::service
