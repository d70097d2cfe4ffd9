// Tests of the two-halves Cholesky factorization (core/linalg/split_cholesky.h): Dirichlet Laplacians of
// regular and irregular meshes solved in two halves agree with the whole factorization, the
// cases that factor whole still solve, a split without a separator, indefinite matrices as a
// NumericalFailure (whether a half or the separator's Schur complement fails), concurrent
// solves, and cancellation.
#include "core/linalg/split_cholesky.h"

#include <gtest/gtest.h>

#include <stop_token>
#include <string>
#include <thread>
#include <vector>

#include "core/methods/laplacian.h"
#include "core/samples/generators.h"
#include "core/mesh/topology.h"

namespace meshdeform::core {
namespace {

/// The clamped-cotangent Laplacian of a mesh with every `stride`-th vertex held (Dirichlet):
/// the free/free block and the free vertices' positions, as the prolongation builds them.
struct System {
  SparseMatrix A;
  Positions points;
};

System dirichlet_laplacian(const MeshData& mesh, int stride) {
  const auto n = static_cast<int>(mesh.V.rows());
  auto topology = build_topology(mesh.F, n);
  EXPECT_TRUE(topology.ok());
  const SparseMatrix L = laplacian_matrix(mesh.V, mesh.F, *topology, LaplacianWeights::Cotangent);
  std::vector<int> free_index(static_cast<size_t>(n), -1);
  int nf = 0;
  for (int v = 0; v < n; ++v) {
    if (v % stride != 0) free_index[static_cast<size_t>(v)] = nf++;
  }
  System system;
  system.points.resize(nf, 3);
  std::vector<Eigen::Triplet<double>> entries;
  for (int c = 0; c < n; ++c) {
    if (free_index[static_cast<size_t>(c)] < 0) continue;
    system.points.row(free_index[static_cast<size_t>(c)]) = mesh.V.row(c);
    for (SparseMatrix::InnerIterator it(L, c); it; ++it) {
      const int r = free_index[static_cast<size_t>(it.row())];
      if (r >= 0) entries.emplace_back(r, free_index[static_cast<size_t>(c)], it.value());
    }
  }
  system.A.resize(nf, nf);
  system.A.setFromTriplets(entries.begin(), entries.end());
  system.A.makeCompressed();
  return system;
}

Eigen::MatrixXd rhs_for(const System& system) {
  // Smooth and rough columns: positions, and a checkerboard.
  Eigen::MatrixXd b(system.A.rows(), 3);
  for (Eigen::Index i = 0; i < b.rows(); ++i) {
    b(i, 0) = system.points(i, 0) - 2 * system.points(i, 1);
    b(i, 1) = (i % 2 == 0) ? 1.0 : -1.0;
    b(i, 2) = std::sin(3 * system.points(i, 0)) + system.points(i, 2);
  }
  return b;
}

Eigen::MatrixXd whole_solve(const SparseMatrix& A, const Eigen::MatrixXd& b) {
  SparseCholesky whole;
  EXPECT_TRUE(whole.factorize(A).ok());
  return whole.solve(b);
}

SplitCholeskySettings split_settings() {
  SplitCholeskySettings settings;
  settings.threads = 2;
  settings.min_rows = 100;  // the tests' systems are small
  return settings;
}

std::vector<std::pair<std::string, MeshData>> meshes() {
  std::vector<std::pair<std::string, MeshData>> out;
  const DeformationBenchmark plane = make_bumpy_plane(61);
  out.emplace_back("plane", plane.mesh);
  auto irregular = make_irregular(plane, 3);
  EXPECT_TRUE(irregular.ok());
  if (irregular.ok()) out.emplace_back("irregular plane", irregular->mesh);
  auto cactus = make_irregular(make_cactus(3), 5);
  EXPECT_TRUE(cactus.ok());
  if (cactus.ok()) out.emplace_back("irregular cactus", cactus->mesh);
  return out;
}

TEST(SplitCholesky, SolvesADirichletLaplacianInTwoHalvesLikeTheWholeFactor) {
  for (const auto& [name, mesh] : meshes()) {
    SCOPED_TRACE(name);
    const System system = dirichlet_laplacian(mesh, 7);
    const Eigen::MatrixXd b = rhs_for(system);
    SplitCholesky split;
    EXPECT_FALSE(split.is_factorized());
    ASSERT_TRUE(split.factorize(system.A, system.points, split_settings()).ok());
    EXPECT_TRUE(split.is_factorized());
    EXPECT_TRUE(split.is_split());
    EXPECT_GT(split.separator_size(), 0);
    EXPECT_LE(split.separator_size(), system.A.rows() / 16);
    const Eigen::MatrixXd x = split.solve(b);
    EXPECT_LT((system.A * x - b).norm(), 1e-12 * b.norm());
    const Eigen::MatrixXd reference = whole_solve(system.A, b);
    EXPECT_LT((x - reference).norm(), 1e-11 * reference.norm());
    // One column at a time gives the same columns.
    const Eigen::MatrixXd first = split.solve(b.col(1));
    EXPECT_LT((first - x.col(1)).norm(), 1e-13 * x.col(1).norm());
  }
}

TEST(SplitCholesky, FactorsWholeWhenTheSplitDoesNotApply) {
  const System system = dirichlet_laplacian(make_bumpy_plane(41).mesh, 5);
  const Eigen::MatrixXd b = rhs_for(system);
  const Eigen::MatrixXd reference = whole_solve(system.A, b);
  SplitCholeskySettings one_thread = split_settings();
  one_thread.threads = 1;
  SplitCholeskySettings small = split_settings();
  small.min_rows = static_cast<int>(system.A.rows()) + 1;
  SplitCholeskySettings wide_separator = split_settings();
  wide_separator.max_separator = 0;
  for (const auto& [name, settings] :
       {std::pair{"one thread", one_thread}, std::pair{"below min_rows", small},
        std::pair{"separator too large", wide_separator}}) {
    SCOPED_TRACE(name);
    SplitCholesky cholesky;
    ASSERT_TRUE(cholesky.factorize(system.A, system.points, settings).ok());
    EXPECT_FALSE(cholesky.is_split());
    EXPECT_EQ(cholesky.separator_size(), 0);
    const Eigen::MatrixXd x = cholesky.solve(b);
    EXPECT_LT((x - reference).norm(), 1e-11 * reference.norm());
  }
}

TEST(SplitCholesky, TwoComponentsSplitWithoutASeparator) {
  // Two planes side by side along x, far apart: the median falls between them.
  const MeshData plane = make_bumpy_plane(31).mesh;
  MeshData both;
  const auto n = plane.V.rows();
  both.V.resize(2 * n, 3);
  both.V.topRows(n) = plane.V;
  both.V.bottomRows(n) = plane.V.rowwise() + Eigen::RowVector3d(10, 0, 0);
  both.F.resize(2 * plane.F.rows(), 3);
  both.F.topRows(plane.F.rows()) = plane.F;
  both.F.bottomRows(plane.F.rows()) = plane.F.array() + static_cast<int>(n);
  const System system = dirichlet_laplacian(both, 6);
  const Eigen::MatrixXd b = rhs_for(system);
  SplitCholesky split;
  ASSERT_TRUE(split.factorize(system.A, system.points, split_settings()).ok());
  EXPECT_TRUE(split.is_split());
  EXPECT_EQ(split.separator_size(), 0);
  const Eigen::MatrixXd x = split.solve(b);
  EXPECT_LT((x - whole_solve(system.A, b)).norm(), 1e-11 * x.norm());
}

TEST(SplitCholesky, IndefiniteMatricesAreANumericalFailure) {
  const System system = dirichlet_laplacian(make_bumpy_plane(41).mesh, 5);
  // Negated: every half fails, and the whole factorization after it.
  const SparseMatrix negated = -system.A;
  // A slab across the middle made indefinite: the separator's Schur complement (or a half, for
  // rows off the separator) fails.
  SparseMatrix slab = system.A;
  const double middle = 0.5 * (system.points.col(0).minCoeff() + system.points.col(0).maxCoeff());
  const double width = 0.05 * (system.points.col(0).maxCoeff() - system.points.col(0).minCoeff());
  for (Eigen::Index i = 0; i < slab.rows(); ++i) {
    if (std::abs(system.points(i, 0) - middle) < width) slab.coeffRef(i, i) -= 100.0;
  }
  for (const auto& [name, A] : {std::pair{"negated", negated}, std::pair{"slab", slab}}) {
    SCOPED_TRACE(name);
    SplitCholesky cholesky;
    const Status status = cholesky.factorize(A, system.points, split_settings());
    EXPECT_EQ(status.code(), ErrorCode::NumericalFailure) << status.to_string();
    EXPECT_FALSE(cholesky.is_factorized());
    // Usable again afterwards.
    ASSERT_TRUE(cholesky.factorize(system.A, system.points, split_settings()).ok());
    EXPECT_TRUE(cholesky.is_split());
  }
}

TEST(SplitCholesky, ConcurrentSolvesGiveTheSequentialResults) {
  const System system = dirichlet_laplacian(make_bumpy_plane(61).mesh, 7);
  SplitCholesky split;
  ASSERT_TRUE(split.factorize(system.A, system.points, split_settings()).ok());
  ASSERT_TRUE(split.is_split());
  const Eigen::MatrixXd b1 = rhs_for(system);
  const Eigen::MatrixXd b2 = -2.0 * b1.rowwise().reverse();
  const Eigen::MatrixXd x1 = split.solve(b1), x2 = split.solve(b2);
  Eigen::MatrixXd y1, y2;
  for (int round = 0; round < 5; ++round) {
    std::thread other([&] { y2 = split.solve(b2); });
    y1 = split.solve(b1);
    other.join();
    EXPECT_EQ(y1, x1);
    EXPECT_EQ(y2, x2);
  }
}

TEST(SplitCholesky, StopRequestCancels) {
  const System system = dirichlet_laplacian(make_bumpy_plane(41).mesh, 5);
  std::stop_source source;
  source.request_stop();
  for (const int threads : {1, 2}) {
    SplitCholeskySettings settings = split_settings();
    settings.threads = threads;
    SplitCholesky cholesky;
    EXPECT_EQ(cholesky.factorize(system.A, system.points, settings, source.get_token()).code(),
              ErrorCode::Cancelled)
        << threads;
    EXPECT_FALSE(cholesky.is_factorized());
  }
}

}  // namespace
}  // namespace meshdeform::core
