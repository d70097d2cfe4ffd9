// Anderson acceleration (Peng et al. 2018): the helper on a model problem, its energy safeguard,
// and ARAP with SolveOptions::anderson_window.
#include "core/linalg/anderson.h"

#include <gtest/gtest.h>

#include <vector>

#include <Eigen/Core>

#include "core/methods/arap.h"
#include "core/methods/scale_aware.h"
#include "core/samples/samples.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

/// A slow fixed-point iteration with an energy: gradient descent x <- x - (A x - b) / L on
/// E(x) = x^T A x / 2 - b^T x, A the 1D Laplacian (+ a small shift), L its largest eigenvalue.
struct Quadratic {
  Eigen::MatrixXd A;
  Eigen::VectorXd b;
  double step = 0;
  explicit Quadratic(int n) : A(Eigen::MatrixXd::Zero(n, n)), b(Eigen::VectorXd::Ones(n)) {
    for (int i = 0; i < n; ++i) {
      A(i, i) = 2.05;
      if (i > 0) A(i, i - 1) = A(i - 1, i) = -1;
    }
    step = 1.0 / 4.05;
  }
  double energy(const Eigen::VectorXd& x) const { return 0.5 * x.dot(A * x) - b.dot(x); }
  Eigen::VectorXd map(const Eigen::VectorXd& x) const { return x - step * (A * x - b); }
  double minimum() const {
    const Eigen::VectorXd x = A.ldlt().solve(b);
    return energy(x);
  }
};

TEST(Anderson, AcceleratesASlowFixedPointIteration) {
  const Quadratic q(40);
  const double e_min = q.minimum();
  // Plain steps until the energy gap is below 1e-10 (relative).
  auto plain_iterations = [&]() {
    Eigen::VectorXd x = Eigen::VectorXd::Zero(40);
    for (int it = 1; it <= 5000; ++it) {
      x = q.map(x);
      if (q.energy(x) - e_min < 1e-10 * std::abs(e_min)) return it;
    }
    return 5001;
  };
  auto run = [&](int window, int budget) {
    Eigen::VectorXd x = Eigen::VectorXd::Zero(40);
    AndersonOptions options;
    options.window = window;
    options.max_iterations = budget;
    options.tolerance = 0;
    const AndersonReport report = anderson_minimize(
        x, [&](const Eigen::VectorXd& y) { return q.energy(y); },
        [&](const Eigen::VectorXd& y) { return q.map(y); }, options);
    return report.energy - e_min;
  };
  const int plain = plain_iterations();
  EXPECT_GT(plain, 240);  // the model problem is slow on purpose (condition number ~80)
  // Anderson with a window of 5 closes the gap to 1e-10 within 120 steps, and after 60 steps it
  // is more than 1e5 times closer than the plain iteration.
  EXPECT_LT(run(5, 120), 1e-10 * std::abs(e_min));
  EXPECT_LT(run(5, 60), 1e-5 * run(0, 60));
}

TEST(Anderson, SafeguardRejectsStepsThatRaiseTheEnergy) {
  // An energy that punishes every iterate the plain map did not produce: each accelerated mix is
  // then rejected, and the run must be the plain iteration, bit for bit, with energies that never
  // increase.
  const Quadratic q(30);
  Eigen::VectorXd last_map;
  std::vector<double> accepted;
  auto energy = [&](const Eigen::VectorXd& y) {
    const bool is_plain = last_map.size() == 0 || y == last_map;
    return q.energy(y) + (is_plain ? 0.0 : 1e6);
  };
  auto map = [&](const Eigen::VectorXd& y) {
    last_map = q.map(y);
    return last_map;
  };
  Eigen::VectorXd x = Eigen::VectorXd::Zero(30);
  AndersonOptions options;
  options.window = 4;
  options.max_iterations = 25;
  options.tolerance = 0;
  const AndersonReport report = anderson_minimize(x, energy, map, options);
  EXPECT_EQ(report.iterations, 25);
  EXPECT_GT(report.rejected, 10);

  Eigen::VectorXd plain = Eigen::VectorXd::Zero(30);
  for (int it = 0; it < 25; ++it) plain = q.map(plain);
  EXPECT_EQ(x, plain);
  EXPECT_DOUBLE_EQ(report.energy, q.energy(plain));
}

TEST(Anderson, AcceleratorRestartsOnNonFiniteMixes) {
  AndersonAccelerator accelerator(3);
  Eigen::VectorXd x = Eigen::VectorXd::Zero(4);
  accelerator.reset(x);
  // Two identical map values make the difference column zero: the normal matrix is singular,
  // and the complete orthogonal decomposition still returns finite coefficients.
  const Eigen::VectorXd g = Eigen::VectorXd::Ones(4);
  EXPECT_TRUE(accelerator.compute(g).allFinite());
  EXPECT_TRUE(accelerator.compute(g).allFinite());
  EXPECT_TRUE(accelerator.compute(g).isApprox(g));
}

SolveOptions arap_options(int window, int iterations) {
  SolveOptions options;
  options.max_iterations = iterations;
  options.tolerance = 0;
  options.track_metrics = false;
  options.anderson_window = window;
  return options;
}

TEST(ArapAnderson, ReachesLowerEnergyAtEqualIterationsAndNeverIncreasesIt) {
  for (const auto& bench : {make_cylinder(20, 21), make_bar(20, 6)}) {
    SCOPED_TRACE(bench.name);
    const auto setup = constraints_from_selection(bench.mesh.V, bench.selection, bench.transform);
    ASSERT_TRUE(setup.ok());
    auto solver = ArapSolver::create(bench.mesh.V, bench.mesh.F, setup->constrained);
    ASSERT_TRUE(solver.ok());
    auto plain = solver->solve(setup->targets, arap_options(0, 30));
    ASSERT_TRUE(plain.ok());
    solver->reset();
    auto accelerated = solver->solve(setup->targets, arap_options(6, 30));
    ASSERT_TRUE(accelerated.ok());
    ASSERT_EQ(accelerated->history.size(), 31u);
    for (size_t k = 1; k < accelerated->history.size(); ++k) {
      EXPECT_LE(accelerated->history[k].energy, accelerated->history[k - 1].energy)
          << "iteration " << k;
    }
    EXPECT_LE(accelerated->history.back().energy, plain->history.back().energy);
    // The handles stay exact: every mix of feasible iterates is feasible.
    EXPECT_EQ(test::gather_rows(accelerated->V, setup->constrained), setup->targets);
    // Plain ARAP after 60 iterations is not better than accelerated after 30.
    solver->reset();
    auto plain_longer = solver->solve(setup->targets, arap_options(0, 60));
    ASSERT_TRUE(plain_longer.ok());
    EXPECT_LE(accelerated->history.back().energy, plain_longer->history.back().energy * 1.001);
  }
}

TEST(ArapAnderson, OnByDefaultAndTheFirstIterationIsThePlainOne) {
  EXPECT_GT(SolveOptions{}.anderson_window, 0);
  const auto bench = make_bar(12, 4);
  const auto setup = constraints_from_selection(bench.mesh.V, bench.selection, bench.transform);
  ASSERT_TRUE(setup.ok());
  // One iteration: Anderson's first step is the plain update, bit for bit (interactive moves
  // with a one-iteration budget are unchanged).
  auto plain = deform_arap(bench.mesh.V, bench.mesh.F, setup->constrained, setup->targets,
                           arap_options(0, 1));
  auto accelerated = deform_arap(bench.mesh.V, bench.mesh.F, setup->constrained, setup->targets,
                                 arap_options(SolveOptions{}.anderson_window, 1));
  ASSERT_TRUE(plain.ok() && accelerated.ok());
  EXPECT_EQ(plain->V, accelerated->V);
}

SolveOptions scale_aware_options(int window, int iterations, double rigidity) {
  SolveOptions options = arap_options(window, iterations);
  options.rigidity = rigidity;
  // From the Laplacian guess, far from the solution, where acceleration has work to do (Auto's
  // rigid start at rigidity > 0 begins at ARAP's converged result, where the plain and the
  // accelerated iterations end within round-off of each other's energy).
  options.start = StartFrom::Laplacian;
  return options;
}

// The scale-aware outer iteration accelerated: at the paper's setting and with scale control, a
// lower energy than the plain iteration at equal iteration counts on the small suite, and the
// safeguard's contract: every accepted iterate's energy after step two stays below its energy
// entering step two (the block steps are still exact), and the handles land as in the plain run.
TEST(ScaleAwareAnderson, ReachesLowerEnergyAtEqualIterations) {
  for (const auto& bench : {make_cylinder(20, 21), make_bar(20, 6), make_cactus(2)}) {
    for (const double rigidity : {0.0, 3.0, 30.0}) {
      SCOPED_TRACE(bench.name + " rigidity " + std::to_string(rigidity));
      const auto setup =
          constraints_from_selection(bench.mesh.V, bench.selection, bench.transform);
      ASSERT_TRUE(setup.ok());
      auto solver = ScaleAwareSolver::create(bench.mesh.V, bench.mesh.F, setup->constrained);
      ASSERT_TRUE(solver.ok());
      auto plain = solver->solve(setup->targets, scale_aware_options(0, 20, rigidity));
      ASSERT_TRUE(plain.ok());
      EXPECT_EQ(plain->anderson_rejections, 0);
      solver->reset();
      auto accelerated = solver->solve(setup->targets, scale_aware_options(6, 20, rigidity));
      ASSERT_TRUE(accelerated.ok());
      ASSERT_EQ(accelerated->history.size(), 21u);
      for (size_t k = 1; k < accelerated->history.size(); ++k) {
        const IterationInfo& info = accelerated->history[k];
        EXPECT_LE(info.energy, info.energy_before * (1 + 1e-9)) << "iteration " << k;
      }
      // Not claimed for the paper's method on the twisted bar: there the accelerated iterate
      // settles on a slower path (energy 0.70 against the plain 0.60 at 20 iterations, small
      // bar) while the plain iteration leaves it at iteration ~10; E_theta and E_phi are lower
      // on the accelerated path all the same (0.127 / 0.225 against 0.138 / 0.259).
      if (!(bench.name == "bar" && rigidity == 0)) {
        // Equal or lower: where both have converged (the cylinder at rigidity 3) they agree to
        // about 1e-5.
        EXPECT_LE(accelerated->history.back().energy, plain->history.back().energy * (1 + 1e-4));
      }
      EXPECT_LT(accelerated->anderson_rejections, 20);
      const double handle_error =
          (test::gather_rows(accelerated->V, setup->constrained) - setup->targets)
              .rowwise()
              .norm()
              .maxCoeff();
      const double plain_error = (test::gather_rows(plain->V, setup->constrained) - setup->targets)
                                     .rowwise()
                                     .norm()
                                     .maxCoeff();
      EXPECT_LE(handle_error, 2 * plain_error + 1e-9);
    }
  }
}

TEST(ScaleAwareAnderson, OnByDefaultAndTheFirstIterationIsThePlainOne) {
  const auto bench = make_bar(12, 4);
  const auto setup = constraints_from_selection(bench.mesh.V, bench.selection, bench.transform);
  ASSERT_TRUE(setup.ok());
  for (const double rigidity : {0.0, 3.0}) {
    auto plain = deform_scale_aware(bench.mesh.V, bench.mesh.F, setup->constrained,
                                    setup->targets, scale_aware_options(0, 1, rigidity));
    auto accelerated =
        deform_scale_aware(bench.mesh.V, bench.mesh.F, setup->constrained, setup->targets,
                           scale_aware_options(SolveOptions{}.anderson_window, 1, rigidity));
    ASSERT_TRUE(plain.ok() && accelerated.ok());
    EXPECT_EQ(plain->V, accelerated->V);
  }
  // Two iterations differ: the second iterate is a mix (or the safeguard's plain update).
  auto plain = deform_scale_aware(bench.mesh.V, bench.mesh.F, setup->constrained, setup->targets,
                                  scale_aware_options(0, 3, 3.0));
  auto accelerated = deform_scale_aware(bench.mesh.V, bench.mesh.F, setup->constrained,
                                        setup->targets, scale_aware_options(6, 3, 3.0));
  ASSERT_TRUE(plain.ok() && accelerated.ok());
  EXPECT_NE(plain->V, accelerated->V);
}

}  // namespace
}  // namespace meshdeform::core
