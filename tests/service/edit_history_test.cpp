// Undo history and edit settings kept with the session (issue 17, server/service/edit_history.h):
// the recording rules, their stored bytes, and through the service: undo and redo give the
// earlier results exactly, the settings and history survive a restart on the state directory,
// and bad history requests are refused with nothing changed.
#include "server/service/edit_history.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <random>
#include <string>

#include "core/io/mesh_io.h"
#include "server/service/deformation_service.h"
#include "server/service/persistence.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::service {
namespace {

namespace fs = std::filesystem;

GroupMove lift_group(int group, double z) {
  GroupMove m;
  m.group = group;
  m.translation = Eigen::Vector3d(0, 0, z);
  return m;
}

EditStep step_of(std::vector<GroupMove> moves, std::uint64_t gesture = 0) {
  EditStep s;
  s.moves = std::move(moves);
  s.gesture = gesture;
  return s;
}

// vertex -> group for a mesh of 10 vertices: 0-1 group 0, 2-3 group 1, 4-5 group 2.
const std::vector<int> kVertexGroup = {0, 0, 1, 1, 2, 2, -1, -1, -1, -1};

TEST(EditHistoryTest, MergeKeepsUnnamedGroupsAndDropsTargetsAMoveOverrides) {
  EditStep current = step_of({lift_group(1, 1.0), lift_group(2, 2.0)});
  current.targets = {VertexTarget{3, Eigen::Vector3d(9, 9, 9)}, VertexTarget{5, Eigen::Vector3d(8, 8, 8)}};
  GroupMove turn = lift_group(1, 0.5);
  turn.rotation = Eigen::Quaterniond(2, 0, 0, 0);  // stored normalised
  const EditStep next = merge_step(current, {turn}, {VertexTarget{4, Eigen::Vector3d(1, 2, 3)}},
                                   kVertexGroup, 7);
  ASSERT_EQ(next.moves.size(), 2u);
  EXPECT_EQ(next.moves[0].group, 1);
  EXPECT_EQ(next.moves[0].translation.z(), 0.5);
  EXPECT_EQ(next.moves[0].rotation.w(), 1.0);
  EXPECT_EQ(next.moves[1].group, 2);
  EXPECT_EQ(next.moves[1].translation.z(), 2.0);
  // Vertex 3 (group 1, moved again) loses its explicit target; 5 (group 2) keeps its; 4 is new.
  ASSERT_EQ(next.targets.size(), 2u);
  EXPECT_EQ(next.targets[0].vertex, 4);
  EXPECT_EQ(next.targets[1].vertex, 5);
  EXPECT_EQ(next.gesture, 7u);
}

TEST(EditHistoryTest, AnIdentityMoveIsNoMove) {
  GroupMove still = lift_group(1, 0.0);
  still.pivot = Eigen::Vector3d(1, 2, 3);
  const EditStep moved = step_of({lift_group(1, 0.5)});
  EXPECT_TRUE(merge_step(moved, {still}, {}, kVertexGroup, 0).moves.empty());
  EXPECT_TRUE(same_state(merge_step(EditStep{}, {still}, {}, kVertexGroup, 0), EditStep{}));
}

TEST(EditHistoryTest, GesturesMakeOneStepAndANewEditDropsTheRedoBranch) {
  EditState state;
  record_step(state, step_of({lift_group(1, 0.1)}, 5), 1000);
  record_step(state, step_of({lift_group(1, 0.2)}, 5), 1000);  // same drag
  record_step(state, step_of({lift_group(1, 0.3)}, 5), 1000);
  ASSERT_EQ(state.steps.size(), 2u);
  EXPECT_EQ(state.position, 1);
  EXPECT_EQ(state.steps[1].moves[0].translation.z(), 0.3);
  record_step(state, step_of({lift_group(1, 0.4)}, 6), 1000);  // next drag
  record_step(state, step_of({lift_group(1, 0.4)}, 0), 1000);  // same state: no step
  ASSERT_EQ(state.steps.size(), 3u);
  EXPECT_EQ(state.position, 2);

  EXPECT_EQ(*history_target(state, HistoryAction::Undo), 1);
  EXPECT_EQ(history_target(state, HistoryAction::Redo).status().code(),
            ErrorCode::FailedPrecondition);
  state.position = 1;  // undone once
  // A gesture equal to the current step's does not replace it after an undo: a new branch.
  record_step(state, step_of({lift_group(1, 0.9)}, 5), 1000);
  ASSERT_EQ(state.steps.size(), 3u);
  EXPECT_EQ(state.position, 2);
  EXPECT_EQ(state.steps[2].moves[0].translation.z(), 0.9);
  state.position = 0;
  EXPECT_EQ(history_target(state, HistoryAction::Undo).status().code(),
            ErrorCode::FailedPrecondition);
}

TEST(EditHistoryTest, OldestStepsGoPastTheStepAndTargetBudgets) {
  EditState state;
  for (int i = 1; i <= kMaxHistorySteps + 20; ++i) {
    record_step(state, step_of({lift_group(1, 0.01 * i)}), 1000);
  }
  EXPECT_EQ(state.steps.size(), static_cast<std::size_t>(kMaxHistorySteps));
  EXPECT_EQ(state.position, kMaxHistorySteps - 1);
  EXPECT_DOUBLE_EQ(state.steps.back().moves[0].translation.z(), 0.01 * (kMaxHistorySteps + 20));

  EditState targets;
  for (int i = 1; i <= 10; ++i) {
    EditStep s;
    s.targets = {VertexTarget{2, Eigen::Vector3d(i, 0, 0)}, VertexTarget{3, Eigen::Vector3d(0, i, 0)}};
    record_step(targets, s, 6);  // at most 6 explicit targets in all: three steps of two
  }
  EXPECT_EQ(targets.steps.size(), 3u);
  EXPECT_EQ(targets.steps.back().targets[0].position.x(), 10.0);
}

TEST(EditHistoryTest, StoredBytesRoundTripAndCorruptionIsNamed) {
  EditState state;
  EditSettings settings;
  settings.method = core::Method::Arap;
  settings.ora = true;
  settings.rigidity = 30;
  settings.max_iterations = 7;
  settings.tolerance = 1e-6;
  core::MagnifyRegion region;
  region.vertices = Eigen::Vector3i(6, 7, 8);
  region.scale = 1.5;
  settings.magnify = {region};
  state.settings = settings;
  GroupMove m = lift_group(2, 0.25);
  m.pivot = Eigen::Vector3d(1, 2, 3);
  m.scale = 1.5;
  EditStep s = step_of({lift_group(1, 0.5), m}, 42);
  s.targets = {VertexTarget{4, Eigen::Vector3d(0.1, 0.2, 0.3)}};
  record_step(state, s, 100);

  BinaryWriter out;
  write_edit_state(out, state);
  const std::string bytes = out.take();
  EditState back;
  BinaryReader in(bytes, "test");
  ASSERT_TRUE(read_edit_state(in, back, 10, 3).ok());
  EXPECT_TRUE(in.done());
  ASSERT_TRUE(back.settings.has_value());
  EXPECT_EQ(back.settings->method, core::Method::Arap);
  EXPECT_TRUE(back.settings->ora);
  EXPECT_EQ(back.settings->rigidity, 30);
  EXPECT_EQ(back.settings->max_iterations, 7);
  EXPECT_EQ(back.settings->tolerance, 1e-6);
  ASSERT_EQ(back.settings->magnify.size(), 1u);
  EXPECT_EQ(back.settings->magnify[0].vertices, Eigen::Vector3i(6, 7, 8));
  ASSERT_EQ(back.steps.size(), 2u);
  EXPECT_EQ(back.position, 1);
  EXPECT_TRUE(same_state(back.steps[1], state.steps[1]));
  EXPECT_EQ(back.steps[1].gesture, 42u);
  EXPECT_EQ(back.steps[1].moves[1].pivot, Eigen::Vector3d(1, 2, 3));
  EXPECT_FALSE(back.steps[1].moves[0].pivot.has_value());

  // A group or vertex out of range for the session reading it is corrupt, named.
  EditState refused;
  BinaryReader few_groups(bytes, "test");
  const Status groups = read_edit_state(few_groups, refused, 10, 2);
  EXPECT_EQ(groups.code(), ErrorCode::InvalidArgument);
  EXPECT_NE(groups.message().find("group"), std::string::npos) << groups.message();
  BinaryReader few_vertices(bytes, "test");
  EXPECT_EQ(read_edit_state(few_vertices, refused, 5, 3).code(), ErrorCode::InvalidArgument);
  for (std::size_t n = 0; n < bytes.size(); ++n) {
    BinaryReader cut(std::string_view(bytes).substr(0, n), "test");
    EXPECT_FALSE(read_edit_state(cut, refused, 10, 3).ok()) << "prefix " << n;
  }
}

// --- through the service -------------------------------------------------------------------------

struct Edited {
  CreatedSession created;
  std::vector<HandleGroup> groups;
};

Edited laplacian_session(DeformationService& service) {
  CreateSessionRequest request;
  request.sample = "cylinder_small";
  Result<CreatedSession> created = service.create_session(request);
  EXPECT_TRUE(created.ok()) << created.status().to_string();
  Edited e{*created, created->suggested_groups};
  EXPECT_TRUE(service
                  .set_handles(e.created.id, e.created.edit_token,
                               SetHandlesRequest{e.groups, core::Method::Laplacian})
                  .ok());
  return e;
}

/// A Laplacian move (one direct solve: the same targets give the same positions bit for bit).
MoveRequest lift(double z, std::uint64_t gesture = 0) {
  MoveRequest move;
  move.moves.push_back(lift_group(1, z));
  move.method = core::Method::Laplacian;
  move.max_iterations = 1;
  move.gesture = gesture;
  return move;
}

MoveRequest history(HistoryAction action) {
  MoveRequest move;
  move.method = core::Method::Laplacian;
  move.max_iterations = 1;
  move.history = action;
  return move;
}

TEST(EditHistoryServiceTest, UndoAndRedoGiveTheEarlierResultsExactly) {
  ServiceOptions options;
  options.workers = 2;
  DeformationService service(options);
  Edited e = laplacian_session(service);
  const auto& id = e.created.id;
  const auto& token = e.created.edit_token;
  Result<DeformResult> first = service.move_handles(id, token, lift(0.2));
  ASSERT_TRUE(first.ok()) << first.status().to_string();
  // A drag of three frames: one step.
  for (double z : {0.3, 0.4, 0.5}) ASSERT_TRUE(service.move_handles(id, token, lift(z, 99)).ok());
  Result<DeformResult> dragged = service.move_handles(id, token, lift(0.6, 99));
  ASSERT_TRUE(dragged.ok());
  Result<SessionInfo> info = service.session_info(id, token);
  ASSERT_TRUE(info.ok());
  ASSERT_EQ(info->edit.steps.size(), 3u);  // as set, lift 0.2, the drag
  EXPECT_EQ(info->edit.position, 2);
  ASSERT_TRUE(info->edit.settings.has_value());
  EXPECT_EQ(info->edit.settings->method, core::Method::Laplacian);
  EXPECT_EQ(info->edit.settings->max_iterations, 1);

  Result<DeformResult> undone = service.move_handles(id, token, history(HistoryAction::Undo));
  ASSERT_TRUE(undone.ok()) << undone.status().to_string();
  EXPECT_EQ(*undone->positions, *first->positions);
  Result<DeformResult> to_rest = service.move_handles(id, token, history(HistoryAction::Undo));
  ASSERT_TRUE(to_rest.ok());
  Result<std::string> rest_obj = service.get_mesh(id, token, io::MeshFormat::Obj, 0);
  ASSERT_TRUE(rest_obj.ok());
  Result<io::LoadedMesh> rest = io::load_mesh_from_memory(*rest_obj, io::MeshFormat::Obj);
  ASSERT_TRUE(rest.ok());
  EXPECT_LT((*to_rest->positions - rest->mesh.V).cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_EQ(service.move_handles(id, token, history(HistoryAction::Undo)).status().code(),
            ErrorCode::FailedPrecondition);
  Result<DeformResult> redone = service.move_handles(id, token, history(HistoryAction::Redo));
  ASSERT_TRUE(redone.ok());
  EXPECT_EQ(*redone->positions, *first->positions);
  redone = service.move_handles(id, token, history(HistoryAction::Redo));
  ASSERT_TRUE(redone.ok());
  EXPECT_EQ(*redone->positions, *dragged->positions);
  EXPECT_EQ(service.move_handles(id, token, history(HistoryAction::Redo)).status().code(),
            ErrorCode::FailedPrecondition);

  // Undo with moves is refused and changes nothing.
  MoveRequest bad = history(HistoryAction::Undo);
  bad.moves.push_back(lift_group(1, 1.0));
  const std::uint64_t before = service.session_info(id, token)->revision;
  EXPECT_EQ(service.move_handles(id, token, bad).status().code(), ErrorCode::InvalidArgument);
  EXPECT_EQ(service.session_info(id, token)->revision, before);
  EXPECT_EQ(service.session_info(id, token)->edit.position, 2);

  // A one-off solve with keep_settings leaves the stored settings alone.
  MoveRequest one_off = lift(0.1);
  one_off.max_iterations = 3;
  one_off.keep_settings = true;
  ASSERT_TRUE(service.move_handles(id, token, one_off).ok());
  EXPECT_EQ(service.session_info(id, token)->edit.settings->max_iterations, 1);
  EXPECT_EQ(service.session_info(id, token)->edit.position, 3);  // but it is a step

  // New handles: a new history, the settings stay.
  ASSERT_TRUE(service
                  .set_handles(id, token, SetHandlesRequest{e.groups, core::Method::Laplacian})
                  .ok());
  info = service.session_info(id, token);
  EXPECT_EQ(info->edit.steps.size(), 1u);
  EXPECT_EQ(info->edit.position, 0);
  EXPECT_TRUE(info->edit.settings.has_value());
}

TEST(EditHistoryServiceTest, GroupAnchorsFollowTheGroupsOrder) {
  ServiceOptions options;
  options.workers = 1;
  DeformationService service(options);
  Edited e = laplacian_session(service);
  Result<SessionInfo> info = service.session_info(e.created.id, e.created.view_token);
  ASSERT_TRUE(info.ok());
  Result<std::string> obj = service.get_mesh(e.created.id, e.created.view_token, io::MeshFormat::Obj, 0);
  Result<io::LoadedMesh> rest = io::load_mesh_from_memory(*obj, io::MeshFormat::Obj);
  ASSERT_TRUE(rest.ok());
  Eigen::Index row = 0;
  for (const HandleGroup& g : info->groups) {
    for (int v : g.vertices) {
      ASSERT_LT(row, info->group_anchors.rows());
      EXPECT_EQ(info->group_anchors.row(row++), rest->mesh.V.row(v)) << "vertex " << v;
    }
  }
  EXPECT_EQ(row, info->group_anchors.rows());
}

TEST(EditHistoryServiceTest, SettingsAndHistorySurviveARestart) {
  std::random_device random;
  const fs::path dir = fs::temp_directory_path() /
                       ("meshdeform-edit-" + std::to_string(random()) + std::to_string(random()));
  struct Cleanup {
    fs::path path;
    ~Cleanup() {
      std::error_code ignored;
      fs::remove_all(path, ignored);
    }
  } cleanup{dir};
  ServiceOptions options;
  options.workers = 2;
  options.state_dir = dir.string();
  Edited e;
  {
    DeformationService service(options);
    e = laplacian_session(service);
    ASSERT_TRUE(service.move_handles(e.created.id, e.created.edit_token, lift(0.2)).ok());
    MoveRequest scale_aware = lift(0.4);
    scale_aware.method = core::Method::ScaleAware;
    scale_aware.rigidity = 30;
    scale_aware.max_iterations = 3;
    ASSERT_TRUE(service.move_handles(e.created.id, e.created.edit_token, scale_aware).ok());
    ASSERT_TRUE(service.move_handles(e.created.id, e.created.edit_token,
                                     history(HistoryAction::Undo)).ok());
  }
  DeformationService restarted(options);
  Result<SessionInfo> info = restarted.session_info(e.created.id, e.created.view_token);
  ASSERT_TRUE(info.ok()) << info.status().to_string();
  ASSERT_EQ(info->edit.steps.size(), 3u);
  EXPECT_EQ(info->edit.position, 1);
  EXPECT_EQ(info->edit.steps[2].moves[0].translation.z(), 0.4);
  ASSERT_TRUE(info->edit.settings.has_value());
  EXPECT_EQ(info->edit.settings->method, core::Method::Laplacian);  // the undo's
  // Redo goes on from the restored history.
  MoveRequest redo = history(HistoryAction::Redo);
  Result<DeformResult> redone = restarted.move_handles(e.created.id, e.created.edit_token, redo);
  ASSERT_TRUE(redone.ok()) << redone.status().to_string();
  EXPECT_EQ(restarted.session_info(e.created.id, e.created.view_token)->edit.position, 2);
}

TEST(EditHistoryServiceTest, StateWrittenBeforeTheEditStateReadsAsAnEmptyHistory) {
  PersistedSession s;
  s.id = SessionId{"0123456789abcdef0123456789abcdef"};
  s.edit_token = Token{std::string(64, 'e')};
  s.view_token = Token{std::string(64, 'v')};
  s.rest = test::make_grid(3, 0.1);
  s.groups = {HandleGroup{HandleRole::Handle, {0, 1}}};
  s.anchors = s.rest.V.topRows(2);
  s.targets = s.anchors;
  s.positions = s.rest.V;
  BinaryWriter full;
  write_session_state(full, s);
  // The first format ended after the method: cut the tag and the edit state off.
  BinaryWriter edit;
  write_edit_state(edit, s.edit);
  const std::string bytes = full.bytes().substr(0, full.bytes().size() - 4 - edit.bytes().size());
  PersistedSession back = s;
  back.edit.steps.resize(3);
  BinaryReader in(bytes, "old state");
  ASSERT_TRUE(read_session_state(in, back).ok());
  EXPECT_EQ(back.edit.steps.size(), 1u);
  EXPECT_FALSE(back.edit.settings.has_value());
}

}  // namespace
}  // namespace meshdeform::service
