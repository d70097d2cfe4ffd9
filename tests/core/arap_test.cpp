// Exact properties of ARAP (Sorkine & Alexa 2007): the rest pose and every rigid motion of it are
// exact zeros of the energy, constrained vertices are met exactly, and the local/global
// alternation is a block-coordinate descent, so the energy never increases.
#include "core/methods/arap.h"

#include <gtest/gtest.h>

#include <stop_token>
#include <vector>

#include <Eigen/Geometry>

#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

using test::bbox_diagonal;
using test::pinned_test_meshes;
const auto& rows_of = test::gather_rows;

Positions apply(const Eigen::Matrix3d& R, const Eigen::Vector3d& t, const Positions& V) {
  return ((V * R.transpose()).rowwise() + t.transpose()).eval();
}

// A bend: left column fixed, right column rotated by 60 degrees about y and lifted.
using test::make_bend;
using Bend = test::BendEdit;

TEST(ArapSolver, HandlesAtRestLeaveTheMeshUnchanged) {
  for (const auto& [name, mesh, constrained] : pinned_test_meshes()) {
    SCOPED_TRACE(name);
    auto solver = ArapSolver::create(mesh.V, mesh.F, constrained);
    ASSERT_TRUE(solver.ok()) << solver.status().to_string();
    for (StartFrom start : {StartFrom::Laplacian, StartFrom::Previous}) {
      SolveOptions options;
      options.start = start;
      auto report = solver->solve(rows_of(mesh.V, constrained), options);
      ASSERT_TRUE(report.ok()) << report.status().to_string();
      const double diag = bbox_diagonal(mesh);
      EXPECT_LT((report->V - mesh.V).cwiseAbs().maxCoeff(), test::kExactTol * diag);
      EXPECT_LT(report->history.back().energy, 1e-20 * diag * diag);
      EXPECT_LT(report->history.back().e_theta, 1e-9);
      EXPECT_LT(report->history.back().e_phi, 1e-9);
      EXPECT_TRUE(report->converged);
    }
  }
}

TEST(ArapSolver, RigidMotionOfHandlesGivesThatMotionOfTheMesh) {
  // A 120-degree rotation about a skew axis and a translation: far from the Laplacian start,
  // which is not rotation invariant, so the iterations have to find the rotation.
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(2.0 * M_PI / 3.0, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(0.3, -1.2, 2.0);
  for (const auto& [name, mesh, constrained] : pinned_test_meshes()) {
    SCOPED_TRACE(name);
    const Positions expected = apply(R, t, mesh.V);
    auto solver = ArapSolver::create(mesh.V, mesh.F, constrained);
    ASSERT_TRUE(solver.ok()) << solver.status().to_string();
    SolveOptions options;
    options.max_iterations = 5000;
    options.tolerance = 1e-14;  // run until the energy reaches round-off
    auto report = solver->solve(rows_of(expected, constrained), options);
    ASSERT_TRUE(report.ok()) << report.status().to_string();
    const double diag = bbox_diagonal(mesh);
    EXPECT_TRUE(report->converged) << "iterations " << report->iterations;
    EXPECT_LT((report->V - expected).cwiseAbs().maxCoeff(), test::kConvergedTol * diag)
        << "iterations " << report->iterations;
    EXPECT_LT(report->history.back().e_theta, 1e-6);
    EXPECT_LT(report->history.back().e_phi, 1e-6);
    // The Laplacian start is visibly not rigid: the iterations did the work.
    EXPECT_GT(report->history.front().e_theta, 1e-3);
  }
}

TEST(ArapSolver, OneConstrainedVertexGivesARigidMotion) {
  const MeshData m = test::make_icosphere(1);
  Eigen::VectorXi one(1);
  one << 7;
  auto solver = ArapSolver::create(m.V, m.F, one);
  ASSERT_TRUE(solver.ok()) << solver.status().to_string();
  const Eigen::RowVector3d shift(0.4, -0.2, 1.5);
  Positions target = rows_of(m.V, one);
  target.row(0) += shift;
  auto report = solver->solve(target);
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  const Positions expected = m.V.rowwise() + shift;
  EXPECT_LT((report->V - expected).cwiseAbs().maxCoeff(), test::kExactTol * bbox_diagonal(m));
  EXPECT_TRUE(report->converged);
}

TEST(ArapSolver, EnergyNeverIncreasesAndHandlesAreExact) {
  const Bend bend = make_bend(16);
  auto solver = ArapSolver::create(bend.mesh.V, bend.mesh.F, bend.constrained);
  ASSERT_TRUE(solver.ok()) << solver.status().to_string();
  SolveOptions options;
  options.max_iterations = 60;
  options.tolerance = 0;  // run the whole budget
  auto report = solver->solve(bend.targets, options);
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  ASSERT_EQ(report->history.size(), 61u);
  EXPECT_EQ(report->iterations, 60);
  for (size_t k = 1; k < report->history.size(); ++k) {
    const double before = report->history[k - 1].energy, after = report->history[k].energy;
    EXPECT_LE(after, before * (1 + 1e-12)) << "iteration " << k;
  }
  // A bend is not rigid: the energy stays well above zero but falls a lot from the start.
  EXPECT_GT(report->history.back().energy, 1e-6);
  EXPECT_LT(report->history.back().energy, 0.75 * report->history.front().energy);
  EXPECT_LT(report->history.back().e_theta, report->history.front().e_theta);
  // Hard constraints: the constrained rows are the targets, bit for bit.
  EXPECT_EQ(rows_of(report->V, bend.constrained), bend.targets);
  EXPECT_TRUE(report->V.allFinite());
  for (const IterationInfo& info : report->history) {
    EXPECT_EQ(info.pcg_iterations, 0);
    EXPECT_EQ(info.normal_sweeps, 0);
  }
  EXPECT_EQ(report->factorizations, 0);
}

// The report counts the mixes Anderson's safeguard replaced by the plain update (it said 0 for
// ARAP before), and none without acceleration.
TEST(ArapSolver, TheSafeguardsReplacementsAreCounted) {
  const Bend bend = make_bend(16);
  SolveOptions options;
  options.max_iterations = 60;
  options.tolerance = 0;  // run the whole budget
  options.track_metrics = false;
  for (const int window : {6, 0}) {
    auto solver = ArapSolver::create(bend.mesh.V, bend.mesh.F, bend.constrained);
    ASSERT_TRUE(solver.ok()) << solver.status().to_string();
    options.anderson_window = window;
    auto report = solver->solve(bend.targets, options);
    ASSERT_TRUE(report.ok()) << report.status().to_string();
    if (window == 0) {
      EXPECT_EQ(report->anderson_rejections, 0);
    } else {
      EXPECT_GT(report->anderson_rejections, 0);
      EXPECT_LE(report->anderson_rejections, report->iterations);
    }
  }
}

TEST(ArapSolver, WarmStartedRepeatOfTheSameTargetsIsAlreadyConverged) {
  const Bend bend = make_bend(12);
  auto solver = ArapSolver::create(bend.mesh.V, bend.mesh.F, bend.constrained);
  ASSERT_TRUE(solver.ok());
  SolveOptions options;
  options.max_iterations = 2000;
  options.tolerance = 1e-8;
  // The last-change rule judges one iteration; the default rule (an estimated remaining change
  // from the rate) needs three by design (core/methods/convergence.h).
  options.stopping_rule = StoppingRule::Change;
  auto first = solver->solve(bend.targets, options);
  ASSERT_TRUE(first.ok());
  ASSERT_TRUE(first->converged);
  EXPECT_EQ(solver->positions(), first->V);
  auto second = solver->solve(bend.targets, options);
  ASSERT_TRUE(second.ok());
  EXPECT_LE(second->iterations, 1);
  EXPECT_LT((second->V - first->V).cwiseAbs().maxCoeff(), 1e-3);
  // The Laplacian start ignores the previous result and repeats the first solve exactly.
  options.start = StartFrom::Laplacian;
  auto third = solver->solve(bend.targets, options);
  ASSERT_TRUE(third.ok());
  EXPECT_EQ(third->V, first->V);
  // reset() forgets: positions are the rest mesh, and Auto starts from the Laplacian guess again.
  solver->reset();
  EXPECT_EQ(solver->positions(), bend.mesh.V);
  options.start = StartFrom::Auto;
  auto fourth = solver->solve(bend.targets, options);
  ASSERT_TRUE(fourth.ok());
  EXPECT_EQ(fourth->V, first->V);
}

TEST(ArapSolver, ResultsAreDeterministicAndIndependentOfThreads) {
  // 51 x 51 vertices: above the size where the per-vertex loops go parallel.
  const Bend bend = make_bend(50);
  SolveOptions options;
  options.max_iterations = 8;
  options.track_metrics = false;
  Positions results[3];
  for (int k = 0; k < 3; ++k) {
    ArapSettings settings;
    settings.threads = k == 2 ? 2 : 1;
    auto solver = ArapSolver::create(bend.mesh.V, bend.mesh.F, bend.constrained, settings);
    ASSERT_TRUE(solver.ok());
    auto report = solver->solve(bend.targets, options);
    ASSERT_TRUE(report.ok());
    results[k] = report->V;
  }
  EXPECT_EQ(results[0], results[1]);  // bit for bit
  EXPECT_EQ(results[0], results[2]);
}

TEST(ArapSolver, ProgressReportsEveryIteration) {
  const Bend bend = make_bend(8);
  SolveOptions options;
  options.max_iterations = 7;
  options.tolerance = 0;
  std::vector<int> seen;
  auto report = deform_arap(bend.mesh.V, bend.mesh.F, bend.constrained, bend.targets, options,
                            [&](const IterationInfo& info) { seen.push_back(info.iteration); });
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  ASSERT_EQ(seen.size(), report->history.size());
  ASSERT_EQ(seen.size(), 8u);
  for (size_t i = 0; i < seen.size(); ++i) EXPECT_EQ(seen[i], int(i));
  EXPECT_FALSE(report->converged);
}

TEST(ArapSolver, CancellationStopsAndKeepsThePreviousState) {
  const Bend bend = make_bend(12);
  auto solver = ArapSolver::create(bend.mesh.V, bend.mesh.F, bend.constrained);
  ASSERT_TRUE(solver.ok());
  SolveOptions options;
  options.tolerance = 0;
  auto cancel_at_first = [&](std::stop_source& source, int& calls) {
    return [&source, &calls](const IterationInfo& info) {
      ++calls;
      if (info.iteration == 1) source.request_stop();
    };
  };
  {
    std::stop_source source;
    int calls = 0;
    auto report =
        solver->solve(bend.targets, options, cancel_at_first(source, calls), source.get_token());
    ASSERT_FALSE(report.ok());
    EXPECT_EQ(report.status().code(), ErrorCode::Cancelled);
    EXPECT_EQ(calls, 2);  // the start and the first iteration, then nothing
    EXPECT_EQ(solver->positions(), bend.mesh.V);
  }
  // After a finished solve, a cancelled one keeps that result.
  auto done = solver->solve(bend.targets);
  ASSERT_TRUE(done.ok());
  Positions moved = bend.targets;
  moved.row(1) += Eigen::RowVector3d(0, 0, 0.2);
  std::stop_source source;
  int calls = 0;
  auto report = solver->solve(moved, options, cancel_at_first(source, calls), source.get_token());
  ASSERT_FALSE(report.ok());
  EXPECT_EQ(report.status().code(), ErrorCode::Cancelled);
  EXPECT_EQ(solver->positions(), done->V);
}

TEST(ArapSolver, RejectsBadIndicesComponentsAndTargets) {
  const MeshData m = test::make_icosphere(1);
  Eigen::VectorXi out_of_range(2);
  out_of_range << 0, 42;
  auto bad = ArapSolver::create(m.V, m.F, out_of_range);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(bad.status().message().find("42 (#V=42)"), std::string::npos) << bad.status().message();

  Eigen::VectorXi repeated(3);
  repeated << 0, 5, 0;
  auto rep = ArapSolver::create(m.V, m.F, repeated);
  ASSERT_FALSE(rep.ok());
  EXPECT_NE(rep.status().message().find("vertex 0 is constrained twice"), std::string::npos)
      << rep.status().message();

  auto none = ArapSolver::create(m.V, m.F, Eigen::VectorXi());
  ASSERT_FALSE(none.ok());
  EXPECT_NE(none.status().message().find("component 0"), std::string::npos)
      << none.status().message();

  // Two components, the second one unconstrained.
  MeshData two = m;
  two.V.conservativeResize(m.V.rows() * 2, 3);
  two.V.bottomRows(m.V.rows()) = m.V.rowwise() + Eigen::RowVector3d(5, 0, 0);
  two.F.conservativeResize(m.F.rows() * 2, 3);
  two.F.bottomRows(m.F.rows()) = m.F.array() + int(m.V.rows());
  Eigen::VectorXi c(2);
  c << 0, 5;
  auto unpinned = ArapSolver::create(two.V, two.F, c);
  ASSERT_FALSE(unpinned.ok());
  EXPECT_EQ(unpinned.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(unpinned.status().message().find("component 1"), std::string::npos)
      << unpinned.status().message();

  MeshData broken = m;
  broken.V(3, 1) = std::nan("");
  auto invalid = ArapSolver::create(broken.V, broken.F, c);
  ASSERT_FALSE(invalid.ok());
  EXPECT_NE(invalid.status().message().find("vertex 3"), std::string::npos)
      << invalid.status().message();

  auto solver = ArapSolver::create(m.V, m.F, c);
  ASSERT_TRUE(solver.ok());
  Positions nan_targets = rows_of(m.V, c);
  nan_targets(1, 2) = std::nan("");
  auto nan_result = solver->solve(nan_targets);
  ASSERT_FALSE(nan_result.ok());
  EXPECT_EQ(nan_result.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(nan_result.status().message().find("target 1 (vertex 5) is not finite"),
            std::string::npos)
      << nan_result.status().message();
  auto wrong_rows = solver->solve(Positions::Zero(3, 3));
  ASSERT_FALSE(wrong_rows.ok());
  EXPECT_EQ(wrong_rows.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(wrong_rows.status().message().find("got 3"), std::string::npos)
      << wrong_rows.status().message();
  SolveOptions bad_options;
  bad_options.max_iterations = -1;
  EXPECT_EQ(solver->solve(rows_of(m.V, c), bad_options).status().code(),
            ErrorCode::InvalidArgument);
  // None of the failures touched the state.
  EXPECT_EQ(solver->positions(), m.V);

  // Coinciding targets are allowed (unlike the scale-aware solver): ARAP keeps edge lengths, so
  // the mesh cannot collapse, it only stretches toward the common point.
  Positions same(2, 3);
  same << 1, 1, 1, 1, 1, 1;
  auto collapsed = solver->solve(same);
  ASSERT_TRUE(collapsed.ok()) << collapsed.status().to_string();
  EXPECT_TRUE(collapsed->V.allFinite());
}

}  // namespace
}  // namespace meshdeform::core
