// Tests of Laplacian editing (core/methods/laplacian.h), the starting guess of the scale-aware solver and a
// baseline: the matrix (graph and cotangent Laplacians: symmetry, zero row sums, known weights, a
// cotangent Laplacian that annihilates linear functions on a flat mesh) and the editor (rest pose
// and translations reproduced exactly, the normal equations satisfied, constraints tightening
// with lambda, invalid input rejected).
#include "core/methods/laplacian.h"

#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <Eigen/SparseCore>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "core/mesh/topology.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

using SpMat = Eigen::SparseMatrix<double>;
using test::bbox_diagonal;
using test::gather_rows;
using test::pinned_test_meshes;

constexpr LaplacianWeights kBothWeights[] = {LaplacianWeights::Uniform,
                                             LaplacianWeights::Cotangent};

const char* weights_name(LaplacianWeights weights) {
  return weights == LaplacianWeights::Uniform ? "uniform" : "cotangent";
}

MeshTopology topology_of(const MeshData& mesh) {
  auto topology = build_topology(mesh.F, static_cast<int>(mesh.V.rows()));
  EXPECT_TRUE(topology.ok()) << topology.status().to_string();
  return *topology;
}

SpMat laplacian_of(const MeshData& mesh, LaplacianWeights weights) {
  return laplacian_matrix(mesh.V, mesh.F, topology_of(mesh), weights);
}

/// An (n+1) x (n+1) patch of the equilateral triangle lattice, interior vertices jittered by up to
/// a tenth of the spacing (every angle stays acute, so no cotangent weight is clamped), laid in a
/// tilted plane of R^3 so that all three coordinates vary. Boundary: i or j equal to 0 or n.
MeshData make_flat_lattice(int n, const Eigen::Matrix3d& frame) {
  MeshData m;
  m.V.resize((n + 1) * (n + 1), 3);
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      const int k = j * (n + 1) + i;
      Eigen::Vector3d p(i + 0.5 * j, j * std::sqrt(3.0) / 2, 0);
      const bool boundary = i == 0 || j == 0 || i == n || j == n;
      if (!boundary) p += 0.1 * Eigen::Vector3d(std::sin(7.0 * k), std::cos(11.0 * k), 0);
      m.V.row(k) = (frame * p).transpose();
    }
  }
  m.F.resize(2 * n * n, 3);
  int f = 0;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int a = j * (n + 1) + i, b = a + 1, c = a + n + 1, d = c + 1;
      m.F.row(f++) << a, b, c;
      m.F.row(f++) << b, d, c;
    }
  }
  return m;
}

bool on_lattice_boundary(int k, int n) {
  const int i = k % (n + 1), j = k / (n + 1);
  return i == 0 || j == 0 || i == n || j == n;
}

Eigen::Matrix3d tilted_frame() {
  return Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
}

// ---------------------------------------------------------------------------------------------
// The matrix.

TEST(LaplacianMatrix, UniformIsTheGraphLaplacian) {
  const MeshData mesh = test::make_grid(4);
  const MeshTopology topology = topology_of(mesh);
  const Eigen::MatrixXd L =
      Eigen::MatrixXd(laplacian_matrix(mesh.V, mesh.F, topology, LaplacianWeights::Uniform));
  const int n = topology.vertex_count;
  Eigen::MatrixXd expected = Eigen::MatrixXd::Zero(n, n);
  for (int i = 0; i < n; ++i) {
    for (int k = topology.vv_offsets[i]; k < topology.vv_offsets[i + 1]; ++k) {
      expected(i, topology.vv_neighbors[k]) = -1.0;
      expected(i, i) += 1.0;
    }
  }
  EXPECT_EQ(L, expected);
  // Spot values from the grid itself: corner 0 touches 1, 5 and 6; centre 12 has six neighbours.
  EXPECT_EQ(L(0, 0), 3.0);
  EXPECT_EQ(L(0, 6), -1.0);
  EXPECT_EQ(L(0, 7), 0.0);
  EXPECT_EQ(L(12, 12), 6.0);
}

TEST(LaplacianMatrix, IsSymmetricWithZeroRowSumsAndNonPositiveOffDiagonal) {
  std::vector<std::pair<std::string, MeshData>> meshes;
  for (auto& pinned : pinned_test_meshes()) meshes.emplace_back(pinned.name, pinned.mesh);
  // Obtuse pairs (a very flat jitter of a grid) whose raw cotangent weight is negative.
  MeshData sheared = test::make_grid(6, 0.05);
  for (Eigen::Index v = 0; v < sheared.V.rows(); ++v) sheared.V(v, 0) += 0.9 * sheared.V(v, 1);
  meshes.emplace_back("sheared_grid", sheared);
  for (const auto& [name, mesh] : meshes) {
    for (const LaplacianWeights weights : kBothWeights) {
      SCOPED_TRACE(name + " " + weights_name(weights));
      const Eigen::MatrixXd L = Eigen::MatrixXd(laplacian_of(mesh, weights));
      ASSERT_EQ(L.rows(), mesh.V.rows());
      ASSERT_EQ(L.cols(), mesh.V.rows());
      EXPECT_EQ((L - L.transpose()).cwiseAbs().maxCoeff(), 0.0);
      const double scale = L.diagonal().maxCoeff();
      EXPECT_LT(L.rowwise().sum().cwiseAbs().maxCoeff(), 1e-12 * scale);
      EXPECT_GT(L.diagonal().minCoeff(), 0.0);
      Eigen::MatrixXd off = L;
      off.diagonal().setZero();
      EXPECT_LE(off.maxCoeff(), 0.0) << "a negative edge weight survived";
      // Non-negative weights make L positive semi-definite: x^T L x = sum w_ij (x_i - x_j)^2.
      const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eig(L);
      EXPECT_GT(eig.eigenvalues().minCoeff(), -1e-10 * scale);
      // One zero eigenvalue per connected component (all of these meshes are connected).
      EXPECT_GT(eig.eigenvalues()(1), 1e-8 * scale);
    }
  }
}

TEST(LaplacianMatrix, CotangentWeightsOfAHandBuiltKite) {
  // Two triangles on edge a-b: a=(0,0), b=(2,0), c=(1,2) above, d=(0.5,-1) below.
  //   angle at c: cot = (c->a . c->b) / |c->a x c->b| = 3/4;  angle at d: cot = 0.25 / 2 = 1/8.
  //   interior edge a-b: w = (3/4 + 1/8) / 2 = 7/16.
  //   boundary edges (one cotangent each): b-c opposite a: cot 1/2, w = 1/4; c-a opposite b:
  //   cot 1/2, w = 1/4; a-d opposite b: cot 3/2, w = 3/4; d-b opposite a: cot 1/2, w = 1/4.
  MeshData kite;
  kite.V.resize(4, 3);
  kite.V << 0, 0, 0, 2, 0, 0, 1, 2, 0, 0.5, -1, 0;
  kite.F.resize(2, 3);
  kite.F << 0, 1, 2, 0, 3, 1;
  const int a = 0, b = 1, c = 2, d = 3;
  Eigen::Matrix4d W = Eigen::Matrix4d::Zero();
  auto set_w = [&](int i, int j, double w) { W(i, j) = W(j, i) = w; };
  set_w(a, b, 7.0 / 16);
  set_w(b, c, 0.25);
  set_w(c, a, 0.25);
  set_w(a, d, 0.75);
  set_w(d, b, 0.25);
  Eigen::Matrix4d expected = -W;
  expected.diagonal() = W.rowwise().sum();

  const Eigen::MatrixXd L = Eigen::MatrixXd(laplacian_of(kite, LaplacianWeights::Cotangent));
  EXPECT_LT((L - expected).cwiseAbs().maxCoeff(), 1e-14) << "L =\n" << L;
  EXPECT_EQ(L(c, d), 0.0);  // not an edge

  // Cotangents are angles: a similarity of the kite (rotation, scale 3, translation) in 3D leaves
  // the weights unchanged.
  MeshData moved = kite;
  const Eigen::Matrix3d R = tilted_frame();
  moved.V = ((3.0 * kite.V * R.transpose()).rowwise() + Eigen::RowVector3d(1, -2, 5)).eval();
  const Eigen::MatrixXd L_moved = Eigen::MatrixXd(laplacian_of(moved, LaplacianWeights::Cotangent));
  EXPECT_LT((L_moved - expected).cwiseAbs().maxCoeff(), 1e-13);
}

TEST(LaplacianMatrix, CotangentAnnihilatesLinearFunctionsOnAFlatMesh) {
  constexpr int n = 8;
  const MeshData mesh = make_flat_lattice(n, tilted_frame());
  const SpMat L = laplacian_of(mesh, LaplacianWeights::Cotangent);
  // f = the three coordinates, a generic linear function, and a constant.
  Eigen::MatrixXd f(mesh.V.rows(), 5);
  f.leftCols(3) = mesh.V;
  f.col(3) = mesh.V * Eigen::Vector3d(0.3, -1.7, 2.2) + Eigen::VectorXd::Constant(f.rows(), 4.0);
  f.col(4).setOnes();
  const Eigen::MatrixXd Lf = L * f;
  int interior = 0;
  double boundary_max = 0;
  for (int k = 0; k < mesh.V.rows(); ++k) {
    if (on_lattice_boundary(k, n)) {
      boundary_max = std::max(boundary_max, Lf.row(k).leftCols(3).norm());
      continue;
    }
    ++interior;
    EXPECT_LT(Lf.row(k).cwiseAbs().maxCoeff(), 1e-12) << "interior vertex " << k;
  }
  EXPECT_EQ(interior, (n - 1) * (n - 1));
  // The boundary rows are not zero (one-sided fans): the property is about interior vertices.
  EXPECT_GT(boundary_max, 0.1);

  // The graph Laplacian does not have the property on the jittered lattice: the cotangent weights
  // are what makes it hold.
  const Eigen::MatrixXd Lf_uniform = laplacian_of(mesh, LaplacianWeights::Uniform) * mesh.V;
  double uniform_interior_max = 0;
  for (int k = 0; k < mesh.V.rows(); ++k) {
    if (!on_lattice_boundary(k, n)) {
      uniform_interior_max = std::max(uniform_interior_max, Lf_uniform.row(k).norm());
    }
  }
  EXPECT_GT(uniform_interior_max, 0.05);
}

// ---------------------------------------------------------------------------------------------
// The editor.

Result<LaplacianEditor> make_editor(const MeshData& mesh, const Eigen::VectorXi& constrained,
                                    LaplacianWeights weights, double lambda) {
  return LaplacianEditor::create(mesh.V, mesh.F, topology_of(mesh), constrained, weights, lambda);
}

TEST(LaplacianEditor, HandlesAtRestReproduceTheRestPose) {
  for (const auto& [name, mesh, constrained] : pinned_test_meshes()) {
    for (const LaplacianWeights weights : kBothWeights) {
      SCOPED_TRACE(std::string(name) + " " + weights_name(weights));
      auto editor = make_editor(mesh, constrained, weights, 100.0);
      ASSERT_TRUE(editor.ok()) << editor.status().to_string();
      auto V = editor->solve(gather_rows(mesh.V, constrained));
      ASSERT_TRUE(V.ok()) << V.status().to_string();
      EXPECT_LT((*V - mesh.V).cwiseAbs().maxCoeff(), test::kExactTol * bbox_diagonal(mesh));
    }
  }
}

TEST(LaplacianEditor, TranslatedHandlesTranslateTheWholeMesh) {
  const Eigen::RowVector3d t(0.4, -1.3, 2.5);
  for (const auto& [name, mesh, constrained] : pinned_test_meshes()) {
    for (const LaplacianWeights weights : kBothWeights) {
      SCOPED_TRACE(std::string(name) + " " + weights_name(weights));
      auto editor = make_editor(mesh, constrained, weights, 10.0);
      ASSERT_TRUE(editor.ok()) << editor.status().to_string();
      Positions targets = gather_rows(mesh.V, constrained);
      targets.rowwise() += t;
      auto V = editor->solve(targets);
      ASSERT_TRUE(V.ok()) << V.status().to_string();
      const Positions expected = (mesh.V.rowwise() + t).eval();
      EXPECT_LT((*V - expected).cwiseAbs().maxCoeff(), test::kExactTol * bbox_diagonal(mesh));
    }
  }
}

TEST(LaplacianEditor, SolveMinimisesTheDocumentedEnergy) {
  // The minimiser of ||L V - L V0||^2 + lambda sum_C ||v_j - t_j||^2 satisfies
  // (L^T L + lambda S) V = L^T L V0 + lambda S^T T, S selecting the constrained rows.
  const test::BendEdit bend = test::make_bend(8);
  const double lambda = 25.0;
  for (const LaplacianWeights weights : kBothWeights) {
    SCOPED_TRACE(weights_name(weights));
    auto editor = make_editor(bend.mesh, bend.constrained, weights, lambda);
    ASSERT_TRUE(editor.ok()) << editor.status().to_string();
    auto V = editor->solve(bend.targets);
    ASSERT_TRUE(V.ok()) << V.status().to_string();
    const SpMat L = laplacian_of(bend.mesh, weights);
    const SpMat LtL = SpMat(L.transpose()) * L;
    Eigen::MatrixXd lhs = LtL * Eigen::MatrixXd(*V);
    Eigen::MatrixXd rhs = LtL * Eigen::MatrixXd(bend.mesh.V);
    for (Eigen::Index j = 0; j < bend.constrained.size(); ++j) {
      lhs.row(bend.constrained(j)) += lambda * V->row(bend.constrained(j));
      rhs.row(bend.constrained(j)) += lambda * bend.targets.row(j);
    }
    EXPECT_LT((lhs - rhs).norm(), 1e-10 * rhs.norm());
    // The edit is not trivial: the free vertices moved.
    EXPECT_GT((*V - bend.mesh.V).rowwise().norm().maxCoeff(), 0.1);
  }
}

TEST(LaplacianEditor, ConstraintsTightenAsLambdaGrows) {
  const test::BendEdit bend = test::make_bend(8);
  for (const LaplacianWeights weights : kBothWeights) {
    SCOPED_TRACE(weights_name(weights));
    double previous = std::numeric_limits<double>::infinity();
    for (const double lambda : {0.01, 1.0, 100.0, 1e4, 1e6}) {
      SCOPED_TRACE(lambda);
      auto editor = make_editor(bend.mesh, bend.constrained, weights, lambda);
      ASSERT_TRUE(editor.ok()) << editor.status().to_string();
      auto V = editor->solve(bend.targets);
      ASSERT_TRUE(V.ok()) << V.status().to_string();
      const double error = (gather_rows(*V, bend.constrained) - bend.targets).norm();
      EXPECT_LT(error, previous);
      previous = error;
    }
    EXPECT_LT(previous, 1e-4 * bbox_diagonal(bend.mesh));
  }
}

TEST(LaplacianEditor, RejectsInvalidSettings) {
  const MeshData mesh = test::make_grid(3);
  Eigen::VectorXi good(2);
  good << 0, 15;
  for (const double lambda : {0.0, -1.0, std::nan(""), std::numeric_limits<double>::infinity()}) {
    SCOPED_TRACE(lambda);
    auto editor = make_editor(mesh, good, LaplacianWeights::Cotangent, lambda);
    ASSERT_FALSE(editor.ok());
    EXPECT_EQ(editor.status().code(), ErrorCode::InvalidArgument);
  }
  const std::vector<std::vector<int>> bad_sets = {{0, 16}, {-1, 3}, {0, 5, 0}, {}};
  for (const auto& set : bad_sets) {
    const Eigen::VectorXi constrained =
        Eigen::Map<const Eigen::VectorXi>(set.data(), static_cast<Eigen::Index>(set.size()));
    SCOPED_TRACE(::testing::PrintToString(set));
    auto editor = make_editor(mesh, constrained, LaplacianWeights::Uniform, 1.0);
    ASSERT_FALSE(editor.ok());
    EXPECT_EQ(editor.status().code(), ErrorCode::InvalidArgument);
  }
  // Two separate triangles, a handle on the first only: the second would float freely.
  MeshData two;
  two.V.resize(6, 3);
  two.V << 0, 0, 0, 1, 0, 0, 0, 1, 0, 5, 0, 0, 6, 0, 0, 5, 1, 0;
  two.F.resize(2, 3);
  two.F << 0, 1, 2, 3, 4, 5;
  Eigen::VectorXi first_only(1);
  first_only << 1;
  auto editor = make_editor(two, first_only, LaplacianWeights::Uniform, 1.0);
  ASSERT_FALSE(editor.ok());
  EXPECT_EQ(editor.status().code(), ErrorCode::InvalidArgument);
  Eigen::VectorXi both(2);
  both << 1, 4;
  EXPECT_TRUE(make_editor(two, both, LaplacianWeights::Uniform, 1.0).ok());
}

TEST(LaplacianEditor, RejectsTargetsOfTheWrongShapeOrNotFinite) {
  const MeshData mesh = test::make_grid(3);
  Eigen::VectorXi constrained(2);
  constrained << 0, 15;
  auto editor = make_editor(mesh, constrained, LaplacianWeights::Cotangent, 1.0);
  ASSERT_TRUE(editor.ok()) << editor.status().to_string();
  const Positions rest = gather_rows(mesh.V, constrained);
  EXPECT_EQ(editor->solve(Positions(1, 3)).status().code(), ErrorCode::InvalidArgument);
  EXPECT_EQ(editor->solve(Positions(3, 3)).status().code(), ErrorCode::InvalidArgument);
  for (const double bad : {std::nan(""), std::numeric_limits<double>::infinity()}) {
    Positions targets = rest;
    targets(1, 2) = bad;
    EXPECT_EQ(editor->solve(targets).status().code(), ErrorCode::InvalidArgument);
  }
  EXPECT_TRUE(editor->solve(rest).ok());
}

TEST(LaplacianEditor, MovedEditorKeepsItsFactorization) {
  const test::BendEdit bend = test::make_bend(6);
  auto editor = make_editor(bend.mesh, bend.constrained, LaplacianWeights::Cotangent, 10.0);
  ASSERT_TRUE(editor.ok()) << editor.status().to_string();
  const Positions expected = *editor->solve(bend.targets);
  LaplacianEditor moved(std::move(*editor));
  EXPECT_EQ(*moved.solve(bend.targets), expected);
  auto other = make_editor(test::make_grid(2), Eigen::VectorXi::LinSpaced(2, 0, 8),
                           LaplacianWeights::Uniform, 1.0);
  ASSERT_TRUE(other.ok());
  *other = std::move(moved);
  EXPECT_EQ(*other->solve(bend.targets), expected);
}

}  // namespace
}  // namespace meshdeform::core
