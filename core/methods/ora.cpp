#include "core/methods/ora.h"

#include <cmath>
#include <limits>
#include <string>

#include <Eigen/Geometry>

#include "core/methods/constraints.h"
#include "core/linalg/sparse_cholesky.h"
#include "core/mesh/topology.h"
#include "core/mesh/validate.h"

namespace meshdeform::core {
namespace {

double face_area(const Positions& V, const Triangles& F, Eigen::Index f) {
  const Eigen::Vector3d a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
  return 0.5 * (b - a).cross(c - a).norm();
}

}  // namespace

Eigen::VectorXd triangle_scale_factors(const Positions& V0, const Positions& V, const Triangles& F) {
  Eigen::VectorXd sigma(F.rows());
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const double a0 = face_area(V0, F, f);
    sigma(f) = a0 > 0 ? face_area(V, F, f) / a0 : std::numeric_limits<double>::infinity();
  }
  return sigma;
}

Result<Eigen::VectorXd> face_scales_from_regions(const std::vector<MagnifyRegion>& regions,
                                                 const Triangles& F, int vertex_count) {
  Eigen::VectorXd scale = Eigen::VectorXd::Ones(F.rows());
  for (size_t r = 0; r < regions.size(); ++r) {
    const MagnifyRegion& region = regions[r];
    const std::string name = "magnify region " + std::to_string(r);
    if (!(region.scale > 0) || !std::isfinite(region.scale)) {
      return Error(ErrorCode::InvalidArgument,
                   name + ": scale must be positive and finite, got " + std::to_string(region.scale));
    }
    int covered = 0;
    if (region.faces.size() > 0) {
      for (Eigen::Index k = 0; k < region.faces.size(); ++k) {
        const int f = region.faces(k);
        if (f < 0 || f >= F.rows()) {
          return Error(ErrorCode::InvalidArgument, name + ": face " + std::to_string(f) +
                                                       " out of range (#F=" +
                                                       std::to_string(F.rows()) + ")");
        }
        scale(f) = region.scale;
        ++covered;
      }
    } else {
      std::vector<char> inside(vertex_count, 0);
      for (Eigen::Index k = 0; k < region.vertices.size(); ++k) {
        const int v = region.vertices(k);
        if (v < 0 || v >= vertex_count) {
          return Error(ErrorCode::InvalidArgument, name + ": vertex " + std::to_string(v) +
                                                       " out of range (#V=" +
                                                       std::to_string(vertex_count) + ")");
        }
        inside[v] = 1;
      }
      for (Eigen::Index f = 0; f < F.rows(); ++f) {
        if (inside[F(f, 0)] && inside[F(f, 1)] && inside[F(f, 2)]) {
          scale(f) = region.scale;
          ++covered;
        }
      }
    }
    if (covered == 0) {
      return Error(ErrorCode::InvalidArgument,
                   name + " is empty: it names no face (a vertex region must contain all three "
                          "corners of at least one face)");
    }
  }
  return scale;
}

struct RigidityStitcher::Impl {
  SparseCholesky cholesky;
  Positions V0;
  Triangles F;
  Eigen::VectorXd rest_area;
  Eigen::VectorXi constrained;
  MeshTopology topology;
  double lambda = 0;
  double length_scale = 1;
};

RigidityStitcher::RigidityStitcher(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
RigidityStitcher::RigidityStitcher(RigidityStitcher&&) noexcept = default;
RigidityStitcher& RigidityStitcher::operator=(RigidityStitcher&&) noexcept = default;
RigidityStitcher::~RigidityStitcher() = default;

Result<RigidityStitcher> RigidityStitcher::create(const Positions& V0, const Triangles& F,
                                                  const Eigen::VectorXi& constrained,
                                                  double lambda) {
  MD_RETURN_IF_ERROR(validate_triangle_mesh(V0, F));
  MD_ASSIGN_OR_RETURN(const MeshTopology topology, build_topology(F, static_cast<int>(V0.rows())));
  return create(V0, F, topology, constrained, lambda);
}

Result<RigidityStitcher> RigidityStitcher::create(const Positions& V0, const Triangles& F,
                                                  const MeshTopology& topology,
                                                  const Eigen::VectorXi& constrained,
                                                  double lambda) {
  MD_ASSERT(topology.vertex_count == V0.rows() && topology.face_count == F.rows());
  if (!(lambda > 0) || !std::isfinite(lambda)) {
    return Error(ErrorCode::InvalidArgument, "lambda must be positive and finite");
  }
  auto impl = std::make_unique<Impl>();
  impl->topology = topology;
  MD_RETURN_IF_ERROR(check_constrained(constrained, impl->topology, 1));
  const int n = static_cast<int>(V0.rows());
  // Each face edge (i, j) adds (x_i - x_j)^2: an edge-count weighted graph Laplacian.
  std::vector<Eigen::Triplet<double>> entries;
  entries.reserve(12 * F.rows() + constrained.size());
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int i = F(f, k), j = F(f, (k + 1) % 3);
      entries.emplace_back(i, i, 1.0);
      entries.emplace_back(j, j, 1.0);
      entries.emplace_back(i, j, -1.0);
      entries.emplace_back(j, i, -1.0);
    }
  }
  for (Eigen::Index c = 0; c < constrained.size(); ++c) {
    entries.emplace_back(constrained(c), constrained(c), lambda);
  }
  SparseMatrix A(n, n);
  A.setFromTriplets(entries.begin(), entries.end());
  MD_RETURN_IF_ERROR(impl->cholesky.analyze(A));
  MD_RETURN_IF_ERROR(impl->cholesky.factorize(A));
  impl->V0 = V0;
  impl->F = F;
  impl->rest_area.resize(F.rows());
  for (Eigen::Index f = 0; f < F.rows(); ++f) impl->rest_area(f) = face_area(V0, F, f);
  impl->constrained = constrained;
  impl->lambda = lambda;
  impl->length_scale = (V0.colwise().maxCoeff() - V0.colwise().minCoeff()).norm();
  return RigidityStitcher(std::move(impl));
}

Result<Positions> RigidityStitcher::stitch(const Positions& V, const Positions& targets,
                                           const Eigen::VectorXd& face_scale) const {
  const Impl& s = *impl_;
  if (V.rows() != s.V0.rows() || !V.allFinite()) {
    return Error(ErrorCode::InvalidArgument,
                 "stitch needs " + std::to_string(s.V0.rows()) + " finite positions, got " +
                     std::to_string(V.rows()));
  }
  if (face_scale.size() != 0 && face_scale.size() != s.F.rows()) {
    return Error(ErrorCode::InvalidArgument, "face_scale has " + std::to_string(face_scale.size()) +
                                                 " entries for " + std::to_string(s.F.rows()) +
                                                 " faces");
  }
  MD_RETURN_IF_ERROR(
      check_targets(targets, s.constrained, s.topology, s.length_scale, /*require_distinct=*/false));
  Eigen::MatrixXd b = Eigen::MatrixXd::Zero(V.rows(), 3);
  for (Eigen::Index f = 0; f < s.F.rows(); ++f) {
    const double area = face_area(V, s.F, f);
    const double k = face_scale.size() != 0 ? face_scale(f) : 1.0;
    // tau_t = k sqrt(Area_t / Area'_t); a collapsed face keeps its (zero) edges.
    const double tau = area > 0 ? k * std::sqrt(s.rest_area(f) / area) : 1.0;
    for (int e = 0; e < 3; ++e) {
      const int i = s.F(f, e), j = s.F(f, (e + 1) % 3);
      const Eigen::RowVector3d d = tau * (V.row(j) - V.row(i));
      b.row(j) += d;
      b.row(i) -= d;
    }
  }
  for (Eigen::Index c = 0; c < s.constrained.size(); ++c) {
    b.row(s.constrained(c)) += s.lambda * targets.row(c);
  }
  Positions out = s.cholesky.solve(b);
  if (!out.allFinite()) {
    return Error(ErrorCode::NumericalFailure, "stitching produced non-finite positions");
  }
  return out;
}

}  // namespace meshdeform::core
