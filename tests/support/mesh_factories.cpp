#include "tests/support/mesh_factories.h"

#include <cmath>
#include <map>
#include <utility>
#include <vector>

#include <Eigen/Geometry>

namespace meshdeform::test {

MeshData make_grid(int n, double bump) {
  MeshData m;
  m.V.resize((n + 1) * (n + 1), 3);
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      const double x = double(i) / n, y = double(j) / n;
      const double z = bump * std::sin(3.0 * M_PI * x) * std::sin(3.0 * M_PI * y);
      m.V.row(j * (n + 1) + i) << x, y, z;
    }
  }
  m.F.resize(2 * n * n, 3);
  int f = 0;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int a = j * (n + 1) + i, b = a + 1, c = a + n + 1, d = c + 1;
      m.F.row(f++) << a, b, d;
      m.F.row(f++) << a, d, c;
    }
  }
  return m;
}

MeshData make_open_cone(int segments) {
  MeshData m;
  m.V.resize(segments + 1, 3);
  m.V.row(0) << 0, 0, 1;
  for (int i = 0; i < segments; ++i) {
    const double t = 2.0 * M_PI * i / segments;
    m.V.row(i + 1) << std::cos(t), std::sin(t), 0;
  }
  m.F.resize(segments, 3);
  for (int i = 0; i < segments; ++i) m.F.row(i) << 0, 1 + i, 1 + (i + 1) % segments;
  return m;
}

MeshData make_icosphere(int subdivisions) {
  const double t = (1.0 + std::sqrt(5.0)) / 2.0;
  std::vector<Eigen::Vector3d> v = {{-1, t, 0}, {1, t, 0},  {-1, -t, 0}, {1, -t, 0},
                                    {0, -1, t}, {0, 1, t},  {0, -1, -t}, {0, 1, -t},
                                    {t, 0, -1}, {t, 0, 1},  {-t, 0, -1}, {-t, 0, 1}};
  std::vector<Eigen::Vector3i> f = {{0, 11, 5}, {0, 5, 1},  {0, 1, 7},   {0, 7, 10}, {0, 10, 11},
                                    {1, 5, 9},  {5, 11, 4}, {11, 10, 2}, {10, 7, 6}, {7, 1, 8},
                                    {3, 9, 4},  {3, 4, 2},  {3, 2, 6},   {3, 6, 8},  {3, 8, 9},
                                    {4, 9, 5},  {2, 4, 11}, {6, 2, 10},  {8, 6, 7},  {9, 8, 1}};
  for (auto& p : v) p.normalize();
  for (int s = 0; s < subdivisions; ++s) {
    std::map<std::pair<int, int>, int> mid;
    auto midpoint = [&](int a, int b) {
      const auto key = std::minmax(a, b);
      auto it = mid.find(key);
      if (it != mid.end()) return it->second;
      v.push_back((v[a] + v[b]).normalized());
      mid.emplace(key, int(v.size()) - 1);
      return int(v.size()) - 1;
    };
    std::vector<Eigen::Vector3i> g;
    for (const auto& tri : f) {
      const int a = midpoint(tri[0], tri[1]), b = midpoint(tri[1], tri[2]),
                c = midpoint(tri[2], tri[0]);
      g.push_back({tri[0], a, c});
      g.push_back({tri[1], b, a});
      g.push_back({tri[2], c, b});
      g.push_back({a, b, c});
    }
    f = std::move(g);
  }
  MeshData m;
  m.V.resize(int(v.size()), 3);
  for (int i = 0; i < int(v.size()); ++i) m.V.row(i) = v[i].transpose();
  m.F.resize(int(f.size()), 3);
  for (int i = 0; i < int(f.size()); ++i) m.F.row(i) = f[i].transpose();
  return m;
}

MeshData make_triangle() {
  MeshData m;
  m.V.resize(3, 3);
  m.V << 0, 0, 0, 1, 0, 0, 0, 1, 0;
  m.F.resize(1, 3);
  m.F << 0, 1, 2;
  return m;
}

double bbox_diagonal(const MeshData& mesh) {
  return (mesh.V.colwise().maxCoeff() - mesh.V.colwise().minCoeff()).norm();
}

Positions gather_rows(const Positions& V, const Eigen::VectorXi& idx) {
  Positions out(idx.size(), 3);
  for (Eigen::Index j = 0; j < idx.size(); ++j) out.row(j) = V.row(idx(j));
  return out;
}

std::vector<PinnedMesh> pinned_test_meshes() {
  std::vector<PinnedMesh> out;
  {
    Eigen::VectorXi c(5);
    c << 0, 12, 13 * 12, 13 * 13 - 1, 2 * 13 + 2;  // four corners and a bump top
    out.push_back({"bumpy_grid", make_grid(12, 0.08), c});
  }
  {
    Eigen::VectorXi c(6);
    c << 0, 1, 2, 3, 4, 5;
    out.push_back({"icosphere", make_icosphere(2), c});
  }
  {
    Eigen::VectorXi c(4);
    c << 0, 1, 5, 9;
    out.push_back({"open_cone", make_open_cone(16), c});
  }
  return out;
}

BendEdit make_bend(int n) {
  BendEdit b{make_grid(n, 0.05), {}, {}};
  std::vector<int> idx;
  for (int j = 0; j <= n; ++j) {
    idx.push_back(j * (n + 1));
    idx.push_back(j * (n + 1) + n);
  }
  b.constrained = Eigen::Map<Eigen::VectorXi>(idx.data(), static_cast<int>(idx.size()));
  b.targets = gather_rows(b.mesh.V, b.constrained);
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(M_PI / 3, Eigen::Vector3d::UnitY()).toRotationMatrix();
  for (Eigen::Index j = 1; j < b.targets.rows(); j += 2) {
    const Eigen::Vector3d p = b.targets.row(j).transpose();
    b.targets.row(j) =
        (R * (p - Eigen::Vector3d(0.5, 0, 0)) + Eigen::Vector3d(0.5, 0, 0.3)).transpose();
  }
  return b;
}

std::string make_grid_obj_text(int rows) {
  std::string out;
  out.reserve(static_cast<std::size_t>(rows) * static_cast<std::size_t>(rows) * 40);
  for (int i = 0; i < rows; ++i) {
    for (int j = 0; j < rows; ++j) {
      out += "v " + std::to_string(i) + " " + std::to_string(j) + " " +
             std::to_string((i * 7 + j * 3) % 5) + "\n";
    }
  }
  for (int i = 0; i + 1 < rows; ++i) {
    for (int j = 0; j + 1 < rows; ++j) {
      const int a = i * rows + j + 1, b = a + 1, c = a + rows, d = c + 1;
      out += "f " + std::to_string(a) + " " + std::to_string(b) + " " + std::to_string(d) + "\n";
      out += "f " + std::to_string(a) + " " + std::to_string(d) + " " + std::to_string(c) + "\n";
    }
  }
  return out;
}

StripEdit make_strip_edit(int n) {
  StripEdit out;
  out.mesh = make_grid(n, 0.05);
  std::vector<int> idx;
  for (int j = 0; j <= n; ++j) {
    idx.push_back(j * (n + 1));
    idx.push_back(j * (n + 1) + n);
  }
  out.constrained = Eigen::Map<const Eigen::VectorXi>(idx.data(), static_cast<Eigen::Index>(idx.size()));
  out.targets = gather_rows(out.mesh.V, out.constrained);
  return out;
}

}  // namespace meshdeform::test
