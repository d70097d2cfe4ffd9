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

#include <cstddef>
#include <cstdint>
#include <vector>

#include "core/base/status.h"
#include "server/service/binary_codec.h"
#include "server/service/types.h"

namespace meshdeform::service {

/// Steps kept per session (the oldest are dropped first).
inline constexpr int kMaxHistorySteps = 100;

/// The current state `current` after a move of `moves` and `targets`: each moved group's move
/// replaces that group's (and drops the explicit targets of its vertices, which the move
/// overrides), each target replaces that vertex's. Moves are stored with a unit rotation.
/// @param vertex_group  the group of each vertex (-1: unconstrained); indices already checked.
EditStep merge_step(const EditStep& current, const std::vector<GroupMove>& moves,
                    const std::vector<VertexTarget>& targets,
                    const std::vector<int>& vertex_group, std::uint64_t gesture);

/// New anchors (set_handles): the history restarts at the state as set (one step, no moves);
/// the settings stay.
void restart_history(EditState& state);

/// True when both steps give the same targets (equal moves and targets; gestures ignored).
bool same_state(const EditStep& a, const EditStep& b);

/// Records `step` as the new current step: it replaces the current step when both belong to the
/// same non-zero gesture and nothing was undone since; it is not recorded when it equals the
/// current state; otherwise it is added after the current step (dropping the redo branch).
/// Then the oldest steps are dropped while there are more than kMaxHistorySteps or the steps
/// hold more than `max_targets` explicit vertex targets in all (the current step is kept).
void record_step(EditState& state, EditStep step, std::size_t max_targets);

/// The index of the step an Undo or Redo applies.
/// @return the index; FailedPrecondition saying there is nothing to undo (redo).
/// @pre action is Undo or Redo.
[[nodiscard]] Result<int> history_target(const EditState& state, HistoryAction action);

/// The settings a move solves with, as the session keeps them.
EditSettings settings_of(const MoveRequest& request, double rigidity);

/// The edit state's stored bytes (state file and shared store): see edit_history.cpp.
void write_edit_state(BinaryWriter& out, const EditState& state);
/// @param vertices, groups  the session's sizes: indices are checked against them.
/// @return success; InvalidArgument (BinaryReader::corrupt) naming the field.
[[nodiscard]] Status read_edit_state(BinaryReader& in, EditState& state, int vertices,
                                     int groups);

}  // namespace meshdeform::service
