#pragma once
/// @file laplacian.h
/// Laplacian editing (Sorkine et al. 2004), the starting guess of the scale-aware solver (paper
/// Section 5.2) and a baseline: min ||L V - L V0||^2 + lambda sum_{j in C} ||v_j - v*_j||^2.
/// One constant #V x #V matrix per handle set: factored once, three back-solves per move.

#include <memory>

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include "core/mesh/mesh_data.h"
#include "core/base/status.h"
#include "core/mesh/topology.h"

namespace meshdeform::core {

enum class LaplacianWeights {
  Uniform,    ///< graph Laplacian
  Cotangent,  ///< cotangent weights (clamped non-negative per edge for a positive definite system)
};

/// The #V x #V Laplacian that LaplacianEditor uses: symmetric, positive diagonal, rows summing to
/// zero, (L V)_i = sum_j w_ij (v_i - v_j). Uniform: w_ij = 1 per neighbour. Cotangent:
/// w_ij = (cot alpha_ij + cot beta_ij) / 2 (one cotangent on a boundary edge), each raised to at
/// least 1e-3 times the mean |w| over the edges so that no weight is negative.
/// @param[in] V         #V x 3 positions the weights are measured on.
/// @param[in] F         #F x 3 triangles.
/// @param[in] topology  build_topology(F, #V).
Eigen::SparseMatrix<double> laplacian_matrix(const Positions& V, const Triangles& F,
                                             const MeshTopology& topology,
                                             LaplacianWeights weights);

/// Prefactored Laplacian editing for one handle set.
class LaplacianEditor {
 public:
  /// @param[in] V0           #V x 3 rest positions.
  /// @param[in] F            #F x 3 triangles.
  /// @param[in] topology     build_topology(F, #V).
  /// @param[in] constrained  #C distinct vertex indices whose targets are given at solve time.
  /// @param[in] lambda       constraint weight.
  /// @return the editor; InvalidArgument for a bad or repeated index or a component with no
  ///         constrained vertex; NumericalFailure if the factorization fails.
  [[nodiscard]] static Result<LaplacianEditor> create(const Positions& V0, const Triangles& F,
                                                      const MeshTopology& topology,
                                                      const Eigen::VectorXi& constrained,
                                                      LaplacianWeights weights, double lambda);

  /// Positions for #C x 3 targets (row j belongs to constrained(j)).
  [[nodiscard]] Result<Positions> solve(const Positions& targets) const;

  LaplacianEditor(LaplacianEditor&&) noexcept;
  LaplacianEditor& operator=(LaplacianEditor&&) noexcept;
  ~LaplacianEditor();

 private:
  struct Impl;
  explicit LaplacianEditor(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace meshdeform::core
