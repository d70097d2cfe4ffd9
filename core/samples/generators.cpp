#include "core/samples/generators.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <functional>
#include <numbers>
#include <queue>
#include <random>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include <Eigen/Geometry>
#include <OpenMesh/Tools/Subdivider/Uniform/LoopT.hh>

#include "core/mesh/openmesh_adapter.h"
#include "core/mesh/validate.h"

namespace meshdeform::core {
namespace {

constexpr double kPi = std::numbers::pi;

double degrees(double deg) { return deg * kPi / 180.0; }

Eigen::VectorXi free_selection(int vertex_count) {
  return Eigen::VectorXi::Constant(vertex_count, static_cast<int>(VertexRole::Free));
}

constexpr int kFixed = static_cast<int>(VertexRole::Fixed);
constexpr int kHandle = static_cast<int>(VertexRole::Handle);

}  // namespace

// ---------------------------------------------------------------------------------------------
// Irregular variants and subdivision (OpenMesh; its mesh type is in core/mesh/openmesh_adapter.h).
// ---------------------------------------------------------------------------------------------
namespace {

using detail::OmMesh;
using detail::from_openmesh;
using detail::to_eigen;
using detail::to_om;
using detail::to_openmesh;

/// Uniform doubles in [0, 1) from the 53 high bits of mt19937_64, whose output sequence the
/// standard fixes (std::uniform_real_distribution's is implementation-defined).
class UniformRng {
 public:
  explicit UniformRng(std::uint64_t seed) : engine_(seed) {}
  double uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  double uniform(double lo, double hi) { return lo + (hi - lo) * uniform(); }
  size_t index(size_t n) { return std::min(n - 1, static_cast<size_t>(uniform() * n)); }

 private:
  std::mt19937_64 engine_;
};

double min_corner_angle(const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                        const Eigen::Vector3d& c) {
  auto angle = [](const Eigen::Vector3d& p, const Eigen::Vector3d& q, const Eigen::Vector3d& r) {
    const Eigen::Vector3d e1 = q - p, e2 = r - p;
    return std::atan2(e1.cross(e2).norm(), e1.dot(e2));
  };
  return std::min({angle(a, b, c), angle(b, c, a), angle(c, a, b)});
}

/// The remesher: target edge lengths from a density field, then split / collapse / flip /
/// jitter / sliver passes, each checking that no face folds over or degenerates.
class IrregularRemesher {
 public:
  IrregularRemesher(OmMesh& mesh, const Eigen::VectorXi& roles, std::uint64_t seed,
                    const IrregularOptions& options)
      : mesh_(mesh), rng_(seed), options_(options) {
    mesh_.add_property(role_);
    mesh_.add_property(base_length_);
    for (const auto v : mesh_.vertices()) {
      mesh_.property(role_, v) = roles(v.idx());
      double sum = 0;
      int count = 0;
      for (const auto h : mesh_.voh_range(v)) {
        sum += mesh_.calc_edge_length(h);
        ++count;
      }
      mesh_.property(base_length_, v) = count > 0 ? sum / count : 0.0;
    }
    build_density_field();
  }
  ~IrregularRemesher() {
    mesh_.remove_property(role_);
    mesh_.remove_property(base_length_);
  }
  IrregularRemesher(const IrregularRemesher&) = delete;
  IrregularRemesher& operator=(const IrregularRemesher&) = delete;

  void run() {
    for (int pass = 0; pass < 4; ++pass) {
      const int splits = split_long_edges();
      const int collapses = collapse_short_edges();
      if (splits == 0 && collapses == 0) break;
    }
    mesh_.garbage_collection();
    flip_edges();
    jitter_vertices();
    add_slivers();
    mesh_.garbage_collection();
  }

  Eigen::VectorXi roles() const {
    Eigen::VectorXi roles(static_cast<Eigen::Index>(mesh_.n_vertices()));
    for (const auto v : mesh_.vertices()) roles(v.idx()) = mesh_.property(role_, v);
    return roles;
  }

 private:
  struct Blob {
    Eigen::Vector3d centre;
    double radius, sign;
  };

  /// Relative target length contrast^(n(x)/2), n in [-1, 1] a sum of Gaussian blobs centred on
  /// random vertices; scale_ makes the mean density (1 / h^2 over the area) that of the input, so
  /// the vertex count stays about the same.
  void build_density_field() {
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e300), hi = -lo;
    for (const auto v : mesh_.vertices()) {
      lo = lo.cwiseMin(to_eigen(mesh_.point(v)));
      hi = hi.cwiseMax(to_eigen(mesh_.point(v)));
    }
    const double diagonal = (hi - lo).norm();
    for (int k = 0; k < options_.density_blobs; ++k) {
      const auto v = mesh_.vertex_handle(static_cast<unsigned>(rng_.index(mesh_.n_vertices())));
      blobs_.push_back(
          {to_eigen(mesh_.point(v)), diagonal * rng_.uniform(0.08, 0.2), k % 2 == 0 ? 1.0 : -1.0});
    }
    scale_ = 1.0;
    double weighted = 0, area = 0;
    for (const auto f : mesh_.faces()) {
      Eigen::Vector3d c = Eigen::Vector3d::Zero();
      for (const auto v : mesh_.fv_range(f)) c += to_eigen(mesh_.point(v)) / 3.0;
      const double a = mesh_.calc_face_area(f);
      const double h = relative_length(c);
      weighted += a / (h * h);
      area += a;
    }
    scale_ = area > 0 ? std::sqrt(weighted / area) : 1.0;
  }

  double relative_length(const Eigen::Vector3d& x) const {
    double n = 0;
    for (const auto& blob : blobs_) {
      n += blob.sign * std::exp(-(x - blob.centre).squaredNorm() / (blob.radius * blob.radius));
    }
    n = std::clamp(n, -1.0, 1.0);
    return std::pow(std::max(options_.density_contrast, 1.0), 0.5 * n);
  }

  double target_length(OmMesh::EdgeHandle e) const {
    const auto h = mesh_.halfedge_handle(e, 0);
    const auto a = mesh_.from_vertex_handle(h), b = mesh_.to_vertex_handle(h);
    const Eigen::Vector3d mid = 0.5 * (to_eigen(mesh_.point(a)) + to_eigen(mesh_.point(b)));
    const double base = 0.5 * (mesh_.property(base_length_, a) + mesh_.property(base_length_, b));
    return scale_ * base * relative_length(mid);
  }

  int role_of_new_vertex(OmMesh::VertexHandle a, OmMesh::VertexHandle b) const {
    const int ra = mesh_.property(role_, a), rb = mesh_.property(role_, b);
    return ra == rb ? ra : static_cast<int>(VertexRole::Free);
  }

  OmMesh::VertexHandle split(OmMesh::EdgeHandle e, double t) {
    const auto h = mesh_.halfedge_handle(e, 0);
    const auto a = mesh_.from_vertex_handle(h), b = mesh_.to_vertex_handle(h);
    const int role = role_of_new_vertex(a, b);
    const double base = 0.5 * (mesh_.property(base_length_, a) + mesh_.property(base_length_, b));
    const OpenMesh::Vec3d p = mesh_.point(a) + t * (mesh_.point(b) - mesh_.point(a));
    const auto v = mesh_.split(e, p);
    mesh_.property(role_, v) = role;
    mesh_.property(base_length_, v) = base;
    return v;
  }

  int split_long_edges() {
    int splits = 0;
    for (int pass = 0; pass < 6; ++pass) {
      int count = 0;
      const size_t n = mesh_.n_edges();
      for (size_t i = 0; i < n; ++i) {
        const auto e = mesh_.edge_handle(static_cast<unsigned>(i));
        if (mesh_.status(e).deleted()) continue;
        if (mesh_.calc_edge_length(e) > 4.0 / 3.0 * target_length(e)) {
          split(e, 0.5);
          ++count;
        }
      }
      splits += count;
      if (count == 0) break;
    }
    return splits;
  }

  /// A vertex that must stay: on the mesh boundary, or next to a vertex of another role (so that
  /// the fixed and handle regions keep their borders).
  bool is_pinned(OmMesh::VertexHandle v) const {
    if (mesh_.is_boundary(v)) return true;
    const int role = mesh_.property(role_, v);
    for (const auto w : mesh_.vv_range(v)) {
      if (mesh_.property(role_, w) != role) return true;
    }
    return false;
  }

  /// Would moving `v` to `p` keep every incident face unfolded (normal within `max_turn` of its
  /// old direction) and not sharper than `min_angle`? Faces in `skip` are ignored (they vanish).
  bool is_move_ok(OmMesh::VertexHandle v, const Eigen::Vector3d& p, double max_turn,
                  double min_angle, OmMesh::FaceHandle skip0 = OmMesh::FaceHandle(),
                  OmMesh::FaceHandle skip1 = OmMesh::FaceHandle()) const {
    for (const auto f : mesh_.vf_range(v)) {
      if (f == skip0 || f == skip1) continue;
      std::array<Eigen::Vector3d, 3> old_corners, new_corners;
      int k = 0;
      for (const auto w : mesh_.fv_range(f)) {
        old_corners[static_cast<size_t>(k)] = to_eigen(mesh_.point(w));
        new_corners[static_cast<size_t>(k)] = w == v ? p : old_corners[static_cast<size_t>(k)];
        ++k;
      }
      const Eigen::Vector3d n0 =
          (old_corners[1] - old_corners[0]).cross(old_corners[2] - old_corners[0]);
      const Eigen::Vector3d n1 =
          (new_corners[1] - new_corners[0]).cross(new_corners[2] - new_corners[0]);
      if (n1.norm() <= 1e-12 * n0.norm()) return false;
      if (n0.normalized().dot(n1.normalized()) < std::cos(max_turn)) return false;
      if (min_corner_angle(new_corners[0], new_corners[1], new_corners[2]) < min_angle) {
        return false;
      }
    }
    return true;
  }

  int collapse_short_edges() {
    int collapses = 0;
    const size_t n = mesh_.n_edges();
    for (size_t i = 0; i < n; ++i) {
      const auto e = mesh_.edge_handle(static_cast<unsigned>(i));
      if (mesh_.status(e).deleted()) continue;
      const double target = target_length(e);
      if (mesh_.calc_edge_length(e) >= 0.8 * target) continue;
      for (int side = 0; side < 2; ++side) {
        const auto h = mesh_.halfedge_handle(e, static_cast<unsigned>(side));
        const auto from = mesh_.from_vertex_handle(h), to = mesh_.to_vertex_handle(h);
        if (is_pinned(from) || !mesh_.is_collapse_ok(h)) continue;
        const Eigen::Vector3d p = to_eigen(mesh_.point(to));
        // No new edge longer than the split threshold (else split and collapse oscillate).
        bool is_short = true;
        for (const auto w : mesh_.vv_range(from)) {
          if ((to_eigen(mesh_.point(w)) - p).norm() > 4.0 / 3.0 * target) is_short = false;
        }
        if (!is_short) continue;
        if (!is_move_ok(from, p, degrees(25), degrees(4), mesh_.face_handle(h),
                        mesh_.face_handle(mesh_.opposite_halfedge_handle(h)))) {
          continue;
        }
        mesh_.collapse(h);
        ++collapses;
        break;
      }
    }
    return collapses;
  }

  /// Random flips of interior edges whose two faces are nearly coplanar (so the shape does not
  /// change), when the flipped faces are not degenerate: valences become irregular.
  void flip_edges() {
    for (const auto e : mesh_.edges()) {
      if (rng_.uniform() >= options_.flip_fraction) continue;
      if (mesh_.is_boundary(e) || !mesh_.is_flip_ok(e)) continue;
      const auto h0 = mesh_.halfedge_handle(e, 0), h1 = mesh_.halfedge_handle(e, 1);
      const Eigen::Vector3d a = to_eigen(mesh_.point(mesh_.to_vertex_handle(h0)));
      const Eigen::Vector3d b = to_eigen(mesh_.point(mesh_.to_vertex_handle(h1)));
      const Eigen::Vector3d c =
          to_eigen(mesh_.point(mesh_.to_vertex_handle(mesh_.next_halfedge_handle(h0))));
      const Eigen::Vector3d d =
          to_eigen(mesh_.point(mesh_.to_vertex_handle(mesh_.next_halfedge_handle(h1))));
      // Faces (b, a, c) and (a, b, d) become (c, d, a)... checked through their normals.
      const Eigen::Vector3d n0 = (a - b).cross(c - b), n1 = (b - a).cross(d - a);
      if (n0.normalized().dot(n1.normalized()) < std::cos(degrees(8))) continue;
      const Eigen::Vector3d m0 = (d - c).cross(a - c), m1 = (c - d).cross(b - d);
      const Eigen::Vector3d n = (n0 + n1).normalized();
      if (m0.dot(n) <= 0 || m1.dot(n) <= 0) continue;
      if (min_corner_angle(c, d, a) < degrees(8) || min_corner_angle(d, c, b) < degrees(8)) {
        continue;
      }
      mesh_.flip(e);
    }
  }

  /// Moves every interior vertex by a random tangential offset (up to `jitter` of its shortest
  /// edge), halving the offset until no incident face folds or gets a corner below 3 degrees.
  void jitter_vertices() {
    for (const auto v : mesh_.vertices()) {
      const double r1 = rng_.uniform(), r2 = rng_.uniform();
      if (mesh_.is_boundary(v)) continue;
      Eigen::Vector3d normal = Eigen::Vector3d::Zero();
      double shortest = 1e300;
      const Eigen::Vector3d p = to_eigen(mesh_.point(v));
      for (const auto h : mesh_.voh_range(v)) {
        shortest = std::min(shortest, mesh_.calc_edge_length(h));
        const auto f = mesh_.face_handle(h);
        if (!f.is_valid()) continue;
        const Eigen::Vector3d b = to_eigen(mesh_.point(mesh_.to_vertex_handle(h)));
        const Eigen::Vector3d c =
            to_eigen(mesh_.point(mesh_.to_vertex_handle(mesh_.next_halfedge_handle(h))));
        normal += (b - p).cross(c - p);
      }
      if (normal.norm() == 0) continue;
      normal.normalize();
      const Eigen::Vector3d helper =
          std::abs(normal.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
      const Eigen::Vector3d t1 = normal.cross(helper).normalized(), t2 = normal.cross(t1);
      const double angle = 2 * kPi * r1;
      Eigen::Vector3d offset =
          options_.jitter * shortest * r2 * (std::cos(angle) * t1 + std::sin(angle) * t2);
      for (int attempt = 0; attempt < 3; ++attempt, offset *= 0.5) {
        if (is_move_ok(v, p + offset, degrees(15), degrees(3))) {
          mesh_.set_point(v, to_om(p + offset));
          break;
        }
      }
    }
  }

  /// Splits the longest edge of a random `skinny_fraction` of the faces at 4-12% of its length:
  /// each side of the edge gets a sliver with a corner of a few degrees.
  void add_slivers() {
    const size_t n = mesh_.n_faces();
    std::vector<char> is_new(mesh_.n_vertices(), 0);
    for (size_t i = 0; i < n; ++i) {
      const double r = rng_.uniform(), t = rng_.uniform(0.04, 0.12);
      if (r >= options_.skinny_fraction) continue;
      const auto f = mesh_.face_handle(static_cast<unsigned>(i));
      OmMesh::HalfedgeHandle longest;
      double length = 0;
      bool touches_new = false;
      for (const auto h : mesh_.fh_range(f)) {
        const auto v = mesh_.to_vertex_handle(h);
        if (static_cast<size_t>(v.idx()) < is_new.size() && is_new[static_cast<size_t>(v.idx())]) {
          touches_new = true;
        }
        if (mesh_.calc_edge_length(h) > length) {
          length = mesh_.calc_edge_length(h);
          longest = h;
        }
      }
      if (touches_new || !longest.is_valid()) continue;
      const auto opposite = mesh_.face_handle(mesh_.opposite_halfedge_handle(longest));
      if (opposite.is_valid()) {
        bool is_opposite_touched = false;
        for (const auto v : mesh_.fv_range(opposite)) {
          if (static_cast<size_t>(v.idx()) < is_new.size() &&
              is_new[static_cast<size_t>(v.idx())]) {
            is_opposite_touched = true;
          }
        }
        if (is_opposite_touched) continue;
      }
      const auto e = mesh_.edge_handle(longest);
      const double along = mesh_.halfedge_handle(e, 0) == longest ? t : 1.0 - t;
      // Slivers, not needles: every new corner stays above 1 degree (scanned meshes have worse,
      // but then the comparison would measure how each solver survives cot weights of 1e3+).
      {
        const auto h = mesh_.halfedge_handle(e, 0);
        const Eigen::Vector3d a = to_eigen(mesh_.point(mesh_.from_vertex_handle(h)));
        const Eigen::Vector3d b = to_eigen(mesh_.point(mesh_.to_vertex_handle(h)));
        const Eigen::Vector3d p = a + along * (b - a);
        bool is_too_sharp = false;
        for (const auto side : {h, mesh_.opposite_halfedge_handle(h)}) {
          if (mesh_.is_boundary(side)) continue;
          const Eigen::Vector3d c =
              to_eigen(mesh_.point(mesh_.to_vertex_handle(mesh_.next_halfedge_handle(side))));
          if (min_corner_angle(a, p, c) < degrees(1) || min_corner_angle(p, b, c) < degrees(1)) {
            is_too_sharp = true;
          }
        }
        if (is_too_sharp) continue;
      }
      const auto v = split(e, along);
      if (static_cast<size_t>(v.idx()) >= is_new.size()) {
        is_new.resize(static_cast<size_t>(v.idx()) + 1, 0);
      }
      is_new[static_cast<size_t>(v.idx())] = 1;
    }
  }

  OmMesh& mesh_;
  UniformRng rng_;
  IrregularOptions options_;
  OpenMesh::VPropHandleT<int> role_;
  OpenMesh::VPropHandleT<double> base_length_;
  std::vector<Blob> blobs_;
  double scale_ = 1.0;
};

}  // namespace

Result<DeformationBenchmark> make_irregular(const DeformationBenchmark& regular, std::uint64_t seed,
                                            const IrregularOptions& options) {
  MD_RETURN_IF_ERROR(validate_triangle_mesh(regular.mesh.V, regular.mesh.F));
  if (regular.selection.size() != regular.mesh.V.rows()) {
    return Error(ErrorCode::InvalidArgument,
                 "selection has " + std::to_string(regular.selection.size()) +
                     " entries but the mesh has " + std::to_string(regular.mesh.V.rows()) +
                     " vertices");
  }
  MD_ASSIGN_OR_RETURN(OmMesh om, to_openmesh(regular.mesh));
  DeformationBenchmark irregular;
  {
    IrregularRemesher remesher(om, regular.selection, seed, options);
    remesher.run();
    irregular.selection = remesher.roles();
  }
  irregular.name = regular.name + "_irregular";
  irregular.mesh = from_openmesh(om);
  irregular.transform = regular.transform;
  const Status status = validate_triangle_mesh(irregular.mesh.V, irregular.mesh.F);
  if (!status.ok()) {
    return Error(ErrorCode::Internal,
                 "irregular " + regular.name + " is not a valid mesh: " + status.to_string());
  }
  return irregular;
}

Result<std::vector<DeformationBenchmark>> make_irregular_suite(SuiteScale scale,
                                                               std::uint64_t seed) {
  std::vector<DeformationBenchmark> suite;
  for (const auto& regular : make_suite(scale)) {
    MD_ASSIGN_OR_RETURN(DeformationBenchmark irregular, make_irregular(regular, seed));
    suite.push_back(std::move(irregular));
  }
  return suite;
}

Result<MeshData> subdivide_loop(const MeshData& mesh, int levels) {
  MD_RETURN_IF_ERROR(validate_triangle_mesh(mesh.V, mesh.F));
  if (levels < 0 || levels > 6) {
    return Error(ErrorCode::InvalidArgument,
                 "subdivision levels " + std::to_string(levels) + " outside [0, 6]");
  }
  if (levels == 0) return mesh;
  MD_ASSIGN_OR_RETURN(OmMesh om, to_openmesh(mesh));
  OpenMesh::Subdivider::Uniform::LoopT<OmMesh, double> loop;
  loop.attach(om);
  loop(static_cast<size_t>(levels));
  loop.detach();
  om.garbage_collection();
  return from_openmesh(om);
}

const char* spot_edit_name(SpotEdit edit) {
  switch (edit) {
    case SpotEdit::Stretch:
      return "stretch";
    case SpotEdit::Bend:
      return "bend";
    case SpotEdit::Twist:
      return "twist";
  }
  return "unknown";
}

Result<DeformationBenchmark> make_spot_edit(const MeshData& spot, SpotEdit edit) {
  MD_RETURN_IF_ERROR(validate_triangle_mesh(spot.V, spot.F));
  const Eigen::Vector3d lo = spot.V.colwise().minCoeff().transpose();
  const Eigen::Vector3d hi = spot.V.colwise().maxCoeff().transpose();
  const Eigen::Vector3d extent = hi - lo;
  DeformationBenchmark bench;
  bench.name = "spot" + std::to_string((spot.V.rows() + 500) / 1000) + "k_" + spot_edit_name(edit);
  bench.mesh = spot;
  bench.selection = free_selection(static_cast<int>(spot.V.rows()));
  Eigen::Vector3d head_centre = Eigen::Vector3d::Zero();
  int head_count = 0;
  for (Eigen::Index v = 0; v < spot.V.rows(); ++v) {
    const double z = (spot.V(v, 2) - lo.z()) / extent.z();
    if (z < 0.12) {
      bench.selection(v) = kHandle;
      head_centre += spot.V.row(v).transpose();
      ++head_count;
    } else if (z > 0.6) {
      bench.selection(v) = kFixed;
    }
  }
  if (head_count == 0 || (bench.selection.array() == kFixed).count() == 0) {
    return Error(ErrorCode::InvalidArgument, "Spot edit: empty head or rear region");
  }
  head_centre /= head_count;
  bench.transform = Eigen::Matrix4d::Identity();
  switch (edit) {
    case SpotEdit::Stretch:
      bench.transform(2, 3) = -0.2 * extent.z();
      break;
    case SpotEdit::Bend: {
      // Nod: rotate about the x axis through the neck (the head region's top-back corner).
      const Eigen::Vector3d pivot(0, head_centre.y(), lo.z() + 0.3 * extent.z());
      const Eigen::Matrix3d R =
          Eigen::AngleAxisd(degrees(60), Eigen::Vector3d::UnitX()).toRotationMatrix();
      bench.transform.topLeftCorner<3, 3>() = R;
      bench.transform.topRightCorner<3, 1>() = pivot - R * pivot;
      break;
    }
    case SpotEdit::Twist: {
      const Eigen::Vector3d axis_point(0, head_centre.y(), 0);
      const Eigen::Matrix3d R =
          Eigen::AngleAxisd(degrees(135), Eigen::Vector3d::UnitZ()).toRotationMatrix();
      bench.transform.topLeftCorner<3, 3>() = R;
      bench.transform.topRightCorner<3, 1>() = axis_point - R * axis_point;
      break;
    }
  }
  return bench;
}

}  // namespace meshdeform::core
