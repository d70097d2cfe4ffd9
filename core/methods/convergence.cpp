#include "core/methods/convergence.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace meshdeform::core {

const char* stopping_rule_name(StoppingRule rule) {
  switch (rule) {
    case StoppingRule::Remaining:
      return "remaining";
    case StoppingRule::Change:
      return "change";
  }
  return "remaining";
}

const char* stopping_rule_description(StoppingRule rule) {
  switch (rule) {
    case StoppingRule::Remaining:
      return "converged when the estimated remaining relative energy change d_k / (1 - q) is at "
             "most the tolerance at two consecutive iterations (d_k the last relative change, q "
             "the larger of the last two change ratios, 0.95 where the energy turned around, at "
             "most 0.95; the change from the start not used), or the energy is at the exact-fit "
             "floor";
    case StoppingRule::Change:
      return "converged when the last relative energy change is below the tolerance, or the "
             "energy is at the exact-fit floor";
  }
  return "";
}

ConvergenceMonitor::ConvergenceMonitor(StoppingRule rule, double tolerance, double floor)
    : rule_(rule),
      tolerance_(tolerance),
      floor_(floor),
      remaining_(std::numeric_limits<double>::infinity()) {}

bool ConvergenceMonitor::start(double energy) {
  previous_energy_ = energy;
  last_change_ = 1;
  change_before_ = 0;
  signed_before_ = 0;
  rate_before_ = -1;
  remaining_ = std::numeric_limits<double>::infinity();
  held_before_ = false;
  iterations_ = 0;
  return energy <= floor_;
}

bool ConvergenceMonitor::add(double energy) {
  ++iterations_;
  const double signed_change = energy - previous_energy_;
  const double change = std::abs(signed_change) / std::max(previous_energy_, floor_);
  previous_energy_ = energy;
  last_change_ = change;
  const bool at_floor = energy <= floor_;
  if (rule_ == StoppingRule::Change) {
    remaining_ = change;
    return at_floor || change < tolerance_;
  }
  // Rates from the second change on (d_1 is measured from the start's own normals); a change of
  // sign (the energy turned around) is no geometric decay.
  double rate = -1;
  if (iterations_ >= 3) {
    const bool turned = (signed_change > 0) != (signed_before_ > 0);
    rate = turned || !(change_before_ > 0) ? kMaxRate : std::min(kMaxRate, change / change_before_);
  }
  bool holds = false;
  if (iterations_ >= 2) {
    const double q = rate < 0 ? kMaxRate : std::max(rate, rate_before_);
    remaining_ = change / (1.0 - std::min(q, kMaxRate));
    holds = remaining_ <= tolerance_;
  }
  const bool converged = at_floor || (holds && held_before_);
  held_before_ = holds;
  change_before_ = change;
  signed_before_ = signed_change;
  rate_before_ = rate;
  return converged;
}

}  // namespace meshdeform::core
