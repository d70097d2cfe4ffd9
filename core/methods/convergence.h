#pragma once
/// @file convergence.h
/// The one stopping rule of the iterative solves (issue 41): when an outer iteration counts as
/// converged, the same for the CLI's report, the server's `converged` flag and the benchmarks.
///
/// The rule watches the energy E_k after each outer iteration k (E_0: the start) through its
/// relative changes d_k = |E_k - E_(k-1)| / E_(k-1) and their ratios q_k = d_k / d_(k-1), which
/// estimate the iteration's linear rate. If the iteration converges linearly at rate q, the
/// energy still has about d_k q / (1 - q) to travel, so r_k = d_k / (1 - q) bounds the relative
/// change from E_(k-1) to the limit: the estimated relative distance of the energy from where
/// the iteration is heading. The rule stops at
///
///     r_(k-1) <= tolerance  and  r_k <= tolerance,   r_k = d_k / (1 - q),
///     q = min(q_max, max(q_k, q_(k-1))),
///
/// It is scale-free twice over: relative changes do not depend on the mesh's units or size, and
/// the rate term does not depend on how fast the iteration moves, which is what changes with
/// the resolution (a slow tail of a fine mesh moves little per iteration yet has far to go: a
/// plain change test calls it converged too early, and at a different distance on every mesh).
/// Guards, each measured to be needed (docs/multilevel.md): the two latest ratios against one
/// lucky small ratio; q_max = 0.95 caps the estimate at 20 changes; an energy that turns
/// around (the change changes sign: the scale-aware energy is not monotone, its minimum along
/// the way is not its limit) counts as q_max; and the test must hold at two consecutive
/// iterations, because a turning point's change is small by construction. d_1 (from the start)
/// and q_2 are not used: the start's energy is measured with the start's own face normals,
/// before step one smooths them, so its first change is not part of the iteration's rate. The
/// earliest stop is at k = 3. An energy at the floor (an exact fit: rest pose, rigid motion,
/// uniform scaling) stops at once.
///
/// A solve that continues the previous one (the same targets and options, from its result) may
/// carry the monitor over (ScaleAwareSolver does), so that short solves in a row (the server's
/// background refinement: a few iterations at a time) are judged as the one long solve they
/// make up.
///
/// StoppingRule::Change is the rule of the solvers before issue 41, kept so that their results
/// stay reachable: d_k < tolerance.

#include <string_view>

namespace meshdeform::core {

/// Which stopping rule an iterative solve uses (SolveOptions::stopping_rule).
enum class StoppingRule {
  /// The estimated remaining relative energy change (above): the default.
  Remaining,
  /// The last relative energy change alone, d_k < tolerance (the rule before issue 41).
  Change,
};

/// "remaining", "change".
const char* stopping_rule_name(StoppingRule rule);
/// One sentence stating the rule, for reports.
const char* stopping_rule_description(StoppingRule rule);

/// The stopping test of one iteration sequence; feed it the start's energy, then each
/// iteration's. Deterministic: energies in, a verdict out.
class ConvergenceMonitor {
 public:
  /// Largest rate the Remaining rule assumes.
  static constexpr double kMaxRate = 0.95;

  /// @param rule       the rule.
  /// @param tolerance  >= 0; 0 never stops (except at the floor).
  /// @param floor      the energy below which the fit is exact (>= 0).
  ConvergenceMonitor(StoppingRule rule, double tolerance, double floor);

  /// The start's energy (iteration 0). Returns true when it is already at the floor.
  bool start(double energy);
  /// The energy after iteration k = 1, 2, ... Returns true when the rule holds.
  bool add(double energy);

  /// The last relative change d_k (1 before any iteration).
  double last_change() const { return last_change_; }
  /// The last estimate d_k / (1 - q) of the Remaining rule (d_k for Change; infinity before
  /// the rule can hold).
  double estimated_remaining() const { return remaining_; }
  /// Iterations added since start().
  int iterations() const { return iterations_; }
  /// Whether `other` judges with the same rule, tolerance and floor (a monitor to carry over).
  bool same_test(const ConvergenceMonitor& other) const {
    return rule_ == other.rule_ && tolerance_ == other.tolerance_ && floor_ == other.floor_;
  }

 private:
  StoppingRule rule_;
  double tolerance_;
  double floor_;
  double previous_energy_ = 0;
  double last_change_ = 1;
  double change_before_ = 0;       // d_(k-1)
  double signed_before_ = 0;       // E_(k-1) - E_(k-2)
  double rate_before_ = 0;         // q_(k-1), negative when unknown
  double remaining_;
  bool held_before_ = false;       // r_(k-1) <= tolerance
  int iterations_ = 0;
};

}  // namespace meshdeform::core
