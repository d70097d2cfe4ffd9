// The multiresolution hierarchy (core/multires/multires.h): coarse levels keep the constrained vertices and
// stay valid manifolds, the prolongation reproduces the rest pose and similarities exactly, and
// a full-resolution solve warm-started from a prolonged coarse solve converges to the
// single-level result.
#include "core/multires/multires.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <set>
#include <stop_token>
#include <string>
#include <string_view>
#include <tuple>
#include <utility>
#include <thread>
#include <vector>

#include <Eigen/Geometry>

#include "core/io/mesh_io.h"
#include "core/mesh/measures.h"
#include "core/mesh/topology.h"
#include "core/mesh/validate.h"
#include "core/methods/deformer.h"
#include "core/methods/scale_aware.h"
#include "core/samples/generators.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

using test::bbox_diagonal;

struct Edit {
  const char* name;
  MeshData mesh;
  HandleSetup setup;
};

Edit edit_of(const DeformationBenchmark& bench) {
  auto setup = constraints_from_selection(bench.mesh.V, bench.selection, bench.transform);
  EXPECT_TRUE(setup.ok()) << setup.status().to_string();
  return {bench.name.c_str(), bench.mesh, *setup};
}

/// Spot after one Loop subdivision (11,700 vertices), head nodded.
const Edit& spot_bend() {
  static const Edit edit = [] {
    auto spot = io::read_mesh(std::string(MESHDEFORM_TEST_DATA_DIR) + "/spot.obj");
    EXPECT_TRUE(spot.ok()) << spot.status().to_string();
    auto fine = subdivide_loop(*spot, 1);
    EXPECT_TRUE(fine.ok()) << fine.status().to_string();
    auto bench = make_spot_edit(*fine, SpotEdit::Bend);
    EXPECT_TRUE(bench.ok()) << bench.status().to_string();
    Edit e = edit_of(*bench);
    e.name = "spot12k_bend";
    return e;
  }();
  return edit;
}

int euler_characteristic(const MeshData& mesh) {
  const MeshTopology topology = build_topology(mesh.F, static_cast<int>(mesh.V.rows())).value();
  const long edges = topology.interior_edges.rows() + topology.boundary_edge_count;
  return static_cast<int>(mesh.V.rows() - edges + mesh.F.rows());
}

int component_count(const MeshData& mesh) {
  return build_topology(mesh.F, static_cast<int>(mesh.V.rows())).value().component_count;
}

/// Checks every invariant of a level against the fine mesh.
void expect_valid_level(const MeshHierarchy& hierarchy, int k, const Eigen::VectorXi& constrained,
                        bool keep_all) {
  SCOPED_TRACE("level " + std::to_string(k));
  const MeshLevel& fine = hierarchy.level(0);
  const MeshLevel& level = hierarchy.level(k);
  const MeshData fine_mesh{fine.V, fine.F}, mesh{level.V, level.F};
  EXPECT_TRUE(validate_triangle_mesh(level.V, level.F).ok())
      << validate_triangle_mesh(level.V, level.F).to_string();
  // Same topology: components, boundary loops, Euler characteristic (so the genus too).
  EXPECT_EQ(component_count(mesh), component_count(fine_mesh));
  EXPECT_EQ(count_boundary_loops(level.F, static_cast<int>(level.V.rows())),
            count_boundary_loops(fine.F, static_cast<int>(fine.V.rows())));
  EXPECT_EQ(euler_characteristic(mesh), euler_characteristic(fine_mesh));
  // A subset of the fine vertices at their rest positions, in fine order.
  ASSERT_EQ(level.to_fine.size(), level.V.rows());
  for (Eigen::Index i = 0; i < level.V.rows(); ++i) {
    ASSERT_EQ(level.V.row(i), fine.V.row(level.to_fine(i))) << "vertex " << i;
    if (i > 0) {
      ASSERT_LT(level.to_fine(i - 1), level.to_fine(i));
    }
  }
  // Constrained vertices: the level's are exactly the fine-constrained ones it holds, and the
  // target rows point back at them.
  std::vector<int> row_of(static_cast<size_t>(fine.V.rows()), -1);
  for (Eigen::Index j = 0; j < constrained.size(); ++j)
    row_of[constrained(j)] = static_cast<int>(j);
  std::set<int> level_constrained;
  ASSERT_EQ(level.constrained.size(), level.constrained_rows.size());
  for (Eigen::Index j = 0; j < level.constrained.size(); ++j) {
    const int fine_vertex = level.to_fine(level.constrained(j));
    EXPECT_EQ(row_of[fine_vertex], level.constrained_rows(j));
    level_constrained.insert(fine_vertex);
  }
  for (Eigen::Index i = 0; i < level.V.rows(); ++i) {
    EXPECT_EQ(level_constrained.count(level.to_fine(i)) == 1, row_of[level.to_fine(i)] >= 0);
  }
  if (keep_all) {
    EXPECT_EQ(level.constrained.size(), constrained.size());
  }
}

TEST(MeshHierarchy, EveryLevelKeepsTheHandleSetAndIsAValidManifold) {
  const Edit cactus = edit_of(make_cactus(4));  // 5,289 vertices, one boundary loop
  MultiresSettings settings;
  settings.level_vertices = {2500, 1200};
  auto hierarchy =
      MeshHierarchy::build(cactus.mesh.V, cactus.mesh.F, cactus.setup.constrained, settings);
  ASSERT_TRUE(hierarchy.ok()) << hierarchy.status().to_string();
  ASSERT_EQ(hierarchy->level_count(), 3);
  EXPECT_EQ(hierarchy->level(0).V.rows(), cactus.mesh.V.rows());
  EXPECT_EQ(hierarchy->level(1).V.rows(), 2500);
  EXPECT_EQ(hierarchy->level(2).V.rows(), 1200);
  for (int k = 0; k < 3; ++k) expect_valid_level(*hierarchy, k, cactus.setup.constrained, true);

  // Coarse targets are the fine targets of the same vertices.
  for (int k = 1; k < 3; ++k) {
    auto targets = hierarchy->level_targets(k, cactus.setup.targets);
    ASSERT_TRUE(targets.ok());
    const MeshLevel& level = hierarchy->level(k);
    for (Eigen::Index j = 0; j < level.constrained.size(); ++j) {
      EXPECT_EQ(targets->row(j), cactus.setup.targets.row(level.constrained_rows(j)));
    }
  }
  EXPECT_EQ(hierarchy->level_targets(1, cactus.setup.targets.topRows(3)).status().code(),
            ErrorCode::InvalidArgument);
  EXPECT_EQ(hierarchy->level_targets(3, cactus.setup.targets).status().code(),
            ErrorCode::InvalidArgument);
}

TEST(MeshHierarchy, KeepAllStopsAtTheHandleSetWhileKeepBordersGoesBelowIt) {
  const Edit& spot = spot_bend();  // 43% of the vertices constrained
  const auto n_constrained = spot.setup.constrained.size();
  MultiresSettings settings;
  settings.level_vertices = {2000};
  auto all = MeshHierarchy::build(spot.mesh.V, spot.mesh.F, spot.setup.constrained, settings);
  ASSERT_TRUE(all.ok()) << all.status().to_string();
  expect_valid_level(*all, 1, spot.setup.constrained, true);
  EXPECT_GE(all->level(1).V.rows(), n_constrained);

  settings.constraint_levels = ConstraintLevels::KeepBorders;
  auto borders = MeshHierarchy::build(spot.mesh.V, spot.mesh.F, spot.setup.constrained, settings);
  ASSERT_TRUE(borders.ok()) << borders.status().to_string();
  expect_valid_level(*borders, 1, spot.setup.constrained, false);
  EXPECT_EQ(borders->level(1).V.rows(), 2000);
  // Every region-border vertex is still there.
  const MeshTopology topology =
      build_topology(spot.mesh.F, static_cast<int>(spot.mesh.V.rows())).value();
  std::vector<char> is_constrained(static_cast<size_t>(spot.mesh.V.rows()), 0);
  for (Eigen::Index j = 0; j < n_constrained; ++j) is_constrained[spot.setup.constrained(j)] = 1;
  const auto& to_fine = borders->level(1).to_fine;
  const std::set<int> kept(to_fine.data(), to_fine.data() + to_fine.size());
  int border_vertices = 0;
  for (int v = 0; v < spot.mesh.V.rows(); ++v) {
    if (!is_constrained[v]) continue;
    bool border = false;
    for (int k = topology.vv_offsets[v]; k < topology.vv_offsets[v + 1]; ++k) {
      border = border || !is_constrained[topology.vv_neighbors[k]];
    }
    if (border) {
      ++border_vertices;
      EXPECT_EQ(kept.count(v), 1u) << "border vertex " << v << " was removed";
    }
  }
  EXPECT_GT(border_vertices, 0);
}

/// How many of the unit square's corners (x, y in {0, 1}) are vertices of V.
int count_corners(const Positions& V) {
  int corners = 0;
  for (const double cx : {0.0, 1.0}) {
    for (const double cy : {0.0, 1.0}) {
      bool found = false;
      for (Eigen::Index i = 0; i < V.rows(); ++i) found = found || (V(i, 0) == cx && V(i, 1) == cy);
      corners += found;
    }
  }
  return corners;
}

TEST(MeshHierarchy, OpenBordersKeepTheirShape) {
  // No constraints at all: the boundary is kept by the decimation itself.
  const MeshData grid = test::make_grid(60, 0.05);  // 3,721 vertices, one boundary loop
  MultiresSettings settings;
  settings.level_vertices = {400};
  auto hierarchy = MeshHierarchy::build(grid.V, grid.F, Eigen::VectorXi(), settings);
  ASSERT_TRUE(hierarchy.ok()) << hierarchy.status().to_string();
  expect_valid_level(*hierarchy, 1, Eigen::VectorXi(), false);
  EXPECT_EQ(hierarchy->level(1).V.rows(), 400);
  // The square's corners survive (an eroded border would cut them off) and every coarse boundary
  // vertex lies on the square's border.
  const Positions& V = hierarchy->level(1).V;
  EXPECT_EQ(count_corners(V), 4);
  // Each coarse boundary edge runs along a side of the square (none cuts across a corner).
  const Triangles& F = hierarchy->level(1).F;
  std::set<std::pair<int, int>> directed;
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) directed.insert({F(f, k), F(f, (k + 1) % 3)});
  }
  int boundary_edges = 0;
  for (const auto& [a, b] : directed) {
    if (directed.count({b, a})) continue;
    ++boundary_edges;
    const bool same_side = (V(a, 0) == V(b, 0) && (V(a, 0) == 0 || V(a, 0) == 1)) ||
                           (V(a, 1) == V(b, 1) && (V(a, 1) == 0 || V(a, 1) == 1));
    EXPECT_TRUE(same_side) << "boundary edge (" << a << ", " << b << ") leaves the square's sides";
  }
  EXPECT_GE(boundary_edges, 8);
  // On a flat square only the boundary quadrics price a collapse: without them the corners go.
  const MeshData flat = test::make_grid(30);
  settings.level_vertices = {100};
  auto kept = MeshHierarchy::build(flat.V, flat.F, Eigen::VectorXi(), settings);
  ASSERT_TRUE(kept.ok()) << kept.status().to_string();
  EXPECT_EQ(count_corners(kept->level(1).V), 4);
  settings.boundary_weight = 0;
  auto eroded = MeshHierarchy::build(flat.V, flat.F, Eigen::VectorXi(), settings);
  ASSERT_TRUE(eroded.ok()) << eroded.status().to_string();
  EXPECT_LT(count_corners(eroded->level(1).V), 4);
  settings.boundary_weight = MultiresSettings{}.boundary_weight;
  settings.level_vertices = {400};

  // An open tube (two boundary loops) with its own constraints.
  const Edit cylinder = edit_of(make_cylinder(40, 30));
  auto tube = MeshHierarchy::build(cylinder.mesh.V, cylinder.mesh.F, cylinder.setup.constrained,
                                   settings);
  ASSERT_TRUE(tube.ok()) << tube.status().to_string();
  expect_valid_level(*tube, 1, cylinder.setup.constrained, true);
}

TEST(MeshHierarchy, IsDeterministic) {
  auto irregular = make_irregular(make_cactus(2), 7);
  ASSERT_TRUE(irregular.ok());
  const Edit edit = edit_of(*irregular);
  MultiresSettings settings;
  settings.level_vertices = {900, 400};
  auto a = MeshHierarchy::build(edit.mesh.V, edit.mesh.F, edit.setup.constrained, settings);
  auto b = MeshHierarchy::build(edit.mesh.V, edit.mesh.F, edit.setup.constrained, settings);
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_EQ(a->level_count(), b->level_count());
  for (int k = 1; k < a->level_count(); ++k) {
    EXPECT_EQ(a->level(k).to_fine, b->level(k).to_fine);
    EXPECT_EQ(a->level(k).F, b->level(k).F);
    EXPECT_EQ(a->level(k).constrained, b->level(k).constrained);
  }
}

double mean_edge_length(const Positions& V, const Triangles& F) {
  double sum = 0;
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) sum += (V.row(F(f, k)) - V.row(F(f, (k + 1) % 3))).norm();
  }
  return sum / static_cast<double>(3 * F.rows());
}

/// How many times denser than on average the level is in the slab of half-width `half_width`
/// around the plane x[axis] = middle: (level vertices in the slab / fine vertices in the slab) /
/// (level vertices / fine vertices).
double slab_density_ratio(const MeshLevel& fine, const MeshLevel& level, int axis, double middle,
                          double half_width) {
  const auto in_slab = [&](const Positions& V) {
    int count = 0;
    for (Eigen::Index i = 0; i < V.rows(); ++i) count += std::abs(V(i, axis) - middle) < half_width;
    return count;
  };
  const double slab = static_cast<double>(in_slab(level.V)) / in_slab(fine.V);
  return slab / (static_cast<double>(level.V.rows()) / static_cast<double>(fine.V.rows()));
}

TEST(MeshHierarchy, ASplitDecimationKeepsTheInvariantsAndTheCutDoesNotShow) {
  const Edit& spot = spot_bend();
  const Positions& V = spot.mesh.V;
  // The cut runs across the longest axis of the bounding box, at the median of the unlocked
  // vertices; with KeepBorders most vertices are unlocked, so near the median of all of them.
  const Eigen::RowVector3d extent = V.colwise().maxCoeff() - V.colwise().minCoeff();
  Eigen::Index axis = 0;
  extent.maxCoeff(&axis);
  std::vector<double> along(V.col(axis).data(), V.col(axis).data() + V.rows());
  std::nth_element(along.begin(), along.begin() + static_cast<long>(along.size() / 2), along.end());
  const double middle = along[along.size() / 2];
  const double edge = mean_edge_length(V, spot.mesh.F);

  for (const ConstraintLevels mode : {ConstraintLevels::KeepBorders, ConstraintLevels::KeepAll}) {
    const bool keep_all = mode == ConstraintLevels::KeepAll;
    SCOPED_TRACE(keep_all ? "KeepAll" : "KeepBorders");
    MultiresSettings settings;
    settings.constraint_levels = mode;
    settings.level_vertices = {keep_all ? 6000 : 1500, keep_all ? 5200 : 600};
    settings.split_above_vertices = 0;
    auto whole = MeshHierarchy::build(V, spot.mesh.F, spot.setup.constrained, settings);
    ASSERT_TRUE(whole.ok()) << whole.status().to_string();
    settings.split_above_vertices = 5000;  // Spot 12k is split
    std::vector<MeshHierarchy> split;
    for (const int threads : {1, 2}) {
      settings.threads = threads;
      auto built = MeshHierarchy::build(V, spot.mesh.F, spot.setup.constrained, settings);
      ASSERT_TRUE(built.ok()) << built.status().to_string();
      split.push_back(std::move(*built));
    }
    const MeshHierarchy& h = split.front();
    ASSERT_EQ(h.level_count(), 3);
    for (int k = 1; k < 3; ++k) {
      expect_valid_level(h, k, spot.setup.constrained, keep_all);
      EXPECT_EQ(h.level(k).V.rows(), settings.level_vertices[static_cast<size_t>(k - 1)]);
      // The same levels on one thread and on two.
      EXPECT_EQ(h.level(k).to_fine, split.back().level(k).to_fine);
      EXPECT_EQ(h.level(k).F, split.back().level(k).F);
      // A split decimation is a different one (other draws), not the whole mesh's.
      EXPECT_NE(h.level(k).to_fine, whole->level(k).to_fine);
    }
    // The band along the cut is decimated like the rest: the level is not much denser next to
    // the cut than a decimation of the whole mesh is there (without the band's own pass, the
    // KeepBorders slab came out at 2.3 times the average density, against 1.1 unsplit).
    const double near_cut = slab_density_ratio(h.level(0), h.level(1), static_cast<int>(axis),
                                               middle, 3 * edge);
    const double unsplit = slab_density_ratio(whole->level(0), whole->level(1),
                                              static_cast<int>(axis), middle, 3 * edge);
    EXPECT_LT(near_cut, 1.5 * unsplit + 0.25) << "split " << near_cut << ", whole " << unsplit;
  }
}

TEST(MeshHierarchy, StopRequestStopsTheBuild) {
  const Edit& spot = spot_bend();
  MultiresSettings settings;
  settings.constraint_levels = ConstraintLevels::KeepBorders;
  settings.level_vertices = {1000};

  std::stop_source before;
  before.request_stop();
  auto early = MeshHierarchy::build(spot.mesh.V, spot.mesh.F, spot.setup.constrained, settings, {},
                                    before.get_token());
  EXPECT_EQ(early.status().code(), ErrorCode::Cancelled);

  // Mid-decimation: the progress callback asks to stop a third of the way through.
  std::stop_source during;
  std::vector<double> fractions;
  auto progress = [&](std::string_view phase, double fraction) {
    if (phase != "decimate") return;
    fractions.push_back(fraction);
    if (fraction > 0.3) during.request_stop();
  };
  auto stopped = MeshHierarchy::build(spot.mesh.V, spot.mesh.F, spot.setup.constrained, settings,
                                      progress, during.get_token());
  EXPECT_EQ(stopped.status().code(), ErrorCode::Cancelled);
  ASSERT_FALSE(fractions.empty());
  EXPECT_TRUE(std::is_sorted(fractions.begin(), fractions.end()));
  EXPECT_LT(fractions.back(), 0.5) << "the decimation went on after the stop request";

  // The same with the first level decimated in two halves on two threads: the progress
  // (reported on the calling thread only) counts both halves, and a stop ends both. How far
  // the other half has got by the calling thread's next report depends on how the two threads
  // are scheduled (on a busy machine the first report past 0.3 was 0.63), so the check is
  // that nothing is reported after the report that asked to stop.
  settings.split_above_vertices = 5000;
  settings.threads = 2;
  std::stop_source during_split;
  fractions.clear();
  double requested_at = -1;
  auto stopped_split = MeshHierarchy::build(
      spot.mesh.V, spot.mesh.F, spot.setup.constrained, settings,
      [&, caller = std::this_thread::get_id()](std::string_view phase, double fraction) {
        EXPECT_EQ(std::this_thread::get_id(), caller);
        if (phase != "decimate") return;
        fractions.push_back(fraction);
        if (fraction > 0.3 && !during_split.stop_requested()) {
          requested_at = fraction;
          during_split.request_stop();
        }
      },
      during_split.get_token());
  EXPECT_EQ(stopped_split.status().code(), ErrorCode::Cancelled);
  ASSERT_FALSE(fractions.empty());
  EXPECT_TRUE(std::is_sorted(fractions.begin(), fractions.end()));
  EXPECT_GT(requested_at, 0.3);
  EXPECT_EQ(fractions.back(), requested_at) << "the decimation went on after the stop request";
  settings.split_above_vertices = MultiresSettings{}.split_above_vertices;

  // Unstopped, the same callback reports the phase to its end.
  fractions.clear();
  auto done = MeshHierarchy::build(spot.mesh.V, spot.mesh.F, spot.setup.constrained, settings,
                                   [&](std::string_view phase, double fraction) {
                                     if (phase == "decimate") fractions.push_back(fraction);
                                   });
  ASSERT_TRUE(done.ok()) << done.status().to_string();
  EXPECT_DOUBLE_EQ(fractions.back(), 1.0);
}

TEST(MeshHierarchy, ProgressReportsAreAtLeastOnePercentApart) {
  // A server streams every report to its client. 32,761 vertices to 1,000 is 31.8k collapses:
  // the decimater's observer fires every 256 (0.8%), more often than is worth a message.
  const DeformationBenchmark plane = make_bumpy_plane(181);
  MultiresSettings settings;
  settings.level_vertices = {8000, 1000};  // observers of two levels and of the split halves
  settings.split_above_vertices = 20000;
  settings.threads = 2;
  std::vector<double> fractions;
  auto built = MeshHierarchy::build(plane.mesh.V, plane.mesh.F, Eigen::VectorXi(), settings,
                                    [&](std::string_view phase, double fraction) {
                                      if (phase == "decimate") fractions.push_back(fraction);
                                    });
  ASSERT_TRUE(built.ok()) << built.status().to_string();
  ASSERT_GT(fractions.size(), 20u);  // still a progress bar
  EXPECT_EQ(fractions.front(), 0.0);
  EXPECT_EQ(fractions.back(), 1.0);
  for (size_t i = 1; i + 1 < fractions.size(); ++i) {
    EXPECT_GE(fractions[i] - fractions[i - 1], 0.01 - 1e-12) << i;
  }
  EXPECT_LE(fractions.size(), 102u);
}

TEST(MeshHierarchy, RejectsBadInput) {
  const Edit cactus = edit_of(make_cactus(1));
  MultiresSettings increasing;
  increasing.level_vertices = {100, 200};
  EXPECT_EQ(MeshHierarchy::build(cactus.mesh.V, cactus.mesh.F, cactus.setup.constrained, increasing)
                .status()
                .code(),
            ErrorCode::InvalidArgument);
  Eigen::VectorXi repeated(2);
  repeated << 3, 3;
  EXPECT_EQ(MeshHierarchy::build(cactus.mesh.V, cactus.mesh.F, repeated).status().code(),
            ErrorCode::InvalidArgument);
  MultiresSettings negative_split;
  negative_split.split_above_vertices = -1;
  EXPECT_EQ(MeshHierarchy::build(cactus.mesh.V, cactus.mesh.F, cactus.setup.constrained,
                                 negative_split)
                .status()
                .code(),
            ErrorCode::InvalidArgument);
  MultiresSettings no_threads;
  no_threads.threads = 0;
  EXPECT_EQ(
      MeshHierarchy::build(cactus.mesh.V, cactus.mesh.F, cactus.setup.constrained, no_threads)
          .status()
          .code(),
      ErrorCode::InvalidArgument);
  Triangles broken = cactus.mesh.F;
  broken(0, 1) = broken(0, 0);
  EXPECT_EQ(MeshHierarchy::build(cactus.mesh.V, broken, cactus.setup.constrained).status().code(),
            ErrorCode::InvalidArgument);
}

// ---- prolongation -------------------------------------------------------------------------------

struct Prolonged {
  const char* name;
  MeshData fine;
  Eigen::VectorXi to_fine;
  Positions coarse_rest;
};

std::vector<Prolonged> prolongation_cases() {
  std::vector<Prolonged> cases;
  auto add = [&](const char* name, const Edit& edit, int coarse_vertices, ConstraintLevels mode) {
    MultiresSettings settings;
    settings.level_vertices = {coarse_vertices};
    settings.constraint_levels = mode;
    auto hierarchy =
        MeshHierarchy::build(edit.mesh.V, edit.mesh.F, edit.setup.constrained, settings);
    EXPECT_TRUE(hierarchy.ok()) << name << ": " << hierarchy.status().to_string();
    if (!hierarchy.ok()) return;
    cases.push_back({name, edit.mesh, hierarchy->level(1).to_fine, hierarchy->level(1).V});
  };
  add("spot12k", spot_bend(), 1500, ConstraintLevels::KeepBorders);
  add("cactus", edit_of(make_cactus(3)), 1000, ConstraintLevels::KeepAll);
  add("cylinder", edit_of(make_cylinder(60, 30)), 500, ConstraintLevels::KeepAll);
  return cases;
}

TEST(Prolongation, RestPoseIsReproduced) {
  for (const auto& c : prolongation_cases()) {
    SCOPED_TRACE(c.name);
    auto prolongation = Prolongation::create(c.fine.V, c.fine.F, c.to_fine);
    ASSERT_TRUE(prolongation.ok()) << prolongation.status().to_string();
    EXPECT_EQ(prolongation->fine_vertex_count(), c.fine.V.rows());
    EXPECT_EQ(prolongation->coarse_vertex_count(), c.to_fine.size());
    auto V = prolongation->apply(c.coarse_rest);
    ASSERT_TRUE(V.ok()) << V.status().to_string();
    EXPECT_LT((*V - c.fine.V).cwiseAbs().maxCoeff(), test::kExactTol * bbox_diagonal(c.fine));
  }
}

TEST(Prolongation, SimilaritiesOfTheCoarseMeshAreExactOnTheFineMesh) {
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(2.0, Eigen::Vector3d(1, -2, 0.5).normalized()).toRotationMatrix();
  const Eigen::RowVector3d t(0.7, -1.5, 2.5);
  for (const auto& c : prolongation_cases()) {
    SCOPED_TRACE(c.name);
    auto prolongation = Prolongation::create(c.fine.V, c.fine.F, c.to_fine);
    ASSERT_TRUE(prolongation.ok()) << prolongation.status().to_string();
    for (const double scale : {1.0, 2.5, 0.4}) {
      SCOPED_TRACE("scale " + std::to_string(scale));
      const Positions coarse = ((scale * c.coarse_rest * R.transpose()).rowwise() + t).eval();
      const Positions expected = ((scale * c.fine.V * R.transpose()).rowwise() + t).eval();
      auto V = prolongation->apply(coarse);
      ASSERT_TRUE(V.ok()) << V.status().to_string();
      EXPECT_LT((*V - expected).cwiseAbs().maxCoeff(),
                test::kExactTol * scale * bbox_diagonal(c.fine));
    }
  }
}

TEST(Prolongation, DetailsFollowALocalBendWithoutSeams) {
  // Bend the coarse cylinder about a horizontal axis; the prolonged fine mesh must stay close to
  // the same bend applied to the fine mesh (a smooth map, locally a rotation), and its corner
  // angles close to the rest ones: detail vectors follow the rotated frames.
  const Edit cylinder = edit_of(make_cylinder(60, 30));
  MultiresSettings settings;
  settings.level_vertices = {500};
  auto hierarchy = MeshHierarchy::build(cylinder.mesh.V, cylinder.mesh.F,
                                        cylinder.setup.constrained, settings);
  ASSERT_TRUE(hierarchy.ok());
  auto prolongation = Prolongation::create(cylinder.mesh.V, cylinder.mesh.F,
                                           hierarchy->level(1).to_fine);
  ASSERT_TRUE(prolongation.ok());
  // Bend: z along the tube becomes an arc of radius 2 in the xz plane (a quarter turn).
  auto bend = [](const Positions& V) {
    Positions out(V.rows(), 3);
    const double radius = 2.0;
    for (Eigen::Index i = 0; i < V.rows(); ++i) {
      const double angle = V(i, 2) / radius;
      const double r = radius - V(i, 0);
      out.row(i) << radius - r * std::cos(angle), V(i, 1), r * std::sin(angle);
    }
    return out;
  };
  auto V = prolongation->apply(bend(hierarchy->level(1).V));
  ASSERT_TRUE(V.ok());
  const Positions expected = bend(cylinder.mesh.V);
  const double diag = bbox_diagonal(cylinder.mesh);
  EXPECT_LT((*V - expected).rowwise().norm().maxCoeff(), 0.01 * diag);
  const MeshTopology topology =
      build_topology(cylinder.mesh.F, static_cast<int>(cylinder.mesh.V.rows())).value();
  const Measures rest = compute_measures(cylinder.mesh.V, cylinder.mesh.F, topology);
  const AngleErrors ours = angle_errors(rest, compute_measures(*V, cylinder.mesh.F, topology));
  const AngleErrors exact =
      angle_errors(rest, compute_measures(expected, cylinder.mesh.F, topology));
  // Without details (the bare base surface) E_theta is an order of magnitude larger.
  EXPECT_LT(ours.e_theta, exact.e_theta + 0.02);
  EXPECT_LT(ours.e_phi, exact.e_phi + 0.02);
}

TEST(Prolongation, TwoThreadsGiveTheOneThreadResult) {
  // 25,921 vertices, every 16th coarse: 24k free vertices, above the size from which two threads
  // factor and solve the base system in two halves (core/linalg/split_cholesky.h).
  const MeshData plane = make_bumpy_plane(161).mesh;
  Eigen::VectorXi coarse_to_fine((plane.V.rows() + 15) / 16);
  for (Eigen::Index i = 0; i < coarse_to_fine.size(); ++i) {
    coarse_to_fine(i) = static_cast<int>(16 * i);
  }
  Positions coarse_rest(coarse_to_fine.size(), 3);
  for (Eigen::Index i = 0; i < coarse_to_fine.size(); ++i) {
    coarse_rest.row(i) = plane.V.row(coarse_to_fine(i));
  }
  // A smooth non-affine deformation of the coarse vertices (a twist and a bulge).
  Positions coarse = coarse_rest;
  for (Eigen::Index i = 0; i < coarse.rows(); ++i) {
    const double x = coarse(i, 0), y = coarse(i, 1), angle = 0.3 * x;
    coarse(i, 1) = std::cos(angle) * y - std::sin(angle) * coarse(i, 2);
    coarse(i, 2) = std::sin(angle) * y + std::cos(angle) * coarse(i, 2) + 0.2 * std::exp(-x * x);
  }
  auto one = Prolongation::create(plane.V, plane.F, coarse_to_fine, {}, 1);
  auto two = Prolongation::create(plane.V, plane.F, coarse_to_fine, {}, 2);
  ASSERT_TRUE(one.ok()) << one.status().to_string();
  ASSERT_TRUE(two.ok()) << two.status().to_string();
  const double diagonal = bbox_diagonal(plane);
  auto rest = two->apply(coarse_rest);
  ASSERT_TRUE(rest.ok());
  EXPECT_LT((*rest - plane.V).cwiseAbs().maxCoeff(), test::kExactTol * diagonal);
  auto a = one->apply(coarse), b = two->apply(coarse);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_GT((*a - plane.V).cwiseAbs().maxCoeff(), 0.01 * diagonal);  // it did deform
  EXPECT_LT((*a - *b).cwiseAbs().maxCoeff(), 1e-10 * diagonal);
  EXPECT_EQ(Prolongation::create(plane.V, plane.F, coarse_to_fine, {}, 0).status().code(),
            ErrorCode::InvalidArgument);
}

TEST(Prolongation, RejectsBadInput) {
  const Edit cactus = edit_of(make_cactus(1));
  Eigen::VectorXi out_of_range(1);
  out_of_range << static_cast<int>(cactus.mesh.V.rows());
  EXPECT_EQ(Prolongation::create(cactus.mesh.V, cactus.mesh.F, out_of_range).status().code(),
            ErrorCode::InvalidArgument);
  // Two copies of the mesh, coarse vertices only in the first: the second is not tied down.
  MeshData twice;
  const auto n = cactus.mesh.V.rows();
  twice.V.resize(2 * n, 3);
  twice.V << cactus.mesh.V, (cactus.mesh.V.rowwise() + Eigen::RowVector3d(5, 0, 0)).eval();
  twice.F.resize(2 * cactus.mesh.F.rows(), 3);
  twice.F << cactus.mesh.F, (cactus.mesh.F.array() + static_cast<int>(n)).matrix();
  Eigen::VectorXi first(3);
  first << 0, 1, 2;
  EXPECT_EQ(Prolongation::create(twice.V, twice.F, first).status().code(),
            ErrorCode::InvalidArgument);
  auto ok = Prolongation::create(cactus.mesh.V, cactus.mesh.F, first);
  ASSERT_TRUE(ok.ok()) << ok.status().to_string();
  EXPECT_EQ(ok->apply(Positions::Zero(2, 3)).status().code(), ErrorCode::InvalidArgument);
  Positions nan = Positions::Zero(3, 3);
  nan(1, 1) = std::nan("");
  EXPECT_EQ(ok->apply(nan).status().code(), ErrorCode::InvalidArgument);
}

// ---- two-level driver ---------------------------------------------------------------------------

TEST(MultiresDeformer, RefinedFromTheProlongedStartMatchesTheSingleLevelSolve) {
  const Edit cactus = edit_of(make_cactus(2));  // 1,329 vertices
  const MeshTopology topology =
      build_topology(cactus.mesh.F, static_cast<int>(cactus.mesh.V.rows())).value();
  const Measures rest = compute_measures(cactus.mesh.V, cactus.mesh.F, topology);
  auto errors_of = [&](const Positions& V) {
    return angle_errors(rest, compute_measures(V, cactus.mesh.F, topology));
  };
  SolveOptions converge;
  // Converged for real: a looser relative-change test stops the two runs at different points of
  // a slow tail (measured: 2-10% apart in E_theta at 1e-5 on the 3,000-vertex cactus).
  converge.max_iterations = 400;
  converge.tolerance = 1e-7;
  converge.stopping_rule = StoppingRule::Change;  // a last change of 1e-7: as measured above
  converge.track_metrics = false;

  // Single level, from the Laplacian guess (named: Auto's cold start at rigidity > 0 is ARAP's
  // converged result, already closer than a prolonged coarse solve). (Measured at the default
  // settings: 256 iterations to the tolerance; the refinement below, from the prolonged start, 53.)
  SolveOptions from_laplacian = converge;
  from_laplacian.start = StartFrom::Laplacian;
  auto single = deform_scale_aware(cactus.mesh.V, cactus.mesh.F, cactus.setup.constrained,
                                   cactus.setup.targets, from_laplacian);
  ASSERT_TRUE(single.ok()) << single.status().to_string();
  const AngleErrors reference = errors_of(single->V);

  // The whole mesh decimated at once, and in two halves (as meshes above
  // MultiresSettings::split_above_vertices are) on two threads.
  for (const int split_above : {0, 1000}) {
    SCOPED_TRACE(split_above == 0 ? "decimated whole" : "decimated in two halves");
    MultiresDeformerSettings settings;
    settings.hierarchy.level_vertices = {500};
    settings.hierarchy.split_above_vertices = split_above;
    settings.hierarchy.threads = 2;
    std::vector<std::string> phases;
    auto deformer = MultiresDeformer::create(
        cactus.mesh.V, cactus.mesh.F, cactus.setup.constrained, settings,
        [&](std::string_view phase, double) {
          if (phases.empty() || phases.back() != phase) phases.emplace_back(phase);
        });
    ASSERT_TRUE(deformer.ok()) << deformer.status().to_string();
    EXPECT_EQ(deformer->coarse_level(), 1);
    EXPECT_EQ(deformer->build_report().coarse_vertices, 500);
    EXPECT_EQ(phases, (std::vector<std::string>{"decimate", "validate", "prolongation",
                                                "coarse_precompute"}));
    EXPECT_EQ(deformer->fine_solver(), nullptr);

    // Interactive move: the coarse solve, prolonged. Constrained vertices land exactly on the
    // coarse solution's (they are coarse vertices).
    SolveOptions coarse_options = converge;
    auto move = deformer->move(cactus.setup.targets, coarse_options);
    ASSERT_TRUE(move.ok()) << move.status().to_string();
    ASSERT_EQ(move->V.rows(), cactus.mesh.V.rows());
    const MeshLevel& level = deformer->hierarchy().level(1);
    for (Eigen::Index j = 0; j < level.constrained.size(); ++j) {
      EXPECT_EQ(move->V.row(level.to_fine(level.constrained(j))),
                move->coarse.V.row(level.constrained(j)));
    }
    EXPECT_EQ(deformer->positions(), move->V);
    const AngleErrors prolonged = errors_of(move->V);

    // Background refinement from the prolonged positions.
    auto refined = deformer->refine(cactus.setup.targets, converge);
    ASSERT_TRUE(refined.ok()) << refined.status().to_string();
    ASSERT_NE(deformer->fine_solver(), nullptr);
    EXPECT_TRUE(refined->converged);
    ASSERT_TRUE(single->converged);
    EXPECT_LT(refined->iterations, single->iterations);
    // It started where the move ended (iteration 0 is the starting iterate's energy, not the
    // Laplacian guess's): the first recorded energy is below the single-level start's.
    EXPECT_LT(refined->history.front().energy, single->history.front().energy);
    const AngleErrors multires = errors_of(refined->V);
    for (const auto& [what, got, want] :
         {std::tuple{"E_theta", multires.e_theta, reference.e_theta},
          std::tuple{"E_phi", multires.e_phi, reference.e_phi},
          std::tuple{"area", multires.area_log_rms, reference.area_log_rms}}) {
      EXPECT_NEAR(got, want, 0.02 * want) << what << " (prolonged start: E_theta "
                                          << prolonged.e_theta << ", E_phi " << prolonged.e_phi
                                          << ")";
    }
    EXPECT_EQ(deformer->positions(), refined->V);
  }
}

TEST(MultiresDeformer, RejectsALevelOutOfRangeAndWrongTargets) {
  const Edit cactus = edit_of(make_cactus(2));
  MultiresDeformerSettings settings;
  settings.hierarchy.level_vertices = {800};
  settings.level = 2;
  EXPECT_EQ(MultiresDeformer::create(cactus.mesh.V, cactus.mesh.F, cactus.setup.constrained,
                                     settings)
                .status()
                .code(),
            ErrorCode::InvalidArgument);
  settings.level = -1;
  auto deformer =
      MultiresDeformer::create(cactus.mesh.V, cactus.mesh.F, cactus.setup.constrained, settings);
  ASSERT_TRUE(deformer.ok()) << deformer.status().to_string();
  EXPECT_EQ(deformer->move(cactus.setup.targets.topRows(2)).status().code(),
            ErrorCode::InvalidArgument);
  EXPECT_EQ(deformer->positions(), cactus.mesh.V);  // unchanged by the failed move
}

}  // namespace
}  // namespace meshdeform::core

namespace meshdeform::core {
namespace {

// Issue 15: make_deformer picks the multiresolution deformer above DeformerSettings::
// multires_above; moves run on the coarse level, full_resolution solves refine the full mesh.
TEST(MultiresThroughMakeDeformer, CoarseMovesThenFullResolutionRefinement) {
  const Edit cactus = edit_of(make_cactus(2));  // 1,329 vertices
  DeformerSettings settings;
  settings.multires_above = 1000;
  settings.multires_coarse_vertices = 500;
  auto deformer = make_deformer(Method::ScaleAware, cactus.mesh.V, cactus.mesh.F,
                                cactus.setup.constrained, settings);
  ASSERT_TRUE(deformer.ok()) << deformer.status().to_string();
  EXPECT_EQ((*deformer)->method(), Method::ScaleAware);
  EXPECT_EQ((*deformer)->constrained(), cactus.setup.constrained);
  EXPECT_EQ((*deformer)->positions(), cactus.mesh.V);
  const double diagonal = bbox_diagonal(cactus.mesh);

  // The rest targets give the rest mesh (coarse rest solve, prolonged with the rest details).
  Positions rest_targets(cactus.setup.constrained.size(), 3);
  for (Eigen::Index j = 0; j < rest_targets.rows(); ++j)
    rest_targets.row(j) = cactus.mesh.V.row(cactus.setup.constrained(j));
  SolveOptions options;
  options.track_metrics = false;
  auto rest = (*deformer)->solve(rest_targets, options);
  ASSERT_TRUE(rest.ok()) << rest.status().to_string();
  EXPECT_LT((rest->V - cactus.mesh.V).cwiseAbs().maxCoeff(), 1e-9 * diagonal);

  // A rigid motion of every constrained vertex moves the whole mesh rigidly.
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 0.5).normalized()).toRotationMatrix();
  const Eigen::RowVector3d t(0.3, -0.2, 0.9);
  const Positions moved_rest = (cactus.mesh.V * R.transpose()).rowwise() + t;
  Positions rigid_targets = (rest_targets * R.transpose()).rowwise() + t;
  SolveOptions converge = options;  // the coarse solver runs until the motion is rigid
  converge.max_iterations = 500;
  converge.tolerance = 1e-14;
  auto rigid = (*deformer)->solve(rigid_targets, converge);
  ASSERT_TRUE(rigid.ok()) << rigid.status().to_string();
  EXPECT_LT((rigid->V - moved_rest).cwiseAbs().maxCoeff(), 1e-5 * diagonal);  // the solver's tail
  EXPECT_FALSE(rigid->converged) << "a coarse solve leaves the full resolution unsolved";

  // The edit: a coarse move, then full-resolution refinement to convergence, which matches the
  // single-level solve (as MultiresDeformer's own test shows for this mesh).
  options.max_iterations = 2;
  auto move = (*deformer)->solve(cactus.setup.targets, options);
  ASSERT_TRUE(move.ok()) << move.status().to_string();
  EXPECT_EQ((*deformer)->positions(), move->V);
  SolveOptions refine = options;
  refine.full_resolution = true;
  refine.max_iterations = 400;
  refine.tolerance = 1e-7;
  refine.stopping_rule = StoppingRule::Change;  // a last change of 1e-7, both runs alike
  auto refined = (*deformer)->solve(cactus.setup.targets, refine);
  ASSERT_TRUE(refined.ok()) << refined.status().to_string();
  EXPECT_TRUE(refined->converged);
  auto single = deform_scale_aware(cactus.mesh.V, cactus.mesh.F, cactus.setup.constrained,
                                   cactus.setup.targets, refine);
  ASSERT_TRUE(single.ok());
  const MeshTopology topology =
      build_topology(cactus.mesh.F, static_cast<int>(cactus.mesh.V.rows())).value();
  const Measures measures0 = compute_measures(cactus.mesh.V, cactus.mesh.F, topology);
  const AngleErrors a = angle_errors(measures0, compute_measures(refined->V, cactus.mesh.F, topology));
  const AngleErrors b = angle_errors(measures0, compute_measures(single->V, cactus.mesh.F, topology));
  EXPECT_NEAR(a.e_theta, b.e_theta, 0.02 * b.e_theta);
  EXPECT_NEAR(a.e_phi, b.e_phi, 0.02 * b.e_phi);
  EXPECT_NEAR(a.area_log_rms, b.area_log_rms, 0.02 * b.area_log_rms);

  (*deformer)->reset();
  EXPECT_EQ((*deformer)->positions(), cactus.mesh.V);
}

TEST(MultiresThroughMakeDeformer, FullResolutionSolverBuildsOnAnotherThreadWhileMovesRun) {
  const Edit cactus = edit_of(make_cactus(2));  // 1,329 vertices
  DeformerSettings settings;
  settings.multires_above = 1000;
  settings.multires_coarse_vertices = 500;
  auto make = [&] {
    return make_deformer(Method::ScaleAware, cactus.mesh.V, cactus.mesh.F,
                         cactus.setup.constrained, settings);
  };
  auto deformer = make();
  auto in_place = make();  // builds its full-resolution solver inside the first refinement
  ASSERT_TRUE(deformer.ok() && in_place.ok());
  ASSERT_TRUE((*deformer)->needs_background_build());
  Deformer::BackgroundBuild build = (*deformer)->background_build(SolveOptions{});
  ASSERT_TRUE(build);

  // The build runs on its own thread while this one keeps moving on the coarse level.
  SolveOptions options;
  options.track_metrics = false;
  options.max_iterations = 2;
  Result<Deformer::Installer> installer = Error(ErrorCode::Internal, "not run");
  std::thread builder([&] { installer = build({}); });
  Result<SolveReport> moves[3] = {Error(ErrorCode::Internal, ""), Error(ErrorCode::Internal, ""),
                                  Error(ErrorCode::Internal, "")};
  for (auto& move : moves) move = (*deformer)->solve(cactus.setup.targets, options);
  builder.join();
  for (const auto& move : moves) ASSERT_TRUE(move.ok()) << move.status().to_string();
  ASSERT_TRUE(installer.ok()) << installer.status().to_string();
  EXPECT_TRUE((*deformer)->needs_background_build()) << "nothing is installed behind its back";

  // The installer refuses any other deformer, then installs into its own.
  (*installer)(**in_place);
  EXPECT_TRUE((*in_place)->needs_background_build());
  (*installer)(**deformer);
  EXPECT_FALSE((*deformer)->needs_background_build());
  EXPECT_FALSE((*deformer)->background_build(SolveOptions{}));

  // Refinement with the installed solver is the refinement with one built in place.
  for (int k = 0; k < 3; ++k) ASSERT_TRUE((*in_place)->solve(cactus.setup.targets, options).ok());
  SolveOptions refine = options;
  refine.full_resolution = true;
  refine.max_iterations = 5;
  auto installed = (*deformer)->solve(cactus.setup.targets, refine);
  auto built_here = (*in_place)->solve(cactus.setup.targets, refine);
  ASSERT_TRUE(installed.ok() && built_here.ok());
  EXPECT_EQ(installed->V, built_here->V);
  EXPECT_FALSE((*in_place)->needs_background_build());
}

TEST(MultiresThroughMakeDeformer, SmallMeshesAndOtherMethodsStaySingleLevel) {
  const Edit cactus = edit_of(make_cactus(2));
  DeformerSettings settings;
  settings.multires_above = 1000;
  settings.multires_coarse_vertices = 1000;  // twice that is more than the mesh: single level
  auto deformer = make_deformer(Method::ScaleAware, cactus.mesh.V, cactus.mesh.F,
                                cactus.setup.constrained, settings);
  ASSERT_TRUE(deformer.ok());
  SolveOptions options;
  options.max_iterations = 200;
  options.tolerance = 1e-6;
  options.track_metrics = false;
  auto solved = (*deformer)->solve(cactus.setup.targets, options);
  ASSERT_TRUE(solved.ok());
  EXPECT_TRUE(solved->converged) << "a single-level solve converges on its own";
  settings.multires_coarse_vertices = 500;
  auto arap = make_deformer(Method::Arap, cactus.mesh.V, cactus.mesh.F, cactus.setup.constrained,
                            settings);
  ASSERT_TRUE(arap.ok());
  EXPECT_EQ((*arap)->method(), Method::Arap);
}

// Issue 41: above multilevel_above, the first full-resolution solve after coarse moves is the
// multilevel cascade toward the targets (a drag's prolonged result differs from the
// full-resolution fixed point at low frequency, which warm iterations remove slowly); later
// ones continue it warm, and ORA moves, the paper mode and multilevel = false keep starting
// from the prolonged move.
TEST(MultiresThroughMakeDeformer, RefinementAfterADragRunsTheCascadeAndThenContinuesIt) {
  const Edit cactus = edit_of(make_cactus(2));  // 1,329 vertices
  DeformerSettings settings;
  settings.multires_above = 1000;
  settings.multires_coarse_vertices = 500;
  settings.multilevel_above = 1000;
  settings.multilevel_coarsest_vertices = 300;  // one cascade level of ~332 vertices
  auto make = [&](const DeformerSettings& s) {
    auto made = make_deformer(Method::ScaleAware, cactus.mesh.V, cactus.mesh.F,
                              cactus.setup.constrained, s);
    EXPECT_TRUE(made.ok()) << made.status().to_string();
    return std::move(made).value();
  };
  SolveOptions move;
  move.track_metrics = false;
  move.max_iterations = 1;
  SolveOptions refine = move;
  refine.full_resolution = true;
  refine.max_iterations = 2;  // the server's slices
  const auto drag = [&](Deformer& d) {
    for (const double s : {0.3, 0.6, 1.0}) {
      const Positions rest_targets = cactus.mesh.V(cactus.setup.constrained, Eigen::all);
      ASSERT_TRUE(d.solve(rest_targets + s * (cactus.setup.targets - rest_targets), move).ok());
    }
  };

  std::unique_ptr<Deformer> deformer = make(settings);
  drag(*deformer);
  auto first = deformer->solve(cactus.setup.targets, refine);
  ASSERT_TRUE(first.ok()) << first.status().to_string();
  ASSERT_EQ(first->levels.size(), 2u) << "the cascade ran (its two levels reported)";
  EXPECT_GT(first->phases.start, 0.0);
  EXPECT_EQ(first->iterations, 2);
  EXPECT_EQ(deformer->positions(), first->V);

  // It is the cold multilevel solve of the same mesh and targets, bit for bit: the drag left
  // nothing in it.
  DeformerSettings plain = settings;
  plain.multires_above = 0;
  std::unique_ptr<Deformer> cold = make(plain);
  auto reference = cold->solve(cactus.setup.targets, refine);
  ASSERT_TRUE(reference.ok()) << reference.status().to_string();
  ASSERT_EQ(reference->levels.size(), 2u);
  EXPECT_EQ(first->V, reference->V);

  // The next slice continues the cascade's result at full resolution, as the cold solver's
  // next (warm) solve does.
  auto second = deformer->solve(cactus.setup.targets, refine);
  auto reference_second = cold->solve(cactus.setup.targets, refine);
  ASSERT_TRUE(second.ok() && reference_second.ok());
  EXPECT_TRUE(second->levels.empty()) << "warm: no second cascade";
  EXPECT_EQ(second->V, reference_second->V);

  // A new move prolongs the coarse level again; the refinement after it is a cascade again.
  ASSERT_TRUE(deformer->solve(cactus.setup.targets, move).ok());
  auto again = deformer->solve(cactus.setup.targets, refine);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(again->levels.size(), 2u);

  // Starting from the prolonged move instead: an ORA move, the paper mode (rigidity 0),
  // multilevel = false, and a deformer below multilevel_above.
  const auto warm_after_drag = [&](const DeformerSettings& s, SolveOptions options,
                                   const char* what) {
    SCOPED_TRACE(what);
    std::unique_ptr<Deformer> d = make(s);
    drag(*d);
    auto solved = d->solve(cactus.setup.targets, options);
    ASSERT_TRUE(solved.ok()) << solved.status().to_string();
    EXPECT_TRUE(solved->levels.empty());
    EXPECT_EQ(solved->start, StartFrom::Previous) << "from the prolonged move, not a cold start";
  };
  SolveOptions ora_move = move;
  ora_move.ora = true;
  warm_after_drag(settings, ora_move, "an ORA move");
  SolveOptions paper = refine;
  paper.rigidity = 0;
  warm_after_drag(settings, paper, "rigidity 0");
  SolveOptions off = refine;
  off.multilevel = false;
  warm_after_drag(settings, off, "multilevel = false");
  DeformerSettings below = settings;
  below.multilevel_above = 0;
  warm_after_drag(below, refine, "multilevel_above 0");
}

// A rigid motion of the handles after a drag: the cascade's refinement returns the rigidly
// moved mesh (exact through every level of the cascade, as a cold multilevel solve is: to the
// rigid start's tolerance), whatever the drag before it left.
TEST(MultiresThroughMakeDeformer, RefinementCascadeKeepsARigidMotionExact) {
  const Edit cactus = edit_of(make_cactus(2));
  DeformerSettings settings;
  settings.multires_above = 1000;
  settings.multires_coarse_vertices = 500;
  settings.multilevel_above = 1000;
  settings.multilevel_coarsest_vertices = 300;
  auto deformer = make_deformer(Method::ScaleAware, cactus.mesh.V, cactus.mesh.F,
                                cactus.setup.constrained, settings);
  ASSERT_TRUE(deformer.ok()) << deformer.status().to_string();
  SolveOptions options;
  options.track_metrics = false;
  options.max_iterations = 1;
  ASSERT_TRUE((*deformer)->solve(cactus.setup.targets, options).ok());  // a drag elsewhere first
  const Eigen::Matrix3d R =
      Eigen::AngleAxisd(0.9, Eigen::Vector3d(0.2, 1, 0.4).normalized()).toRotationMatrix();
  const Eigen::RowVector3d t(-0.4, 0.25, 0.6);
  const Positions rest_targets = cactus.mesh.V(cactus.setup.constrained, Eigen::all);
  SolveOptions refine = options;
  refine.full_resolution = true;
  refine.max_iterations = 30;
  auto refined =
      (*deformer)->solve((rest_targets * R.transpose()).rowwise() + t, refine);
  ASSERT_TRUE(refined.ok()) << refined.status().to_string();
  ASSERT_FALSE(refined->levels.empty());
  const Positions moved = (cactus.mesh.V * R.transpose()).rowwise() + t;
  EXPECT_LT((refined->V - moved).cwiseAbs().maxCoeff(),
            test::kConvergedTol * bbox_diagonal(cactus.mesh));
  EXPECT_TRUE(refined->converged);
  EXPECT_EQ(refined->iterations, 1) << "exact at the cascade's start: the rule holds at once";
}

}  // namespace
}  // namespace meshdeform::core
