#include "core/measures.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>

namespace meshdeform::core {
namespace {

// atan2 of |a x b| and a . b: accurate near 0 and pi, unlike acos of a normalised dot product.
double angle_between(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b));
}

double rms(const Eigen::VectorXd& x) {
  return x.size() == 0 ? 0.0 : std::sqrt(x.squaredNorm() / static_cast<double>(x.size()));
}

}  // namespace

Positions face_normals(const Positions& V, const Triangles& F) {
  Positions N(F.rows(), 3);
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const Eigen::Vector3d a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
    const Eigen::Vector3d n = (b - a).cross(c - a);
    const double len = n.norm();
    N.row(f) = len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
  }
  return N;
}

Measures compute_measures(const Positions& V, const Triangles& F, const MeshTopology& topology,
                          int threads) {
  Measures m;
  const Eigen::Index nf = F.rows();
  m.theta.resize(3 * nf);
  m.ratio.resize(3 * nf);
  m.area.resize(nf);
  // A server session's full-resolution metrics after every move: about 1.7 million atan2 at
  // 187k vertices, worth the solver's threads.
  const bool parallel = threads > 1 && nf > 8000;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (Eigen::Index f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d v = V.row(F(f, k));
      const Eigen::Vector3d e1 = Eigen::Vector3d(V.row(F(f, (k + 1) % 3))) - v;
      const Eigen::Vector3d e2 = Eigen::Vector3d(V.row(F(f, (k + 2) % 3))) - v;
      m.theta(3 * f + k) = angle_between(e1, e2);
      const double l1 = e1.norm();
      m.ratio(3 * f + k) = l1 > 0 ? e2.norm() / l1 : 0.0;
      if (k == 0) m.area(f) = 0.5 * e1.cross(e2).norm();
    }
  }
  m.phi = dihedral_angles(V, F, topology, threads);
  return m;
}

Eigen::VectorXd dihedral_angles(const Positions& V, const Triangles& F,
                                const MeshTopology& topology, int threads) {
  const Positions N = face_normals(V, F);
  const Eigen::Index ne = topology.interior_edges.rows();
  Eigen::VectorXd phi(ne);
  const bool parallel = threads > 1 && F.rows() > 8000;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (Eigen::Index e = 0; e < ne; ++e) {
    phi(e) = angle_between(N.row(topology.edge_faces(e, 0)).transpose(),
                           N.row(topology.edge_faces(e, 1)).transpose());
  }
  return phi;
}

int count_folds(const Eigen::VectorXd& rest_phi, const Eigen::VectorXd& phi) {
  int folds = 0;
  for (Eigen::Index e = 0; e < std::min(rest_phi.size(), phi.size()); ++e) {
    folds += std::abs(phi(e) - rest_phi(e)) > 0.5 * M_PI ? 1 : 0;
  }
  return folds;
}

AngleErrors angle_errors(const Measures& rest, const Measures& deformed) {
  AngleErrors out;
  out.e_theta = rms(rest.theta - deformed.theta);
  out.e_phi = rms(rest.phi - deformed.phi);
  Eigen::VectorXd log_ratio(rest.area.size());
  for (Eigen::Index f = 0; f < rest.area.size(); ++f) {
    const double a0 = rest.area(f), a1 = deformed.area(f);
    // A collapsed face has infinite log distortion; report it as large but finite.
    log_ratio(f) = (a0 > 0 && a1 > 0) ? std::log(a1 / a0) : 50.0;
  }
  out.area_log_rms = rms(log_ratio);
  return out;
}

Distortion local_distortion(const Measures& rest, const Measures& deformed, const Triangles& F,
                            const MeshTopology& topology) {
  Distortion d;
  const Eigen::Index nf = F.rows();
  d.per_face.resize(nf);
  Eigen::VectorXd sum = Eigen::VectorXd::Zero(topology.vertex_count);
  Eigen::VectorXd count = Eigen::VectorXd::Zero(topology.vertex_count);
  for (Eigen::Index f = 0; f < nf; ++f) {
    double s = 0;
    for (int k = 0; k < 3; ++k) {
      const double err = rest.theta(3 * f + k) - deformed.theta(3 * f + k);
      s += err * err;
      sum(F(f, k)) += err * err;
      count(F(f, k)) += 1;
    }
    d.per_face(f) = std::sqrt(s / 3.0);
  }
  for (Eigen::Index e = 0; e < topology.interior_edges.rows(); ++e) {
    const double err = rest.phi(e) - deformed.phi(e);
    for (int k = 0; k < 2; ++k) {
      sum(topology.interior_edges(e, k)) += err * err;
      count(topology.interior_edges(e, k)) += 1;
    }
  }
  d.per_vertex = (sum.array() / count.array().max(1.0)).sqrt();
  return d;
}

}  // namespace meshdeform::core
