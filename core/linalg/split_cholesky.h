#pragma once
/// @file split_cholesky.h
/// Internal to core: the Cholesky factorization of a large sparse SPD system over mesh vertices,
/// factored and solved on two threads by splitting the mesh in two (one level of nested
/// dissection, done by hand because CHOLMOD runs on one core here: BLAS is single-threaded,
/// see sparse_cholesky.cpp).
///
/// The unknowns are split at the median of their positions along the bounding box's longest
/// axis; the unknowns of the first half with a neighbour in the second (in A's graph) form the
/// separator S, and the rest the interiors I1 and I2, which no entry of A couples:
///
///     A = [A1 0 B1; 0 A2 B2; B1' B2' C].
///
/// Each half's matrix M_i = [A_i B_i; B_i' D_i], with D_i diagonal (twice the separator row's
/// absolute sum in B_i', so M_i is positive definite when A is diagonally dominant, as a
/// Laplacian with Dirichlet rows is), is factored by CHOLMOD with the separator ordered last
/// (CAMD), the two halves on their own threads; each half is factored supernodally and kept in
/// simplicial form without the supernodes' zeros for the solves (supernodal_to_simplicial: on
/// Spot 187k the prolongation's set-up took 0.62-0.70 s with simplicial halves and 0.42-0.63 s
/// so, four alternated runs, its solves unchanged). The trailing block L33_i of M_i's factor gives
/// B_i' A_i^-1 B_i = D_i - L33_i L33_i', so the Schur complement of the separator,
/// C - sum_i B_i' A_i^-1 B_i, is a small dense matrix (a few hundred rows on a 200k-vertex
/// mesh), factored densely. A solve is a forward substitution in each half (side by side),
/// a dense solve on the separator and a back substitution in each half:
///
///     forward  [y_I; y_S] = L_i^-1 P_i [b_I; 0],   B_i' A_i^-1 b_I = -L33_i y_S,
///     x_S = Schur^-1 (b_S - sum_i B_i' A_i^-1 b_I),
///     back     [x_I; .] = P_i' L_i^-T [y_I; L33_i' x_S].
///
/// Measured on the prolongation system of Spot 187k (177k unknowns, 531 on the separator, this
/// 2-core machine): factor 0.46-0.52 s against 0.96-1.06 s for the whole system, a solve with
/// three right-hand sides 25-28 ms against 37-44 ms; on one thread the split is no faster, so
/// it is only used with two. Smaller systems, separators above `max_separator` and a half that
/// is not positive definite (A not diagonally dominant) factor the whole system instead.

#include <Eigen/Core>
#include <memory>
#include <stop_token>

#include "core/mesh/mesh_data.h"
#include "core/linalg/sparse_cholesky.h"
#include "core/base/status.h"

namespace meshdeform::core {

struct SplitCholeskySettings {
  /// Threads for the halves: the split is used with 2 or more (2 are used), never with 1.
  int threads = 1;
  /// Systems with fewer rows are factored whole.
  int min_rows = 20000;
  /// Largest separator: its Schur complement is dense (m^2 doubles, m^3 flops); above, or
  /// above a sixteenth of the rows, the system is factored whole.
  int max_separator = 2000;
};

class SplitCholesky {
 public:
  SplitCholesky();
  SplitCholesky(SplitCholesky&&) noexcept;
  SplitCholesky& operator=(SplitCholesky&&) noexcept;
  ~SplitCholesky();

  /// Factors the SPD matrix A (both triangles stored), whose unknown k sits at points.row(k).
  /// @return NumericalFailure if A is not positive definite; Cancelled when `stop` is
  ///         requested (checked between the phases).
  [[nodiscard]] Status factorize(const SparseMatrix& A, const Positions& points,
                                 const SplitCholeskySettings& settings,
                                 const std::stop_token& stop = {});
  /// x = A^-1 b (b may have several columns); safe to call from several threads at once.
  Eigen::MatrixXd solve(const Eigen::MatrixXd& b) const;

  bool is_factorized() const;
  /// True when the system was factored in two halves (false: whole).
  bool is_split() const;
  /// Unknowns on the separator (0 when not split).
  int separator_size() const;

 private:
  struct Half;
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace meshdeform::core
