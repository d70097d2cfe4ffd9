// Exact undo (issue 44, server/service/edit_history.h): a step the session leaves keeps the
// positions that showed it, and undo, redo and MoveRequest::restore_revision commit them again
// bit for bit instead of solving (a scale-aware re-solve from another start lands elsewhere); a
// settings change alone is a step; the kept positions are bounded and charged to the session's
// memory estimate; they survive set_handles but not a restart.
#include <gtest/gtest.h>

#include <memory>
#include <optional>
#include <stop_token>
#include <string>
#include <utility>
#include <vector>

#include "server/service/edit_history.h"
#include "server/service/session.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::service {
namespace {

/// Group 0 Fixed: the column x = 0; group 1 Handle: the column x = 1 (a 7 x 7 bumpy grid).
std::vector<HandleGroup> column_groups(const MeshData& mesh) {
  HandleGroup fixed{HandleRole::Fixed, {}}, handle{HandleRole::Handle, {}};
  for (int v = 0; v < static_cast<int>(mesh.V.rows()); ++v) {
    if (mesh.V(v, 0) < 1e-9) fixed.vertices.push_back(v);
    if (mesh.V(v, 0) > 1.0 - 1e-9) handle.vertices.push_back(v);
  }
  return {fixed, handle};
}

struct Fixture {
  std::shared_ptr<ServiceCounters> counters = std::make_shared<ServiceCounters>();
  ServiceOptions options;
  MeshData mesh = test::make_grid(6, 0.05);
  std::shared_ptr<Session> session;

  explicit Fixture(ServiceOptions o = {}) : options(std::move(o)) {
    Result<std::shared_ptr<Session>> made =
        Session::create(SessionId{"s1"}, Token{"edit"}, Token{"view"}, mesh,
                        core::DeformerSettings{}, options, counters, {});
    EXPECT_TRUE(made.ok()) << made.status().to_string();
    if (made.ok()) session = *made;
  }

  void set_groups(std::vector<HandleGroup> groups) {
    SetHandlesRequest request;
    request.groups = std::move(groups);
    const Result<SessionInfo> info = session->set_handles(request);
    ASSERT_TRUE(info.ok()) << info.status().to_string();
  }

  Result<DeformResult> move(const MoveRequest& request) { return session->move(request, {}); }
};

/// A scale-aware move of the handle column, two iterations (far from converged): a solve of
/// the same targets from another start lands elsewhere, so only a restore gives the same bits.
MoveRequest drag(double dz, double turn = 0.0, std::uint64_t gesture = 0) {
  MoveRequest request;
  GroupMove move;
  move.group = 1;
  move.translation = Eigen::Vector3d(0, 0.1 * dz, dz);
  move.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(turn, Eigen::Vector3d::UnitY()));
  request.moves.push_back(move);
  request.method = core::Method::ScaleAware;
  request.max_iterations = 2;
  request.tolerance = 0;
  request.gesture = gesture;
  return request;
}

MoveRequest history(HistoryAction action) {
  MoveRequest request = drag(0);
  request.moves.clear();
  request.history = action;
  return request;
}

TEST(ExactUndoTest, UndoAndRedoCommitTheKeptPositionsBitForBit) {
  Fixture f;
  f.set_groups(column_groups(f.mesh));
  Result<DeformResult> one = f.move(drag(0.2, 0.3));
  Result<DeformResult> two = f.move(drag(0.5, 0.9));
  ASSERT_TRUE(one.ok() && two.ok()) << one.status().to_string() << two.status().to_string();
  EXPECT_EQ(two->history_position, 2);

  Result<DeformResult> undone = f.move(history(HistoryAction::Undo));
  ASSERT_TRUE(undone.ok()) << undone.status().to_string();
  EXPECT_EQ(*undone->positions, *one->positions);  // exactly: no solve
  EXPECT_EQ(undone->iterations, 0);
  EXPECT_TRUE(undone->converged);
  EXPECT_EQ(undone->history_position, 1);
  EXPECT_GT(undone->revision, two->revision);

  Result<DeformResult> at_start = f.move(history(HistoryAction::Undo));
  ASSERT_TRUE(at_start.ok());
  EXPECT_EQ(*at_start->positions, f.mesh.V);  // the shape as the handles were set: the rest
  Result<DeformResult> redone = f.move(history(HistoryAction::Redo));
  ASSERT_TRUE(redone.ok());
  EXPECT_EQ(*redone->positions, *one->positions);
  redone = f.move(history(HistoryAction::Redo));
  ASSERT_TRUE(redone.ok());
  EXPECT_EQ(*redone->positions, *two->positions);

  // The next move after a restore solves again (its deformer restarts) and is a new step.
  Result<DeformResult> three = f.move(drag(0.3, 0.2));
  ASSERT_TRUE(three.ok()) << three.status().to_string();
  EXPECT_GT(three->iterations, 0);
  EXPECT_EQ(three->history_position, 3);
  EXPECT_NE(*three->positions, *two->positions);
  undone = f.move(history(HistoryAction::Undo));
  ASSERT_TRUE(undone.ok());
  EXPECT_EQ(*undone->positions, *two->positions);
}

TEST(ExactUndoTest, AStepLeftWhileRefiningKeepsTheRefinedPositions) {
  ServiceOptions options;
  options.refine_budget = 20;
  Fixture f(options);
  f.set_groups(column_groups(f.mesh));
  ASSERT_TRUE(f.move(drag(0.4, 0.6)).ok());
  ASSERT_TRUE(f.session->wants_refinement());
  Result<std::optional<DeformResult>> refined = f.session->refine(std::stop_source{});
  ASSERT_TRUE(refined.ok() && refined->has_value()) << refined.status().to_string();
  const Positions shown = *(*refined)->positions;
  ASSERT_TRUE(f.move(drag(0.1)).ok());
  Result<DeformResult> undone = f.move(history(HistoryAction::Undo));
  ASSERT_TRUE(undone.ok());
  EXPECT_EQ(*undone->positions, shown);  // what the user last saw of that step
}

TEST(ExactUndoTest, ASettingsChangeAloneIsAStepAndUndoRestoresItsShape) {
  Fixture f;
  f.set_groups(column_groups(f.mesh));
  Result<DeformResult> first = f.move(drag(0.4, 0.5));
  ASSERT_TRUE(first.ok());
  MoveRequest stiffer = drag(0.4, 0.5);
  stiffer.rigidity = 300;
  Result<DeformResult> resolved = f.move(stiffer);
  ASSERT_TRUE(resolved.ok());
  EXPECT_EQ(resolved->history_position, 2);  // same state, other settings: a step
  SessionInfo info = f.session->info();
  ASSERT_EQ(info.edit.steps.size(), 3u);
  ASSERT_TRUE(info.edit.steps[1].settings && info.edit.steps[2].settings);
  EXPECT_EQ(info.edit.steps[2].settings->rigidity, 300);
  EXPECT_NE(info.edit.steps[1].settings->rigidity, 300);
  // Re-sending the same move with the same settings adds nothing.
  ASSERT_TRUE(f.move(stiffer).ok());
  EXPECT_EQ(f.session->info().edit.steps.size(), 3u);

  Result<DeformResult> undone = f.move(history(HistoryAction::Undo));
  ASSERT_TRUE(undone.ok());
  EXPECT_EQ(*undone->positions, *first->positions);
  // The first step of a fresh session has no settings: the first settings-only move is a step.
  EXPECT_FALSE(f.session->info().edit.steps[0].settings.has_value());
}

TEST(ExactUndoTest, RestoreRevisionCommitsAnEarlierShapeAlsoAfterSetHandles) {
  Fixture f;
  std::vector<HandleGroup> groups = column_groups(f.mesh);
  f.set_groups(groups);
  Result<DeformResult> one = f.move(drag(0.3, 0.4));
  Result<DeformResult> two = f.move(drag(0.6, 0.8));
  ASSERT_TRUE(one.ok() && two.ok());
  // A group change (a client deleting a group, say): new anchors, a new history.
  HandleGroup extra{HandleRole::Handle, {24}};  // the middle vertex
  f.set_groups({groups[0], groups[1], extra});
  EXPECT_EQ(f.session->info().edit.steps.size(), 1u);

  MoveRequest restore;
  restore.method = core::Method::ScaleAware;
  restore.restore_revision = one->revision;
  Result<DeformResult> restored = f.move(restore);
  ASSERT_TRUE(restored.ok()) << restored.status().to_string();
  EXPECT_EQ(*restored->positions, *one->positions);
  EXPECT_EQ(restored->iterations, 0);
  EXPECT_EQ(restored->history_position, 1);  // recorded like a move
  // Undo of it restores the shape it left (revision two's), also exactly.
  Result<DeformResult> undone = f.move(history(HistoryAction::Undo));
  ASSERT_TRUE(undone.ok());
  EXPECT_EQ(*undone->positions, *two->positions);

  restore.restore_revision = 0;  // the rest mesh is always there
  restored = f.move(restore);
  ASSERT_TRUE(restored.ok());
  EXPECT_EQ(*restored->positions, f.mesh.V);

  const std::uint64_t before = f.session->revision();
  restore.restore_revision = before + 5;
  const Result<DeformResult> unknown = f.move(restore);
  EXPECT_EQ(unknown.status().code(), ErrorCode::FailedPrecondition);
  EXPECT_NE(unknown.status().message().find("not kept"), std::string::npos)
      << unknown.status().message();
  EXPECT_EQ(f.session->revision(), before);

  MoveRequest both = history(HistoryAction::Undo);
  both.restore_revision = 0;
  EXPECT_EQ(f.move(both).status().code(), ErrorCode::InvalidArgument);
  EXPECT_EQ(f.session->revision(), before);
}

TEST(ExactUndoTest, KeptPositionsAreBoundedAndCharged) {
  Fixture f;
  f.set_groups(column_groups(f.mesh));
  const int limit = kept_positions_limit(static_cast<int>(f.mesh.V.rows()));
  EXPECT_EQ(limit, kMaxKeptPositions);  // a small mesh: the count bounds it
  for (int i = 1; i <= limit + 10; ++i) ASSERT_TRUE(f.move(drag(0.01 * i)).ok());
  const SessionInfo info = f.session->info();
  EXPECT_EQ(static_cast<int>(info.edit.kept.size()), limit);
  int named = 0;
  for (const EditStep& step : info.edit.steps) {
    if (!step.revision) continue;
    ++named;
    EXPECT_NE(kept_positions(info.edit, *step.revision), nullptr);
  }
  EXPECT_EQ(named, limit);  // every step left names kept positions, the oldest forgot theirs
  // Undo past what is kept solves instead (not exact, but it works).
  for (int i = 0; i < limit + 10; ++i) {
    ASSERT_TRUE(f.move(history(HistoryAction::Undo)).ok()) << "undo " << i;
  }

  // The charge: 24 bytes per vertex per kept revision, as they are kept (a new session holds
  // none, so the memory budget's admission of a big mesh is unchanged), bounded by the limit.
  const int v = static_cast<int>(f.mesh.V.rows());
  const int faces = static_cast<int>(f.mesh.F.rows());
  const SessionInfo undone = f.session->info();
  const std::size_t kept = kept_positions_bytes(undone.edit);
  EXPECT_EQ(kept, std::size_t{24} * static_cast<std::size_t>(v) * undone.edit.kept.size());
  EXPECT_GT(kept, 0u);
  EXPECT_LE(undone.edit.kept.size(), static_cast<std::size_t>(limit));
  EXPECT_EQ(undone.estimated_bytes - kept,
            Fixture().session->info().estimated_bytes + static_cast<std::size_t>(undone.cached_deformers) *
                (estimate_session_bytes(v, faces, 1, 0) - estimate_session_bytes(v, faces, 0, 0)));
  EXPECT_EQ(kept_positions_limit(187'000), 7);
  EXPECT_EQ(kept_positions_limit(750'000), kMinKeptPositions);
  EXPECT_LE(std::size_t{24} * 187'000 * static_cast<std::size_t>(kept_positions_limit(187'000)),
            kKeptPositionsBytes);
}

TEST(ExactUndoTest, StepSettingsAreStoredAndOlderBytesStillRead) {
  EditState state;
  EditSettings settings;
  settings.method = core::Method::Arap;
  settings.max_iterations = 9;
  EditStep step;
  step.settings = settings;
  step.revision = 7;  // memory only
  record_step(state, step, 100);
  state.kept.push_back(KeptPositions{7, std::make_shared<const Positions>(Positions::Zero(3, 3))});
  BinaryWriter out;
  write_edit_state(out, state);
  const std::string bytes = out.take();
  EditState back;
  BinaryReader in(bytes, "test");
  ASSERT_TRUE(read_edit_state(in, back, 10, 3).ok());
  EXPECT_TRUE(in.done());
  ASSERT_EQ(back.steps.size(), 2u);
  EXPECT_FALSE(back.steps[0].settings.has_value());
  ASSERT_TRUE(back.steps[1].settings.has_value());
  EXPECT_EQ(back.steps[1].settings->method, core::Method::Arap);
  EXPECT_EQ(back.steps[1].settings->max_iterations, 9);
  EXPECT_FALSE(back.steps[1].revision.has_value());
  EXPECT_TRUE(back.kept.empty());

  // Bytes from before steps had settings: flags byte 0, steps without the trailing settings.
  BinaryWriter old;
  old.pod<std::uint8_t>(0);
  old.pod<std::uint32_t>(1);
  old.pod<std::uint64_t>(3);  // gesture
  old.pod<std::uint32_t>(0);  // moves
  old.pod<std::uint32_t>(0);  // targets
  old.pod<std::int32_t>(0);   // position
  const std::string old_bytes = old.take();
  BinaryReader old_in(old_bytes, "old");
  EditState old_state;
  ASSERT_TRUE(read_edit_state(old_in, old_state, 10, 3).ok());
  EXPECT_TRUE(old_in.done());
  EXPECT_EQ(old_state.steps[0].gesture, 3u);
  EXPECT_FALSE(old_state.steps[0].settings.has_value());

  // Unknown flag bits are corrupt, named.
  std::string flagged = bytes;
  flagged[0] = static_cast<char>(0x10);
  BinaryReader bad(flagged, "test");
  const Status status = read_edit_state(bad, back, 10, 3);
  EXPECT_EQ(status.code(), ErrorCode::InvalidArgument);
  EXPECT_NE(status.message().find("flags"), std::string::npos) << status.message();
}

TEST(ExactUndoTest, RememberingMovesARevisionToTheNewestEnd) {
  EditState state;
  state.steps.resize(3);
  auto pos = [](double x) {
    return std::make_shared<const Positions>(Positions::Constant(1, 3, x));
  };
  remember_step(state, 0, KeptPositions{10, pos(1)}, 2);
  remember_step(state, 1, KeptPositions{11, pos(2)}, 2);
  remember_step(state, 0, KeptPositions{10, pos(1)}, 2);  // again: now the newest
  remember_step(state, 2, KeptPositions{12, pos(3)}, 2);  // drops 11, the oldest
  ASSERT_EQ(state.kept.size(), 2u);
  EXPECT_EQ(state.kept[0].revision, 10u);
  EXPECT_EQ(state.kept[1].revision, 12u);
  EXPECT_EQ(state.steps[0].revision, 10u);
  EXPECT_FALSE(state.steps[1].revision.has_value());
  EXPECT_EQ(kept_positions(state, 11), nullptr);
  EXPECT_EQ((*kept_positions(state, 12))(0, 0), 3.0);
  restart_history(state);  // set_handles: the steps go, the kept positions stay
  EXPECT_EQ(state.steps.size(), 1u);
  EXPECT_EQ(state.kept.size(), 2u);
}

}  // namespace
}  // namespace meshdeform::service
