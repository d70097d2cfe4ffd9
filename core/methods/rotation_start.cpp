#include "core/methods/rotation_start.h"

#include <cmath>
#include <string>
#include <vector>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "core/methods/laplacian.h"
#include "core/linalg/rotation_fit.h"
#include "core/linalg/sparse_cholesky.h"

namespace meshdeform::core {

struct RotationPropagationStart::Impl {
  int nv = 0;
  Positions V0;
  Eigen::VectorXi constrained;
  std::vector<int> patch;  // #C: the patch of each constrained row
  int patch_count = 0;
  double lambda = 0;
  SparseMatrix L;  // clamped cotangent Laplacian: w_ij = -L(i, j)
  SparseCholesky factor;  // L + lambda C^T C
  mutable std::vector<Eigen::Matrix3d> rotations;
};

RotationPropagationStart::RotationPropagationStart(std::unique_ptr<Impl> impl)
    : impl_(std::move(impl)) {}
RotationPropagationStart::RotationPropagationStart(RotationPropagationStart&&) noexcept = default;
RotationPropagationStart& RotationPropagationStart::operator=(RotationPropagationStart&&) noexcept =
    default;
RotationPropagationStart::~RotationPropagationStart() = default;

Result<RotationPropagationStart> RotationPropagationStart::create(const Positions& V0,
                                                                 const Triangles& F,
                                                                 const MeshTopology& topology,
                                                                 const Eigen::VectorXi& constrained,
                                                                 double lambda) {
  if (!(lambda > 0) || !std::isfinite(lambda)) {
    return Error(ErrorCode::InvalidArgument, "lambda must be positive and finite");
  }
  auto impl = std::make_unique<Impl>();
  impl->nv = static_cast<int>(V0.rows());
  impl->V0 = V0;
  impl->constrained = constrained;
  impl->lambda = lambda;

  // Patches: constrained vertices joined by mesh edges (union-find over the constrained rows).
  std::vector<int> row_of(impl->nv, -1);
  for (Eigen::Index j = 0; j < constrained.size(); ++j) row_of[constrained(j)] = static_cast<int>(j);
  std::vector<int> parent(constrained.size());
  for (size_t j = 0; j < parent.size(); ++j) parent[j] = static_cast<int>(j);
  auto find = [&parent](int j) {
    while (parent[j] != j) j = parent[j] = parent[parent[j]];
    return j;
  };
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    const int v = constrained(j);
    for (int k = topology.vv_offsets[v]; k < topology.vv_offsets[v + 1]; ++k) {
      const int other = row_of[topology.vv_neighbors[k]];
      if (other >= 0) parent[find(static_cast<int>(j))] = find(other);
    }
  }
  std::vector<int> label(constrained.size(), -1);
  impl->patch.resize(constrained.size());
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    const int root = find(static_cast<int>(j));
    if (label[root] < 0) label[root] = impl->patch_count++;
    impl->patch[j] = label[root];
  }

  impl->L = laplacian_matrix(V0, F, topology, LaplacianWeights::Cotangent);
  SparseMatrix K = impl->L;
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    K.coeffRef(constrained(j), constrained(j)) += lambda;
  }
  K.makeCompressed();
  // Kept for the solver's life and solved with a few right-hand sides (sparse_cholesky.h).
  impl->factor.set_simplicial_solves(true);
  MD_RETURN_IF_ERROR(impl->factor.analyze(K));
  MD_RETURN_IF_ERROR(impl->factor.factorize(K));
  return RotationPropagationStart(std::move(impl));
}

Result<Positions> RotationPropagationStart::guess(const Positions& targets) const {
  const Impl& s = *impl_;
  const Eigen::Index nc = s.constrained.size();
  // 1. One rotation per patch: Procrustes of the centred rest points onto the centred targets.
  std::vector<Eigen::Vector3d> rest_mean(s.patch_count, Eigen::Vector3d::Zero());
  std::vector<Eigen::Vector3d> target_mean(s.patch_count, Eigen::Vector3d::Zero());
  std::vector<int> count(s.patch_count, 0);
  for (Eigen::Index j = 0; j < nc; ++j) {
    rest_mean[s.patch[j]] += s.V0.row(s.constrained(j)).transpose();
    target_mean[s.patch[j]] += targets.row(j).transpose();
    ++count[s.patch[j]];
  }
  std::vector<Eigen::Matrix3d> covariance(s.patch_count, Eigen::Matrix3d::Zero());
  std::vector<Eigen::Matrix3d> scatter(s.patch_count, Eigen::Matrix3d::Zero());
  for (int p = 0; p < s.patch_count; ++p) {
    rest_mean[p] /= count[p];
    target_mean[p] /= count[p];
  }
  for (Eigen::Index j = 0; j < nc; ++j) {
    const int p = s.patch[j];
    const Eigen::Vector3d a = s.V0.row(s.constrained(j)).transpose() - rest_mean[p];
    const Eigen::Vector3d b = targets.row(j).transpose() - target_mean[p];
    covariance[p].noalias() += b * a.transpose();
    scatter[p].noalias() += a * a.transpose();
  }
  Eigen::MatrixXd q_hat(nc, 4);
  std::vector<Eigen::Vector4d> patch_quaternion(s.patch_count);
  for (int p = 0; p < s.patch_count; ++p) {
    // A rotation is defined by a patch whose rest points span a plane: the middle eigenvalue of
    // their scatter must not vanish next to the largest.
    const Eigen::Vector3d spread =
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(scatter[p], Eigen::EigenvaluesOnly)
            .eigenvalues();
    Eigen::Quaterniond q = Eigen::Quaterniond::Identity();
    if (count[p] >= 3 && spread(1) > 1e-10 * spread(2) && covariance[p].squaredNorm() > 0) {
      q = Eigen::Quaterniond(closest_rotation(covariance[p]));
      if (q.w() < 0) q.coeffs() = -q.coeffs();  // the representative nearest the identity
    }
    patch_quaternion[p] << q.w(), q.x(), q.y(), q.z();
  }
  for (Eigen::Index j = 0; j < nc; ++j) q_hat.row(j) = patch_quaternion[s.patch[j]].transpose();

  // 2. Harmonic interpolation of the quaternions, normalised per vertex.
  Eigen::MatrixXd b = Eigen::MatrixXd::Zero(s.nv, 4);
  for (Eigen::Index j = 0; j < nc; ++j) b.row(s.constrained(j)) = s.lambda * q_hat.row(j);
  const Eigen::MatrixXd Q = s.factor.solve(b);
  if (!Q.allFinite()) {
    return Error(ErrorCode::NumericalFailure, "rotation propagation produced non-finite values");
  }
  s.rotations.resize(s.nv);
  for (int v = 0; v < s.nv; ++v) {
    const Eigen::Quaterniond q(Q(v, 0), Q(v, 1), Q(v, 2), Q(v, 3));
    // Opposite rotations can cancel to ~0 far from every handle: no rotation there.
    s.rotations[v] = q.norm() > 1e-8 ? q.normalized().toRotationMatrix()
                                     : Eigen::Matrix3d::Identity();
  }

  // 3. ARAP's global step with those rotations (spokes, the Laplacian's clamped weights).
  Eigen::MatrixXd rhs = Eigen::MatrixXd::Zero(s.nv, 3);
  for (int c = 0; c < s.L.outerSize(); ++c) {
    for (SparseMatrix::InnerIterator it(s.L, c); it; ++it) {
      const int i = static_cast<int>(it.row());
      if (i == c) continue;
      const double w = -it.value();
      const Eigen::Vector3d e0 = (s.V0.row(i) - s.V0.row(c)).transpose();
      rhs.row(i) += (0.5 * w * (s.rotations[i] + s.rotations[c]) * e0).transpose();
    }
  }
  for (Eigen::Index j = 0; j < nc; ++j) rhs.row(s.constrained(j)) += s.lambda * targets.row(j);
  Positions V = s.factor.solve(rhs);
  if (!V.allFinite()) {
    return Error(ErrorCode::NumericalFailure, "rotation propagation produced non-finite positions");
  }
  return V;
}

const std::vector<Eigen::Matrix3d>& RotationPropagationStart::rotations() const {
  return impl_->rotations;
}

}  // namespace meshdeform::core
