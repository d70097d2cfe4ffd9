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
  /// When on, every numeric factorization is followed by a conversion of the supernodal factor to
  /// CHOLMOD's simplicial form (cholmod_change_factor, one O(nnz(L)) copy): supernodal is the
  /// fast way to factor, simplicial the fast way to solve with a few right-hand sides (the
  /// supernodal solve spends its time in small BLAS calls). Measured with 3 right-hand sides on
  /// mesh Laplacians (bench/README.md): 1.4x faster solves at 5k vertices, 1.8x at 47k, 1.4x at
  /// 333k. A simplicial factor cannot be refactored supernodally, so the next factorize() first
  /// repeats the symbolic analysis: worth it for factors kept for many solves (ARAP's), not for a
  /// factor refreshed often. Off by default.
  void set_simplicial_solves(bool on);
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
