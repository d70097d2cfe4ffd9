#include "server/service/deformation_service.h"

#include <gtest/gtest.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <future>
#include <set>
#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include "core/io/mesh_io.h"
#include "core/methods/deformer.h"
#include "core/samples/samples.h"
#include "server/service/tokens.h"
#include "server/service/worker_pool.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::service {
namespace {

using std::chrono::milliseconds;
using std::chrono::seconds;
using TimePoint = std::chrono::steady_clock::time_point;

template <typename T>
std::string message_of(const Result<T>& r) {
  return r.ok() ? std::string("ok") : r.status().to_string();
}

void expect_code(const Status& status, ErrorCode code, const std::string& fragment = "") {
  EXPECT_EQ(status.code(), code) << status.to_string();
  if (!fragment.empty()) {
    EXPECT_NE(status.message().find(fragment), std::string::npos)
        << "'" << status.message() << "' lacks '" << fragment << "'";
  }
}

std::string obj_bytes(const MeshData& mesh) {
  Result<std::string> bytes = io::write_mesh_to_memory(mesh, io::MeshFormat::Obj);
  EXPECT_TRUE(bytes.ok()) << message_of(bytes);
  return bytes.ok() ? *bytes : std::string();
}

CreateSessionRequest sample_request(const std::string& name) {
  CreateSessionRequest request;
  request.sample = name;
  return request;
}

ServiceOptions small_options() {
  ServiceOptions options;
  options.workers = 2;
  return options;
}

/// A handle move of group 1 (the sample's handle group): rotate about y and lift.
MoveRequest bend_move(double angle_deg, int iterations = 2) {
  MoveRequest move;
  GroupMove g;
  g.group = 1;
  g.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(angle_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()));
  g.translation = Eigen::Vector3d(0.1, 0.0, 0.05);
  move.moves.push_back(g);
  move.max_iterations = iterations;
  return move;
}

/// The targets bend_move() gives for a session whose handles were set at rest.
Positions expected_targets(const Positions& V, const std::vector<HandleGroup>& groups,
                           const std::vector<int>& constrained, double angle_deg) {
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(angle_deg * M_PI / 180.0, Eigen::Vector3d::UnitY()).toRotationMatrix();
  Eigen::Vector3d pivot = Eigen::Vector3d::Zero();
  for (int v : groups[1].vertices) pivot += V.row(v).transpose();
  pivot /= static_cast<double>(groups[1].vertices.size());
  const std::set<int> handle(groups[1].vertices.begin(), groups[1].vertices.end());
  Positions targets(static_cast<Eigen::Index>(constrained.size()), 3);
  for (std::size_t j = 0; j < constrained.size(); ++j) {
    const Eigen::Vector3d x = V.row(constrained[j]).transpose();
    const Eigen::Vector3d t =
        handle.count(constrained[j]) ? Eigen::Vector3d(pivot + R * (x - pivot) + Eigen::Vector3d(0.1, 0.0, 0.05)) : x;
    targets.row(static_cast<Eigen::Index>(j)) = t.transpose();
  }
  return targets;
}

std::vector<int> constrained_of(const std::vector<HandleGroup>& groups) {
  std::vector<int> c;
  for (const auto& g : groups) c.insert(c.end(), g.vertices.begin(), g.vertices.end());
  std::sort(c.begin(), c.end());
  return c;
}

/// A created sample session with its handles set.
struct Fixture {
  CreatedSession created;
  std::vector<HandleGroup> groups;
};

Fixture create_with_handles(DeformationService& service, const std::string& sample) {
  Result<CreatedSession> created = service.create_session(sample_request(sample));
  EXPECT_TRUE(created.ok()) << message_of(created);
  Fixture f{*created, created->suggested_groups};
  EXPECT_EQ(f.groups.size(), 2u);
  SetHandlesRequest handles{f.groups, core::Method::ScaleAware};
  Result<SessionInfo> info = service.set_handles(f.created.id, f.created.edit_token, handles);
  EXPECT_TRUE(info.ok()) << message_of(info);
  return f;
}

// --- tokens and pool ---------------------------------------------------------------------------

TEST(TokensTest, RandomHexHasLengthAlphabetAndDiffers) {
  const std::string a = random_hex(32), b = random_hex(32);
  EXPECT_EQ(a.size(), 64u);
  EXPECT_EQ(a.find_first_not_of("0123456789abcdef"), std::string::npos);
  EXPECT_NE(a, b);
  EXPECT_TRUE(constant_time_equal(a, a));
  EXPECT_FALSE(constant_time_equal(a, b));
  EXPECT_FALSE(constant_time_equal(a, a.substr(0, 63)));
}

TEST(WorkerPoolTest, RunsEveryTaskAndDrainsOnDestruction) {
  std::atomic<int> count{0};
  {
    WorkerPool pool(2);
    EXPECT_EQ(pool.size(), 2);
    for (int i = 0; i < 100; ++i) pool.submit([&count] { count.fetch_add(1); });
  }
  EXPECT_EQ(count.load(), 100);
}

// --- create ------------------------------------------------------------------------------------

TEST(CreateSessionTest, FromObjBytes) {
  DeformationService service(small_options());
  CreateSessionRequest request;
  request.mesh_bytes = obj_bytes(test::make_grid(6, 0.05));
  request.format = io::MeshFormat::Obj;
  Result<CreatedSession> created = service.create_session(request);
  ASSERT_TRUE(created.ok()) << message_of(created);
  EXPECT_EQ(created->id.value.size(), 32u);
  EXPECT_EQ(created->edit_token.value.size(), 64u);
  EXPECT_EQ(created->view_token.value.size(), 64u);
  EXPECT_NE(created->edit_token.value, created->view_token.value);
  EXPECT_EQ(created->info.vertices, 49);
  EXPECT_EQ(created->info.faces, 72);
  EXPECT_EQ(created->info.boundary_loops, 1);
  EXPECT_EQ(created->info.components, 1);
  EXPECT_EQ(created->info.revision, 0u);
  EXPECT_NEAR(created->info.bbox_min.x(), 0.0, 1e-12);
  EXPECT_NEAR(created->info.bbox_max.y(), 1.0, 1e-12);
  EXPECT_EQ(service.stats().sessions, 1u);
}

TEST(CreateSessionTest, FromSampleWithSuggestedGroups) {
  DeformationService service(small_options());
  Result<CreatedSession> created = service.create_session(sample_request("cylinder_small"));
  ASSERT_TRUE(created.ok()) << message_of(created);
  EXPECT_EQ(created->info.vertices, 420);
  EXPECT_EQ(created->info.boundary_loops, 2);  // an open tube
  ASSERT_EQ(created->suggested_groups.size(), 2u);
  EXPECT_EQ(created->suggested_groups[0].role, HandleRole::Fixed);
  EXPECT_EQ(created->suggested_groups[1].role, HandleRole::Handle);
  Result<CreatedSession> closed = service.create_session(sample_request("bar_small"));
  ASSERT_TRUE(closed.ok()) << message_of(closed);
  EXPECT_EQ(closed->info.boundary_loops, 0);
}

TEST(CreateSessionTest, LargeSampleIsTheBumpyPlaneAt187k) {
  DeformationService service(small_options());
  Result<CreatedSession> created = service.create_session(sample_request("bumpy_plane_large"));
  ASSERT_TRUE(created.ok()) << message_of(created);
  EXPECT_EQ(created->info.vertices, 433 * 433);
  EXPECT_EQ(created->info.boundary_loops, 1);
  ASSERT_EQ(created->suggested_groups.size(), 2u);
  EXPECT_EQ(created->suggested_groups[0].role, HandleRole::Fixed);
  EXPECT_EQ(created->suggested_groups[1].role, HandleRole::Handle);
  EXPECT_GT(created->suggested_groups[1].vertices.size(), 1000u);  // the centre disc, r 0.15
}

TEST(CreateSessionTest, BadInputIsInvalidArgument) {
  DeformationService service(small_options());
  CreateSessionRequest garbage;
  garbage.mesh_bytes = "this is not a mesh\nf 1 2 9\n";
  expect_code(service.create_session(garbage).status(), ErrorCode::InvalidArgument);
  CreateSessionRequest both = sample_request("cylinder_small");
  both.mesh_bytes = "v 0 0 0\n";
  expect_code(service.create_session(both).status(), ErrorCode::InvalidArgument, "both");
  expect_code(service.create_session(CreateSessionRequest{}).status(), ErrorCode::InvalidArgument,
              "neither");
  expect_code(service.create_session(sample_request("spot")).status(), ErrorCode::InvalidArgument,
              "cylinder_small");
  CreateSessionRequest nan_mesh;
  nan_mesh.mesh_bytes = "v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n";
  expect_code(service.create_session(nan_mesh).status(), ErrorCode::InvalidArgument);
  EXPECT_EQ(service.stats().sessions, 0u);
}

// --- move --------------------------------------------------------------------------------------

TEST(MoveHandlesTest, MatchesCoreDeformerAndReportsExactDeltas) {
  DeformationService service(small_options());
  Fixture f = create_with_handles(service, "cylinder_small");
  const std::vector<int> constrained = constrained_of(f.groups);
  core::DeformationBenchmark bench;
  for (auto& b : core::make_suite(core::SuiteScale::Small))
    if (b.name == "cylinder") bench = b;
  const Positions& V0 = bench.mesh.V;

  // Core's own solve on the same input, the same deformer object for both edits (warm start).
  const Eigen::VectorXi idx = Eigen::Map<const Eigen::VectorXi>(
      constrained.data(), static_cast<Eigen::Index>(constrained.size()));
  auto deformer = core::make_deformer(core::Method::ScaleAware, V0, bench.mesh.F, idx);
  ASSERT_TRUE(deformer.ok()) << message_of(deformer);
  core::SolveOptions options;
  options.max_iterations = 2;

  const double diag = test::bbox_diagonal(bench.mesh);
  Positions previous = V0;
  for (int step = 1; step <= 2; ++step) {
    const double angle = 20.0 * step;
    auto expected = (*deformer)->solve(expected_targets(V0, f.groups, constrained, angle), options);
    ASSERT_TRUE(expected.ok()) << message_of(expected);
    Result<DeformResult> result =
        service.move_handles(f.created.id, f.created.edit_token, bend_move(angle));
    ASSERT_TRUE(result.ok()) << message_of(result);
    EXPECT_EQ(result->revision, static_cast<std::uint64_t>(step));
    EXPECT_EQ(result->method, core::Method::ScaleAware);
    EXPECT_EQ(result->iterations, expected->iterations);
    const Positions& V = *result->positions;
    EXPECT_LE((V - expected->V).cwiseAbs().maxCoeff(), test::kExactTol * diag);
    // Deltas: exactly the vertices that differ from the previous revision.
    std::vector<int> changed;
    for (int v = 0; v < V.rows(); ++v)
      if (V.row(v) != previous.row(v)) changed.push_back(v);
    EXPECT_EQ(result->changed, changed);
    EXPECT_FALSE(changed.empty());
    ASSERT_EQ(result->changed_positions.rows(), static_cast<Eigen::Index>(changed.size()));
    for (std::size_t j = 0; j < changed.size(); ++j)
      EXPECT_EQ(result->changed_positions.row(static_cast<Eigen::Index>(j)), V.row(changed[j]));
    EXPECT_GT(result->e_theta, 0.0);
    EXPECT_TRUE(std::isfinite(result->e_phi));
    previous = V;
  }
  Result<SessionInfo> info = service.session_info(f.created.id, f.created.view_token);
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->revision, 2u);
  EXPECT_EQ(info->last_method, core::Method::ScaleAware);
}

TEST(MoveHandlesTest, OnlyNewTargetsReuseTheCachedDeformer) {
  DeformationService service(small_options());
  Fixture f = create_with_handles(service, "cylinder_small");
  EXPECT_EQ(service.stats().deformer_constructions, 1u);  // built by set_handles
  for (int step = 1; step <= 3; ++step) {
    Result<DeformResult> r =
        service.move_handles(f.created.id, f.created.edit_token, bend_move(10.0 * step));
    ASSERT_TRUE(r.ok()) << message_of(r);
    EXPECT_FALSE(r->built_deformer);
  }
  EXPECT_EQ(service.stats().deformer_constructions, 1u);
  // Explicit per-vertex targets are targets too.
  MoveRequest explicit_move;
  explicit_move.targets.push_back({f.groups[1].vertices[0], Eigen::Vector3d(0.3, 0.1, 2.2)});
  ASSERT_TRUE(service.move_handles(f.created.id, f.created.edit_token, explicit_move).ok());
  EXPECT_EQ(service.stats().deformer_constructions, 1u);
  // Setting the same groups again reuses the factorization.
  ASSERT_TRUE(service.set_handles(f.created.id, f.created.edit_token, {f.groups, core::Method::ScaleAware}).ok());
  EXPECT_EQ(service.stats().deformer_constructions, 1u);
  // A different method needs its own factorization, once.
  MoveRequest arap = bend_move(15.0);
  arap.method = core::Method::Arap;
  Result<DeformResult> a1 = service.move_handles(f.created.id, f.created.edit_token, arap);
  ASSERT_TRUE(a1.ok()) << message_of(a1);
  EXPECT_TRUE(a1->built_deformer);
  EXPECT_EQ(a1->method, core::Method::Arap);
  arap.moves[0].translation.z() += 0.1;
  Result<DeformResult> a2 = service.move_handles(f.created.id, f.created.edit_token, arap);
  ASSERT_TRUE(a2.ok()) << message_of(a2);
  EXPECT_FALSE(a2->built_deformer);
  EXPECT_EQ(service.stats().deformer_constructions, 2u);
  Result<SessionInfo> info = service.session_info(f.created.id, f.created.edit_token);
  ASSERT_TRUE(info.ok());
  EXPECT_EQ(info->cached_deformers, 2);
}

TEST(MoveHandlesTest, ErrorsNameTheProblem) {
  DeformationService service(small_options());
  Result<CreatedSession> c = service.create_session(sample_request("cylinder_small"));
  ASSERT_TRUE(c.ok());
  const SessionId id = c->id;
  const Token edit = c->edit_token;
  expect_code(service.move_handles(id, edit, bend_move(10)).status(),
              ErrorCode::FailedPrecondition, "set_handles");
  // Scale-aware cannot pin a component with one constrained vertex.
  expect_code(service.set_handles(id, edit, {{{HandleRole::Handle, {3}}}, core::Method::ScaleAware})
                  .status(),
              ErrorCode::FailedPrecondition, "component 0");
  expect_code(service.set_handles(id, edit, {{{HandleRole::Handle, {3, 420}}}}).status(),
              ErrorCode::InvalidArgument, "vertex 420 (#V=420)");
  expect_code(service.set_handles(id, edit,
                                  {{{HandleRole::Fixed, {1, 2}}, {HandleRole::Handle, {2, 5}}}})
                  .status(),
              ErrorCode::InvalidArgument, "vertex 2");
  expect_code(service.set_handles(id, edit, {}).status(), ErrorCode::InvalidArgument);
  ASSERT_TRUE(service.set_handles(id, edit, {c->suggested_groups}).ok());

  MoveRequest fixed_move = bend_move(10);
  fixed_move.moves[0].group = 0;
  expect_code(service.move_handles(id, edit, fixed_move).status(), ErrorCode::InvalidArgument,
              "fixed");
  MoveRequest bad_group = bend_move(10);
  bad_group.moves[0].group = 7;
  expect_code(service.move_handles(id, edit, bad_group).status(), ErrorCode::InvalidArgument,
              "group 7");
  MoveRequest nan_target;
  nan_target.targets.push_back({c->suggested_groups[1].vertices[0],
                                Eigen::Vector3d(0, std::nan(""), 0)});
  expect_code(service.move_handles(id, edit, nan_target).status(), ErrorCode::InvalidArgument,
              "non-finite");
  MoveRequest free_target;
  free_target.targets.push_back({200, Eigen::Vector3d(0, 0, 0)});
  expect_code(service.move_handles(id, edit, free_target).status(), ErrorCode::InvalidArgument,
              "not constrained");
  MoveRequest ora_arap = bend_move(10);
  ora_arap.method = core::Method::Arap;
  ora_arap.ora = true;
  expect_code(service.move_handles(id, edit, ora_arap).status(), ErrorCode::InvalidArgument);
  EXPECT_EQ(service.session_info(id, edit)->revision, 0u);  // nothing committed
}

// --- access ------------------------------------------------------------------------------------

TEST(AccessTest, TokensAndUnknownSessions) {
  DeformationService service(small_options());
  Fixture f = create_with_handles(service, "cylinder_small");
  const SessionId& id = f.created.id;
  const Token& view = f.created.view_token;
  const Token wrong{random_hex(32)};

  expect_code(service.move_handles(id, view, bend_move(10)).status(), ErrorCode::PermissionDenied,
              "view token");
  expect_code(service.set_handles(id, view, {f.groups}).status(), ErrorCode::PermissionDenied);
  expect_code(service.close_session(id, view), ErrorCode::PermissionDenied);
  expect_code(service.move_handles(id, wrong, bend_move(10)).status(), ErrorCode::PermissionDenied);
  expect_code(service.session_info(id, wrong).status(), ErrorCode::PermissionDenied);
  expect_code(service.get_mesh(id, wrong, io::MeshFormat::Obj).status(),
              ErrorCode::PermissionDenied);
  expect_code(service.watch(id, wrong).status(), ErrorCode::PermissionDenied);
  // The view token reads and watches.
  EXPECT_TRUE(service.session_info(id, view).ok());
  EXPECT_TRUE(service.get_mesh(id, view, io::MeshFormat::Glb).ok());
  EXPECT_TRUE(service.watch(id, view).ok());

  const SessionId unknown{random_hex(16)};
  expect_code(service.move_handles(unknown, f.created.edit_token, bend_move(1)).status(),
              ErrorCode::NotFound, unknown.value);
  expect_code(service.session_info(unknown, view).status(), ErrorCode::NotFound);
  expect_code(service.get_mesh(unknown, view, io::MeshFormat::Obj).status(), ErrorCode::NotFound);
  expect_code(service.watch(unknown, view).status(), ErrorCode::NotFound);
  expect_code(service.close_session(unknown, f.created.edit_token), ErrorCode::NotFound);

  ASSERT_TRUE(service.close_session(id, f.created.edit_token).ok());
  expect_code(service.session_info(id, view).status(), ErrorCode::NotFound);
  expect_code(service.move_handles(id, f.created.edit_token, bend_move(1)).status(),
              ErrorCode::NotFound);
  EXPECT_EQ(service.stats().sessions, 0u);
}

// --- get mesh ----------------------------------------------------------------------------------

TEST(GetMeshTest, CurrentAndKeptRevisions) {
  ServiceOptions options = small_options();
  options.kept_revisions = 2;
  DeformationService service(options);
  Fixture f = create_with_handles(service, "cylinder_small");
  Result<std::string> rest_before =
      service.get_mesh(f.created.id, f.created.view_token, io::MeshFormat::Obj, 0);
  ASSERT_TRUE(rest_before.ok()) << message_of(rest_before);
  Result<DeformResult> last = Status(ErrorCode::Internal, "unset");
  for (int step = 1; step <= 3; ++step) {
    last = service.move_handles(f.created.id, f.created.edit_token, bend_move(10.0 * step));
    ASSERT_TRUE(last.ok()) << message_of(last);
  }
  Result<std::string> obj = service.get_mesh(f.created.id, f.created.view_token, io::MeshFormat::Obj);
  ASSERT_TRUE(obj.ok()) << message_of(obj);
  Result<MeshData> back = io::read_mesh_from_memory(*obj, io::MeshFormat::Obj);
  ASSERT_TRUE(back.ok()) << message_of(back);
  EXPECT_EQ(back->V, *last->positions);  // OBJ keeps full precision
  Result<std::string> rev2 =
      service.get_mesh(f.created.id, f.created.view_token, io::MeshFormat::Ply, 2);
  EXPECT_TRUE(rev2.ok()) << message_of(rev2);
  Result<std::string> glb = service.get_mesh(f.created.id, f.created.view_token, io::MeshFormat::Glb);
  ASSERT_TRUE(glb.ok()) << message_of(glb);
  Result<MeshData> glb_back = io::read_mesh_from_memory(*glb, io::MeshFormat::Glb);
  ASSERT_TRUE(glb_back.ok()) << message_of(glb_back);
  EXPECT_LE((glb_back->V - *last->positions).cwiseAbs().maxCoeff(), 1e-6);  // float32
  expect_code(service.get_mesh(f.created.id, f.created.view_token, io::MeshFormat::Obj, 1).status(),
              ErrorCode::NotFound, "kept: 0 and 2..3");
  // Revision 0, the rest mesh, is always kept: a late watcher or a reopened link compares
  // against it (the viewer's heat map).
  Result<std::string> rest = service.get_mesh(f.created.id, f.created.view_token, io::MeshFormat::Obj, 0);
  ASSERT_TRUE(rest.ok()) << message_of(rest);
  EXPECT_EQ(*rest, *rest_before);
  Result<MeshData> rest_back = io::read_mesh_from_memory(*rest, io::MeshFormat::Obj);
  ASSERT_TRUE(rest_back.ok()) << message_of(rest_back);
  EXPECT_NE(rest_back->V, *last->positions);
  expect_code(service.get_mesh(f.created.id, f.created.view_token, io::MeshFormat::Obj, 99).status(),
              ErrorCode::NotFound, "revision 99");
}

// --- limits ------------------------------------------------------------------------------------

TEST(LimitsTest, MaxSessions) {
  ServiceOptions options = small_options();
  options.max_sessions = 2;
  DeformationService service(options);
  auto a = service.create_session(sample_request("cactus_small"));
  auto b = service.create_session(sample_request("cactus_small"));
  ASSERT_TRUE(a.ok() && b.ok());
  expect_code(service.create_session(sample_request("cactus_small")).status(),
              ErrorCode::ResourceExhausted, "the limit is 2");
  ASSERT_TRUE(service.close_session(a->id, a->edit_token).ok());
  EXPECT_TRUE(service.create_session(sample_request("cactus_small")).ok());
}

TEST(LimitsTest, MaxVertices) {
  ServiceOptions options = small_options();
  options.max_vertices = 100;
  DeformationService service(options);
  CreateSessionRequest request;
  request.mesh_bytes = obj_bytes(test::make_grid(12));
  expect_code(service.create_session(request).status(), ErrorCode::ResourceExhausted,
              "mesh has 169 vertices, the limit is 100");
  request.mesh_bytes = obj_bytes(test::make_grid(8));  // 81 vertices
  EXPECT_TRUE(service.create_session(request).ok());
}

struct FakeClock {
  std::shared_ptr<std::atomic<long long>> ns = std::make_shared<std::atomic<long long>>(1'000'000'000);
  Clock clock() const {
    auto p = ns;
    return [p] { return TimePoint(std::chrono::nanoseconds(p->load())); };
  }
  void advance(std::chrono::nanoseconds d) const { ns->fetch_add(d.count()); }
  TimePoint now() const { return TimePoint(std::chrono::nanoseconds(ns->load())); }
};

TEST(LimitsTest, MemoryBudgetEvictsLeastRecentlyUsedIdleSession) {
  FakeClock clock;
  ServiceOptions options = small_options();
  options.clock = clock.clock();
  int nv = 0, nf = 0;
  for (const auto& b : core::make_suite(core::SuiteScale::Small)) {
    if (b.name == "cactus") {
      nv = static_cast<int>(b.mesh.V.rows());
      nf = static_cast<int>(b.mesh.F.rows());
    }
  }
  const std::size_t one = estimate_session_bytes(nv, nf, 0, options.kept_revisions);
  options.memory_budget_bytes = 2 * one + one / 2;
  DeformationService service(options);
  auto a = service.create_session(sample_request("cactus_small"));
  ASSERT_TRUE(a.ok()) << message_of(a);
  ASSERT_EQ(a->info.vertices, nv);
  ASSERT_EQ(a->info.faces, nf);
  ASSERT_EQ(a->info.estimated_bytes, one);
  clock.advance(seconds(1));
  auto b = service.create_session(sample_request("cactus_small"));
  ASSERT_TRUE(b.ok()) << message_of(b);
  clock.advance(seconds(1));
  ASSERT_TRUE(service.session_info(a->id, a->view_token).ok());  // a is now the most recent
  clock.advance(seconds(1));
  auto c = service.create_session(sample_request("cactus_small"));
  ASSERT_TRUE(c.ok()) << message_of(c);
  expect_code(service.session_info(b->id, b->view_token).status(), ErrorCode::NotFound);
  EXPECT_TRUE(service.session_info(a->id, a->view_token).ok());
  EXPECT_TRUE(service.session_info(c->id, c->view_token).ok());
  EXPECT_EQ(service.stats().evicted_lru, 1u);
  EXPECT_LE(service.stats().estimated_bytes, options.memory_budget_bytes);
  // A factorization that cannot fit even after evicting every other session is refused.
  expect_code(service.set_handles(a->id, a->edit_token, {a->suggested_groups}).status(),
              ErrorCode::ResourceExhausted, "memory budget");
  // A mesh larger than the whole budget is refused without evicting anyone.
  ServiceOptions tiny = small_options();
  tiny.memory_budget_bytes = one / 2;
  DeformationService tiny_service(tiny);
  expect_code(tiny_service.create_session(sample_request("cactus_small")).status(),
              ErrorCode::ResourceExhausted, "memory budget");
}

TEST(LimitsTest, IdleTtlWithInjectedClock) {
  FakeClock clock;
  ServiceOptions options = small_options();
  options.clock = clock.clock();
  options.idle_ttl = seconds(60);
  DeformationService service(options);
  auto a = service.create_session(sample_request("cactus_small"));
  auto watched = service.create_session(sample_request("cactus_small"));
  ASSERT_TRUE(a.ok() && watched.ok());
  Result<Subscription> sub = service.watch(watched->id, watched->view_token);
  ASSERT_TRUE(sub.ok());
  clock.advance(seconds(30));
  ASSERT_TRUE(service.session_info(a->id, a->view_token).ok());  // touch
  clock.advance(seconds(45));
  EXPECT_EQ(service.evict_expired(), 0u);  // 45 s since the last use
  clock.advance(seconds(16));
  EXPECT_EQ(service.evict_expired(), 1u);  // a; the watched session stays
  expect_code(service.session_info(a->id, a->view_token).status(), ErrorCode::NotFound);
  EXPECT_TRUE(service.session_info(watched->id, watched->view_token).ok());
  EXPECT_EQ(service.stats().evicted_idle, 1u);
  // Once nobody watches it, it expires too (here on lookup, without a sweep).
  sub->reset();
  clock.advance(seconds(61));
  expect_code(service.session_info(watched->id, watched->view_token).status(),
              ErrorCode::NotFound);
}

// --- cancellation ------------------------------------------------------------------------------

TEST(CancellationTest, StoppedMoveCommitsNothing) {
  DeformationService service(small_options());
  Fixture f = create_with_handles(service, "bumpy_plane_small");
  // Stopped before it starts.
  std::stop_source stopped;
  stopped.request_stop();
  expect_code(service.move_handles(f.created.id, f.created.edit_token, bend_move(10), stopped.get_token())
                  .status(),
              ErrorCode::Cancelled);
  // Stopped mid-solve: a budget of 1000 iterations with tolerance 0 runs far longer than it
  // takes to request the stop.
  std::stop_source source;
  MoveRequest long_move = bend_move(30, 1000);
  long_move.tolerance = 0;
  std::promise<Result<DeformResult>> promise;
  auto future = promise.get_future();
  service.move_handles_async(f.created.id, f.created.edit_token, long_move, source.get_token(),
                             [&promise](Result<DeformResult> r) { promise.set_value(std::move(r)); });
  std::this_thread::sleep_for(milliseconds(20));
  source.request_stop();
  expect_code(future.get().status(), ErrorCode::Cancelled, "revision 0 unchanged");
  // A deadline in the past gives DeadlineExceeded.
  MoveRequest late = long_move;
  late.deadline = std::chrono::steady_clock::now() + milliseconds(30);
  expect_code(service.move_handles(f.created.id, f.created.edit_token, late).status(),
              ErrorCode::DeadlineExceeded);
  EXPECT_EQ(service.session_info(f.created.id, f.created.view_token)->revision, 0u);
  EXPECT_EQ(service.stats().moves_cancelled, 3u);
  // The session still works afterwards.
  Result<DeformResult> ok = service.move_handles(f.created.id, f.created.edit_token, bend_move(10));
  ASSERT_TRUE(ok.ok()) << message_of(ok);
  EXPECT_EQ(ok->revision, 1u);
}

// --- watch -------------------------------------------------------------------------------------

TEST(WatchTest, TwoWatchersSeeEveryRevision) {
  DeformationService service(small_options());
  Fixture f = create_with_handles(service, "cylinder_small");
  auto w1 = service.watch(f.created.id, f.created.view_token);
  auto w2 = service.watch(f.created.id, f.created.edit_token);  // the edit token may watch too
  ASSERT_TRUE(w1.ok() && w2.ok());
  for (auto* w : {&*w1, &*w2}) {
    auto snapshot = (*w)->try_take();
    ASSERT_TRUE(snapshot.has_value());
    EXPECT_TRUE(snapshot->is_snapshot);
    EXPECT_EQ(snapshot->result->revision, 0u);
    EXPECT_EQ(snapshot->result->positions->rows(), 420);
  }
  for (int step = 1; step <= 3; ++step) {
    Result<DeformResult> r = service.move_handles(f.created.id, f.created.edit_token, bend_move(10.0 * step));
    ASSERT_TRUE(r.ok()) << message_of(r);
    for (auto* w : {&*w1, &*w2}) {
      auto update = (*w)->wait_take(milliseconds(1000));
      ASSERT_TRUE(update.has_value());
      EXPECT_FALSE(update->is_snapshot);
      EXPECT_EQ(update->result->revision, r->revision);
      EXPECT_EQ(update->result->changed, r->changed);
      EXPECT_EQ(update->skipped_revisions, 0u);
    }
  }
  EXPECT_EQ(service.session_info(f.created.id, f.created.view_token)->watchers, 2);
  w1->reset();
  EXPECT_EQ(service.session_info(f.created.id, f.created.view_token)->watchers, 1);
  ASSERT_TRUE(service.close_session(f.created.id, f.created.edit_token).ok());
  EXPECT_TRUE((*w2)->closed());
  EXPECT_FALSE((*w2)->wait_take(milliseconds(50)).has_value());
}

TEST(WatchTest, OnlyTheNewestRevisionKeepsItsEncodedBytes) {
  // The transport encodes a revision's positions once into its memo (DeformResult::encoded),
  // shared by the response and every watcher; a newer commit clears the older one's.
  DeformationService service(small_options());
  Fixture f = create_with_handles(service, "cylinder_small");
  auto watcher = service.watch(f.created.id, f.created.view_token);
  ASSERT_TRUE(watcher.ok());
  ASSERT_TRUE((*watcher)->try_take().has_value());  // the join snapshot
  std::vector<std::shared_ptr<const DeformResult>> seen;
  for (int step = 1; step <= 2; ++step) {
    Result<DeformResult> r =
        service.move_handles(f.created.id, f.created.edit_token, bend_move(10.0 * step));
    ASSERT_TRUE(r.ok()) << message_of(r);
    auto update = (*watcher)->wait_take(milliseconds(1000));
    ASSERT_TRUE(update.has_value());
    seen.push_back(update->result);
    // The response's copy shares the watcher's memo: bytes made through one are there for both.
    ASSERT_TRUE(r->encoded);
    EXPECT_EQ(r->encoded.get(), update->result->encoded.get());
    int made = 0;
    r->encoded->get(7, [&] { ++made; return std::string(100, 'x'); });
    update->result->encoded->get(7, [&] { ++made; return std::string(); });
    EXPECT_EQ(made, 1);
    EXPECT_EQ(update->result->encoded->bytes(), 100u);
  }
  EXPECT_EQ(seen[0]->encoded->bytes(), 0u) << "revision 1's bytes outlived revision 2's commit";
  EXPECT_EQ(seen[1]->encoded->bytes(), 100u);
}

TEST(WatchTest, SlowWatcherSkipsToNewestWithoutBlockingTheEditor) {
  DeformationService service(small_options());
  Fixture f = create_with_handles(service, "cylinder_small");
  // Declared before the subscription: closing it (its destructor) notifies once more.
  std::atomic<int> notifications{0};
  auto slow = service.watch(f.created.id, f.created.view_token);
  ASSERT_TRUE(slow.ok());
  (*slow)->set_notify([&notifications] { notifications.fetch_add(1); });
  EXPECT_EQ(notifications.load(), 1);  // the join snapshot is already pending
  Result<DeformResult> last = Status(ErrorCode::Internal, "unset");
  for (int step = 1; step <= 4; ++step) {  // the watcher reads nothing meanwhile
    last = service.move_handles(f.created.id, f.created.edit_token, bend_move(5.0 * step));
    ASSERT_TRUE(last.ok()) << message_of(last);
  }
  EXPECT_EQ(notifications.load(), 1);  // the mailbox was never empty again
  auto update = (*slow)->try_take();
  ASSERT_TRUE(update.has_value());
  EXPECT_EQ(update->result->revision, 4u);
  EXPECT_TRUE(update->is_snapshot);
  EXPECT_EQ(update->skipped_revisions, 4u);  // the snapshot of 0 and revisions 1..3
  EXPECT_EQ(*update->result->positions, *last->positions);
  EXPECT_FALSE((*slow)->try_take().has_value());
  // Caught up: the next one is a plain delta again.
  ASSERT_TRUE(service.move_handles(f.created.id, f.created.edit_token, bend_move(30)).ok());
  auto next = (*slow)->try_take();
  ASSERT_TRUE(next.has_value());
  EXPECT_FALSE(next->is_snapshot);
  EXPECT_EQ(next->result->revision, 5u);
  EXPECT_EQ(notifications.load(), 2);
}

// --- concurrency -------------------------------------------------------------------------------

TEST(ConcurrencyTest, TwoSessionsSolveConcurrentlyAndEditsAreSerialised) {
  DeformationService service(small_options());
  Fixture a = create_with_handles(service, "cylinder_small");
  Fixture b = create_with_handles(service, "cylinder_small");
  std::vector<std::future<Result<DeformResult>>> futures_a, futures_b;
  std::vector<std::shared_ptr<std::promise<Result<DeformResult>>>> promises;
  auto submit = [&](const Fixture& f, double angle, auto& futures) {
    auto promise = std::make_shared<std::promise<Result<DeformResult>>>();
    futures.push_back(promise->get_future());
    service.move_handles_async(f.created.id, f.created.edit_token, bend_move(angle), {},
                               [promise](Result<DeformResult> r) { promise->set_value(std::move(r)); });
  };
  for (int step = 1; step <= 4; ++step) {
    submit(a, 5.0 * step, futures_a);
    submit(b, 7.0 * step, futures_b);
  }
  for (auto* futures : {&futures_a, &futures_b}) {
    for (std::size_t i = 0; i < futures->size(); ++i) {
      Result<DeformResult> r = (*futures)[i].get();
      ASSERT_TRUE(r.ok()) << message_of(r);
      EXPECT_EQ(r->revision, i + 1);  // submission order within a session
    }
  }
  // Serialised edits give the same result as the same edits one after another.
  DeformationService sequential(small_options());
  Fixture s = create_with_handles(sequential, "cylinder_small");
  Result<DeformResult> expected = Status(ErrorCode::Internal, "unset");
  for (int step = 1; step <= 4; ++step)
    expected = sequential.move_handles(s.created.id, s.created.edit_token, bend_move(5.0 * step));
  ASSERT_TRUE(expected.ok());
  Result<std::string> mesh_a = service.get_mesh(a.created.id, a.created.view_token, io::MeshFormat::Obj);
  Result<std::string> mesh_s = sequential.get_mesh(s.created.id, s.created.view_token, io::MeshFormat::Obj);
  ASSERT_TRUE(mesh_a.ok() && mesh_s.ok());
  EXPECT_EQ(*mesh_a, *mesh_s);
  EXPECT_EQ(service.stats().moves_committed, 8u);
}

}  // namespace
}  // namespace meshdeform::service

// --- background refinement ---------------------------------------------------------------------

namespace meshdeform::service {
namespace {

/// Waits (bounded) until the session reaches `revision`.
bool wait_for_revision(DeformationService& service, const Fixture& f, std::uint64_t revision,
                       seconds bound = seconds(60)) {
  const auto deadline = std::chrono::steady_clock::now() + bound;
  while (std::chrono::steady_clock::now() < deadline) {
    Result<SessionInfo> info = service.session_info(f.created.id, f.created.view_token);
    if (!info.ok()) return false;
    if (info->revision >= revision) return info->revision == revision;
    std::this_thread::sleep_for(milliseconds(5));
  }
  return false;
}

TEST(RefinementTest, ContinuesTheSameSolveWhileHandlesRestAndStops) {
  ServiceOptions options = small_options();
  options.refine_budget = 9;
  options.kept_revisions = 64;
  DeformationService service(options);
  Fixture f = create_with_handles(service, "cylinder_small");
  const std::vector<int> constrained = constrained_of(f.groups);
  core::DeformationBenchmark bench;
  for (auto& b : core::make_suite(core::SuiteScale::Small))
    if (b.name == "cylinder") bench = b;
  const Eigen::VectorXi idx = Eigen::Map<const Eigen::VectorXi>(
      constrained.data(), static_cast<Eigen::Index>(constrained.size()));

  // What refinement must do: the move's 1 iteration, then slices of at most 2 iterations on the
  // same targets, warm-started, until converged or 9 iterations are spent.
  auto deformer = core::make_deformer(core::Method::ScaleAware, bench.mesh.V, bench.mesh.F, idx);
  ASSERT_TRUE(deformer.ok()) << message_of(deformer);
  const Positions targets = expected_targets(bench.mesh.V, f.groups, constrained, 60.0);
  core::SolveOptions solve;
  solve.max_iterations = 1;
  solve.tolerance = MoveRequest{}.tolerance;  // the service's default, not the CLI's
  auto first = (*deformer)->solve(targets, solve);
  ASSERT_TRUE(first.ok());
  ASSERT_FALSE(first->converged);
  std::vector<Positions> expected;
  for (int remaining = 9; remaining > 0;) {
    solve.max_iterations = std::min(2, remaining);
    auto slice = (*deformer)->solve(targets, solve);
    ASSERT_TRUE(slice.ok()) << message_of(slice);
    expected.push_back(slice->V);
    remaining -= slice->iterations;
    if (slice->converged) break;
  }
  ASSERT_GE(expected.size(), 2u) << "the edit should need more than one refinement slice";

  Result<Subscription> watch = service.watch(f.created.id, f.created.view_token);
  ASSERT_TRUE(watch.ok());
  ASSERT_TRUE(watch->watcher().wait_take(milliseconds(5000)).has_value());  // join snapshot
  Result<DeformResult> moved =
      service.move_handles(f.created.id, f.created.edit_token, bend_move(60.0, 1));
  ASSERT_TRUE(moved.ok()) << message_of(moved);
  EXPECT_FALSE(moved->refinement);
  EXPECT_FALSE(moved->settled) << "refinement follows";
  EXPECT_EQ(moved->revision, 1u);

  const std::uint64_t last = 1 + expected.size();
  ASSERT_TRUE(wait_for_revision(service, f, last)) << "refinement did not reach revision " << last;
  const double diag = test::bbox_diagonal(bench.mesh);
  for (std::size_t k = 0; k < expected.size(); ++k) {
    Result<std::string> obj = service.get_mesh(f.created.id, f.created.view_token,
                                               io::MeshFormat::Obj, 2 + k);
    ASSERT_TRUE(obj.ok()) << message_of(obj);
    Result<io::LoadedMesh> loaded = io::load_mesh_from_memory(*obj, io::MeshFormat::Obj);
    ASSERT_TRUE(loaded.ok()) << message_of(loaded);
    EXPECT_LE((loaded->mesh.V - expected[k]).cwiseAbs().maxCoeff(), test::kExactTol * diag)
        << "refinement revision " << 2 + k;
  }
  // Watchers see refinements marked as such, in order.
  std::uint64_t seen = 1;
  while (seen < last) {
    std::optional<DeformUpdate> update = watch->watcher().wait_take(milliseconds(5000));
    ASSERT_TRUE(update.has_value());
    EXPECT_GT(update->result->revision, seen);
    seen = update->result->revision;
    if (seen >= 2) {
      EXPECT_TRUE(update->result->refinement);
      EXPECT_EQ(update->result->editor, "refinement");
    }
    // Settled: refinement's last revision only (converged, or the budget spent with it).
    EXPECT_EQ(update->result->settled, seen == last) << "revision " << seen;
  }
  const ServiceStats stats = service.stats();
  EXPECT_EQ(stats.refinements_committed, expected.size());
  EXPECT_EQ(stats.moves_committed, 1u);
}

TEST(RefinementTest, AnEditDuringRefinementIsServedAndRefinementResumesOnItsTargets) {
  ServiceOptions options = small_options();
  options.refine_budget = 200;  // long enough to be running when the next edit arrives
  DeformationService service(options);
  Fixture f = create_with_handles(service, "cylinder_small");
  Result<DeformResult> first =
      service.move_handles(f.created.id, f.created.edit_token, bend_move(40.0, 1));
  ASSERT_TRUE(first.ok()) << message_of(first);
  Result<DeformResult> second =
      service.move_handles(f.created.id, f.created.edit_token, bend_move(70.0, 1));
  ASSERT_TRUE(second.ok()) << message_of(second);
  EXPECT_FALSE(second->refinement);
  EXPECT_GE(second->revision, 2u);
  // Refinement goes on after the second move (its targets), so more revisions follow it.
  const auto deadline = std::chrono::steady_clock::now() + seconds(60);
  while (service.session_info(f.created.id, f.created.view_token)->revision <= second->revision &&
         std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(milliseconds(5));
  }
  ASSERT_GT(service.session_info(f.created.id, f.created.view_token)->revision, second->revision);
  // set_handles ends refinement: the revision stops changing once it returns.
  Result<SessionInfo> reset = service.set_handles(f.created.id, f.created.edit_token,
                                                  SetHandlesRequest{f.groups, core::Method::ScaleAware});
  ASSERT_TRUE(reset.ok()) << message_of(reset);
  const std::uint64_t after_reset = reset->revision;
  // Queue an edit-free probe through the strand: a failing move runs after anything queued.
  MoveRequest bad = bend_move(10.0, 1);
  bad.moves[0].group = 7;
  EXPECT_EQ(service.move_handles(f.created.id, f.created.edit_token, bad).status().code(),
            ErrorCode::InvalidArgument);
  EXPECT_EQ(service.session_info(f.created.id, f.created.view_token)->revision, after_reset);
  EXPECT_GE(service.stats().refinements_committed, 1u);
}

TEST(RefinementTest, OffByDefaultInTheService) {
  DeformationService service(small_options());
  Fixture f = create_with_handles(service, "cylinder_small");
  Result<DeformResult> moved =
      service.move_handles(f.created.id, f.created.edit_token, bend_move(60.0, 1));
  ASSERT_TRUE(moved.ok());
  EXPECT_FALSE(moved->converged);
  EXPECT_TRUE(moved->settled) << "no refinement follows";
  // A second edit through the strand runs after anything the first could have queued.
  ASSERT_TRUE(service.set_handles(f.created.id, f.created.edit_token,
                                  SetHandlesRequest{f.groups, core::Method::ScaleAware})
                  .ok());
  EXPECT_EQ(service.session_info(f.created.id, f.created.view_token)->revision, 1u);
  EXPECT_EQ(service.stats().refinements_committed, 0u);
}

TEST(RefinementTest, WaitsUntilTheHandlesRest) {
  // A drag: moves back to back. With a rest delay longer than the drag, nothing is refined in
  // between (no wasted solves, no extra revisions to watchers); the revisions are exactly the
  // moves. Once the handles rest past the delay, refinement runs.
  ServiceOptions options = small_options();
  options.refine_budget = 30;
  options.refine_delay = milliseconds(2000);  // far longer than five small moves
  DeformationService service(options);
  Fixture f = create_with_handles(service, "cylinder_small");
  for (int i = 1; i <= 5; ++i) {
    Result<DeformResult> moved =
        service.move_handles(f.created.id, f.created.edit_token, bend_move(10.0 * i, 1));
    ASSERT_TRUE(moved.ok()) << message_of(moved);
    EXPECT_EQ(moved->revision, static_cast<std::uint64_t>(i));  // no refinement in between
  }
  EXPECT_EQ(service.stats().refinements_committed, 0u);
  // Resting: refinement starts after the delay (bounded wait).
  const auto deadline = std::chrono::steady_clock::now() + seconds(30);
  while (service.stats().refinements_committed == 0 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(milliseconds(20));
  }
  EXPECT_GE(service.stats().refinements_committed, 1u);
}

TEST(RefinementTest, TheRestOutlastsTheDragsOwnPauses) {
  using std::chrono::steady_clock;
  const auto ms = [](int n) { return steady_clock::duration(milliseconds(n)); };
  // No drag (a first move, or moves over kDragGap apart): the configured delay.
  EXPECT_EQ(refinement_rest(milliseconds(150), steady_clock::duration::zero()), ms(150));
  // A fast drag whose pauses are shorter than half the delay: the delay.
  EXPECT_EQ(refinement_rest(milliseconds(150), ms(50)), ms(150));
  // A drag over a slow line, a move every 250 ms: twice that, so no slice starts between two
  // of its moves.
  EXPECT_EQ(refinement_rest(milliseconds(150), ms(250)), ms(500));
  // At most kDragGap, however slow the drag; a longer configured delay is kept.
  EXPECT_EQ(refinement_rest(milliseconds(150), ms(900)), steady_clock::duration(kDragGap));
  EXPECT_EQ(refinement_rest(milliseconds(5000), ms(900)), ms(5000));
  // A delay of 0 means no wait, drag or not.
  EXPECT_EQ(refinement_rest(milliseconds(0), ms(250)), steady_clock::duration::zero());
}

}  // namespace
}  // namespace meshdeform::service
