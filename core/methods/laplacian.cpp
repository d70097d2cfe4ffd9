#include "core/methods/laplacian.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Geometry>

#include "core/methods/constraints.h"
#include "core/linalg/sparse_cholesky.h"

namespace meshdeform::core {

SparseMatrix laplacian_matrix(const Positions& V, const Triangles& F, const MeshTopology& topology,
                              LaplacianWeights weights) {
  const int n = topology.vertex_count;
  std::vector<Eigen::Triplet<double>> entries;
  if (weights == LaplacianWeights::Uniform) {
    for (int i = 0; i < n; ++i) {
      for (int k = topology.vv_offsets[i]; k < topology.vv_offsets[i + 1]; ++k) {
        entries.emplace_back(i, topology.vv_neighbors[k], -1.0);
        entries.emplace_back(i, i, 1.0);
      }
    }
  } else {
    // Cotangent weights, accumulated per face corner, then clamped per edge: negative weights
    // (obtuse pairs) would let L^T L lose rank on bad meshes; the guess need not be exact.
    std::vector<Eigen::Triplet<double>> raw;
    for (Eigen::Index f = 0; f < F.rows(); ++f) {
      for (int k = 0; k < 3; ++k) {
        const int i = F(f, (k + 1) % 3), j = F(f, (k + 2) % 3);
        const Eigen::Vector3d a = V.row(i) - V.row(F(f, k)), b = V.row(j) - V.row(F(f, k));
        const double cot = a.dot(b) / std::max(a.cross(b).norm(), 1e-300);
        raw.emplace_back(std::min(i, j), std::max(i, j), 0.5 * cot);
      }
    }
    SparseMatrix W(n, n);
    W.setFromTriplets(raw.begin(), raw.end());
    double mean = 0;
    for (int c = 0; c < W.outerSize(); ++c) {
      for (SparseMatrix::InnerIterator it(W, c); it; ++it) mean += std::abs(it.value());
    }
    mean /= std::max<Eigen::Index>(W.nonZeros(), 1);
    for (int c = 0; c < W.outerSize(); ++c) {
      for (SparseMatrix::InnerIterator it(W, c); it; ++it) {
        const double w = std::max(it.value(), 1e-3 * mean);
        const int i = static_cast<int>(it.row()), j = static_cast<int>(it.col());
        entries.emplace_back(i, j, -w);
        entries.emplace_back(j, i, -w);
        entries.emplace_back(i, i, w);
        entries.emplace_back(j, j, w);
      }
    }
  }
  SparseMatrix L(n, n);
  L.setFromTriplets(entries.begin(), entries.end());
  return L;
}

struct LaplacianEditor::Impl {
  SparseCholesky cholesky;
  Eigen::MatrixXd rhs_rest;  // L^T L V0: the detail term of the right-hand side
  Eigen::VectorXi constrained;
  double lambda = 0;
  int vertex_count = 0;
};

LaplacianEditor::LaplacianEditor(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
LaplacianEditor::LaplacianEditor(LaplacianEditor&&) noexcept = default;
LaplacianEditor& LaplacianEditor::operator=(LaplacianEditor&&) noexcept = default;
LaplacianEditor::~LaplacianEditor() = default;

Result<LaplacianEditor> LaplacianEditor::create(const Positions& V0, const Triangles& F,
                                                const MeshTopology& topology,
                                                const Eigen::VectorXi& constrained,
                                                LaplacianWeights weights, double lambda) {
  if (!(lambda > 0) || !std::isfinite(lambda)) {
    return Error(ErrorCode::InvalidArgument, "lambda must be positive and finite");
  }
  MD_RETURN_IF_ERROR(check_constrained(constrained, topology, 1));
  auto impl = std::make_unique<Impl>();
  const SparseMatrix L = laplacian_matrix(V0, F, topology, weights);
  SparseMatrix A = SparseMatrix(L.transpose()) * L;
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    A.coeffRef(constrained(j), constrained(j)) += lambda;
  }
  A.makeCompressed();
  MD_RETURN_IF_ERROR(impl->cholesky.analyze(A));
  MD_RETURN_IF_ERROR(impl->cholesky.factorize(A));
  impl->rhs_rest = SparseMatrix(L.transpose()) * (L * Eigen::MatrixXd(V0));
  impl->constrained = constrained;
  impl->lambda = lambda;
  impl->vertex_count = static_cast<int>(V0.rows());
  return LaplacianEditor(std::move(impl));
}

Result<Positions> LaplacianEditor::solve(const Positions& targets) const {
  if (targets.rows() != impl_->constrained.size() || !targets.allFinite()) {
    return Error(ErrorCode::InvalidArgument,
                 "Laplacian editing needs " + std::to_string(impl_->constrained.size()) +
                     " finite target rows, got " + std::to_string(targets.rows()));
  }
  Eigen::MatrixXd b = impl_->rhs_rest;
  for (Eigen::Index j = 0; j < impl_->constrained.size(); ++j) {
    b.row(impl_->constrained(j)) += impl_->lambda * targets.row(j);
  }
  Positions V = impl_->cholesky.solve(b);
  if (!V.allFinite()) {
    return Error(ErrorCode::NumericalFailure, "Laplacian editing produced non-finite positions");
  }
  return V;
}

}  // namespace meshdeform::core
