#pragma once
/// @file rotation_start.h
/// Internal to core: a rotation-aware starting guess for the iterative solvers (issue 12,
/// docs "Initial guess"). Laplacian editing blends handle positions linearly, so a handle turned
/// far (a 135 degree twist) drags the free region through a collapsed, folded guess that the
/// scale-aware iteration then spends dozens of iterations (or forever) undoing. Here the
/// handles' rotations are propagated instead (harmonic guidance, Zayer, Roessl, Karni and Seidel
/// 2005, "Harmonic guidance for surface deformation"):
///  1. the constrained vertices split into mesh-connected patches; each patch's rotation is the
///     Procrustes fit of its rest positions to its targets (closest_rotation); a patch too thin
///     to define one (fewer than 3 vertices, or collinear) counts as not rotated;
///  2. the unit quaternions of the patches (scalar part >= 0) are interpolated harmonically
///     over the surface, (L + lambda C^T C) Q = lambda C^T Q_hat, and normalised per vertex;
///  3. the guess minimises sum_ij w_ij || (x_i - x_j) - (R_i + R_j) / 2 (x0_i - x0_j) ||^2 +
///     lambda sum_c || x_c - t_c ||^2, ARAP's global step with those rotations.
/// Both solves use one n x n matrix L + lambda C^T C (clamped cotangent weights, the Laplacian
/// editor's): a one-ring factor, smaller than the Laplacian editor's bi-Laplacian one.

#include <memory>

#include "core/mesh/mesh_data.h"
#include "core/base/status.h"
#include "core/mesh/topology.h"

namespace meshdeform::core {

class RotationPropagationStart {
 public:
  /// Factors L + lambda C^T C.
  /// @return InvalidArgument for lambda <= 0 or not finite; NumericalFailure if the matrix
  ///         cannot be factored.
  [[nodiscard]] static Result<RotationPropagationStart> create(const Positions& V0,
                                                               const Triangles& F,
                                                               const MeshTopology& topology,
                                                               const Eigen::VectorXi& constrained,
                                                               double lambda);
  RotationPropagationStart(RotationPropagationStart&&) noexcept;
  RotationPropagationStart& operator=(RotationPropagationStart&&) noexcept;
  ~RotationPropagationStart();

  /// The guess for `targets` (#C x 3, rows in `constrained` order).
  /// @return NumericalFailure if a solve produced non-finite values.
  [[nodiscard]] Result<Positions> guess(const Positions& targets) const;

  /// The per-vertex rotations of the last guess() (for tests), row-major 3x3 per vertex.
  const std::vector<Eigen::Matrix3d>& rotations() const;

 private:
  struct Impl;
  explicit RotationPropagationStart(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace meshdeform::core
