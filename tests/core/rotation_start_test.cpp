#include "core/methods/rotation_start.h"

#include <cmath>

#include <Eigen/Geometry>
#include <gtest/gtest.h>

#include "core/methods/laplacian.h"
#include "core/samples/samples.h"
#include "core/methods/scale_aware.h"
#include "core/mesh/topology.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

struct Edit {
  DeformationBenchmark bench;
  MeshTopology topology;
  HandleSetup setup;
};

Edit make_edit(DeformationBenchmark bench) {
  Edit edit{std::move(bench), {}, {}};
  edit.topology =
      build_topology(edit.bench.mesh.F, static_cast<int>(edit.bench.mesh.V.rows())).value();
  edit.setup = constraints_from_selection(edit.bench.mesh.V, edit.bench.selection,
                                          edit.bench.transform)
                   .value();
  return edit;
}

// Every handle moved by one rigid motion: the propagated rotations are that rotation everywhere
// and the guess is the moved mesh itself (both terms of the global step vanish there).
TEST(RotationPropagationStart, RigidMotionOfEveryHandleIsReproduced) {
  const Edit edit = make_edit(make_bar(12, 3));
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(2.0, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  const Eigen::RowVector3d t(0.3, -0.1, 2.0);
  const Positions moved = ((edit.bench.mesh.V * R.transpose()).rowwise() + t).eval();
  auto start = RotationPropagationStart::create(edit.bench.mesh.V, edit.bench.mesh.F,
                                                edit.topology, edit.setup.constrained, 100.0);
  ASSERT_TRUE(start.ok()) << start.status().to_string();
  auto guess = start->guess(test::gather_rows(moved, edit.setup.constrained));
  ASSERT_TRUE(guess.ok()) << guess.status().to_string();
  EXPECT_LT((*guess - moved).cwiseAbs().maxCoeff(), 1e-9);
  for (const Eigen::Matrix3d& Rv : start->rotations()) EXPECT_LT((Rv - R).norm(), 1e-9);
}

// The Table 1 bar: one end fixed, the other twisted by 135 degrees about the bar's axis. The
// propagated rotation turns monotonically along the bar, about that axis, and the guess keeps
// the cross-section's size, where Laplacian editing's linear blend collapses it near the middle.
TEST(RotationPropagationStart, TwistTurnsAlongTheBarAndKeepsTheCrossSection) {
  const Edit edit = make_edit(make_bar(40, 4));  // rings every 0.05 along z
  const Positions& V = edit.bench.mesh.V;
  auto start = RotationPropagationStart::create(V, edit.bench.mesh.F, edit.topology,
                                                edit.setup.constrained, 100.0);
  ASSERT_TRUE(start.ok()) << start.status().to_string();
  auto guess = start->guess(edit.setup.targets);
  ASSERT_TRUE(guess.ok()) << guess.status().to_string();

  // Angle about z at heights z = 0.5, 1.0, 1.5, from the vertices on that cross-section.
  const Eigen::Vector3d axis(0, 0, 1);
  auto angle_at = [&](double z) {
    double sum = 0;
    int count = 0;
    for (Eigen::Index v = 0; v < V.rows(); ++v) {
      if (std::abs(V(v, 2) - z) > 1e-6) continue;
      const Eigen::AngleAxisd turn(Eigen::Matrix3d(start->rotations()[v]));
      sum += turn.angle() * (turn.axis().dot(axis) >= 0 ? 1.0 : -1.0);
      ++count;
    }
    EXPECT_GT(count, 0) << "no vertex at z = " << z;
    return sum / std::max(count, 1);
  };
  const double a1 = angle_at(0.5), a2 = angle_at(1.0), a3 = angle_at(1.5);
  const double twist = 135.0 * M_PI / 180.0;
  EXPECT_GT(std::abs(a2), std::abs(a1));
  EXPECT_GT(std::abs(a3), std::abs(a2));
  EXPECT_LT(std::abs(a3), twist);
  EXPECT_GT(std::abs(a2), 0.25 * twist);
  EXPECT_LT(std::abs(a2), 0.75 * twist);

  // RMS distance from the axis of the mid cross-section, rest vs guess vs Laplacian editing.
  auto mid_radius = [&](const Positions& P) {
    Eigen::RowVector3d centre = Eigen::RowVector3d::Zero();
    int count = 0;
    for (Eigen::Index v = 0; v < V.rows(); ++v) {
      if (std::abs(V(v, 2) - 1.0) > 1e-6) continue;
      centre += P.row(v);
      ++count;
    }
    centre /= count;
    double sum = 0;
    for (Eigen::Index v = 0; v < V.rows(); ++v) {
      if (std::abs(V(v, 2) - 1.0) > 1e-6) continue;
      const Eigen::RowVector3d d = P.row(v) - centre;
      sum += d.x() * d.x() + d.y() * d.y();
    }
    return std::sqrt(sum / count);
  };
  auto laplacian = LaplacianEditor::create(V, edit.bench.mesh.F, edit.topology,
                                           edit.setup.constrained, LaplacianWeights::Cotangent, 100.0);
  ASSERT_TRUE(laplacian.ok()) << laplacian.status().to_string();
  auto linear = laplacian->solve(edit.setup.targets);
  ASSERT_TRUE(linear.ok()) << linear.status().to_string();
  const double rest = mid_radius(V), propagated = mid_radius(*guess), blended = mid_radius(*linear);
  EXPECT_GT(propagated, 0.9 * rest);
  EXPECT_LT(propagated, 1.1 * rest);
  EXPECT_LT(blended, 0.9 * rest) << "the test's premise: the linear blend shrinks the middle";
}

// A handle too thin to define a rotation (one vertex) counts as not rotated: dragging it gives
// identity rotations at that handle, and the guess still lands on the targets.
TEST(RotationPropagationStart, ThinHandleCountsAsNotRotated) {
  const MeshData grid = test::make_grid(9);
  const MeshTopology topology = build_topology(grid.F, static_cast<int>(grid.V.rows())).value();
  Eigen::VectorXi constrained(4);
  constrained << 0, 8, 40, 80;  // corners (single vertices) and the centre
  Positions targets = test::gather_rows(grid.V, constrained);
  targets.row(2) += Eigen::RowVector3d(0, 0, 0.5);
  auto start = RotationPropagationStart::create(grid.V, grid.F, topology, constrained, 100.0);
  ASSERT_TRUE(start.ok()) << start.status().to_string();
  auto guess = start->guess(targets);
  ASSERT_TRUE(guess.ok()) << guess.status().to_string();
  for (const Eigen::Matrix3d& Rv : start->rotations()) {
    EXPECT_LT((Rv - Eigen::Matrix3d::Identity()).norm(), 1e-12);
  }
  EXPECT_LT((test::gather_rows(*guess, constrained) - targets).cwiseAbs().maxCoeff(), 0.05);
  EXPECT_GT((*guess)(40, 2), 0.4);
}

// The solver's Propagated start is that guess: with no iteration the result is the guess.
TEST(RotationPropagationStart, IsTheScaleAwareSolversPropagatedStart) {
  const Edit edit = make_edit(make_bar(12, 3));
  auto solver = ScaleAwareSolver::create(edit.bench.mesh.V, edit.bench.mesh.F,
                                         edit.setup.constrained);
  ASSERT_TRUE(solver.ok()) << solver.status().to_string();
  SolveOptions options;
  options.start = StartFrom::Propagated;
  options.max_iterations = 0;
  auto report = solver->solve(edit.setup.targets, options);
  ASSERT_TRUE(report.ok()) << report.status().to_string();
  auto start = RotationPropagationStart::create(edit.bench.mesh.V, edit.bench.mesh.F,
                                                edit.topology, edit.setup.constrained,
                                                ScaleAwareSettings{}.lambda);
  ASSERT_TRUE(start.ok());
  auto guess = start->guess(edit.setup.targets);
  ASSERT_TRUE(guess.ok());
  EXPECT_LT((report->V - *guess).cwiseAbs().maxCoeff(), 1e-12);
}

TEST(RotationPropagationStart, RejectsBadLambda) {
  const MeshData grid = test::make_grid(5);
  const MeshTopology topology = build_topology(grid.F, static_cast<int>(grid.V.rows())).value();
  Eigen::VectorXi constrained(1);
  constrained << 0;
  for (double lambda : {0.0, -1.0, std::nan("")}) {
    auto start = RotationPropagationStart::create(grid.V, grid.F, topology, constrained, lambda);
    ASSERT_FALSE(start.ok());
    EXPECT_EQ(start.status().code(), ErrorCode::InvalidArgument);
  }
}

}  // namespace
}  // namespace meshdeform::core
