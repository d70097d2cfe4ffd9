// Tests of the CHOLMOD wrapper (core/linalg/sparse_cholesky.h): solves of random sparse SPD systems
// against Eigen's SimplicialLDLT, several right-hand sides at once, numeric refactorization on the
// same pattern (supernodal and with simplicial solves), a NumericalFailure status (not a crash)
// for indefinite and singular matrices with recovery afterwards, and moves.
#include "core/linalg/sparse_cholesky.h"

#include <gtest/gtest.h>

#include <Eigen/CholmodSupport>
#include <Eigen/Eigenvalues>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <random>
#include <string>
#include <utility>
#include <vector>

namespace meshdeform::core {
namespace {

/// A random sparse SPD matrix: M^T M + shift I with M sparse (about `per_row` entries a row)
/// plus a band so that the factor has fill. Same seed and per_row: same pattern; `shift` and
/// `value_seed` change only the values.
SparseMatrix random_spd(int n, int per_row, double shift, unsigned pattern_seed,
                        unsigned value_seed) {
  std::mt19937 pattern_rng(pattern_seed);
  std::mt19937 value_rng(value_seed);
  std::uniform_int_distribution<int> column(0, n - 1);
  std::uniform_real_distribution<double> value(-1.0, 1.0);
  std::vector<Eigen::Triplet<double>> entries;
  for (int i = 0; i < n; ++i) {
    entries.emplace_back(i, i, 1.0 + value(value_rng));
    if (i + 1 < n) entries.emplace_back(i, i + 1, value(value_rng));
    for (int k = 0; k < per_row; ++k)
      entries.emplace_back(i, column(pattern_rng), value(value_rng));
  }
  SparseMatrix M(n, n);
  M.setFromTriplets(entries.begin(), entries.end());
  SparseMatrix I(n, n);
  I.setIdentity();
  SparseMatrix A = SparseMatrix(M.transpose()) * M + shift * I;
  A.makeCompressed();
  return A;
}

Eigen::MatrixXd random_rhs(int n, int columns, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> value(-1.0, 1.0);
  Eigen::MatrixXd b(n, columns);
  for (Eigen::Index i = 0; i < b.size(); ++i) b.data()[i] = value(rng);
  return b;
}

double relative_residual(const SparseMatrix& A, const Eigen::MatrixXd& x,
                         const Eigen::MatrixXd& b) {
  return (A * x - b).norm() / b.norm();
}

Eigen::MatrixXd ldlt_solve(const SparseMatrix& A, const Eigen::MatrixXd& b) {
  Eigen::SimplicialLDLT<SparseMatrix> ldlt(A);
  EXPECT_EQ(ldlt.info(), Eigen::Success);
  return ldlt.solve(b);
}

SparseMatrix diagonal(const std::vector<double>& d) {
  SparseMatrix A(static_cast<int>(d.size()), static_cast<int>(d.size()));
  for (size_t i = 0; i < d.size(); ++i) A.insert(int(i), int(i)) = d[i];
  A.makeCompressed();
  return A;
}

TEST(SparseCholesky, SolvesARandomSpdSystemLikeSimplicialLdlt) {
  for (const int n : {50, 400}) {
    SCOPED_TRACE(n);
    const SparseMatrix A = random_spd(n, 3, 0.1, 1, 2);
    const Eigen::MatrixXd b = random_rhs(n, 1, 3);
    SparseCholesky cholesky;
    EXPECT_FALSE(cholesky.is_factorized());
    ASSERT_TRUE(cholesky.analyze(A).ok());
    EXPECT_FALSE(cholesky.is_factorized());
    EXPECT_GT(cholesky.factor_flops(), 0.0);
    // Forward and back substitution touch every entry of L, which holds A's lower triangle.
    const SparseMatrix lower = A.triangularView<Eigen::Lower>();
    EXPECT_GE(cholesky.solve_flops(), 4.0 * static_cast<double>(lower.nonZeros()));
    ASSERT_TRUE(cholesky.factorize(A).ok());
    EXPECT_TRUE(cholesky.is_factorized());
    const Eigen::MatrixXd x = cholesky.solve(b);
    EXPECT_LT(relative_residual(A, x, b), 1e-12);
    const Eigen::MatrixXd reference = ldlt_solve(A, b);
    EXPECT_LT((x - reference).norm(), 1e-9 * reference.norm());
  }
}

TEST(SparseCholesky, SolvesSeveralRightHandSidesAtOnce) {
  const int n = 300;
  const SparseMatrix A = random_spd(n, 4, 0.05, 5, 6);
  const Eigen::MatrixXd B = random_rhs(n, 4, 7);
  SparseCholesky cholesky;
  ASSERT_TRUE(cholesky.factorize(A).ok());  // analyses on its own when analyze() was not called
  const Eigen::MatrixXd X = cholesky.solve(B);
  ASSERT_EQ(X.rows(), n);
  ASSERT_EQ(X.cols(), 4);
  EXPECT_LT(relative_residual(A, X, B), 1e-12);
  for (int c = 0; c < 4; ++c) {
    SCOPED_TRACE(c);
    const Eigen::MatrixXd single = cholesky.solve(B.col(c));
    EXPECT_LT((X.col(c) - single).norm(), 1e-12 * single.norm());
  }
}

class SparseCholeskyRefactor : public ::testing::TestWithParam<bool> {};

TEST_P(SparseCholeskyRefactor, RefactorsNewValuesOnTheSamePattern) {
  const bool simplicial_solves = GetParam();
  const int n = 250;
  const SparseMatrix A1 = random_spd(n, 3, 0.1, 11, 12);
  const SparseMatrix A2 = random_spd(n, 3, 2.0, 11, 13);  // same pattern, other values
  ASSERT_EQ(A1.nonZeros(), A2.nonZeros());
  ASSERT_GT((Eigen::MatrixXd(A1) - Eigen::MatrixXd(A2)).norm(), 1.0);
  const Eigen::MatrixXd b = random_rhs(n, 3, 14);

  SparseCholesky cholesky;
  cholesky.set_simplicial_solves(simplicial_solves);
  ASSERT_TRUE(cholesky.analyze(A1).ok());
  for (int round = 0; round < 2; ++round) {
    SCOPED_TRACE(round);
    ASSERT_TRUE(cholesky.factorize(A1).ok());
    const Eigen::MatrixXd x1 = cholesky.solve(b);
    EXPECT_LT(relative_residual(A1, x1, b), 1e-12);
    ASSERT_TRUE(cholesky.factorize(A2).ok());
    const Eigen::MatrixXd x2 = cholesky.solve(b);
    EXPECT_LT(relative_residual(A2, x2, b), 1e-12);
    EXPECT_LT((x2 - ldlt_solve(A2, b)).norm(), 1e-9 * x2.norm());
    EXPECT_GT((x1 - x2).norm(), 0.1 * x2.norm());  // the new values were used
  }
}

INSTANTIATE_TEST_SUITE_P(SupernodalAndSimplicialSolves, SparseCholeskyRefactor, ::testing::Bool(),
                         [](const auto& info) {
                           return info.param ? "SimplicialSolves" : "Supernodal";
                         });

/// The 5-point Laplacian of a side x side grid plus shift I: a mesh-like, sparse factor.
SparseMatrix grid_laplacian(int side, double shift) {
  std::vector<Eigen::Triplet<double>> entries;
  const auto id = [side](int i, int j) { return i * side + j; };
  for (int i = 0; i < side; ++i) {
    for (int j = 0; j < side; ++j) {
      entries.emplace_back(id(i, j), id(i, j), shift);
      for (const auto& [di, dj] : {std::pair{1, 0}, std::pair{0, 1}}) {
        if (i + di >= side || j + dj >= side) continue;
        const int a = id(i, j), b = id(i + di, j + dj);
        entries.emplace_back(a, a, 1.0);
        entries.emplace_back(b, b, 1.0);
        entries.emplace_back(a, b, -1.0);
        entries.emplace_back(b, a, -1.0);
      }
    }
  }
  SparseMatrix A(side * side, side * side);
  A.setFromTriplets(entries.begin(), entries.end());
  return A;
}

// With simplicial solves a mesh-like sparse matrix is factored simplicially directly and a
// dense-factor one supernodally and converted; both solve, refactor new values and match LDL^T.
TEST(SparseCholesky, SimplicialSolvesFactorSparseMatricesDirectlyAndDenseOnesSupernodally) {
  struct Case {
    const char* name;
    SparseMatrix A1, A2;
    bool direct;
  };
  const std::vector<Case> cases = {
      {"grid", grid_laplacian(40, 0.1), grid_laplacian(40, 2.0), true},
      {"random_graph", random_spd(700, 4, 0.1, 41, 42), random_spd(700, 4, 2.0, 41, 43), false},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    SparseCholesky cholesky;
    cholesky.set_simplicial_solves(true);
    ASSERT_TRUE(cholesky.analyze(c.A1).ok());
    // solve_flops() is 4 per factor entry.
    const double flops_per_entry = cholesky.factor_flops() / (0.25 * cholesky.solve_flops());
    RecordProperty(std::string(c.name) + "_flops_per_entry", std::to_string(flops_per_entry));
    EXPECT_EQ(flops_per_entry < SparseCholesky::kSimplicialFlopsPerEntry, c.direct);
    const Eigen::MatrixXd b = random_rhs(static_cast<int>(c.A1.rows()), 3, 44);
    for (int round = 0; round < 2; ++round) {
      SCOPED_TRACE(round);
      for (const SparseMatrix* A : {&c.A1, &c.A2}) {
        ASSERT_TRUE(cholesky.factorize(*A).ok());
        EXPECT_EQ(cholesky.factored_simplicially(), c.direct);
        const Eigen::MatrixXd x = cholesky.solve(b);
        EXPECT_LT(relative_residual(*A, x, b), 1e-12);
        EXPECT_LT((x - ldlt_solve(*A, b)).norm(), 1e-9 * x.norm());
      }
    }
    // Without simplicial solves every factor is supernodal.
    SparseCholesky supernodal;
    ASSERT_TRUE(supernodal.factorize(c.A1).ok());
    EXPECT_FALSE(supernodal.factored_simplicially());
    const Eigen::MatrixXd x = supernodal.solve(b);
    EXPECT_LT((x - ldlt_solve(c.A1, b)).norm(), 1e-9 * x.norm());
  }
}

/// The pattern of a simplicial CHOLMOD factor, column by column.
std::vector<std::vector<int>> factor_pattern(const cholmod_factor& L) {
  const auto* p = static_cast<const int*>(L.p);
  const auto* i = static_cast<const int*>(L.i);
  const auto* nz = static_cast<const int*>(L.nz);
  std::vector<std::vector<int>> columns(L.n);
  for (size_t j = 0; j < L.n; ++j) columns[j].assign(i + p[j], i + p[j] + nz[j]);
  return columns;
}

/// Blocks [4 2 2; 2 5 1; 2 1 6] along the diagonal, each coupled to a last, heavier unknown:
/// the factor's (3, 2) entry of every block is exactly 0 (1 - 1 * 1, over 2) though it is in the
/// symbolic pattern, since A's is not.
SparseMatrix blocks_with_cancellation(int blocks) {
  const int n = 3 * blocks + 1;
  std::vector<Eigen::Triplet<double>> entries;
  const double block[3][3] = {{4, 2, 2}, {2, 5, 1}, {2, 1, 6}};
  for (int b = 0; b < blocks; ++b) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) entries.emplace_back(3 * b + r, 3 * b + c, block[r][c]);
      entries.emplace_back(n - 1, 3 * b + r, 0.25);
      entries.emplace_back(3 * b + r, n - 1, 0.25);
    }
  }
  entries.emplace_back(n - 1, n - 1, 4.0 * n);
  SparseMatrix A(n, n);
  A.setFromTriplets(entries.begin(), entries.end());
  A.makeCompressed();
  return A;
}

TEST(SparseCholesky, SupernodalToSimplicialGivesTheSimplicialFactorsPatternAndSolutions) {
  // A supernodal factor with relaxed supernodes (CHOLMOD's defaults) stores explicit zeros;
  // converted, it must have the pattern of the directly simplicial factor (same ordering),
  // including entries that are zero by exact cancellation, and solve like it.
  struct Case {
    const char* name;
    SparseMatrix A;
    bool has_cancellations;
  };
  const std::vector<Case> cases = {{"grid", grid_laplacian(60, 0.1), false},
                                   {"cancellation", blocks_with_cancellation(400), true}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const SparseMatrix& A = c.A;
    const Eigen::MatrixXd b = random_rhs(static_cast<int>(A.rows()), 3, 45);
    cholmod_common common;
    cholmod_start(&common);
    common.print = 0;
    cholmod_sparse view = Eigen::viewAsCholmod(std::as_const(A).selfadjointView<Eigen::Lower>());
    std::vector<int> perm;  // the supernodal factor's ordering, given to the simplicial one
    std::vector<std::vector<int>> patterns[2];
    Eigen::MatrixXd solutions[2];
    bool zero_in_pattern = false;
    for (int simplicial = 0; simplicial < 2; ++simplicial) {
      SCOPED_TRACE(simplicial);
      common.supernodal = simplicial ? CHOLMOD_SIMPLICIAL : CHOLMOD_SUPERNODAL;
      common.final_ll = 1;
      if (simplicial) {
        common.nmethods = 1;
        common.method[0].ordering = CHOLMOD_GIVEN;
        common.postorder = 0;
      }
      cholmod_factor* L =
          cholmod_analyze_p(&view, simplicial ? perm.data() : nullptr, nullptr, 0, &common);
      ASSERT_NE(L, nullptr);
      ASSERT_TRUE(cholmod_factorize(&view, L, &common));
      ASSERT_EQ(L->minor, L->n);
      if (!simplicial) {
        ASSERT_TRUE(L->is_super);
        perm.assign(static_cast<const int*>(L->Perm), static_cast<const int*>(L->Perm) + L->n);
        ASSERT_TRUE(supernodal_to_simplicial(L, &view, &common));
        EXPECT_FALSE(L->is_super);
        EXPECT_TRUE(L->is_ll);
        const auto columns = factor_pattern(*L);
        size_t entries = 0;
        for (const auto& column : columns) entries += column.size();
        EXPECT_EQ(L->nzmax, entries);  // the arrays shrank to the pattern
        const auto* x = static_cast<const double*>(L->x);
        for (size_t k = 0; k < entries; ++k) zero_in_pattern |= x[k] == 0.0;
      } else {
        ASSERT_FALSE(L->is_super);
        ASSERT_TRUE(std::equal(perm.begin(), perm.end(), static_cast<const int*>(L->Perm)));
        EXPECT_TRUE(supernodal_to_simplicial(L, &view, &common));  // simplicial: unchanged
      }
      patterns[simplicial] = factor_pattern(*L);
      Eigen::MatrixXd bc = b;
      cholmod_dense rhs = Eigen::viewAsCholmod(bc);
      cholmod_dense* x = cholmod_solve(CHOLMOD_A, L, &rhs, &common);
      ASSERT_NE(x, nullptr);
      solutions[simplicial] =
          Eigen::Map<const Eigen::MatrixXd>(static_cast<const double*>(x->x), A.rows(), 3);
      cholmod_free_dense(&x, &common);
      cholmod_free_factor(&L, &common);
    }
    cholmod_finish(&common);
    EXPECT_EQ(zero_in_pattern, c.has_cancellations);
    EXPECT_TRUE(patterns[0] == patterns[1]);
    EXPECT_LT(relative_residual(A, solutions[0], b), 1e-12);
    EXPECT_LT((solutions[0] - solutions[1]).norm(), 1e-12 * solutions[1].norm());
  }
}

TEST(SparseCholesky, IndefiniteOrSingularMatrixIsANumericalFailure) {
  const int n = 120;
  const SparseMatrix spd = random_spd(n, 3, 0.1, 21, 22);
  SparseMatrix shift(n, n);
  shift.setIdentity();
  // Shifted by its median eigenvalue: half the spectrum negative, same pattern as spd.
  const Eigen::VectorXd eigenvalues =
      Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd>(Eigen::MatrixXd(spd)).eigenvalues();
  const double median = eigenvalues(n / 2);
  ASSERT_GT(eigenvalues(n / 2 + 1), median);
  const SparseMatrix indefinite = spd - median * shift;
  const std::vector<std::pair<const char*, SparseMatrix>> bad = {
      {"negative_definite", SparseMatrix(-1.0 * spd)},
      {"indefinite", indefinite},
      {"singular_diagonal", diagonal({2.0, 1.0, 0.0, 3.0})},
      {"one_negative_pivot", diagonal({2.0, 1.0, -1e-3, 3.0})},
  };
  for (const auto& [name, A] : bad) {
    SCOPED_TRACE(name);
    for (const bool simplicial_solves : {false, true}) {
      SparseCholesky cholesky;
      cholesky.set_simplicial_solves(simplicial_solves);
      const Status s = cholesky.factorize(A);
      ASSERT_FALSE(s.ok());
      EXPECT_EQ(s.code(), ErrorCode::NumericalFailure);
      EXPECT_NE(s.message().find("not positive definite"), std::string::npos) << s.message();
      EXPECT_FALSE(cholesky.is_factorized());
    }
  }
  // The same object recovers on an SPD matrix of the same pattern.
  SparseCholesky cholesky;
  ASSERT_TRUE(cholesky.analyze(spd).ok());
  ASSERT_FALSE(cholesky.factorize(indefinite).ok());
  ASSERT_TRUE(cholesky.factorize(spd).ok());
  EXPECT_TRUE(cholesky.is_factorized());
  const Eigen::MatrixXd b = random_rhs(n, 1, 23);
  EXPECT_LT(relative_residual(spd, cholesky.solve(b), b), 1e-12);
}

TEST(SparseCholesky, MovesKeepTheFactor) {
  const int n = 150;
  const SparseMatrix A = random_spd(n, 3, 0.1, 31, 32);
  const SparseMatrix A_other = random_spd(n, 3, 1.0, 31, 34);  // same pattern, other values
  const Eigen::MatrixXd b = random_rhs(n, 2, 35);
  SparseCholesky original;
  ASSERT_TRUE(original.factorize(A).ok());
  const Eigen::MatrixXd expected = original.solve(b);

  SparseCholesky constructed(std::move(original));
  EXPECT_TRUE(constructed.is_factorized());
  EXPECT_EQ(constructed.solve(b), expected);

  SparseCholesky assigned;
  ASSERT_TRUE(assigned.factorize(A_other).ok());
  assigned = std::move(constructed);
  EXPECT_TRUE(assigned.is_factorized());
  EXPECT_EQ(assigned.solve(b), expected);

  // A moved-to object refactors as usual.
  ASSERT_TRUE(assigned.factorize(A_other).ok());
  EXPECT_LT(relative_residual(A_other, assigned.solve(b), b), 1e-12);

  // Objects in a vector survive reallocation (moves) with their factors.
  std::vector<SparseCholesky> many(1);
  ASSERT_TRUE(many[0].factorize(A).ok());
  for (int k = 0; k < 8; ++k) many.emplace_back();
  EXPECT_EQ(many[0].solve(b), expected);
}

}  // namespace
}  // namespace meshdeform::core
