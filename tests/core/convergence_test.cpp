// The stopping rule (core/methods/convergence.h): energies in, a verdict out.
#include "core/methods/convergence.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

namespace meshdeform::core {
namespace {

// Feeds E_k = limit + gap * rate^k (k = 0 the start) until the monitor stops or `budget` runs
// out; returns the iteration it stopped at (0: never).
int stop_iteration(ConvergenceMonitor& monitor, double limit, double gap, double rate, int budget,
                   double* energy_at_stop = nullptr) {
  if (monitor.start(limit + gap)) return 0;
  for (int k = 1; k <= budget; ++k) {
    const double energy = limit + gap * std::pow(rate, k);
    if (monitor.add(energy)) {
      if (energy_at_stop != nullptr) *energy_at_stop = energy;
      return k;
    }
  }
  return 0;
}

TEST(ConvergenceMonitor, RemainingRuleStopsWhenTheTrueRemainingChangeIsNearTheTolerance) {
  // A linear tail: the rule's estimate d_k / (1 - q) is the true remaining relative change
  // (E_(k-1) - E*) / E_(k-1) of a geometric sequence, so the stop lands at the tolerance for
  // slow and fast rates alike, where the last-change rule stops early on slow ones.
  constexpr double kTolerance = 1e-3;
  for (const double rate : {0.3, 0.7, 0.9}) {
    SCOPED_TRACE(rate);
    ConvergenceMonitor monitor(StoppingRule::Remaining, kTolerance, 0.0);
    double energy = 0;
    const int k = stop_iteration(monitor, 1.0, 1.0, rate, 1000, &energy);
    ASSERT_GT(k, 0);
    EXPECT_GE(k, 3) << "the earliest stop is at k = 3";
    // Where it stopped, the energy is within the tolerance of the limit (relative) ...
    EXPECT_LE((energy - 1.0) / energy, kTolerance);
    // ... and one iteration earlier it was not yet (it stops no later than it needs to, up to the
    // two-in-a-row guard).
    const double two_before = 1.0 + std::pow(rate, k - 2);
    EXPECT_GT((two_before - 1.0) / two_before, kTolerance * rate);
  }
  // The last-change rule on the same slow tail stops while the energy is still far away.
  ConvergenceMonitor change(StoppingRule::Change, 1e-3, 0.0);
  double energy = 0;
  ASSERT_GT(stop_iteration(change, 1.0, 1.0, 0.99, 5000, &energy), 0);
  EXPECT_GT((energy - 1.0) / energy, 1e-2);
  ConvergenceMonitor remaining(StoppingRule::Remaining, 1e-3, 0.0);
  ASSERT_GT(stop_iteration(remaining, 1.0, 1.0, 0.99, 5000, &energy), 0);
  // The rate is capped at 0.95: the estimate is 20 changes, a lower bound on a slower tail.
  EXPECT_LT((energy - 1.0) / energy, 1e-3 * (1 - 0.95) / (1 - 0.99) * 1.01);
}

TEST(ConvergenceMonitor, IsScaleFree) {
  // The same sequence in other units (energy scaled by a power of two: bit for bit the same
  // relative changes) stops at the same iteration.
  for (const StoppingRule rule : {StoppingRule::Remaining, StoppingRule::Change}) {
    ConvergenceMonitor a(rule, 1e-4, 0.0), b(rule, 1e-4, 0.0);
    EXPECT_EQ(stop_iteration(a, 2.0, 3.0, 0.8, 1000), stop_iteration(b, 2048.0, 3072.0, 0.8, 1000));
  }
}

TEST(ConvergenceMonitor, AnEnergyThatTurnsAroundIsNotConverged) {
  // A small change at a turning point (the scale-aware energy is not monotone) must not stop it.
  ConvergenceMonitor monitor(StoppingRule::Remaining, 1e-3, 0.0);
  ASSERT_FALSE(monitor.start(10.0));
  EXPECT_FALSE(monitor.add(5.0));
  EXPECT_FALSE(monitor.add(3.0));
  EXPECT_FALSE(monitor.add(2.0));
  EXPECT_FALSE(monitor.add(2.0001));  // turned: counts as rate 0.95, estimate 20 x 5e-5 = 1e-3 ...
  EXPECT_FALSE(monitor.add(2.5));     // ... and it rises on
  EXPECT_GT(monitor.estimated_remaining(), 1e-3);
}

TEST(ConvergenceMonitor, FloorStopsAtOnceAndChangeRuleIsTheOldTest) {
  ConvergenceMonitor at_floor(StoppingRule::Remaining, 1e-3, 1e-20);
  EXPECT_TRUE(at_floor.start(1e-25));
  ConvergenceMonitor reaching(StoppingRule::Remaining, 1e-3, 1e-20);
  ASSERT_FALSE(reaching.start(1.0));
  EXPECT_TRUE(reaching.add(0.0)) << "an exact fit stops after one iteration";

  // Change: d_k < tolerance, as the solvers tested before issue 41.
  ConvergenceMonitor change(StoppingRule::Change, 1e-2, 0.0);
  ASSERT_FALSE(change.start(1.0));
  EXPECT_FALSE(change.add(0.5));
  EXPECT_TRUE(change.add(0.496));  // 0.8% change
  EXPECT_DOUBLE_EQ(change.last_change(), 0.004 / 0.5);
  EXPECT_DOUBLE_EQ(change.estimated_remaining(), change.last_change());

  // Tolerance 0 never stops above the floor while the energy still changes (2^-40 is far
  // above 1's round-off).
  ConvergenceMonitor never(StoppingRule::Remaining, 0.0, 0.0);
  EXPECT_EQ(stop_iteration(never, 1.0, 1.0, 0.5, 40), 0);
}

TEST(ConvergenceMonitor, EstimateIsInfiniteUntilItCanBeFormed) {
  ConvergenceMonitor monitor(StoppingRule::Remaining, 1e-3, 0.0);
  ASSERT_FALSE(monitor.start(1.0));
  EXPECT_TRUE(std::isinf(monitor.estimated_remaining()));
  EXPECT_FALSE(monitor.add(0.5));
  EXPECT_TRUE(std::isinf(monitor.estimated_remaining())) << "d_1 is not used";
  EXPECT_FALSE(monitor.add(0.25));
  EXPECT_TRUE(std::isfinite(monitor.estimated_remaining()));
  EXPECT_EQ(monitor.iterations(), 2);
  EXPECT_TRUE(monitor.same_test(ConvergenceMonitor(StoppingRule::Remaining, 1e-3, 0.0)));
  EXPECT_FALSE(monitor.same_test(ConvergenceMonitor(StoppingRule::Remaining, 1e-4, 0.0)));
  EXPECT_FALSE(monitor.same_test(ConvergenceMonitor(StoppingRule::Change, 1e-3, 0.0)));
}

}  // namespace
}  // namespace meshdeform::core
