#pragma once
/// @file sparse_cholesky.h
/// Internal to core: a sparse Cholesky factorization (CHOLMOD supernodal) that keeps its symbolic
/// analysis across numeric refactorizations and reports flop counts, so callers can decide
/// deterministically when a lagged factor stops paying for itself.

#include <memory>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "core/status.h"

namespace meshdeform::core {

using SparseMatrix = Eigen::SparseMatrix<double, Eigen::ColMajor, int>;

class SparseCholesky {
 public:
  SparseCholesky();
  SparseCholesky(SparseCholesky&&) noexcept;
  SparseCholesky& operator=(SparseCholesky&&) noexcept;
  ~SparseCholesky();

  /// Symbolic analysis (fill-reducing ordering) of the lower triangle of A's pattern.
  [[nodiscard]] Status analyze(const SparseMatrix& A);
  /// Numeric factorization of A (same pattern as analyze()); NumericalFailure if A is not SPD.
  [[nodiscard]] Status factorize(const SparseMatrix& A);
  /// x = A^-1 b with the current factor (b may have several columns).
  Eigen::MatrixXd solve(const Eigen::MatrixXd& b) const;

  bool is_factorized() const;
  /// Flops of one numeric factorization, from the symbolic analysis.
  double factor_flops() const;
  /// Flops of one solve with one right-hand side (forward and back substitution).
  double solve_flops() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace meshdeform::core
