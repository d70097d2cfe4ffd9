// Session on its own, without DeformationService: no worker pool, no strand, no store. Each test
// drives the session from the test thread the way the service's strand would.
#include "server/service/session.h"

#include <gtest/gtest.h>
#include <malloc.h>

#include <chrono>
#include <cmath>
#include <functional>
#include <memory>
#include <optional>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include "tests/support/mesh_factories.h"

namespace meshdeform::service {
namespace {

void expect_error(const Status& status, ErrorCode code, const std::string& fragment) {
  EXPECT_EQ(status.code(), code) << status.to_string();
  EXPECT_NE(status.message().find(fragment), std::string::npos)
      << "'" << status.message() << "' lacks '" << fragment << "'";
}

/// A 7 x 7 bumpy grid on [0,1]^2.
MeshData grid() { return test::make_grid(6, 0.05); }

/// Group 0 Fixed: the column x = 0; group 1 Handle: the column x = 1.
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
  MeshData mesh = grid();
  std::shared_ptr<Session> session;

  /// Creates the session (again) with the current options.
  void create(Session::ReserveFn reserve = {}) {
    Result<std::shared_ptr<Session>> made =
        Session::create(SessionId{"s1"}, Token{"edit"}, Token{"view"}, mesh,
                        core::DeformerSettings{}, options, counters, std::move(reserve));
    ASSERT_TRUE(made.ok()) << made.status().to_string();
    session = *made;
  }

  /// Sets the column groups for `method`.
  void set_columns(core::Method method = core::Method::ScaleAware) {
    SetHandlesRequest request;
    request.groups = column_groups(mesh);
    request.prepare = method;
    const Result<SessionInfo> info = session->set_handles(request);
    ASSERT_TRUE(info.ok()) << info.status().to_string();
  }

  Result<DeformResult> move(const MoveRequest& request, std::stop_token stop = {}) {
    return session->move(request, std::move(stop));
  }

  std::vector<int> handle_vertices() const { return column_groups(mesh)[1].vertices; }
};

/// Moves the handle group by `lift` along z.
MoveRequest lift(double dz, core::Method method = core::Method::Arap) {
  MoveRequest request;
  GroupMove move;
  move.group = 1;
  move.translation = Eigen::Vector3d(0, 0, dz);
  request.moves.push_back(move);
  request.method = method;
  return request;
}

// --- create / restore ----------------------------------------------------------------------------

TEST(SessionTest, MovesUnderTheDragGapApartAreOneDrag) {
  // drag_interval(): the interval between the last two moves' arrivals while they are one drag
  // (under kDragGap apart), which refinement's rest outlasts (refinement_rest()); 0 otherwise.
  Fixture f;
  f.create();
  using std::chrono::steady_clock;
  EXPECT_EQ(f.session->drag_interval(), steady_clock::duration::zero());
  const auto before = steady_clock::now();
  f.session->note_move_arrival();
  EXPECT_EQ(f.session->drag_interval(), steady_clock::duration::zero());  // the first move
  std::this_thread::sleep_for(std::chrono::milliseconds(2));
  f.session->note_move_arrival();
  const auto after = steady_clock::now();
  EXPECT_GE(f.session->drag_interval(), std::chrono::milliseconds(2));
  EXPECT_LE(f.session->drag_interval(), after - before);
  std::this_thread::sleep_for(kDragGap + std::chrono::milliseconds(10));
  f.session->note_move_arrival();  // a new drag
  EXPECT_EQ(f.session->drag_interval(), steady_clock::duration::zero());
}

TEST(SessionTest, CreateDescribesTheMeshAtRevisionZero) {
  Fixture f;
  f.create();
  const SessionInfo info = f.session->info();
  EXPECT_EQ(info.vertices, 49);
  EXPECT_EQ(info.faces, 72);
  EXPECT_EQ(info.boundary_loops, 1);
  EXPECT_EQ(info.components, 1);
  EXPECT_EQ(info.revision, 0u);
  EXPECT_TRUE(info.groups.empty());
  EXPECT_EQ(info.cached_deformers, 0);
  EXPECT_EQ(f.session->estimated_bytes(),
            estimate_session_bytes(49, 72, 0, f.options.kept_revisions));
  Result<std::shared_ptr<const Positions>> rest = f.session->positions_at(0);
  ASSERT_TRUE(rest.ok());
  EXPECT_EQ(**rest, f.mesh.V);
  EXPECT_TRUE(f.session->can_edit(Token{"edit"}));
  EXPECT_FALSE(f.session->can_edit(Token{"view"}));
  EXPECT_TRUE(f.session->can_view(Token{"view"}));
  EXPECT_FALSE(f.session->can_view(Token{"other"}));
}

TEST(SessionTest, OnlyBigSessionsSolveOnSeveralThreads) {
  Fixture f;  // 49 vertices
  f.options.solver_threads = 2;
  f.options.parallel_solve_above = 49;
  f.create();
  EXPECT_EQ(f.session->solve_threads(), 2);
  f.options.parallel_solve_above = 50;
  f.create();
  EXPECT_EQ(f.session->solve_threads(), 1);
  f.options.solver_threads = 0;  // one per core
  f.options.parallel_solve_above = 10;
  f.create();
  EXPECT_EQ(f.session->solve_threads(),
            std::max(1, static_cast<int>(std::thread::hardware_concurrency())));
  // A big session still moves: the solve on two threads gives a result.
  f.options.solver_threads = 2;
  f.create();
  f.set_columns();
  const Result<DeformResult> moved = f.move(lift(0.2, core::Method::ScaleAware));
  ASSERT_TRUE(moved.ok()) << moved.status().to_string();
  EXPECT_GT(moved->revision, 0u);
}

// glibc's heap statistics; a sanitizer's allocator does not keep them.
#if defined(__has_feature)
#if __has_feature(address_sanitizer)
#define MESHDEFORM_SANITIZED_HEAP 1
#endif
#endif
#if defined(__SANITIZE_ADDRESS__)
#define MESHDEFORM_SANITIZED_HEAP 1
#endif
#if defined(__GLIBC__) && !defined(MESHDEFORM_SANITIZED_HEAP)
TEST(SessionTest, TheDeformerChargeCoversTheScaleAwareDeformersHeap) {
  // The memory budget is only as good as the estimate: a built and solved scale-aware deformer
  // (the largest method) must not hold more heap than a cached deformer is charged.
  Fixture f;
  f.mesh = test::make_grid(100, 0.05);  // 10,201 vertices
  f.create();
  const int v = static_cast<int>(f.mesh.V.rows()), faces = static_cast<int>(f.mesh.F.rows());
  const std::size_t charge =
      estimate_session_bytes(v, faces, 1, 0) - estimate_session_bytes(v, faces, 0, 0);
  const auto heap = [] {
    const struct mallinfo2 info = mallinfo2();
    return info.uordblks + info.hblkhd;
  };
  const std::size_t before = heap();
  f.set_columns(core::Method::ScaleAware);
  const Result<DeformResult> moved = f.move(lift(0.2, core::Method::ScaleAware));
  ASSERT_TRUE(moved.ok()) << moved.status().to_string();
  const std::size_t after = heap();
  ASSERT_GT(after, before);
  EXPECT_LE(after - before, charge) << "heap grew by " << (after - before) << " bytes, charged "
                                    << charge;
  EXPECT_GT(after - before, charge / 4) << "the charge is far above what a deformer holds";
}
#endif

TEST(SessionTest, RefinementBuildsTheFullResolutionSolverOffTheStrandOnce) {
  Fixture f;
  f.mesh = test::make_grid(30, 0.05);  // 961 vertices: multiresolution above 500
  f.options.multires_above = 500;
  f.options.multires_coarse_vertices = 200;
  f.options.refine_budget = 10;
  f.create();
  f.set_columns(core::Method::ScaleAware);
  ASSERT_TRUE(f.move(lift(0.2, core::Method::ScaleAware)).ok());
  ASSERT_TRUE(f.session->wants_refinement()) << "a coarse move leaves work for refinement";

  // A failed build ends refinement instead of being retried for ever.
  std::optional<Session::BackgroundBuild> failing = f.session->take_background_build();
  ASSERT_TRUE(failing.has_value());
  EXPECT_TRUE(f.session->background_build_running());
  EXPECT_FALSE(f.session->take_background_build().has_value()) << "one build at a time";
  EXPECT_FALSE(f.session->finish_background_build(
      *failing, Error(ErrorCode::NumericalFailure, "injected")));
  EXPECT_FALSE(f.session->background_build_running());
  EXPECT_FALSE(f.session->wants_refinement());

  // The next move wants refinement again; its build runs (here on this thread) and installs.
  ASSERT_TRUE(f.move(lift(0.3, core::Method::ScaleAware)).ok());
  ASSERT_TRUE(f.session->wants_refinement());
  std::optional<Session::BackgroundBuild> build = f.session->take_background_build();
  ASSERT_TRUE(build.has_value());
  Result<core::Deformer::Installer> installer = build->task(f.session->background_build_stop());
  ASSERT_TRUE(installer.ok()) << installer.status().to_string();
  EXPECT_TRUE(f.session->finish_background_build(*build, std::move(installer)));
  EXPECT_FALSE(f.session->take_background_build().has_value()) << "built once, not again";
  Result<std::optional<DeformResult>> refined = f.session->refine(std::stop_source());
  ASSERT_TRUE(refined.ok()) << refined.status().to_string();
  ASSERT_TRUE(refined->has_value());
  EXPECT_TRUE((*refined)->refinement);
}

TEST(SessionTest, CreateRefusesAMeshWithoutATopology) {
  Fixture f;
  // Three triangles on one edge: not a manifold.
  f.mesh.V.resize(5, 3);
  f.mesh.V << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, -1, 0, 0, 0, 1;
  f.mesh.F.resize(3, 3);
  f.mesh.F << 0, 1, 2, 1, 0, 3, 0, 1, 4;
  Result<std::shared_ptr<Session>> made =
      Session::create(SessionId{"s1"}, Token{"edit"}, Token{"view"}, f.mesh, {}, f.options,
                      f.counters, {});
  expect_error(made.status(), ErrorCode::InvalidArgument, "non-manifold");
}

TEST(SessionTest, RestoreGivesBackTheStateWithoutTheFactorizations) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  MoveRequest first = lift(0.2);
  first.gesture = 7;
  ASSERT_TRUE(f.move(first).ok());
  ASSERT_TRUE(f.move(lift(0.3)).ok());
  const SessionInfo before = f.session->info();

  Result<std::shared_ptr<Session>> restored =
      Session::restore(f.session->persisted_state(), f.options, f.counters, {});
  ASSERT_TRUE(restored.ok()) << restored.status().to_string();
  const SessionInfo after = (*restored)->info();
  EXPECT_EQ(after.revision, 2u);
  ASSERT_EQ(after.groups.size(), 2u);
  EXPECT_EQ(after.groups[1].vertices, before.groups[1].vertices);
  EXPECT_EQ(after.groups[0].role, HandleRole::Fixed);
  EXPECT_EQ(after.group_anchors, before.group_anchors);
  EXPECT_EQ(after.edit.position, before.edit.position);
  EXPECT_EQ(after.edit.steps.size(), before.edit.steps.size());
  EXPECT_EQ(after.last_method, std::optional<core::Method>(core::Method::Arap));
  EXPECT_EQ(after.cached_deformers, 0);
  EXPECT_EQ(**(*restored)->positions_at(std::nullopt), **f.session->positions_at(std::nullopt));

  // The restored copy edits on: its first move builds its own deformer.
  const std::uint64_t built = f.counters->deformer_constructions.load();
  Result<DeformResult> moved = (*restored)->move(lift(0.1), {});
  ASSERT_TRUE(moved.ok()) << moved.status().to_string();
  EXPECT_EQ(moved->revision, 3u);
  EXPECT_TRUE(moved->built_deformer);
  EXPECT_EQ(f.counters->deformer_constructions.load(), built + 1);
}

TEST(SessionTest, RestoreRefusesAVertexInTwoGroups) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  PersistedSession state = f.session->persisted_state();
  state.groups[0].vertices.push_back(state.groups[1].vertices.front());
  Result<std::shared_ptr<Session>> restored =
      Session::restore(std::move(state), f.options, f.counters, {});
  expect_error(restored.status(), ErrorCode::InvalidArgument, "two groups");
}

// --- set_handles ---------------------------------------------------------------------------------

TEST(SessionTest, SetHandlesAnchorsTheGroupsAndBuildsTheFactorization) {
  Fixture f;
  f.create();
  SetHandlesRequest request;
  request.groups = column_groups(f.mesh);
  const Result<SessionInfo> info = f.session->set_handles(request);
  ASSERT_TRUE(info.ok()) << info.status().to_string();
  ASSERT_EQ(info->groups.size(), 2u);
  EXPECT_EQ(info->cached_deformers, 1);
  EXPECT_EQ(f.counters->deformer_constructions.load(), 1u);
  EXPECT_EQ(f.session->estimated_bytes(),
            estimate_session_bytes(49, 72, 1, f.options.kept_revisions));
  // Anchors: the groups in order, each group's vertices in its order, at the current positions.
  Eigen::Index row = 0;
  for (const HandleGroup& g : request.groups) {
    for (int v : g.vertices) EXPECT_EQ(info->group_anchors.row(row++), f.mesh.V.row(v));
  }
  EXPECT_EQ(row, info->group_anchors.rows());

  // The same groups again reuse the factorization.
  ASSERT_TRUE(f.session->set_handles(request).ok());
  EXPECT_EQ(f.counters->deformer_constructions.load(), 1u);
}

TEST(SessionTest, SetHandlesNamesWhatIsWrongWithTheGroups) {
  Fixture f;
  f.create();
  SetHandlesRequest request;
  expect_error(f.session->set_handles(request).status(), ErrorCode::InvalidArgument,
               "at least one handle group");

  request.groups = column_groups(f.mesh);
  request.groups.push_back(HandleGroup{HandleRole::Handle, {}});
  expect_error(f.session->set_handles(request).status(), ErrorCode::InvalidArgument,
               "handle group 2 is empty");

  request.groups = column_groups(f.mesh);
  request.groups[1].vertices.push_back(49);
  expect_error(f.session->set_handles(request).status(), ErrorCode::InvalidArgument,
               "handle group 1 references vertex 49 (#V=49)");
  request.groups[1].vertices.back() = -1;
  expect_error(f.session->set_handles(request).status(), ErrorCode::InvalidArgument,
               "references vertex -1");

  request.groups = column_groups(f.mesh);
  request.groups[1].vertices.push_back(request.groups[0].vertices[2]);
  expect_error(f.session->set_handles(request).status(), ErrorCode::InvalidArgument,
               "is in fixed group 0 and in handle group 1");

  // Nothing was set by the refused calls.
  EXPECT_TRUE(f.session->info().groups.empty());
  EXPECT_EQ(f.counters->deformer_constructions.load(), 0u);
}

TEST(SessionTest, SetHandlesRefusesAComponentTheMethodCannotPin) {
  Fixture f;
  f.create();
  SetHandlesRequest request;
  request.groups = {HandleGroup{HandleRole::Handle, {5}}};
  // Scale-aware needs two constrained vertices per component; ARAP one.
  expect_error(f.session->set_handles(request).status(), ErrorCode::FailedPrecondition,
               "component 0 has 1");
  request.prepare = core::Method::Arap;
  EXPECT_TRUE(f.session->set_handles(request).ok());
}

TEST(SessionTest, SetHandlesOverTheBudgetBuildsNothing) {
  Fixture f;
  int asked = 0;
  f.create([&asked](std::size_t, const Session&) {
    ++asked;
    return Error(ErrorCode::ResourceExhausted, "budget");
  });
  SetHandlesRequest request;
  request.groups = column_groups(f.mesh);
  expect_error(f.session->set_handles(request).status(), ErrorCode::ResourceExhausted, "budget");
  EXPECT_EQ(asked, 1);
  EXPECT_EQ(f.session->info().cached_deformers, 0);
  EXPECT_TRUE(f.session->info().groups.empty());
}

// --- move ----------------------------------------------------------------------------------------

TEST(SessionTest, MoveBeforeSetHandlesIsAPreconditionFailure) {
  Fixture f;
  f.create();
  expect_error(f.move(lift(0.1)).status(), ErrorCode::FailedPrecondition, "set_handles");
}

TEST(SessionTest, GroupMoveSetsTheTargetsOfItsGroupOnly) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  MoveRequest request;
  GroupMove move;
  move.group = 1;
  move.translation = Eigen::Vector3d(0.1, 0, 0.2);
  move.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.3, Eigen::Vector3d::UnitY()));
  move.scale = 1.5;
  move.pivot = Eigen::Vector3d(1, 0.5, 0);
  request.moves.push_back(move);
  request.method = core::Method::Arap;
  request.editor = "tester";
  Result<DeformResult> result = f.move(request);
  ASSERT_TRUE(result.ok()) << result.status().to_string();
  EXPECT_EQ(result->revision, 1u);
  EXPECT_EQ(result->editor, "tester");
  EXPECT_FALSE(result->built_deformer);  // set_handles built it
  const Positions& V = *result->positions;
  const Eigen::Matrix3d R = move.rotation.toRotationMatrix();
  // ARAP puts handles exactly on their targets: pivot + s R (anchor - pivot) + t.
  for (int v : f.handle_vertices()) {
    const Eigen::Vector3d anchor = f.mesh.V.row(v).transpose();
    const Eigen::Vector3d target =
        *move.pivot + move.scale * R * (anchor - *move.pivot) + move.translation;
    EXPECT_LT((V.row(v).transpose() - target).norm(), test::kExactTol) << "vertex " << v;
  }
  const std::vector<HandleGroup> groups = column_groups(f.mesh);
  for (int v : groups[0].vertices) {
    EXPECT_LT((V.row(v) - f.mesh.V.row(v)).norm(), test::kExactTol) << "fixed vertex " << v;
  }
  EXPECT_EQ(f.session->revision(), 1u);
  EXPECT_EQ(f.counters->moves_committed.load(), 1u);
}

TEST(SessionTest, ExplicitTargetsApplyAfterTheMoves) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  const int v = f.handle_vertices()[3];
  MoveRequest request = lift(0.2);
  const Eigen::Vector3d where(1.2, 0.4, -0.3);
  request.targets.push_back(VertexTarget{v, where});
  Result<DeformResult> result = f.move(request);
  ASSERT_TRUE(result.ok()) << result.status().to_string();
  EXPECT_LT((result->positions->row(v).transpose() - where).norm(), test::kExactTol);
  const int other = f.handle_vertices()[0];
  EXPECT_NEAR((*result->positions)(other, 2), f.mesh.V(other, 2) + 0.2, test::kExactTol);

  // Targets persist: a later move of nothing keeps them.
  MoveRequest nothing;
  nothing.method = core::Method::Arap;
  Result<DeformResult> again = f.move(nothing);
  ASSERT_TRUE(again.ok());
  EXPECT_LT((again->positions->row(v).transpose() - where).norm(), test::kExactTol);
}

TEST(SessionTest, MoveNamesWhatIsWrongWithTheRequest) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  constexpr int nv = 49;
  const int fixed_vertex = column_groups(f.mesh)[0].vertices[0];
  const int handle_vertex = f.handle_vertices()[0];
  int free_vertex = 0;
  while (f.mesh.V(free_vertex, 0) < 1e-9 || f.mesh.V(free_vertex, 0) > 1 - 1e-9) ++free_vertex;

  struct Case {
    const char* name;
    std::function<void(MoveRequest&)> edit;
    std::string fragment;
  };
  const double nan = std::nan("");
  const std::vector<Case> cases = {
      {"group out of range", [](MoveRequest& r) { r.moves[0].group = 2; },
       "moves[0].group 2 does not exist (2 groups)"},
      {"negative group", [](MoveRequest& r) { r.moves[0].group = -1; }, "moves[0].group -1 does not exist"},
      {"fixed group", [](MoveRequest& r) { r.moves[0].group = 0; },
       "moves[0].group 0 is fixed and cannot move"},
      {"non-finite translation", [nan](MoveRequest& r) { r.moves[0].translation.x() = nan; },
       "moves[0].translation has a non-finite component"},
      {"non-finite pivot",
       [nan](MoveRequest& r) { r.moves[0].pivot = Eigen::Vector3d(0, nan, 0); },
       "moves[0].pivot has a non-finite component"},
      {"non-finite rotation",
       [nan](MoveRequest& r) { r.moves[0].rotation = Eigen::Quaterniond(1, nan, 0, 0); },
       "moves[0].rotation has a non-finite component"},
      {"zero scale", [](MoveRequest& r) { r.moves[0].scale = 0; },
       "moves[0].scale 0 is outside [1e-06, 1e+06]"},
      {"non-finite scale", [nan](MoveRequest& r) { r.moves[0].scale = nan; },
       "moves[0].scale nan is outside [1e-06, 1e+06]"},
      {"zero quaternion",
       [](MoveRequest& r) { r.moves[0].rotation = Eigen::Quaterniond(0, 0, 0, 0); },
       "moves[0].rotation is the zero quaternion"},
      {"target out of range",
       [](MoveRequest& r) { r.targets.push_back(VertexTarget{nv, Eigen::Vector3d::Zero()}); },
       "targets.vertices[0]: vertex 49 is out of range (#V=49)"},
      {"target not constrained",
       [free_vertex](MoveRequest& r) {
         r.targets.push_back(VertexTarget{free_vertex, Eigen::Vector3d::Zero()});
       },
       "is not constrained"},
      {"target in a fixed group",
       [fixed_vertex](MoveRequest& r) {
         r.targets.push_back(VertexTarget{fixed_vertex, Eigen::Vector3d::Zero()});
       },
       "is in fixed group 0"},
      {"non-finite target",
       [handle_vertex, nan](MoveRequest& r) {
         r.targets.push_back(VertexTarget{handle_vertex, Eigen::Vector3d(nan, 0, 0)});
       },
       "targets.positions of vertex " + std::to_string(handle_vertex) +
           " has a non-finite component"},
      {"no iterations", [](MoveRequest& r) { r.max_iterations = 0; },
       "max_iterations 0 is outside [1, 1000]"},
      {"too many iterations", [](MoveRequest& r) { r.max_iterations = 1001; },
       "max_iterations 1001"},
      {"negative tolerance", [](MoveRequest& r) { r.tolerance = -1; },
       "tolerance -1.000000 is not finite and >= 0"},
      {"non-finite tolerance", [nan](MoveRequest& r) { r.tolerance = nan; }, "tolerance"},
      {"rigidity out of range", [](MoveRequest& r) { r.rigidity = -1; }, "rigidity"},
      {"too many magnify regions",
       [](MoveRequest& r) { r.magnify.resize(kMaxMagnifyRegions + 1); },
       "65 magnify regions (at most 64)"},
      {"magnify scale",
       [](MoveRequest& r) {
         r.method = core::Method::ScaleAware;
         core::MagnifyRegion region;
         region.vertices = Eigen::Vector3i(0, 1, 7);
         region.scale = 0;
         r.magnify.push_back(region);
       },
       "magnify[0].scale 0 is outside [0.001, 1000]"},
      {"magnify with ARAP",
       [](MoveRequest& r) {
         core::MagnifyRegion region;
         region.vertices = Eigen::Vector3i(0, 1, 7);
         region.scale = 2;
         r.magnify.push_back(region);
       },
       "magnify regions need the scale-aware method"},
      {"magnify by faces",
       [](MoveRequest& r) {
         r.method = core::Method::ScaleAware;
         core::MagnifyRegion region;
         region.faces = Eigen::Vector2i(0, 1);
         region.scale = 2;
         r.magnify.push_back(region);
       },
       "magnify[0]: name the region by vertices"},
      {"undo with moves", [](MoveRequest& r) { r.history = HistoryAction::Undo; },
       "send no moves or targets"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    MoveRequest request = lift(0.1);
    c.edit(request);
    Result<DeformResult> result = f.move(request);
    EXPECT_EQ(result.status().code(), ErrorCode::InvalidArgument) << result.status().to_string();
    EXPECT_NE(result.status().message().find(c.fragment), std::string::npos)
        << "'" << result.status().message() << "' lacks '" << c.fragment << "'";
  }
  // Nothing was committed by the refused moves.
  EXPECT_EQ(f.session->revision(), 0u);
  EXPECT_EQ(f.counters->moves_committed.load(), 0u);
}

TEST(SessionTest, StoppedOrLateMoveCommitsNothing) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  std::stop_source stop;
  stop.request_stop();
  expect_error(f.move(lift(0.1), stop.get_token()).status(), ErrorCode::Cancelled,
               "revision 0 unchanged");
  MoveRequest late = lift(0.1);
  late.deadline = std::chrono::steady_clock::now() - std::chrono::seconds(1);
  expect_error(f.move(late).status(), ErrorCode::DeadlineExceeded, "revision 0 unchanged");
  EXPECT_EQ(f.session->revision(), 0u);
  EXPECT_EQ(f.counters->moves_cancelled.load(), 2u);
  EXPECT_EQ(f.counters->moves_committed.load(), 0u);
}

// --- undo history --------------------------------------------------------------------------------

TEST(SessionTest, UndoAndRedoApplyTheRecordedSteps) {
  Fixture f;
  f.create();
  // Laplacian: one direct solve of the targets, so a step's positions come back exactly.
  f.set_columns(core::Method::Laplacian);
  Result<DeformResult> one = f.move(lift(0.1, core::Method::Laplacian));
  Result<DeformResult> two = f.move(lift(0.3, core::Method::Laplacian));
  ASSERT_TRUE(one.ok() && two.ok());
  EXPECT_EQ(f.session->info().edit.steps.size(), 3u);  // set_handles, one, two
  EXPECT_EQ(f.session->info().edit.position, 2);

  MoveRequest undo;
  undo.method = core::Method::Laplacian;
  undo.history = HistoryAction::Undo;
  Result<DeformResult> undone = f.move(undo);
  ASSERT_TRUE(undone.ok()) << undone.status().to_string();
  EXPECT_EQ(undone->revision, 3u);  // an undo is a new revision
  EXPECT_EQ(*undone->positions, *one->positions);
  EXPECT_EQ(f.session->info().edit.position, 1);

  ASSERT_TRUE(f.move(undo).ok());
  Result<DeformResult> at_start = f.move(undo);
  expect_error(at_start.status(), ErrorCode::FailedPrecondition, "nothing to undo");

  MoveRequest redo = undo;
  redo.history = HistoryAction::Redo;
  ASSERT_TRUE(f.move(redo).ok());
  Result<DeformResult> redone = f.move(redo);
  ASSERT_TRUE(redone.ok());
  EXPECT_EQ(*redone->positions, *two->positions);
  expect_error(f.move(redo).status(), ErrorCode::FailedPrecondition, "nothing to redo");

  // A recorded move after an undo drops the redo branch.
  ASSERT_TRUE(f.move(undo).ok());
  ASSERT_TRUE(f.move(lift(0.2, core::Method::Laplacian)).ok());
  EXPECT_EQ(f.session->info().edit.steps.size(), 3u);
  expect_error(f.move(redo).status(), ErrorCode::FailedPrecondition, "nothing to redo");
}

TEST(SessionTest, MovesOfOneGestureRecordOneStep) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  for (double dz : {0.1, 0.2, 0.3}) {
    MoveRequest drag = lift(dz);
    drag.gesture = 5;
    ASSERT_TRUE(f.move(drag).ok());
  }
  EXPECT_EQ(f.session->info().edit.steps.size(), 2u);
  MoveRequest next = lift(0.4);
  next.gesture = 6;
  ASSERT_TRUE(f.move(next).ok());
  EXPECT_EQ(f.session->info().edit.steps.size(), 3u);
  // Gesture 0 is no gesture: every such move is a step.
  ASSERT_TRUE(f.move(lift(0.5)).ok());
  ASSERT_TRUE(f.move(lift(0.6)).ok());
  EXPECT_EQ(f.session->info().edit.steps.size(), 5u);
  // The drag's step holds its last move.
  ASSERT_EQ(f.session->info().edit.steps[1].moves.size(), 1u);
  EXPECT_DOUBLE_EQ(f.session->info().edit.steps[1].moves[0].translation.z(), 0.3);

  // set_handles starts a new history.
  f.set_columns(core::Method::Arap);
  EXPECT_EQ(f.session->info().edit.steps.size(), 1u);
  EXPECT_EQ(f.session->info().edit.position, 0);
}

TEST(SessionTest, KeepSettingsLeavesTheStoredSettings) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  MoveRequest first = lift(0.1);
  first.max_iterations = 3;
  ASSERT_TRUE(f.move(first).ok());
  MoveRequest once = lift(0.2);
  once.max_iterations = 9;
  once.keep_settings = true;
  ASSERT_TRUE(f.move(once).ok());
  ASSERT_TRUE(f.session->info().edit.settings.has_value());
  EXPECT_EQ(f.session->info().edit.settings->max_iterations, 3);
}

// --- background refinement -----------------------------------------------------------------------

/// A scale-aware move that stops after one iteration, far from converged.
MoveRequest unconverged_move() {
  MoveRequest request = lift(0.4, core::Method::ScaleAware);
  request.moves[0].rotation = Eigen::Quaterniond(Eigen::AngleAxisd(0.8, Eigen::Vector3d::UnitY()));
  request.max_iterations = 1;
  request.tolerance = 0;
  return request;
}

TEST(SessionTest, RefineCommitsSlicesUntilTheBudgetIsSpent) {
  Fixture f;
  f.options.refine_budget = 6;
  f.create();
  f.set_columns();
  EXPECT_FALSE(f.session->wants_refinement());
  Result<std::optional<DeformResult>> nothing = f.session->refine(std::stop_source());
  ASSERT_TRUE(nothing.ok());
  EXPECT_FALSE(nothing->has_value());

  Result<DeformResult> moved = f.move(unconverged_move());
  ASSERT_TRUE(moved.ok()) << moved.status().to_string();
  ASSERT_FALSE(moved->converged);
  EXPECT_TRUE(f.session->wants_refinement());

  int slices = 0, iterations = 0;
  std::uint64_t revision = moved->revision;
  while (f.session->wants_refinement() && slices < 10) {
    Result<std::optional<DeformResult>> refined = f.session->refine(std::stop_source());
    ASSERT_TRUE(refined.ok()) << refined.status().to_string();
    ASSERT_TRUE(refined->has_value());
    const DeformResult& r = **refined;
    EXPECT_TRUE(r.refinement);
    EXPECT_EQ(r.editor, "refinement");
    EXPECT_EQ(r.revision, revision + 1);
    EXPECT_LE(r.iterations, 2);  // slices of two outer iterations
    revision = r.revision;
    iterations += std::max(r.iterations, 1);
    ++slices;
  }
  EXPECT_FALSE(f.session->wants_refinement());
  EXPECT_GE(slices, 1);
  EXPECT_LE(iterations, 6);
  EXPECT_EQ(f.counters->refinements_committed.load(), static_cast<std::uint64_t>(slices));
  EXPECT_EQ(f.session->revision(), revision);
}

TEST(SessionTest, RefineYieldsToAQueuedEditOrAStop) {
  Fixture f;
  f.options.refine_budget = 6;
  f.create();
  f.set_columns();
  ASSERT_TRUE(f.move(unconverged_move()).ok());
  ASSERT_TRUE(f.session->wants_refinement());

  // An edit waiting on the strand preempts the slice before it solves.
  ASSERT_TRUE(f.session->enqueue([] {}, {}).has_value());
  expect_error(f.session->refine(std::stop_source()).status(), ErrorCode::Cancelled, "preempted");
  EXPECT_EQ(f.counters->refinements_preempted.load(), 1u);
  EXPECT_TRUE(f.session->wants_refinement());  // resumes after the edit
  EXPECT_FALSE(f.session->run_next().has_value());

  std::stop_source stop;
  stop.request_stop();
  EXPECT_EQ(f.session->refine(stop).status().code(), ErrorCode::Cancelled);
  EXPECT_EQ(f.counters->refinements_preempted.load(), 2u);
  EXPECT_EQ(f.session->revision(), 1u);

  // Nothing stops it now: a slice commits.
  Result<std::optional<DeformResult>> refined = f.session->refine(std::stop_source());
  ASSERT_TRUE(refined.ok()) << refined.status().to_string();
  EXPECT_TRUE(refined->has_value());
}

TEST(SessionTest, SetHandlesAndCloseEndRefinement) {
  Fixture f;
  f.options.refine_budget = 6;
  f.create();
  f.set_columns();
  ASSERT_TRUE(f.move(unconverged_move()).ok());
  ASSERT_TRUE(f.session->wants_refinement());
  f.set_columns();
  EXPECT_FALSE(f.session->wants_refinement());

  ASSERT_TRUE(f.move(unconverged_move()).ok());
  ASSERT_TRUE(f.session->wants_refinement());
  f.session->close();
  EXPECT_FALSE(f.session->wants_refinement());
}

// --- watchers and close --------------------------------------------------------------------------

TEST(SessionTest, WatchersGetTheSnapshotThenEveryRevision) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  std::shared_ptr<Watcher> watcher = f.session->add_watcher();
  std::optional<DeformUpdate> joined = watcher->try_take();
  ASSERT_TRUE(joined.has_value());
  EXPECT_TRUE(joined->is_snapshot);
  EXPECT_EQ(joined->result->revision, 0u);
  ASSERT_TRUE(f.move(lift(0.1)).ok());
  std::optional<DeformUpdate> update = watcher->try_take();
  ASSERT_TRUE(update.has_value());
  EXPECT_FALSE(update->is_snapshot);
  EXPECT_EQ(update->result->revision, 1u);
  EXPECT_FALSE(update->result->changed.empty());
  EXPECT_EQ(f.session->watcher_count(), 1);
  f.session->remove_watcher(watcher.get());
  EXPECT_EQ(f.session->watcher_count(), 0);
}

TEST(SessionTest, CloseEndsWatchersAndEdits) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  std::shared_ptr<Watcher> first = f.session->add_watcher();
  std::shared_ptr<Watcher> second = f.session->add_watcher();
  EXPECT_FALSE(first->closed());
  f.session->close();
  EXPECT_TRUE(f.session->is_closed());
  EXPECT_TRUE(first->closed());
  EXPECT_TRUE(second->closed());
  EXPECT_EQ(f.session->watcher_count(), 0);
  // A watcher that comes late gets the snapshot and the end at once.
  std::shared_ptr<Watcher> late = f.session->add_watcher();
  EXPECT_TRUE(late->closed());
  EXPECT_TRUE(late->try_take().has_value());

  expect_error(f.move(lift(0.1)).status(), ErrorCode::NotFound, "closed");
  SetHandlesRequest request;
  request.groups = column_groups(f.mesh);
  expect_error(f.session->set_handles(request).status(), ErrorCode::NotFound, "closed");
  EXPECT_EQ(f.session->revision(), 0u);
}

TEST(SessionTest, CloseWatchersKeepsTheSessionOpen) {
  Fixture f;
  f.create();
  f.set_columns(core::Method::Arap);
  std::shared_ptr<Watcher> watcher = f.session->add_watcher();
  f.session->close_watchers(Error(ErrorCode::Unavailable, "shutting down"));
  EXPECT_EQ(watcher->close_status().code(), ErrorCode::Unavailable);
  EXPECT_TRUE(watcher->closed());
  EXPECT_FALSE(f.session->is_closed());
  EXPECT_TRUE(f.move(lift(0.1)).ok());
}

// --- kept revisions ------------------------------------------------------------------------------

TEST(SessionTest, KeepsTheRestAndTheNewestRevisions) {
  Fixture f;
  f.options.kept_revisions = 2;
  f.create();
  f.set_columns(core::Method::Arap);
  std::vector<Positions> committed;
  for (double dz : {0.1, 0.2, 0.3, 0.4}) {
    Result<DeformResult> r = f.move(lift(dz));
    ASSERT_TRUE(r.ok());
    committed.push_back(*r->positions);
  }
  EXPECT_EQ(**f.session->positions_at(0), f.mesh.V);
  EXPECT_EQ(**f.session->positions_at(3), committed[2]);
  EXPECT_EQ(**f.session->positions_at(4), committed[3]);
  EXPECT_EQ(**f.session->positions_at(std::nullopt), committed[3]);
  expect_error(f.session->positions_at(2).status(), ErrorCode::NotFound,
               "revision 2 is not kept (kept: 0 and 3..4)");
  expect_error(f.session->positions_at(5).status(), ErrorCode::NotFound, "kept: 0 and 3..4");
}

}  // namespace
}  // namespace meshdeform::service
