#include "core/mesh/measures.h"

#include <algorithm>
#include <array>
#include <cmath>

#include <Eigen/Geometry>

#include "core/mesh/fast_angle.h"

namespace meshdeform::core {
namespace {

// Corners or edges per block of the batched atan2 (a few KB on the stack).
constexpr Eigen::Index kBlock = 256;

// The squared log area ratio of a face; a collapsed face has infinite log distortion, reported
// as large but finite (50).
double area_log_error2(double rest_area, double area) {
  const double log_ratio = (rest_area > 0 && area > 0) ? std::log(area / rest_area) : 50.0;
  return log_ratio * log_ratio;
}

// The faces [first, end): the corners of face f get slots c = 3 (f - first) + k (corner k at
// F(f, k), between e1 = F(f, k+1) - F(f, k) and e2 = F(f, k+2) - F(f, k)), with e1 . e2 in
// dot[c] and |e1 x e2| in cross_norm[c], the arguments of the angle's atan2 (accurate near 0 and
// pi, unlike acos of a normalised dot product). |e1 x e2| is twice the face's area at each of
// its corners, so it is computed once, from n = (b - a) x (c - a); per_face(f, b - a, c - b,
// a - c, n, |n|) does what else a caller needs there (areas, normals, length ratios). One pass a
// face: this is a server session's full-resolution metric after every move.
template <typename PerFace>
void face_block(const Positions& V, const Triangles& F, Eigen::Index first, Eigen::Index end,
                double* cross_norm, double* dot, PerFace&& per_face) {
  for (Eigen::Index f = first; f < end; ++f) {
    const Eigen::Vector3d a = V.row(F(f, 0)), b = V.row(F(f, 1)), c = V.row(F(f, 2));
    const Eigen::Vector3d ab = b - a, bc = c - b, ca = a - c;
    const Eigen::Vector3d n = ab.cross(c - a);
    const double len = n.norm();
    double* cn = cross_norm + 3 * (f - first);
    double* d = dot + 3 * (f - first);
    cn[0] = cn[1] = cn[2] = len;
    d[0] = ab.dot(c - a);   // at a: (b - a) . (c - a)
    d[1] = bc.dot(a - b);   // at b: (c - b) . (a - b)
    d[2] = ca.dot(b - c);   // at c: (a - c) . (b - c)
    per_face(f, ab, bc, ca, n, len);
  }
}

// A face's unit normal n / |n| (zero for a zero-area face), as face_normals computes it.
Eigen::Vector3d unit_normal(const Eigen::Vector3d& n, double len) {
  return len > 0 ? Eigen::Vector3d(n / len) : Eigen::Vector3d::Zero();
}

// The interior edges [first, end): edge e's slot e - first gets |n0 x n1| in cross_norm and
// n0 . n1 in dot for the unit normals N of its two faces, the arguments of its dihedral angle's
// atan2.
template <typename Normals>
void dihedral_block(const Normals& N, const MeshTopology& topology, Eigen::Index first,
                    Eigen::Index end, double* cross_norm, double* dot) {
  for (Eigen::Index e = first; e < end; ++e) {
    const Eigen::Vector3d n0 = N.row(topology.edge_faces(e, 0));
    const Eigen::Vector3d n1 = N.row(topology.edge_faces(e, 1));
    cross_norm[e - first] = n0.cross(n1).norm();
    dot[e - first] = n0.dot(n1);
  }
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
    N.row(f) = unit_normal(n, n.norm());
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
  // 187k vertices, worth the solver's threads and the batched atan2.
  const bool parallel = threads > 1 && nf > 8000;
  const Eigen::Index blocks = (nf + kBlock - 1) / kBlock;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (Eigen::Index b = 0; b < blocks; ++b) {
    const Eigen::Index first = b * kBlock, end = std::min(nf, first + kBlock);
    // theta holds the dot products until the batched atan2.
    std::array<double, 3 * kBlock> cross_norm;
    double* theta = m.theta.data() + 3 * first;
    face_block(V, F, first, end, cross_norm.data(), theta,
               [&m](Eigen::Index f, const Eigen::Vector3d& ab, const Eigen::Vector3d& bc,
                    const Eigen::Vector3d& ca, const Eigen::Vector3d&, double len) {
                 // |e2| / |e1| at each corner: |ca| / |ab|, |ab| / |bc|, |bc| / |ca|.
                 const double lab = ab.norm(), lbc = bc.norm(), lca = ca.norm();
                 m.ratio(3 * f) = lab > 0 ? lca / lab : 0.0;
                 m.ratio(3 * f + 1) = lbc > 0 ? lab / lbc : 0.0;
                 m.ratio(3 * f + 2) = lca > 0 ? lbc / lca : 0.0;
                 m.area(f) = 0.5 * len;
               });
    atan2_nonnegative(cross_norm.data(), theta, theta, 3 * (end - first));
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
  const Eigen::Index blocks = (ne + kBlock - 1) / kBlock;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (Eigen::Index b = 0; b < blocks; ++b) {
    const Eigen::Index first = b * kBlock, end = std::min(ne, first + kBlock);
    std::array<double, kBlock> cross_norm;
    // phi holds the dot products until the batched atan2.
    dihedral_block(N, topology, first, end, cross_norm.data(), phi.data() + first);
    atan2_nonnegative(cross_norm.data(), phi.data() + first, phi.data() + first, end - first);
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
  double area_log2 = 0;
  for (Eigen::Index f = 0; f < rest.area.size(); ++f) {
    area_log2 += area_log_error2(rest.area(f), deformed.area(f));
  }
  out.area_log_rms =
      rest.area.size() == 0 ? 0.0 : std::sqrt(area_log2 / static_cast<double>(rest.area.size()));
  return out;
}

AngleErrors angle_errors(const Measures& rest, const Positions& V, const Triangles& F,
                         const MeshTopology& topology, int threads) {
  const Eigen::Index nf = F.rows();
  const Eigen::Index ne = topology.interior_edges.rows();
  const Eigen::Index face_blocks = (nf + kBlock - 1) / kBlock;
  const Eigen::Index edge_blocks = (ne + kBlock - 1) / kBlock;
  // Per-block sums, added in block order afterwards: the same value at any thread count.
  Eigen::VectorXd theta_sum(face_blocks), area_sum(face_blocks), phi_sum(edge_blocks);
  // Unit face normals (face_normals), for the dihedral angles: row-major, so that an edge's
  // two normals are two reads, not six strided ones.
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> N(nf, 3);
  const bool parallel = threads > 1 && nf > 8000;
#pragma omp parallel num_threads(threads) if (parallel)
  {
    std::array<double, 3 * kBlock> cross_norm, angle;
#pragma omp for schedule(static)
    for (Eigen::Index b = 0; b < face_blocks; ++b) {
      const Eigen::Index first = b * kBlock, end = std::min(nf, first + kBlock);
      double area_log2 = 0;
      face_block(V, F, first, end, cross_norm.data(), angle.data(),
                 [&](Eigen::Index f, const Eigen::Vector3d&, const Eigen::Vector3d&,
                     const Eigen::Vector3d&, const Eigen::Vector3d& n, double len) {
                   area_log2 += area_log_error2(rest.area(f), 0.5 * len);
                   N.row(f) = unit_normal(n, len);
                 });
      const Eigen::Index corners = 3 * (end - first);
      atan2_nonnegative(cross_norm.data(), angle.data(), angle.data(), corners);
      double theta2 = 0;
      for (Eigen::Index i = 0; i < corners; ++i) {
        const double d = rest.theta(3 * first + i) - angle[static_cast<std::size_t>(i)];
        theta2 += d * d;
      }
      theta_sum(b) = theta2;
      area_sum(b) = area_log2;
    }
#pragma omp for schedule(static)
    for (Eigen::Index b = 0; b < edge_blocks; ++b) {
      const Eigen::Index first = b * kBlock, end = std::min(ne, first + kBlock);
      dihedral_block(N, topology, first, end, cross_norm.data(), angle.data());
      atan2_nonnegative(cross_norm.data(), angle.data(), angle.data(), end - first);
      double phi2 = 0;
      for (Eigen::Index e = first; e < end; ++e) {
        const double d = rest.phi(e) - angle[static_cast<std::size_t>(e - first)];
        phi2 += d * d;
      }
      phi_sum(b) = phi2;
    }
  }
  auto rms_of = [](const Eigen::VectorXd& sums, Eigen::Index count) {
    double total = 0;
    for (Eigen::Index b = 0; b < sums.size(); ++b) total += sums(b);
    return count == 0 ? 0.0 : std::sqrt(total / static_cast<double>(count));
  };
  AngleErrors out;
  out.e_theta = rms_of(theta_sum, 3 * nf);
  out.e_phi = rms_of(phi_sum, ne);
  out.area_log_rms = rms_of(area_sum, nf);
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
