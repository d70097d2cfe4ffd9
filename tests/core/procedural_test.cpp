#include "core/samples/generators.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <numeric>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Geometry>
#include <Eigen/LU>

#include "core/mesh/validate.h"

namespace meshdeform::core {
namespace {

constexpr double kPi = 3.14159265358979323846;

/// Edges used by exactly one face.
int boundary_edge_count(const Triangles& F) {
  std::map<std::pair<int, int>, int> uses;
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) ++uses[std::minmax(F(f, k), F(f, (k + 1) % 3))];
  }
  return static_cast<int>(
      std::count_if(uses.begin(), uses.end(), [](const auto& entry) { return entry.second == 1; }));
}

/// Connected component of every vertex (through faces), by union-find.
std::vector<int> components(const MeshData& mesh) {
  std::vector<int> parent(static_cast<size_t>(mesh.V.rows()));
  std::iota(parent.begin(), parent.end(), 0);
  auto find = [&](int v) {
    while (parent[static_cast<size_t>(v)] != v) {
      v = parent[static_cast<size_t>(v)] =
          parent[static_cast<size_t>(parent[static_cast<size_t>(v)])];
    }
    return v;
  };
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 1; k < 3; ++k)
      parent[static_cast<size_t>(find(mesh.F(f, k)))] = find(mesh.F(f, 0));
  }
  std::vector<int> id(parent.size());
  for (size_t v = 0; v < parent.size(); ++v) id[v] = find(static_cast<int>(v));
  return id;
}

/// sum(centroid . area vector) / 6: the enclosed volume for a closed outward mesh.
double signed_volume(const MeshData& mesh) {
  double volume = 0;
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    const Eigen::Vector3d a = mesh.V.row(mesh.F(f, 0)), b = mesh.V.row(mesh.F(f, 1)),
                          c = mesh.V.row(mesh.F(f, 2));
    volume += a.dot(b.cross(c)) / 6.0;
  }
  return volume;
}

Eigen::Vector3d area_vector(const MeshData& mesh, Eigen::Index f) {
  const Eigen::Vector3d a = mesh.V.row(mesh.F(f, 0)), b = mesh.V.row(mesh.F(f, 1)),
                        c = mesh.V.row(mesh.F(f, 2));
  return (b - a).cross(c - a);
}

/// Rotation angle (radians) of the linear part of an affine transform.
double rotation_angle(const Eigen::Matrix4d& T) {
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  return std::acos(std::clamp((R.trace() - 1.0) / 2.0, -1.0, 1.0));
}

void expect_well_formed(const DeformationBenchmark& bench) {
  SCOPED_TRACE(bench.name);
  const MeshData& mesh = bench.mesh;
  const Status status = validate_triangle_mesh(mesh.V, mesh.F);
  EXPECT_TRUE(status.ok()) << status.to_string();

  // Welded by construction: no two vertices at the same position.
  std::set<std::array<double, 3>> positions;
  for (Eigen::Index v = 0; v < mesh.V.rows(); ++v) {
    positions.insert({mesh.V(v, 0), mesh.V(v, 1), mesh.V(v, 2)});
  }
  EXPECT_EQ(static_cast<Eigen::Index>(positions.size()), mesh.V.rows());

  ASSERT_EQ(bench.selection.size(), mesh.V.rows());
  EXPECT_TRUE(((bench.selection.array() >= 0) && (bench.selection.array() <= 2)).all());
  EXPECT_GT((bench.selection.array() == 0).count(), 0);
  EXPECT_GT((bench.selection.array() == 1).count(), 0);
  EXPECT_GT((bench.selection.array() == 2).count(), 0);

  // Every connected component has at least two constrained vertices.
  const std::vector<int> component = components(mesh);
  std::map<int, int> constrained_per_component;
  for (size_t v = 0; v < component.size(); ++v) {
    constrained_per_component[component[v]] += 0;
    if (bench.selection(static_cast<Eigen::Index>(v)) != 1)
      ++constrained_per_component[component[v]];
  }
  for (const auto& [root, count] : constrained_per_component) {
    EXPECT_GE(count, 2) << "component of vertex " << root;
  }

  const Eigen::Matrix4d& T = bench.transform;
  EXPECT_TRUE(T.allFinite());
  EXPECT_TRUE(T.row(3).isApprox(Eigen::RowVector4d(0, 0, 0, 1)));
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  EXPECT_TRUE((R.transpose() * R).isApprox(Eigen::Matrix3d::Identity(), 1e-12));
  EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
}

TEST(Procedural, SmallSuiteIsWellFormed) {
  const auto suite = make_suite(SuiteScale::Small);
  ASSERT_EQ(suite.size(), 4u);
  for (const auto& bench : suite) {
    EXPECT_LT(bench.mesh.V.rows(), 1000) << bench.name;
    EXPECT_GT(bench.mesh.V.rows(), 200) << bench.name;
    expect_well_formed(bench);
  }
}

TEST(Procedural, PaperSuiteMatchesTable1) {
  const auto suite = make_suite(SuiteScale::Paper);
  ASSERT_EQ(suite.size(), 4u);
  const std::array<std::pair<const char*, double>, 4> expected = {
      {{"bumpy_plane", 40401}, {"cylinder", 4802}, {"bar", 2602}, {"cactus", 5261}}};
  for (size_t k = 0; k < suite.size(); ++k) {
    EXPECT_EQ(suite[k].name, expected[k].first);
    EXPECT_NEAR(static_cast<double>(suite[k].mesh.V.rows()), expected[k].second,
                0.02 * expected[k].second)
        << suite[k].name;
    expect_well_formed(suite[k]);
  }
  EXPECT_EQ(suite[0].mesh.V.rows(), 40401);
  EXPECT_EQ(suite[1].mesh.V.rows(), 4802);
  EXPECT_EQ(suite[2].mesh.V.rows(), 2602);
}

TEST(Procedural, OpenAndClosedAsDesigned) {
  const auto plane = make_bumpy_plane(21);
  EXPECT_EQ(boundary_edge_count(plane.mesh.F), 4 * 20);
  const auto cylinder = make_cylinder(20, 21);
  EXPECT_EQ(boundary_edge_count(cylinder.mesh.F), 2 * 21);
  const auto bar = make_bar(20, 6);
  EXPECT_EQ(boundary_edge_count(bar.mesh.F), 0);
  const auto cactus = make_cactus(1);
  EXPECT_EQ(boundary_edge_count(cactus.mesh.F), 12);  // the open base ring only
  // Closed genus 0: Euler characteristic 2 (edges = 3F/2).
  EXPECT_EQ(bar.mesh.V.rows() - 3 * bar.mesh.F.rows() / 2 + bar.mesh.F.rows(), 2);
}

TEST(Procedural, FacesPointOutward) {
  const auto plane = make_bumpy_plane(21);
  for (Eigen::Index f = 0; f < plane.mesh.F.rows(); ++f) {
    ASSERT_GT(area_vector(plane.mesh, f).z(), 0) << "face " << f;
  }
  const auto cylinder = make_cylinder(20, 21);
  for (Eigen::Index f = 0; f < cylinder.mesh.F.rows(); ++f) {
    const Eigen::Vector3d centroid =
        (cylinder.mesh.V.row(cylinder.mesh.F(f, 0)) + cylinder.mesh.V.row(cylinder.mesh.F(f, 1)) +
         cylinder.mesh.V.row(cylinder.mesh.F(f, 2)))
            .transpose() /
        3.0;
    ASSERT_GT(area_vector(cylinder.mesh, f).head<2>().dot(centroid.head<2>()), 0) << "face " << f;
  }
  const auto bar = make_bar(20, 6);
  EXPECT_GT(signed_volume(bar.mesh), 0.9 * 0.4 * 0.4 * 2.0);
  EXPECT_LT(signed_volume(bar.mesh), 1.2 * 0.4 * 0.4 * 2.0);
  // The cactus base lies in z = 0, so the signed volume of the open surface is its volume.
  EXPECT_GT(signed_volume(make_cactus(1).mesh), 0);
  EXPECT_GT(signed_volume(make_cactus(2).mesh), 0);
}

TEST(Procedural, TransformsAreTheBenchmarkEdits) {
  const auto plane = make_bumpy_plane(21);
  Eigen::Matrix4d lift = Eigen::Matrix4d::Identity();
  lift(2, 3) = 0.5;
  EXPECT_TRUE(plane.transform.isApprox(lift));
  const auto cylinder = make_cylinder(20, 21);
  EXPECT_NEAR(rotation_angle(cylinder.transform), 120 * kPi / 180, 1e-9);
  const auto bar = make_bar(20, 6);
  EXPECT_NEAR(rotation_angle(bar.transform), 135 * kPi / 180, 1e-9);
  EXPECT_TRUE((bar.transform.topLeftCorner<3, 3>() * Eigen::Vector3d::UnitZ())
                  .isApprox(Eigen::Vector3d::UnitZ()));  // twist about the long axis (z)
  EXPECT_NEAR((bar.transform.topRightCorner<3, 1>().norm()), 0, 1e-12);
  const auto cactus = make_cactus(1);
  EXPECT_NEAR(rotation_angle(cactus.transform), 70 * kPi / 180, 1e-9);
  // Bends are about horizontal axes: the rotation axis has no z component.
  for (const auto* bench : {&cylinder, &cactus}) {
    const Eigen::Matrix3d R = bench->transform.topLeftCorner<3, 3>();
    const Eigen::Vector3d axis(R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1));
    EXPECT_NEAR(axis.z(), 0, 1e-12) << bench->name;
  }
}

TEST(Procedural, HandleTargetsApplyTheTransform) {
  for (const auto& bench : make_suite(SuiteScale::Small)) {
    SCOPED_TRACE(bench.name);
    auto setup = constraints_from_selection(bench.mesh.V, bench.selection, bench.transform);
    ASSERT_TRUE(setup.ok()) << setup.status().to_string();
    const auto count = (bench.selection.array() != 1).count();
    ASSERT_EQ(setup->constrained.size(), count);
    ASSERT_EQ(setup->targets.rows(), count);
    for (Eigen::Index j = 0; j < setup->constrained.size(); ++j) {
      const int v = setup->constrained(j);
      if (j > 0) {
        ASSERT_LT(setup->constrained(j - 1), v);
      }
      ASSERT_NE(bench.selection(v), 1);
      const Eigen::Vector4d rest(bench.mesh.V(v, 0), bench.mesh.V(v, 1), bench.mesh.V(v, 2), 1.0);
      const Eigen::Vector3d expected = bench.selection(v) == 2
                                           ? Eigen::Vector3d((bench.transform * rest).head<3>())
                                           : Eigen::Vector3d(rest.head<3>());
      ASSERT_TRUE(setup->targets.row(j).transpose().isApprox(expected, 1e-12)) << "vertex " << v;
    }
  }
}

TEST(Procedural, ConstraintsFromSelectionRejectsBadInput) {
  const auto bench = make_bar(8, 2);
  const Eigen::Index n = bench.mesh.V.rows();

  const Eigen::VectorXi short_selection = bench.selection.head(n - 1);
  auto wrong_length = constraints_from_selection(bench.mesh.V, short_selection, bench.transform);
  ASSERT_FALSE(wrong_length.ok());
  EXPECT_EQ(wrong_length.status().code(), ErrorCode::InvalidArgument);
  EXPECT_NE(wrong_length.status().message().find(std::to_string(n - 1)), std::string::npos)
      << wrong_length.status().message();
  EXPECT_NE(wrong_length.status().message().find(std::to_string(n)), std::string::npos);

  for (const int bad : {3, -1}) {
    Eigen::VectorXi selection = bench.selection;
    selection(7) = bad;
    auto result = constraints_from_selection(bench.mesh.V, selection, bench.transform);
    ASSERT_FALSE(result.ok());
    EXPECT_EQ(result.status().code(), ErrorCode::InvalidArgument);
    EXPECT_NE(result.status().message().find("vertex 7"), std::string::npos)
        << result.status().message();
  }

  Eigen::Matrix4d projective = bench.transform;
  projective(3, 0) = 0.5;
  auto not_affine = constraints_from_selection(bench.mesh.V, bench.selection, projective);
  ASSERT_FALSE(not_affine.ok());
  EXPECT_EQ(not_affine.status().code(), ErrorCode::InvalidArgument);

  Eigen::Matrix4d non_finite = bench.transform;
  non_finite(1, 3) = std::nan("");
  auto nan_result = constraints_from_selection(bench.mesh.V, bench.selection, non_finite);
  ASSERT_FALSE(nan_result.ok());
  EXPECT_EQ(nan_result.status().code(), ErrorCode::InvalidArgument);

  // All-free is not an error here (the solver reports the missing constraints).
  auto all_free =
      constraints_from_selection(bench.mesh.V, Eigen::VectorXi::Ones(n), bench.transform);
  ASSERT_TRUE(all_free.ok());
  EXPECT_EQ(all_free->constrained.size(), 0);
}

// ---------------------------------------------------------------------------------------------
// Irregular variants (issue 13): real input is not a regular grid.
// ---------------------------------------------------------------------------------------------

/// Coefficient of variation of the edge lengths and the share of corners below 10 degrees.
struct Regularity {
  double edge_length_cv = 0;
  double share_below_10_degrees = 0;
  double min_angle_degrees = 180;
};

Regularity regularity(const MeshData& mesh) {
  std::map<std::pair<int, int>, double> edges;
  Regularity stats;
  int sharp = 0;
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int a = mesh.F(f, k), b = mesh.F(f, (k + 1) % 3), c = mesh.F(f, (k + 2) % 3);
      edges[std::minmax(a, b)] = (mesh.V.row(a) - mesh.V.row(b)).norm();
      const Eigen::Vector3d e1 = mesh.V.row(b) - mesh.V.row(a), e2 = mesh.V.row(c) - mesh.V.row(a);
      const double angle = std::atan2(e1.cross(e2).norm(), e1.dot(e2)) * 180 / kPi;
      stats.min_angle_degrees = std::min(stats.min_angle_degrees, angle);
      if (angle < 10) ++sharp;
    }
  }
  double sum = 0, sum2 = 0;
  for (const auto& [key, length] : edges) {
    sum += length;
    sum2 += length * length;
  }
  const double n = static_cast<double>(edges.size()), mean = sum / n;
  stats.edge_length_cv = std::sqrt(std::max(0.0, sum2 / n - mean * mean)) / mean;
  stats.share_below_10_degrees = sharp / (3.0 * static_cast<double>(mesh.F.rows()));
  return stats;
}

/// Largest distance from a vertex of role `role` in `a` to the nearest vertex of that role in b.
double one_sided_role_distance(const DeformationBenchmark& a, const DeformationBenchmark& b,
                               int role) {
  double worst = 0;
  for (Eigen::Index i = 0; i < a.mesh.V.rows(); ++i) {
    if (a.selection(i) != role) continue;
    double nearest = 1e300;
    for (Eigen::Index j = 0; j < b.mesh.V.rows(); ++j) {
      if (b.selection(j) != role) continue;
      nearest = std::min(nearest, (a.mesh.V.row(i) - b.mesh.V.row(j)).squaredNorm());
    }
    worst = std::max(worst, std::sqrt(nearest));
  }
  return worst;
}

double max_edge_length(const MeshData& mesh) {
  double longest = 0;
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      longest =
          std::max(longest, (mesh.V.row(mesh.F(f, k)) - mesh.V.row(mesh.F(f, (k + 1) % 3))).norm());
    }
  }
  return longest;
}

TEST(ProceduralIrregular, ValidManifoldsWithTheRegularTopology) {
  const auto regular = make_suite(SuiteScale::Small);
  const auto irregular = make_irregular_suite(SuiteScale::Small, 7);
  ASSERT_TRUE(irregular.ok()) << irregular.status().to_string();
  ASSERT_EQ(irregular->size(), regular.size());
  for (size_t k = 0; k < regular.size(); ++k) {
    const auto& bench = (*irregular)[k];
    EXPECT_EQ(bench.name, regular[k].name + "_irregular");
    expect_well_formed(bench);
    // Same topology (Euler characteristic); boundary vertices are never collapsed, only split.
    const auto euler = [](const MeshData& mesh) {
      std::set<std::pair<int, int>> edges;
      for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
        for (int j = 0; j < 3; ++j) edges.insert(std::minmax(mesh.F(f, j), mesh.F(f, (j + 1) % 3)));
      }
      return mesh.V.rows() - static_cast<Eigen::Index>(edges.size()) + mesh.F.rows();
    };
    EXPECT_EQ(euler(bench.mesh), euler(regular[k].mesh)) << bench.name;
    EXPECT_GE(boundary_edge_count(bench.mesh.F), boundary_edge_count(regular[k].mesh.F))
        << bench.name;
    EXPECT_EQ(boundary_edge_count(bench.mesh.F) == 0, boundary_edge_count(regular[k].mesh.F) == 0)
        << bench.name;
    // About the regular vertex count.
    EXPECT_GT(bench.mesh.V.rows(), 0.7 * static_cast<double>(regular[k].mesh.V.rows()));
    EXPECT_LT(bench.mesh.V.rows(), 1.5 * static_cast<double>(regular[k].mesh.V.rows()));
    EXPECT_TRUE(bench.transform.isApprox(regular[k].transform)) << bench.name;
  }
}

TEST(ProceduralIrregular, DeterministicForASeedAndDifferentAcrossSeeds) {
  const auto regular = make_cylinder(20, 21);
  const auto a = make_irregular(regular, 3);
  const auto b = make_irregular(regular, 3);
  const auto c = make_irregular(regular, 4);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  EXPECT_EQ(a->mesh.V, b->mesh.V);  // bitwise
  EXPECT_EQ(a->mesh.F, b->mesh.F);
  EXPECT_EQ(a->selection, b->selection);
  EXPECT_FALSE(a->mesh.V.rows() == c->mesh.V.rows() && a->mesh.V == c->mesh.V);
}

TEST(ProceduralIrregular, MeasurablyIrregular) {
  const auto regular = make_suite(SuiteScale::Small);
  const auto irregular = make_irregular_suite(SuiteScale::Small, 1);
  ASSERT_TRUE(irregular.ok());
  for (size_t k = 0; k < regular.size(); ++k) {
    SCOPED_TRACE(regular[k].name);
    const Regularity before = regularity(regular[k].mesh);
    const Regularity after = regularity((*irregular)[k].mesh);
    // The regular models: edge lengths within ~30% of each other, no corner below 10 degrees.
    EXPECT_LT(before.edge_length_cv, 0.3);
    EXPECT_EQ(before.share_below_10_degrees, 0.0);
    // The variants: lengths spread (density contrast 4), ~1-2% of the corners are slivers'
    // sharp ones, yet none is a needle (every corner above 1 degree).
    EXPECT_GT(after.edge_length_cv, 0.35);
    EXPECT_GT(after.edge_length_cv, 1.3 * before.edge_length_cv);
    EXPECT_GT(after.share_below_10_degrees, 0.008);
    EXPECT_LT(after.share_below_10_degrees, 0.05);
    EXPECT_GT(after.min_angle_degrees, 1.0);
  }
}

TEST(ProceduralIrregular, HandleAndFixedRegionsStayWhereTheyWere) {
  const auto regular = make_suite(SuiteScale::Small);
  const auto irregular = make_irregular_suite(SuiteScale::Small, 1);
  ASSERT_TRUE(irregular.ok());
  for (size_t k = 0; k < regular.size(); ++k) {
    SCOPED_TRACE(regular[k].name);
    const auto& bench = (*irregular)[k];
    // Every fixed (handle) vertex of either mesh lies within one regular edge length of a fixed
    // (handle) vertex of the other: the same geometric regions, at a different sampling.
    const double h = max_edge_length(regular[k].mesh);
    for (const int role : {0, 2}) {
      EXPECT_LT(one_sided_role_distance(bench, regular[k], role), h) << "role " << role;
      EXPECT_LT(one_sided_role_distance(regular[k], bench, role), h) << "role " << role;
    }
    const auto setup = constraints_from_selection(bench.mesh.V, bench.selection, bench.transform);
    ASSERT_TRUE(setup.ok());
    EXPECT_GT(setup->constrained.size(), 2);
  }
}

TEST(ProceduralIrregular, OptionsOffKeepTheMeshRegular) {
  IrregularOptions off;
  off.density_contrast = 1;
  off.skinny_fraction = 0;
  off.jitter = 0;
  off.flip_fraction = 0;
  const auto regular = make_bar(20, 6);
  const auto same = make_irregular(regular, 1, off);
  ASSERT_TRUE(same.ok());
  EXPECT_EQ(regularity(same->mesh).share_below_10_degrees, 0.0);
  EXPECT_NEAR(static_cast<double>(same->mesh.V.rows()), static_cast<double>(regular.mesh.V.rows()),
              0.1 * static_cast<double>(regular.mesh.V.rows()));
}

TEST(ProceduralIrregular, RejectsAWrongSelection) {
  auto bench = make_bar(20, 6);
  bench.selection.conservativeResize(bench.selection.size() - 1);
  const auto result = make_irregular(bench, 1);
  ASSERT_FALSE(result.ok());
  EXPECT_EQ(result.status().code(), ErrorCode::InvalidArgument);
}

TEST(ProceduralSpot, LoopSubdivisionQuadruplesAndEditsCarryAcrossLevels) {
  // A small closed genus-0 stand-in (the bar), since core tests do not read files.
  const auto bar = make_bar(8, 2);
  const auto once = subdivide_loop(bar.mesh, 1);
  ASSERT_TRUE(once.ok()) << once.status().to_string();
  // Closed triangle mesh: V' = V + E = V + 3F/2, F' = 4F.
  EXPECT_EQ(once->V.rows(), bar.mesh.V.rows() + 3 * bar.mesh.F.rows() / 2);
  EXPECT_EQ(once->F.rows(), 4 * bar.mesh.F.rows());
  EXPECT_TRUE(validate_triangle_mesh(once->V, once->F).ok());
  EXPECT_FALSE(subdivide_loop(bar.mesh, 7).ok());
  for (const SpotEdit edit : {SpotEdit::Stretch, SpotEdit::Bend, SpotEdit::Twist}) {
    const auto coarse = make_spot_edit(bar.mesh, edit);
    const auto fine = make_spot_edit(*once, edit);
    ASSERT_TRUE(coarse.ok() && fine.ok());
    EXPECT_TRUE(coarse->transform.isApprox(fine->transform, 0.05)) << spot_edit_name(edit);
    EXPECT_GT((fine->selection.array() == 0).count(), (coarse->selection.array() == 0).count());
    EXPECT_GT((fine->selection.array() == 2).count(), (coarse->selection.array() == 2).count());
  }
}

}  // namespace
}  // namespace meshdeform::core
