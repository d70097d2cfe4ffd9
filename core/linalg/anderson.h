#pragma once
/// @file anderson.h
/// Anderson acceleration of a fixed-point iteration x <- G(x), for local/global solvers (ARAP, the
/// scale-aware outer loop): Peng, Deng, Zhang, Liu, "Anderson Acceleration for Geometry
/// Optimization and Physics Simulation", SIGGRAPH 2018 (after Walker & Ni 2011). Header-only,
/// plain Eigen.
///
/// Each step takes g = G(x_k) and returns x_{k+1} = g - dG theta, where theta minimises
/// ||f_k - dF theta|| over the last m residual differences (f = G(x) - x; dF, dG the differences
/// of consecutive residuals and maps, each column scaled by its dF norm). The least-squares problem
/// is solved through its m x m normal equations with a complete orthogonal decomposition (rank
/// deficient windows happen when an iteration stalls), updated one row per step.
///
/// Anderson steps are not descent steps: callers that minimise an energy must guard them. The
/// driver anderson_minimize() does: an accelerated iterate whose energy is not below the last
/// accepted one is replaced by the plain update G(x_k) and the window restarts there (Peng et al.,
/// Algorithm 1), so the accepted energies never increase when the plain iteration never increases
/// them.

#include <algorithm>
#include <cmath>
#include <limits>

#include <Eigen/Core>
#include <Eigen/QR>

namespace meshdeform::core {

/// The accelerator's state: the last m differences of residuals and of map values.
class AndersonAccelerator {
 public:
  /// @param[in] window  m, the number of past steps mixed (at least 1; 5-10 is typical).
  explicit AndersonAccelerator(int window) : m_(std::max(window, 1)) {}

  /// Starts (or restarts) from the accepted iterate x, forgetting the window.
  void reset(const Eigen::Ref<const Eigen::VectorXd>& x) {
    if (dF_.rows() != x.size()) {
      dF_.resize(x.size(), m_);
      dG_.resize(x.size(), m_);
    }
    gram_.setZero(m_, m_);
    x_ = x;
    steps_ = 0;
    column_ = 0;
  }

  /// One step: `g` = G(x) for the current iterate x (the last reset() argument or the last
  /// value returned). Returns the accelerated iterate, which becomes the current one. Falls back
  /// to g itself (and restarts the window) if the mixing coefficients are not finite.
  const Eigen::VectorXd& compute(const Eigen::Ref<const Eigen::VectorXd>& g) {
    f_ = g - x_;
    if (steps_ == 0) {
      dF_.col(0) = -f_;
      dG_.col(0) = -g;
      x_ = g;
      ++steps_;
      return x_;
    }
    dF_.col(column_) += f_;
    dG_.col(column_) += g;
    const double norm = std::max(dF_.col(column_).norm(), std::numeric_limits<double>::min());
    dF_.col(column_) /= norm;
    dG_.col(column_) /= norm;
    const int used = std::min(m_, steps_);
    for (int j = 0; j < used; ++j) {
      gram_(column_, j) = gram_(j, column_) = dF_.col(column_).dot(dF_.col(j));
    }
    rhs_ = dF_.leftCols(used).transpose() * f_;
    theta_ = gram_.topLeftCorner(used, used).completeOrthogonalDecomposition().solve(rhs_);
    if (!theta_.allFinite()) {
      reset(g);
      x_ = g;
      return x_;
    }
    x_ = g - dG_.leftCols(used) * theta_;
    column_ = (column_ + 1) % m_;
    dF_.col(column_) = -f_;
    dG_.col(column_) = -g;
    ++steps_;
    return x_;
  }

  /// The current iterate.
  const Eigen::VectorXd& current() const { return x_; }
  int window() const { return m_; }

 private:
  int m_;
  int steps_ = 0;
  int column_ = 0;
  Eigen::MatrixXd dF_, dG_;
  Eigen::MatrixXd gram_;
  Eigen::VectorXd x_, f_, rhs_, theta_;
};

/// Options of anderson_minimize.
struct AndersonOptions {
  int window = 6;            ///< m (0: no acceleration, the plain iteration)
  int max_iterations = 100;  ///< accepted steps
  double tolerance = 1e-4;   ///< stop when the relative energy change falls below this
};

/// What anderson_minimize did.
struct AndersonReport {
  int iterations = 0;  ///< accepted steps
  int rejected = 0;    ///< accelerated iterates replaced by the plain update (safeguard)
  bool converged = false;
  double energy = 0;  ///< energy of the final iterate
};

/// Minimises an energy by a safeguarded, Anderson-accelerated fixed-point iteration.
/// `energy(x)` returns E(x); `map(x)` returns G(x). Contract that lets a local/global solver share
/// work: map() is only ever called on the argument of the most recent energy() call (so energy()
/// may cache the local step, e.g. ARAP's rotations, for map() to use). Each step costs one map()
/// and one energy(), plus one more energy() when the safeguard rejects the accelerated iterate.
/// @param[in,out] x  start, then the result.
template <typename EnergyFn, typename MapFn>
AndersonReport anderson_minimize(Eigen::VectorXd& x, EnergyFn&& energy, MapFn&& map,
                                 const AndersonOptions& options) {
  AndersonReport report;
  double e = energy(x);
  AndersonAccelerator accelerator(options.window);
  accelerator.reset(x);
  for (int it = 0; it < options.max_iterations; ++it) {
    const Eigen::VectorXd g = map(x);
    double e_next;
    if (options.window > 0) {
      const Eigen::VectorXd& candidate = accelerator.compute(g);
      const double e_candidate = energy(candidate);
      if (e_candidate < e) {
        x = candidate;
        e_next = e_candidate;
      } else {
        ++report.rejected;
        x = g;
        e_next = energy(x);
        accelerator.reset(x);
      }
    } else {
      x = g;
      e_next = energy(x);
    }
    ++report.iterations;
    const double change = std::abs(e - e_next) / std::max(std::abs(e), 1e-300);
    e = e_next;
    if (change < options.tolerance) {
      report.converged = true;
      break;
    }
  }
  report.energy = e;
  return report;
}

}  // namespace meshdeform::core
