#include "core/samples/samples.h"

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

#include "core/mesh/openmesh_adapter.h"
#include "core/mesh/validate.h"

namespace meshdeform::core {
namespace {

constexpr double kPi = std::numbers::pi;

double degrees(double deg) { return deg * kPi / 180.0; }

/// Accumulates vertices and triangles. Every generator builds its surface from quad grids whose
/// shared boundaries reuse the same vertex ids (welded by construction), then lets
/// orient_consistently() fix the winding, so no generator has to get each patch's winding right.
class MeshBuilder {
 public:
  int add_vertex(const Eigen::Vector3d& p) {
    vertices_.push_back(p);
    return static_cast<int>(vertices_.size()) - 1;
  }
  int vertex_count() const { return static_cast<int>(vertices_.size()); }
  const Eigen::Vector3d& position(int v) const { return vertices_[static_cast<size_t>(v)]; }

  void add_triangle(int a, int b, int c) { faces_.push_back({a, b, c}); }

  /// Quad a-b-c-d (cyclic), split along a-c when `split_ac`, else along b-d.
  void add_quad(int a, int b, int c, int d, bool split_ac) {
    if (split_ac) {
      add_triangle(a, b, c);
      add_triangle(a, c, d);
    } else {
      add_triangle(a, b, d);
      add_triangle(b, c, d);
    }
  }

  /// Quad split along its shorter diagonal (better triangles on the curved caps).
  void add_quad_short(int a, int b, int c, int d) {
    const double ac = (position(a) - position(c)).squaredNorm();
    const double bd = (position(b) - position(d)).squaredNorm();
    add_quad(a, b, c, d, ac <= bd);
  }

  /// Makes the winding consistent across every shared edge (breadth-first from the first face of
  /// each component), then flips everything when `outward_score` (a sum over faces of a function
  /// of centroid and area vector) is negative.
  MeshData finish(const std::function<double(const Eigen::Vector3d& centroid,
                                             const Eigen::Vector3d& area_vector)>& outward_score) {
    orient_consistently();
    double score = 0;
    for (const auto& f : faces_) {
      const Eigen::Vector3d &a = position(f[0]), &b = position(f[1]), &c = position(f[2]);
      score += outward_score((a + b + c) / 3.0, (b - a).cross(c - a));
    }
    if (score < 0) {
      for (auto& f : faces_) std::swap(f[1], f[2]);
    }
    MeshData mesh;
    mesh.V.resize(vertex_count(), 3);
    for (int v = 0; v < vertex_count(); ++v) mesh.V.row(v) = position(v).transpose();
    mesh.F.resize(static_cast<Eigen::Index>(faces_.size()), 3);
    for (size_t f = 0; f < faces_.size(); ++f) {
      mesh.F.row(static_cast<Eigen::Index>(f)) << faces_[f][0], faces_[f][1], faces_[f][2];
    }
    return mesh;
  }

 private:
  static std::uint64_t edge_key(int u, int v) {
    const auto [lo, hi] = std::minmax(u, v);
    return (static_cast<std::uint64_t>(lo) << 32) | static_cast<std::uint32_t>(hi);
  }
  static bool has_directed_edge(const std::array<int, 3>& f, int u, int v) {
    for (int k = 0; k < 3; ++k) {
      if (f[k] == u && f[(k + 1) % 3] == v) return true;
    }
    return false;
  }

  void orient_consistently() {
    std::unordered_map<std::uint64_t, std::vector<int>> edge_faces;
    edge_faces.reserve(faces_.size() * 2);
    for (size_t f = 0; f < faces_.size(); ++f) {
      for (int k = 0; k < 3; ++k) {
        edge_faces[edge_key(faces_[f][k], faces_[f][(k + 1) % 3])].push_back(static_cast<int>(f));
      }
    }
    std::vector<char> visited(faces_.size(), 0);
    std::queue<int> queue;
    for (size_t seed = 0; seed < faces_.size(); ++seed) {
      if (visited[seed]) continue;
      visited[seed] = 1;
      queue.push(static_cast<int>(seed));
      while (!queue.empty()) {
        const int f = queue.front();
        queue.pop();
        for (int k = 0; k < 3; ++k) {
          const int u = faces_[static_cast<size_t>(f)][k];
          const int v = faces_[static_cast<size_t>(f)][(k + 1) % 3];
          const auto& incident = edge_faces[edge_key(u, v)];
          MD_ASSERT(incident.size() <= 2);  // the generators only build manifold grids
          for (const int g : incident) {
            if (g == f) continue;
            auto& face_g = faces_[static_cast<size_t>(g)];
            // Consistent neighbours traverse the shared edge in opposite directions.
            const bool is_consistent = has_directed_edge(face_g, v, u);
            if (visited[static_cast<size_t>(g)]) {
              MD_ASSERT(is_consistent);  // orientable by construction
              continue;
            }
            if (!is_consistent) std::swap(face_g[1], face_g[2]);
            visited[static_cast<size_t>(g)] = 1;
            queue.push(g);
          }
        }
      }
    }
  }

  std::vector<Eigen::Vector3d> vertices_;
  std::vector<std::array<int, 3>> faces_;
};

/// Maps the square [-1,1]^2 onto the unit disc (elliptical grid mapping): the square's boundary
/// lands on the circle and grid lines stay smooth, which gives the caps well-shaped quads.
Eigen::Vector2d square_to_disc(double x, double y) {
  return {x * std::sqrt(std::max(0.0, 1.0 - 0.5 * y * y)),
          y * std::sqrt(std::max(0.0, 1.0 - 0.5 * x * x))};
}

/// The handle motion that bends a straight tube into a circular arc: the tube runs along +z from
/// `base` (top of the fixed region); the free part of length `free_length` becomes an arc turning
/// by `angle` toward the horizontal direction `toward`, and the handle moves rigidly with the arc's
/// end. The result is a rotation by `angle` about the horizontal axis z x toward through a fixed
/// point (the pivot), chosen so that an arc is the natural solution rather than a kinked tube.
Eigen::Matrix4d arc_bend_transform(const Eigen::Vector3d& base, double free_length,
                                   const Eigen::Vector3d& toward, double angle) {
  const Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(angle, up.cross(toward).normalized()).toRotationMatrix();
  const double radius = free_length / angle;
  const Eigen::Vector3d arc_end =
      base + radius * (1.0 - std::cos(angle)) * toward + radius * std::sin(angle) * up;
  const Eigen::Vector3d straight_end = base + free_length * up;
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  T.topLeftCorner<3, 3>() = R;
  T.topRightCorner<3, 1>() = arc_end - R * straight_end;
  return T;
}

Eigen::VectorXi free_selection(int vertex_count) {
  return Eigen::VectorXi::Constant(vertex_count, static_cast<int>(VertexRole::Free));
}

constexpr int kFixed = static_cast<int>(VertexRole::Fixed);
constexpr int kHandle = static_cast<int>(VertexRole::Handle);

}  // namespace

Result<HandleSetup> constraints_from_selection(const Positions& V, const Eigen::VectorXi& selection,
                                               const Eigen::Matrix4d& transform) {
  if (selection.size() != V.rows()) {
    return Error(ErrorCode::InvalidArgument, "selection has " + std::to_string(selection.size()) +
                                                 " entries but the mesh has " +
                                                 std::to_string(V.rows()) + " vertices");
  }
  for (Eigen::Index v = 0; v < selection.size(); ++v) {
    const int role = selection(v);
    if (role != kFixed && role != kHandle && role != static_cast<int>(VertexRole::Free)) {
      return Error(ErrorCode::InvalidArgument, "selection value " + std::to_string(role) +
                                                   " at vertex " + std::to_string(v) +
                                                   " is not 0 (fixed), 1 (free) or 2 (handle)");
    }
  }
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) {
      if (!std::isfinite(transform(r, c))) {
        return Error(ErrorCode::InvalidArgument, "transform entry (" + std::to_string(r) + ", " +
                                                     std::to_string(c) + ") is not finite");
      }
    }
  }
  if (transform.row(3) != Eigen::RowVector4d(0, 0, 0, 1)) {
    return Error(ErrorCode::InvalidArgument,
                 "transform is not affine: its last row is (" + std::to_string(transform(3, 0)) +
                     ", " + std::to_string(transform(3, 1)) + ", " +
                     std::to_string(transform(3, 2)) + ", " + std::to_string(transform(3, 3)) +
                     "), expected (0, 0, 0, 1)");
  }
  const auto count = static_cast<Eigen::Index>((selection.array() != 1).count());
  HandleSetup setup;
  setup.constrained.resize(count);
  setup.targets.resize(count, 3);
  const Eigen::Matrix3d R = transform.topLeftCorner<3, 3>();
  const Eigen::Vector3d t = transform.topRightCorner<3, 1>();
  Eigen::Index j = 0;
  for (Eigen::Index v = 0; v < selection.size(); ++v) {
    if (selection(v) == static_cast<int>(VertexRole::Free)) continue;
    setup.constrained(j) = static_cast<int>(v);
    const Eigen::Vector3d x = V.row(v).transpose();
    setup.targets.row(j) = (selection(v) == kHandle ? Eigen::Vector3d(R * x + t) : x).transpose();
    ++j;
  }
  return setup;
}

DeformationBenchmark make_bumpy_plane(int n) {
  n = std::max(n, 5);
  // Three sizes of Gaussian bumps on regular lattices: coarse hills, medium bumps, fine texture,
  // so that a scale-aware method has details of several sizes to preserve.
  struct BumpLattice {
    int per_side;
    double height, sigma;
  };
  constexpr std::array<BumpLattice, 3> kLattices = {
      {{4, 0.08, 0.12}, {8, 0.04, 0.05}, {16, 0.015, 0.025}}};
  auto height = [&](double x, double y) {
    double z = 0;
    for (const auto& lattice : kLattices) {
      const double step = 2.0 / lattice.per_side;
      for (int a = 0; a < lattice.per_side; ++a) {
        const double cx = -1.0 + step * (a + 0.5);
        if (std::abs(x - cx) > 4 * lattice.sigma) continue;
        for (int b = 0; b < lattice.per_side; ++b) {
          const double cy = -1.0 + step * (b + 0.5);
          const double d2 = (x - cx) * (x - cx) + (y - cy) * (y - cy);
          z += lattice.height * std::exp(-d2 / (2 * lattice.sigma * lattice.sigma));
        }
      }
    }
    return z;
  };

  MeshBuilder builder;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const double x = -1.0 + 2.0 * i / (n - 1), y = -1.0 + 2.0 * j / (n - 1);
      builder.add_vertex({x, y, height(x, y)});
    }
  }
  for (int j = 0; j + 1 < n; ++j) {
    for (int i = 0; i + 1 < n; ++i) {
      const int a = j * n + i;
      // Alternating diagonals keep the triangulation symmetric (no preferred shear direction).
      builder.add_quad(a, a + 1, a + n + 1, a + n, (i + j) % 2 == 0);
    }
  }
  DeformationBenchmark bench;
  bench.name = "bumpy_plane";
  bench.mesh =
      builder.finish([](const Eigen::Vector3d&, const Eigen::Vector3d& area) { return area.z(); });
  bench.selection = free_selection(n * n);
  const int band = std::max(2, n / 50);
  constexpr double kHandleRadius = 0.15;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int v = j * n + i;
      if (std::min({i, j, n - 1 - i, n - 1 - j}) < band) {
        bench.selection(v) = kFixed;
      } else if (bench.mesh.V.row(v).head<2>().norm() <= kHandleRadius + 1e-12) {
        bench.selection(v) = kHandle;
      }
    }
  }
  bench.transform = Eigen::Matrix4d::Identity();
  bench.transform(2, 3) = 0.5;
  return bench;
}

DeformationBenchmark make_cylinder(int rings, int segments) {
  rings = std::max(rings, 6);
  segments = std::max(segments, 6);
  constexpr double kRadius = 0.2, kHeight = 2.0;
  // Surface detail: 7 lengthwise ridges plus 6 circumferential waves.
  auto radius = [](double theta, double z) {
    return kRadius + 0.012 * std::cos(7 * theta) + 0.008 * std::cos(2 * kPi * 6 * z / kHeight);
  };
  MeshBuilder builder;
  for (int j = 0; j < rings; ++j) {
    const double z = kHeight * j / (rings - 1);
    for (int i = 0; i < segments; ++i) {
      const double theta = 2 * kPi * i / segments;
      const double r = radius(theta, z);
      builder.add_vertex({r * std::cos(theta), r * std::sin(theta), z});
    }
  }
  for (int j = 0; j + 1 < rings; ++j) {
    for (int i = 0; i < segments; ++i) {
      const int i1 = (i + 1) % segments;
      builder.add_quad(j * segments + i, j * segments + i1, (j + 1) * segments + i1,
                       (j + 1) * segments + i, (i + j) % 2 == 0);
    }
  }
  DeformationBenchmark bench;
  bench.name = "cylinder";
  bench.mesh = builder.finish([](const Eigen::Vector3d& c, const Eigen::Vector3d& area) {
    return c.x() * area.x() + c.y() * area.y();
  });
  bench.selection = free_selection(rings * segments);
  const int end_rings = std::max(2, rings / 12);
  for (int j = 0; j < rings; ++j) {
    const int role = j < end_rings ? kFixed : (j >= rings - end_rings ? kHandle : -1);
    if (role < 0) continue;
    bench.selection.segment(j * segments, segments).setConstant(role);
  }
  const double z0 = kHeight * (end_rings - 1) / (rings - 1);
  const double z1 = kHeight * (rings - end_rings) / (rings - 1);
  bench.transform = arc_bend_transform({0, 0, z0}, z1 - z0, Eigen::Vector3d::UnitX(), degrees(120));
  return bench;
}

DeformationBenchmark make_bar(int length_segments, int width_segments) {
  const int L = std::max(length_segments, 4);
  const int w = std::max(width_segments, 2);
  constexpr double kLength = 2.0, kHalfWidth = 0.2;
  // Detail: 6 ridges around the bar along its length and two lengthwise grooves per side, which
  // the twist turns into helices.
  auto ridge_scale = [](double z) { return 1.0 + 0.05 * std::cos(2 * kPi * 6 * z / kLength); };
  constexpr double kGrooveDepth = 0.008;

  // Ring m = 0..4w-1 runs counter-clockwise (seen from +z) around the square, starting at (-h,-h).
  auto ring_point = [&](int m, double z) {
    const int side = m / w;
    const double t = -1.0 + 2.0 * (m % w) / w;  // position along the side in [-1, 1)
    Eigen::Vector2d p, outward;
    switch (side) {
      case 0:
        p = {t, -1};
        outward = {0, -1};
        break;
      case 1:
        p = {1, t};
        outward = {1, 0};
        break;
      case 2:
        p = {-t, 1};
        outward = {0, 1};
        break;
      default:
        p = {-1, -t};
        outward = {-1, 0};
        break;
    }
    const double groove = std::sin(kPi * t);
    const Eigen::Vector2d xy =
        ridge_scale(z) * kHalfWidth * p - kGrooveDepth * groove * groove * outward;
    return Eigen::Vector3d(xy.x(), xy.y(), z);
  };
  MeshBuilder builder;
  const int ring_size = 4 * w;
  for (int k = 0; k <= L; ++k) {
    for (int m = 0; m < ring_size; ++m) builder.add_vertex(ring_point(m, kLength * k / L));
  }
  for (int k = 0; k < L; ++k) {
    for (int m = 0; m < ring_size; ++m) {
      const int m1 = (m + 1) % ring_size;
      builder.add_quad(k * ring_size + m, k * ring_size + m1, (k + 1) * ring_size + m1,
                       (k + 1) * ring_size + m, (k + m) % 2 == 0);
    }
  }
  // Caps: a (w+1) x (w+1) grid whose border is the end ring itself.
  auto ring_index = [w](int u, int v) {
    if (v == 0) return u;
    if (u == w) return w + v;
    if (v == w) return 2 * w + (w - u);
    return (3 * w + (w - v)) % (4 * w);  // u == 0
  };
  std::vector<int> cap_vertices[2];
  for (int end = 0; end < 2; ++end) {
    const int ring = end == 0 ? 0 : L;
    const double z = end == 0 ? 0.0 : kLength;
    std::vector<int> id(static_cast<size_t>((w + 1) * (w + 1)));
    for (int v = 0; v <= w; ++v) {
      for (int u = 0; u <= w; ++u) {
        const bool is_border = u == 0 || v == 0 || u == w || v == w;
        int vertex;
        if (is_border) {
          vertex = ring * ring_size + ring_index(u, v);
        } else {
          const double s = ridge_scale(z) * kHalfWidth;
          vertex = builder.add_vertex({s * (-1.0 + 2.0 * u / w), s * (-1.0 + 2.0 * v / w), z});
          cap_vertices[end].push_back(vertex);
        }
        id[static_cast<size_t>(v * (w + 1) + u)] = vertex;
      }
    }
    for (int v = 0; v < w; ++v) {
      for (int u = 0; u < w; ++u) {
        const auto at = [&](int uu, int vv) { return id[static_cast<size_t>(vv * (w + 1) + uu)]; };
        builder.add_quad(at(u, v), at(u + 1, v), at(u + 1, v + 1), at(u, v + 1), (u + v) % 2 == 0);
      }
    }
  }
  DeformationBenchmark bench;
  bench.name = "bar";
  bench.mesh = builder.finish([&](const Eigen::Vector3d& c, const Eigen::Vector3d& area) {
    return (c - Eigen::Vector3d(0, 0, kLength / 2)).dot(area);
  });
  bench.selection = free_selection(builder.vertex_count());
  const int end_rings = std::max(2, L / 20);
  for (int k = 0; k <= L; ++k) {
    const int role = k < end_rings ? kFixed : (k > L - end_rings ? kHandle : -1);
    if (role >= 0) bench.selection.segment(k * ring_size, ring_size).setConstant(role);
  }
  for (const int v : cap_vertices[0]) bench.selection(v) = kFixed;
  for (const int v : cap_vertices[1]) bench.selection(v) = kHandle;
  bench.transform = Eigen::Matrix4d::Identity();
  bench.transform.topLeftCorner<3, 3>() =
      Eigen::AngleAxisd(degrees(135), Eigen::Vector3d::UnitZ()).toRotationMatrix();
  return bench;
}

DeformationBenchmark make_cactus(int resolution) {
  // Topology: an open tube (the trunk, open at the base) with a domed cap on top and two square
  // holes; each hole's border is the first ring of an arm tube, which sweeps outward, turns up and
  // ends in a domed cap. Every patch is a quad grid sharing its border vertices with its
  // neighbour, so the surface is welded and 2-manifold by construction (genus 0, one boundary).
  const int r = std::max(resolution, 1);
  const int segments = 12 * r;  // around the trunk
  const int rows = 16 * r;      // trunk rows (rows + 1 vertex rings)
  const int hole = 2 * r;       // arm hole size in trunk quads; arm rings have 4 * hole vertices
  const int cap = 3 * r;        // trunk cap grid size (4 * cap == segments)
  const int arm_rings = 8 * r;  // new rings per arm
  constexpr double kTrunkRadius = 0.25, kHeight = 2.0;
  constexpr int kRibs = 12;
  auto trunk_angle = [&](int i) { return kPi / 4 + 2 * kPi * i / segments; };
  auto rib = [](double angle, double amount) {
    return 1.0 + 0.05 * amount * std::cos(kRibs * angle);
  };

  struct Arm {
    int c0, h0;  // first trunk column and row of the hole
  };
  const std::array<Arm, 2> arms = {{{0, 5 * r}, {6 * r, 8 * r}}};
  auto in_hole_interior = [&](int i, int j) {
    for (const auto& arm : arms) {
      if (i > arm.c0 && i < arm.c0 + hole && j > arm.h0 && j < arm.h0 + hole) return true;
    }
    return false;
  };
  auto in_hole_quad = [&](int i, int j) {
    for (const auto& arm : arms) {
      if (i >= arm.c0 && i < arm.c0 + hole && j >= arm.h0 && j < arm.h0 + hole) return true;
    }
    return false;
  };

  MeshBuilder builder;
  std::vector<int> trunk(static_cast<size_t>(segments * (rows + 1)), -1);
  auto trunk_id = [&](int i, int j) -> int& {
    return trunk[static_cast<size_t>(j * segments + (i % segments))];
  };
  for (int j = 0; j <= rows; ++j) {
    const double z = kHeight * j / rows;
    for (int i = 0; i < segments; ++i) {
      if (in_hole_interior(i, j)) continue;
      const double angle = trunk_angle(i);
      const double radius = kTrunkRadius * rib(angle, 1.0);
      trunk_id(i, j) = builder.add_vertex({radius * std::cos(angle), radius * std::sin(angle), z});
    }
  }
  for (int j = 0; j < rows; ++j) {
    for (int i = 0; i < segments; ++i) {
      if (in_hole_quad(i, j)) continue;
      builder.add_quad(trunk_id(i, j), trunk_id(i + 1, j), trunk_id(i + 1, j + 1),
                       trunk_id(i, j + 1), (i + j) % 2 == 0);
    }
  }

  // Trunk cap: grid (u, v) in [0, cap]^2, square coordinates X = -1 + 2u/cap, Y = -1 + 2v/cap; its
  // border runs counter-clockwise from the corner (1, 1), which sits at trunk angle pi/4 (column
  // 0).
  std::vector<int> top_cap_vertices;
  {
    auto border_column = [cap](int u, int v) {
      if (v == cap) return cap - u;
      if (u == 0) return 2 * cap - v;
      if (v == 0) return 2 * cap + u;
      return (3 * cap + v) % (4 * cap);  // u == cap
    };
    std::vector<int> id(static_cast<size_t>((cap + 1) * (cap + 1)));
    const double dome = 0.7 * kTrunkRadius;
    for (int v = 0; v <= cap; ++v) {
      for (int u = 0; u <= cap; ++u) {
        int vertex;
        if (u == 0 || v == 0 || u == cap || v == cap) {
          vertex = trunk_id(border_column(u, v), rows);
        } else {
          const Eigen::Vector2d d = square_to_disc(-1.0 + 2.0 * u / cap, -1.0 + 2.0 * v / cap);
          const double rho2 = d.squaredNorm();
          const Eigen::Vector2d xy = kTrunkRadius * rib(std::atan2(d.y(), d.x()), rho2) * d;
          vertex = builder.add_vertex({xy.x(), xy.y(), kHeight + dome * (1.0 - rho2)});
          top_cap_vertices.push_back(vertex);
        }
        id[static_cast<size_t>(v * (cap + 1) + u)] = vertex;
      }
    }
    for (int v = 0; v < cap; ++v) {
      for (int u = 0; u < cap; ++u) {
        const auto at = [&](int uu, int vv) {
          return id[static_cast<size_t>(vv * (cap + 1) + uu)];
        };
        builder.add_quad_short(at(u, v), at(u + 1, v), at(u + 1, v + 1), at(u, v + 1));
      }
    }
  }

  // Arms. Hole-local grid coordinates (u, v) in [0, hole]^2 (u along the trunk's angle, v up);
  // loop index p of a border point is shared by every ring of the arm and by its cap.
  auto loop_index = [hole](int u, int v) {
    if (u == 0 && v < hole) return v;
    if (v == hole && u < hole) return hole + u;
    if (u == hole && v > 0) return 2 * hole + (hole - v);
    return 3 * hole + (hole - u);  // v == 0 && u > 0
  };
  const int loop_size = 4 * hole;
  constexpr double kOut = 0.2, kTurn = 0.15, kUp = 0.3, kArmRadius = 0.09, kHoleRadius = 0.13;
  const double arm_length = kOut + kPi / 2 * kTurn + kUp;
  for (const auto& arm : arms) {
    const double angle = trunk_angle(arm.c0) + 2 * kPi * (hole / 2.0) / segments;
    const Eigen::Vector3d out(std::cos(angle), std::sin(angle), 0);
    const Eigen::Vector3d side(-std::sin(angle), std::cos(angle), 0);
    const Eigen::Vector3d up = Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d origin(0, 0, kHeight * (arm.h0 + hole / 2.0) / rows);

    std::vector<int> ring(static_cast<size_t>(loop_size));
    std::vector<Eigen::Vector2d> disc(static_cast<size_t>(loop_size));
    for (int v = 0; v <= hole; ++v) {
      for (int u = 0; u <= hole; ++u) {
        if (u != 0 && v != 0 && u != hole && v != hole) continue;
        const auto p = static_cast<size_t>(loop_index(u, v));
        ring[p] = trunk_id(arm.c0 + u, arm.h0 + v);
        disc[p] = square_to_disc(-1.0 + 2.0 * u / hole, -1.0 + 2.0 * v / hole);
      }
    }
    // The arm's centre line: straight out, a quarter turn upward, straight up. `normal` is the
    // cross-section's second axis (parallel transported), `tangent` the direction of travel.
    struct Frame {
      Eigen::Vector3d centre, tangent, normal;
    };
    auto frame = [&](double s) -> Frame {
      if (s <= kOut) return {origin + (kTrunkRadius + s) * out, out, up};
      if (s <= kOut + kPi / 2 * kTurn) {
        const double t = (s - kOut) / kTurn;
        return {origin + (kTrunkRadius + kOut + kTurn * std::sin(t)) * out +
                    kTurn * (1 - std::cos(t)) * up,
                std::cos(t) * out + std::sin(t) * up, -std::sin(t) * out + std::cos(t) * up};
      }
      const double rise = s - kOut - kPi / 2 * kTurn;
      return {origin + (kTrunkRadius + kOut + kTurn) * out + (kTurn + rise) * up, up, -out};
    };
    // The cross-section flares from the hole's size to the arm's radius near the trunk.
    auto section_radius = [&](double s) {
      return kArmRadius + (kHoleRadius - kArmRadius) * std::exp(-s / 0.06);
    };
    Frame last{};
    double last_radius = 0;
    for (int k = 1; k <= arm_rings; ++k) {
      const double s = arm_length * k / arm_rings;
      last = frame(s);
      last_radius = section_radius(s);
      std::vector<int> next(static_cast<size_t>(loop_size));
      for (int p = 0; p < loop_size; ++p) {
        const auto& d = disc[static_cast<size_t>(p)];
        next[static_cast<size_t>(p)] =
            builder.add_vertex(last.centre + last_radius * (d.x() * side + d.y() * last.normal));
      }
      for (int p = 0; p < loop_size; ++p) {
        const auto p0 = static_cast<size_t>(p), p1 = static_cast<size_t>((p + 1) % loop_size);
        builder.add_quad(ring[p0], ring[p1], next[p1], next[p0], (p + k) % 2 == 0);
      }
      ring = std::move(next);
    }
    // Domed end cap on the last ring.
    std::vector<int> id(static_cast<size_t>((hole + 1) * (hole + 1)));
    for (int v = 0; v <= hole; ++v) {
      for (int u = 0; u <= hole; ++u) {
        int vertex;
        if (u == 0 || v == 0 || u == hole || v == hole) {
          vertex = ring[static_cast<size_t>(loop_index(u, v))];
        } else {
          const Eigen::Vector2d d = square_to_disc(-1.0 + 2.0 * u / hole, -1.0 + 2.0 * v / hole);
          vertex =
              builder.add_vertex(last.centre + last_radius * (d.x() * side + d.y() * last.normal) +
                                 0.8 * last_radius * (1.0 - d.squaredNorm()) * last.tangent);
        }
        id[static_cast<size_t>(v * (hole + 1) + u)] = vertex;
      }
    }
    for (int v = 0; v < hole; ++v) {
      for (int u = 0; u < hole; ++u) {
        const auto at = [&](int uu, int vv) {
          return id[static_cast<size_t>(vv * (hole + 1) + uu)];
        };
        builder.add_quad_short(at(u, v), at(u + 1, v), at(u + 1, v + 1), at(u, v + 1));
      }
    }
  }

  DeformationBenchmark bench;
  bench.name = "cactus";
  // The open base lies in z = 0, so sum(centroid . area) is three times the enclosed volume.
  bench.mesh = builder.finish(
      [](const Eigen::Vector3d& c, const Eigen::Vector3d& area) { return c.dot(area); });
  bench.selection = free_selection(builder.vertex_count());
  const int fixed_rows = std::max(2, rows / 16);
  const int handle_rows = std::max(2, rows / 8);
  for (int j = 0; j <= rows; ++j) {
    const int role = j < fixed_rows ? kFixed : (j > rows - handle_rows ? kHandle : -1);
    if (role < 0) continue;
    for (int i = 0; i < segments; ++i) {
      const int v = trunk_id(i, j);
      if (v >= 0) bench.selection(v) = role;
    }
  }
  for (const int v : top_cap_vertices) bench.selection(v) = kHandle;
  // Bend the top forward, perpendicular to the plane of the arms.
  const double arm_angle = trunk_angle(arms[0].c0) + 2 * kPi * (hole / 2.0) / segments;
  const Eigen::Vector3d forward(-std::sin(arm_angle), std::cos(arm_angle), 0);
  const double z0 = kHeight * (fixed_rows - 1) / rows;
  const double z1 = kHeight * (rows - handle_rows + 1) / rows;
  bench.transform = arc_bend_transform({0, 0, z0}, z1 - z0, forward, degrees(70));
  return bench;
}

std::vector<DeformationBenchmark> make_suite(SuiteScale scale) {
  std::vector<DeformationBenchmark> suite;
  if (scale == SuiteScale::Paper) {
    suite.push_back(make_bumpy_plane());
    suite.push_back(make_cylinder());
    suite.push_back(make_bar());
    suite.push_back(make_cactus());
  } else {
    suite.push_back(make_bumpy_plane(21));
    suite.push_back(make_cylinder(20, 21));
    suite.push_back(make_bar(20, 6));
    suite.push_back(make_cactus(1));
  }
  return suite;
}

}  // namespace meshdeform::core
