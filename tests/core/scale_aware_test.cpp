// Exact properties of the scale-aware solver (docs/algorithm.md section 4): the rest pose and any
// similarity of it are exact zeros of the energy, so the solver must reproduce them.
#include "core/methods/scale_aware.h"

#include <gtest/gtest.h>

#include <cmath>
#include <stop_token>
#include <vector>

#include <Eigen/Geometry>

#include "core/mesh/measures.h"
#include "core/samples/samples.h"
#include "core/mesh/topology.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

using test::bbox_diagonal;
using test::pinned_test_meshes;
const auto& rows_of = test::gather_rows;

Positions apply(const Eigen::Matrix3d& R, double scale, const Eigen::Vector3d& t, const Positions& V) {
  return ((scale * V * R.transpose()).rowwise() + t.transpose()).eval();
}

TEST(ScaleAwareSolver, HandlesAtRestLeaveTheMeshUnchanged) {
  for (const auto& [name, mesh, constrained] : pinned_test_meshes()) {
    SCOPED_TRACE(name);
    auto solver = ScaleAwareSolver::create(mesh.V, mesh.F, constrained);
    ASSERT_TRUE(solver.ok()) << solver.status().to_string();
    auto report = solver->solve(rows_of(mesh.V, constrained));
    ASSERT_TRUE(report.ok()) << report.status().to_string();
    const double diag = bbox_diagonal(mesh);
    EXPECT_LT((report->V - mesh.V).cwiseAbs().maxCoeff(), test::kExactTol * diag);
    EXPECT_LT(report->history.back().energy, 1e-20 * diag * diag);
    EXPECT_LT(report->history.back().e_theta, 1e-9);
    EXPECT_LT(report->history.back().e_phi, 1e-9);
    EXPECT_TRUE(report->converged);
  }
}

TEST(ScaleAwareSolver, SimilarityOfHandlesGivesThatSimilarityOfTheMesh) {
  // A 120-degree rotation about a skew axis, scale 2 and a translation.
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(2.0 * M_PI / 3.0, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(0.3, -1.2, 2.0);
  for (const auto& [name, mesh, constrained] : pinned_test_meshes()) {
    SCOPED_TRACE(name);
    const Positions expected = apply(R, 2.0, t, mesh.V);
    auto solver = ScaleAwareSolver::create(mesh.V, mesh.F, constrained);
    ASSERT_TRUE(solver.ok()) << solver.status().to_string();
    SolveOptions options;
    options.max_iterations = 300;
    options.inner_iterations = 30;
    options.tolerance = 1e-12;  // run until the energy stops changing at round-off
    auto report = solver->solve(rows_of(expected, constrained), options);
    ASSERT_TRUE(report.ok()) << report.status().to_string();
    const double diag = 2.0 * bbox_diagonal(mesh);
    EXPECT_TRUE(report->converged) << "iterations " << report->iterations;
    EXPECT_LT((report->V - expected).cwiseAbs().maxCoeff(), test::kConvergedTol * diag);
    EXPECT_LT(report->history.back().e_theta, 1e-6);
    EXPECT_LT(report->history.back().e_phi, 1e-6);
  }
}

TEST(ScaleAwareSolver, SingleTriangleFollowsTheRightHandRule) {
  // With the stored face order, R(N, +theta) must map the first edge onto the second: then the
  // rest triangle is an exact zero of the energy from the first evaluation on. The opposite sense
  // would leave a residual of |e2| |2 sin theta| per corner.
  const MeshData tri = test::make_triangle();
  Eigen::VectorXi constrained(2);
  constrained << 0, 1;
  SolveOptions options;
  options.start = StartFrom::Previous;  // start at the rest pose itself
  auto at_rest = deform_scale_aware(tri.V, tri.F, constrained, rows_of(tri.V, constrained), options);
  ASSERT_TRUE(at_rest.ok()) << at_rest.status().to_string();
  EXPECT_LT(at_rest->history.front().energy, 1e-28);
  EXPECT_EQ(at_rest->pcg_iterations, 0);

  // A 30-degree rotation with scale 3: the free corner follows onto the rotated side.
  const Eigen::Matrix3d R = Eigen::AngleAxisd(M_PI / 6, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  const Positions expected = apply(R, 3.0, Eigen::Vector3d(1, 1, 0), tri.V);
  options.start = StartFrom::Laplacian;
  options.max_iterations = 100;
  options.tolerance = 1e-14;
  options.rigidity = 0;  // Eq. 12's rotation sense; the scale term has its own similarity test
  auto moved = deform_scale_aware(tri.V, tri.F, constrained, rows_of(expected, constrained), options);
  ASSERT_TRUE(moved.ok()) << moved.status().to_string();
  EXPECT_LT((moved->V - expected).cwiseAbs().maxCoeff(), 1e-9);
  // Rest (0,1,0), rotated by +30 degrees about z, scaled by 3 and translated.
  EXPECT_NEAR(moved->V(2, 0), 1.0 - 1.5, 1e-9);
  EXPECT_NEAR(moved->V(2, 1), 1.0 + 3.0 * std::cos(M_PI / 6), 1e-9);
}

TEST(ScaleAwareSolver, DeformationLowersAngleErrorBelowTheLaplacianStart) {
  // Left column fixed, right column lifted and rotated: a bend.
  auto [m, constrained, targets] = test::make_strip_edit(16);
  const Eigen::Matrix3d R = Eigen::AngleAxisd(M_PI / 3, Eigen::Vector3d::UnitY()).toRotationMatrix();
  for (Eigen::Index j = 1; j < targets.rows(); j += 2) {
    const Eigen::Vector3d p = targets.row(j).transpose();
    targets.row(j) = (R * (p - Eigen::Vector3d(0.5, 0, 0)) + Eigen::Vector3d(0.5, 0, 0.3)).transpose();
  }
  // The paper's method (rigidity 0) lowers both; with the default scale control E_theta still
  // falls but E_phi ends slightly above this smooth Laplacian start (measured 0.050 vs 0.042):
  // the scale term trades some dihedral fidelity for area.
  SolveOptions paper;
  paper.rigidity = 0;
  auto report = deform_scale_aware(m.V, m.F, constrained, targets, paper);
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  EXPECT_LT(report->history.back().e_theta, report->history.front().e_theta);
  EXPECT_LT(report->history.back().e_phi, report->history.front().e_phi);
  auto scaled = deform_scale_aware(m.V, m.F, constrained, targets);
  ASSERT_TRUE(scaled.ok()) << scaled.status().to_string();
  EXPECT_LT(scaled->history.back().e_theta, scaled->history.front().e_theta);
}

TEST(ScaleAwareSolver, ALazyLaplacianGuessGivesTheSameSolveBitForBit) {
  auto [m, constrained, targets] = test::make_strip_edit(12);
  for (Eigen::Index j = 1; j < targets.rows(); j += 2) targets(j, 2) += 0.3;
  ScaleAwareSettings eager, lazy;
  lazy.lazy_laplacian_guess = true;
  auto a = ScaleAwareSolver::create(m.V, m.F, constrained, eager);
  auto b = ScaleAwareSolver::create(m.V, m.F, constrained, lazy);
  ASSERT_TRUE(a.ok() && b.ok());
  SolveOptions options;
  options.max_iterations = 5;
  for (int round = 0; round < 2; ++round) {  // the second warm-starts; then a reset restarts
    auto ra = a->solve(targets, options);
    auto rb = b->solve(targets, options);
    ASSERT_TRUE(ra.ok() && rb.ok());
    EXPECT_EQ(ra->V, rb->V) << "round " << round;
  }
  a->reset();
  b->reset();
  auto ra = a->solve(targets, options);
  auto rb = b->solve(targets, options);
  ASSERT_TRUE(ra.ok() && rb.ok());
  EXPECT_EQ(ra->V, rb->V);
}

TEST(ScaleAwareSolver, ACallersTopologyGivesTheSameSolveBitForBit) {
  // A caller that has validated the mesh and built its topology (a multilevel level, a server
  // session) passes it in; the solve, ORA's stitch included, is the one create() builds itself.
  auto [m, constrained, targets] = test::make_strip_edit(12);
  for (Eigen::Index j = 1; j < targets.rows(); j += 2) targets(j, 0) += 0.4;
  auto topology = build_topology(m.F, static_cast<int>(m.V.rows()));
  ASSERT_TRUE(topology.ok());
  auto own = ScaleAwareSolver::create(m.V, m.F, constrained);
  auto given = ScaleAwareSolver::create(m.V, m.F, *topology, constrained);
  ASSERT_TRUE(own.ok() && given.ok());
  SolveOptions options;
  options.max_iterations = 5;
  options.ora = true;
  auto a = own->solve(targets, options);
  auto b = given->solve(targets, options);
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_TRUE(b->stitch.applied);
  EXPECT_EQ(a->V, b->V);
  EXPECT_EQ(a->history.back().energy, b->history.back().energy);
  // The constrained indices are still checked.
  Eigen::VectorXi bad = constrained;
  bad(0) = static_cast<int>(m.V.rows());
  const auto rejected = ScaleAwareSolver::create(m.V, m.F, *topology, bad);
  ASSERT_FALSE(rejected.ok());
  EXPECT_EQ(rejected.status().code(), ErrorCode::InvalidArgument);
}

TEST(ScaleAwareSolver, WarmStartedRepeatOfTheSameTargetsIsAlreadyConverged) {
  MeshData m = test::make_icosphere(2);
  Eigen::VectorXi constrained(6);
  constrained << 0, 1, 2, 3, 4, 5;
  auto solver = ScaleAwareSolver::create(m.V, m.F, constrained);
  ASSERT_TRUE(solver.ok());
  Positions targets = rows_of(m.V, constrained);
  targets.row(0) += Eigen::RowVector3d(0.3, 0.1, 0.0);
  SolveOptions options;
  options.max_iterations = 500;
  options.tolerance = 1e-6;
  options.rigidity = 0;
  // Plain, and accelerated (from its second iteration Anderson extrapolates along what motion
  // the 1e-6 stop left, so the repeat takes a few more iterations to settle).
  for (const int window : {0, SolveOptions{}.anderson_window}) {
    SCOPED_TRACE("anderson window " + std::to_string(window));
    options.anderson_window = window;
    solver->reset();
    auto first = solver->solve(targets, options);
    ASSERT_TRUE(first.ok());
    ASSERT_TRUE(first->converged);
    auto second = solver->solve(targets, options);
    ASSERT_TRUE(second.ok());
    EXPECT_LE(second->iterations, window == 0 ? 2 : 4);
    // Linear convergence leaves a little motion after a 1e-6 relative-energy stop.
    EXPECT_LT((second->V - first->V).cwiseAbs().maxCoeff(), 1e-4);
    EXPECT_EQ(solver->positions(), second->V);
  }
  options.anderson_window = SolveOptions{}.anderson_window;

  // With scale control the outer loop converges more slowly (the face frames follow the normals),
  // so a relative-energy stop leaves more motion (bounded here by 1e-3, diagonal 2).
  options.rigidity = kDefaultRigidity;
  solver->reset();
  auto scaled_first = solver->solve(targets, options);
  ASSERT_TRUE(scaled_first.ok());
  ASSERT_TRUE(scaled_first->converged);
  auto scaled_second = solver->solve(targets, options);
  ASSERT_TRUE(scaled_second.ok());
  EXPECT_LT(scaled_second->iterations, scaled_first->iterations);
  EXPECT_LT((scaled_second->V - scaled_first->V).cwiseAbs().maxCoeff(), 1e-3);
}

TEST(ScaleAwareSolver, ResultsAreDeterministic) {
  MeshData m = test::make_grid(20, 0.1);
  Eigen::VectorXi constrained(3);
  constrained << 0, 20, 440;
  Positions targets = rows_of(m.V, constrained);
  targets.row(2) += Eigen::RowVector3d(0.2, 0.4, 0.5);
  auto a = deform_scale_aware(m.V, m.F, constrained, targets);
  auto b = deform_scale_aware(m.V, m.F, constrained, targets);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->V, b->V);  // bit for bit
}

TEST(ScaleAwareSolver, ProgressReportsEveryIteration) {
  MeshData m = test::make_icosphere(1);
  Eigen::VectorXi constrained(2);
  constrained << 0, 3;
  Positions targets = rows_of(m.V, constrained);
  targets.row(0) *= 1.5;
  std::vector<int> seen;
  std::vector<int> start_seen;  // the rigid start's ARAP iterations (Auto's cold start)
  bool start_after_fine = false;
  auto report = deform_scale_aware(m.V, m.F, constrained, targets, {},
                                   [&](const IterationInfo& info) {
                                     if (info.phase == SolvePhase::Start) {
                                       start_after_fine = start_after_fine || !seen.empty();
                                       EXPECT_EQ(info.level, 0);
                                       EXPECT_EQ(info.level_vertices, m.V.rows());
                                       start_seen.push_back(info.iteration);
                                     } else {
                                       EXPECT_EQ(info.phase, SolvePhase::Fine);
                                       seen.push_back(info.iteration);
                                     }
                                   });
  ASSERT_TRUE(report.ok());
  ASSERT_EQ(seen.size(), report->history.size());
  for (size_t i = 0; i < seen.size(); ++i) EXPECT_EQ(seen[i], int(i));
  // The start is reported too, before the outer iterations, so that a caller whose callback
  // yields (the server) yields during it as well.
  ASSERT_GE(start_seen.size(), 2u);
  for (size_t i = 0; i < start_seen.size(); ++i) EXPECT_EQ(start_seen[i], int(i));
  EXPECT_FALSE(start_after_fine);
}

TEST(ScaleAwareSolver, AStopDuringTheRigidStartCancelsAndKeepsTheState) {
  MeshData m = test::make_icosphere(2);
  Eigen::VectorXi constrained(3);
  constrained << 0, 3, 7;
  auto solver = ScaleAwareSolver::create(m.V, m.F, constrained);
  ASSERT_TRUE(solver.ok());
  Positions targets = rows_of(m.V, constrained);
  targets.row(1) += Eigen::RowVector3d(0, 0, 1);
  std::stop_source source;
  int fine_calls = 0;
  auto report = solver->solve(targets, {}, [&](const IterationInfo& info) {
    if (info.phase == SolvePhase::Fine) ++fine_calls;
    if (info.phase == SolvePhase::Start && info.iteration == 1) source.request_stop();
  }, source.get_token());
  ASSERT_FALSE(report.ok());
  EXPECT_EQ(report.status().code(), ErrorCode::Cancelled);
  EXPECT_EQ(fine_calls, 0);
  EXPECT_EQ(solver->positions(), m.V);
  // Nothing lost: the next solve runs whole.
  EXPECT_TRUE(solver->solve(targets).ok());
}

TEST(ScaleAwareSolver, CancellationStopsAndKeepsThePreviousState) {
  MeshData m = test::make_icosphere(2);
  Eigen::VectorXi constrained(3);
  constrained << 0, 3, 7;
  auto solver = ScaleAwareSolver::create(m.V, m.F, constrained);
  ASSERT_TRUE(solver.ok());
  std::stop_source source;
  Positions targets = rows_of(m.V, constrained);
  targets.row(1) += Eigen::RowVector3d(0, 0, 1);
  int calls = 0;
  auto report = solver->solve(targets, {}, [&](const IterationInfo& info) {
    if (info.phase != SolvePhase::Fine) return;  // the rigid start's ARAP iterations
    ++calls;
    if (info.iteration == 1) source.request_stop();
  }, source.get_token());
  ASSERT_FALSE(report.ok());
  EXPECT_EQ(report.status().code(), ErrorCode::Cancelled);
  EXPECT_EQ(calls, 2);  // the guess and the first iteration, then nothing
  EXPECT_EQ(solver->positions(), m.V);
}

TEST(ScaleAwareSolver, RejectsConfigurationsTheEnergyCannotPin) {
  const MeshData m = test::make_icosphere(1);
  Eigen::VectorXi one(1);
  one << 0;
  auto single = ScaleAwareSolver::create(m.V, m.F, one);
  ASSERT_FALSE(single.ok());
  EXPECT_EQ(single.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(single.status().message().find("component 0"), std::string::npos)
      << single.status().message();

  // Two components, the second one unconstrained.
  MeshData two = m;
  const MeshData other = test::make_icosphere(1);
  two.V.conservativeResize(m.V.rows() * 2, 3);
  two.V.bottomRows(m.V.rows()) = other.V.rowwise() + Eigen::RowVector3d(5, 0, 0);
  two.F.conservativeResize(m.F.rows() * 2, 3);
  two.F.bottomRows(m.F.rows()) = other.F.array() + int(m.V.rows());
  Eigen::VectorXi c(2);
  c << 0, 1;
  auto unpinned = ScaleAwareSolver::create(two.V, two.F, c);
  ASSERT_FALSE(unpinned.ok());
  EXPECT_NE(unpinned.status().message().find("component 1"), std::string::npos)
      << unpinned.status().message();

  auto solver = ScaleAwareSolver::create(m.V, m.F, c);
  ASSERT_TRUE(solver.ok());
  Positions same(2, 3);
  same << 1, 1, 1, 1, 1, 1;
  auto collapsed = solver->solve(same);
  ASSERT_FALSE(collapsed.ok());
  EXPECT_EQ(collapsed.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(collapsed.status().message().find("coincide"), std::string::npos);
}

TEST(ScaleAwareSolver, RejectsBadIndicesAndTargets) {
  const MeshData m = test::make_icosphere(1);
  Eigen::VectorXi out_of_range(2);
  out_of_range << 0, 42;
  auto bad = ScaleAwareSolver::create(m.V, m.F, out_of_range);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find("42 (#V=42)"), std::string::npos) << bad.status().message();

  Eigen::VectorXi repeated(3);
  repeated << 0, 5, 0;
  auto rep = ScaleAwareSolver::create(m.V, m.F, repeated);
  ASSERT_FALSE(rep.ok());
  EXPECT_NE(rep.status().message().find("vertex 0 is constrained twice"), std::string::npos);

  Eigen::VectorXi c(2);
  c << 0, 5;
  auto solver = ScaleAwareSolver::create(m.V, m.F, c);
  ASSERT_TRUE(solver.ok());
  Positions nan_targets = rows_of(m.V, c);
  nan_targets(1, 2) = std::nan("");
  auto nan_result = solver->solve(nan_targets);
  ASSERT_FALSE(nan_result.ok());
  EXPECT_NE(nan_result.status().message().find("target 1 (vertex 5) is not finite"),
            std::string::npos);
  auto wrong_rows = solver->solve(Positions::Zero(3, 3));
  ASSERT_FALSE(wrong_rows.ok());
  EXPECT_EQ(wrong_rows.status().code(), ErrorCode::InvalidArgument);
  SolveOptions bad_options;
  bad_options.inner_iterations = 0;
  EXPECT_EQ(solver->solve(rows_of(m.V, c), bad_options).status().code(),
            ErrorCode::InvalidArgument);
}

}  // namespace
}  // namespace meshdeform::core

namespace meshdeform::core {
namespace {

// Every edit of the (small) Table 1 suite: the iterations must improve on the Laplacian start.
TEST(ScaleAwareSolver, EverySuiteEditEndsBelowTheLaplacianStartInETheta) {
  for (const DeformationBenchmark& bench : make_suite(SuiteScale::Small)) {
    SCOPED_TRACE(bench.name);
    auto setup = constraints_from_selection(bench.mesh.V, bench.selection, bench.transform);
    ASSERT_TRUE(setup.ok()) << setup.status().to_string();
    for (double rigidity : {0.0, kDefaultRigidity}) {
      SCOPED_TRACE(rigidity);
      SolveOptions options;
      options.rigidity = rigidity;
      options.start = StartFrom::Laplacian;
      auto report = deform_scale_aware(bench.mesh.V, bench.mesh.F, setup->constrained,
                                       setup->targets, options);
      ASSERT_TRUE(report.ok()) << report.status().to_string();
      ASSERT_GE(report->history.size(), 2u);
      EXPECT_LT(report->history.back().e_theta, report->history.front().e_theta);
      EXPECT_TRUE(report->V.allFinite());
    }
  }
}

}  // namespace
}  // namespace meshdeform::core

namespace meshdeform::core {
namespace {

// Both step-two preconditioners solve the same exact system: the exact zeros hold for each, and
// on a real edit they agree to the PCG tolerance. The block-trace path multiplies by step two's
// matrix face by face without forming it, the lagged path multiplies by the assembled matrix, so
// this is also the check that the two products agree, with and without the scale term.
class BothPreconditioners : public ::testing::TestWithParam<double> {};

TEST_P(BothPreconditioners, ReproduceZerosAndAgree) {
  const double rigidity = GetParam();
  const MeshData m = test::make_icosphere(2);
  Eigen::VectorXi constrained(6);
  constrained << 0, 1, 2, 3, 4, 5;
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(2.0 * M_PI / 3.0, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Positions similar = ((2.0 * m.V * R.transpose()).rowwise() + Eigen::RowVector3d(1, 0, 0)).eval();
  Positions bend(constrained.size(), 3);
  for (Eigen::Index j = 0; j < constrained.size(); ++j) bend.row(j) = m.V.row(constrained(j));
  bend.row(0) += Eigen::RowVector3d(0.4, 0.2, 0.0);
  std::vector<Positions> results;
  for (auto preconditioner :
       {StepTwoPreconditioner::BlockTrace, StepTwoPreconditioner::LaggedCholesky}) {
    SCOPED_TRACE(static_cast<int>(preconditioner));
    ScaleAwareSettings settings;
    settings.preconditioner = preconditioner;
    auto solver = ScaleAwareSolver::create(m.V, m.F, constrained, settings);
    ASSERT_TRUE(solver.ok()) << solver.status().to_string();
    SolveOptions exact;
    exact.rigidity = rigidity;
    exact.max_iterations = 300;
    exact.inner_iterations = 30;
    exact.tolerance = 1e-12;
    Positions targets(constrained.size(), 3);
    for (Eigen::Index j = 0; j < constrained.size(); ++j) targets.row(j) = similar.row(constrained(j));
    auto sim = solver->solve(targets, exact);
    ASSERT_TRUE(sim.ok()) << sim.status().to_string();
    EXPECT_LT((sim->V - similar).cwiseAbs().maxCoeff(), test::kConvergedTol * 2 * test::bbox_diagonal(m));
    solver->reset();
    SolveOptions tight;
    tight.rigidity = rigidity;
    tight.max_iterations = 40;
    tight.tolerance = 0;
    tight.adaptive_pcg = false;  // solve every step two to pcg_tolerance
    // Plain iterations: Anderson's accept/reject decisions compare merits that differ in the
    // last digits between the two preconditioners, and this test is about step two alone.
    tight.anderson_window = 0;
    auto edited = solver->solve(bend, tight);
    ASSERT_TRUE(edited.ok()) << edited.status().to_string();
    results.push_back(edited->V);
  }
  EXPECT_LT((results[0] - results[1]).cwiseAbs().maxCoeff(), 1e-7);
}

INSTANTIATE_TEST_SUITE_P(ScaleAwareSolver, BothPreconditioners,
                         ::testing::Values(0.0, 1.0, kDefaultRigidity));

// split_preconditioner (the default) factors the block-trace matrix over the free vertices and
// the constrained ones next to them, and takes the inside of the constrained region by its
// diagonal. It preconditions the same system, so with every step two solved to the PCG
// tolerance the iterates are the whole factor's; and since it keeps every coupling of the free
// vertices it stays as good a preconditioner (measured: the same PCG steps on the bench models;
// here at most a quarter more).
class SplitPreconditioner : public ::testing::TestWithParam<double> {};

TEST_P(SplitPreconditioner, IteratesEqualTheWholeFactorsInAsManySteps) {
  const double rigidity = GetParam();
  const MeshData m = test::make_icosphere(3);
  std::vector<int> lower;  // the lower half: about 45% of the vertices, most inside the region
  for (Eigen::Index v = 0; v < m.V.rows(); ++v) {
    if (m.V(v, 2) < -0.05) lower.push_back(static_cast<int>(v));
  }
  const Eigen::VectorXi constrained = Eigen::Map<const Eigen::VectorXi>(
      lower.data(), static_cast<Eigen::Index>(lower.size()));
  Positions targets(constrained.size(), 3);
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    targets.row(j) = m.V.row(constrained(j));
    // Shear the constrained half: its lowest vertices move most.
    targets(j, 0) += 0.3 * (-0.05 - m.V(constrained(j), 2));
  }
  SolveOptions tight;
  tight.rigidity = rigidity;
  tight.max_iterations = 20;
  tight.tolerance = 0;
  tight.adaptive_pcg = false;
  tight.anderson_window = 0;
  std::vector<SolveReport> reports;
  for (const bool split : {true, false}) {
    SCOPED_TRACE(split);
    ScaleAwareSettings settings;
    settings.split_preconditioner = split;
    auto solver = ScaleAwareSolver::create(m.V, m.F, constrained, settings);
    ASSERT_TRUE(solver.ok()) << solver.status().to_string();
    auto report = solver->solve(targets, tight);
    ASSERT_TRUE(report.ok()) << report.status().to_string();
    ASSERT_EQ(report->iterations, 20);
    reports.push_back(*std::move(report));
  }
  EXPECT_LT((reports[0].V - reports[1].V).cwiseAbs().maxCoeff(), 1e-7 * test::bbox_diagonal(m));
  EXPECT_GT(reports[0].pcg_iterations, 0);
  EXPECT_LE(4 * reports[0].pcg_iterations, 5 * reports[1].pcg_iterations);
}

INSTANTIATE_TEST_SUITE_P(ScaleAwareSolver, SplitPreconditioner,
                         ::testing::Values(0.0, kDefaultRigidity));

TEST(ScaleAwareSolver, SetPositionsIsWhereTheNextWarmSolveStarts) {
  const test::BendEdit bend = test::make_bend(12);
  auto solver = ScaleAwareSolver::create(bend.mesh.V, bend.mesh.F, bend.constrained);
  ASSERT_TRUE(solver.ok()) << solver.status().to_string();
  SolveOptions converge;
  converge.max_iterations = 1000;  // measured: ~400 at the default rigidity
  converge.tolerance = 1e-6;
  auto reference = solver->solve(bend.targets, converge);
  ASSERT_TRUE(reference.ok()) << reference.status().to_string();
  ASSERT_TRUE(reference->converged);

  // A second solver handed the converged result starts there: iteration 0 is that iterate, and
  // it settles far sooner than from the Laplacian guess (step one's normals and rotations are
  // not carried over, so it needs some iterations to find them again).
  for (const StartFrom start : {StartFrom::Auto, StartFrom::Previous}) {
    auto other = ScaleAwareSolver::create(bend.mesh.V, bend.mesh.F, bend.constrained);
    ASSERT_TRUE(other.ok());
    ASSERT_TRUE(other->set_positions(reference->V).ok());
    EXPECT_EQ(other->positions(), reference->V);
    SolveOptions options = converge;
    options.start = start;
    options.max_iterations = 0;
    auto none = other->solve(bend.targets, options);
    ASSERT_TRUE(none.ok()) << none.status().to_string();
    EXPECT_EQ(none->V, reference->V);
    EXPECT_LT(none->history.front().energy, 0.5 * reference->history.front().energy);
    options.max_iterations = 1000;
    auto warm = other->solve(bend.targets, options);
    ASSERT_TRUE(warm.ok()) << warm.status().to_string();
    EXPECT_TRUE(warm->converged);
    EXPECT_LT(warm->iterations, reference->iterations);
    EXPECT_LT((warm->V - reference->V).cwiseAbs().maxCoeff(), 1e-3);
  }
  // Laplacian ignores it; reset forgets it.
  ASSERT_TRUE(solver->set_positions(reference->V).ok());
  SolveOptions laplacian = converge;
  laplacian.start = StartFrom::Laplacian;
  laplacian.max_iterations = 0;
  auto from_guess = solver->solve(bend.targets, laplacian);
  ASSERT_TRUE(from_guess.ok());
  EXPECT_GT((from_guess->V - reference->V).cwiseAbs().maxCoeff(), 1e-3);
  ASSERT_TRUE(solver->set_positions(reference->V).ok());
  solver->reset();
  EXPECT_EQ(solver->positions(), bend.mesh.V);

  // Bad input leaves the solver as it was.
  EXPECT_EQ(solver->set_positions(bend.mesh.V.topRows(3)).code(), ErrorCode::InvalidArgument);
  Positions nan = bend.mesh.V;
  nan(4, 2) = std::nan("");
  EXPECT_EQ(solver->set_positions(nan).code(), ErrorCode::InvalidArgument);
  EXPECT_EQ(solver->positions(), bend.mesh.V);
}

// The server's background refinement runs a solve as short solves in a row (2 iterations at a
// time). They continue one another: the stopping rule's state, the inexact PCG's reduction and
// Anderson's window carry over, so the slices take the one long solve's steps (before the window
// carried over, each slice restarted the acceleration: at 187k vertices the sliced refinement
// had energy 0.81 after 40 iterations against 0.56 for the long solve).
TEST(ScaleAwareSolver, ShortSolvesInARowTakeTheLongSolvesSteps) {
  const test::BendEdit bend = test::make_bend(12);
  for (const double rigidity : {0.0, kDefaultRigidity}) {
    SCOPED_TRACE(rigidity);
    auto whole = ScaleAwareSolver::create(bend.mesh.V, bend.mesh.F, bend.constrained);
    auto sliced = ScaleAwareSolver::create(bend.mesh.V, bend.mesh.F, bend.constrained);
    ASSERT_TRUE(whole.ok() && sliced.ok());
    SolveOptions options;
    options.rigidity = rigidity;
    options.max_iterations = 2;  // both start with the same short (cold) solve
    ASSERT_TRUE(whole->solve(bend.targets, options).ok());
    ASSERT_TRUE(sliced->solve(bend.targets, options).ok());

    options.start = StartFrom::Previous;
    options.tolerance = 1e-9;  // not reached in the iterations below
    options.max_iterations = 16;
    auto long_solve = whole->solve(bend.targets, options);
    ASSERT_TRUE(long_solve.ok()) << long_solve.status().to_string();
    ASSERT_FALSE(long_solve->converged);
    ASSERT_GT(long_solve->anderson_rejections, 0);  // the safeguard's path is exercised too
    options.max_iterations = 2;
    SolveReport slice;
    int iterations = 0, rejections = 0;
    for (int k = 0; k < 8; ++k) {
      auto next = sliced->solve(bend.targets, options);
      ASSERT_TRUE(next.ok()) << next.status().to_string();
      iterations += next->iterations;
      rejections += next->anderson_rejections;
      slice = *std::move(next);
    }
    EXPECT_EQ(iterations, 16);
    EXPECT_EQ(rejections, long_solve->anderson_rejections);
    EXPECT_LT((slice.V - long_solve->V).cwiseAbs().maxCoeff(), 1e-9 * test::bbox_diagonal(bend.mesh));
    EXPECT_NEAR(slice.history.back().energy, long_solve->history.back().energy,
                1e-9 * long_solve->history.back().energy);
    EXPECT_NEAR(slice.estimated_remaining, long_solve->estimated_remaining,
                1e-6 * long_solve->estimated_remaining);

    // A solve that does not continue (other targets) starts its window afresh, and so does one
    // after reset(): the carried state belongs to the solve it came from.
    Positions moved = bend.targets;
    moved.col(1).array() += 0.01 * test::bbox_diagonal(bend.mesh);
    auto other = sliced->solve(moved, options);
    ASSERT_TRUE(other.ok());
    EXPECT_EQ(other->iterations, 2);
  }
}

}  // namespace
}  // namespace meshdeform::core
