#include "core/mesh/validate.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <map>
#include <numeric>
#include <sstream>
#include <string>
#include <vector>

#include "core/mesh/edge_table.h"

namespace meshdeform::core {
namespace {

Status invalid(const std::string& message) { return Error(ErrorCode::InvalidArgument, message); }

std::string face_text(const Triangles& F, Eigen::Index f) {
  return "face " + std::to_string(f) + " (" + std::to_string(F(f, 0)) + ", " +
         std::to_string(F(f, 1)) + ", " + std::to_string(F(f, 2)) + ")";
}

std::string format_double(double value) {
  std::ostringstream out;
  out.precision(6);
  out << value;
  return out.str();
}

// Union-find over face corners (3 * f + k), used to count the fans around each vertex.
class CornerSets {
 public:
  explicit CornerSets(Eigen::Index n) : parent_(static_cast<std::size_t>(n)) {
    std::iota(parent_.begin(), parent_.end(), 0);
  }
  int find(int x) {
    while (parent_[static_cast<std::size_t>(x)] != x) {
      auto& p = parent_[static_cast<std::size_t>(x)];
      p = parent_[static_cast<std::size_t>(p)];
      x = p;
    }
    return x;
  }
  void unite(int a, int b) {
    a = find(a);
    b = find(b);
    if (a != b) parent_[static_cast<std::size_t>(a < b ? b : a)] = a < b ? a : b;
  }

 private:
  std::vector<int> parent_;
};

int corner_of(const Triangles& F, int f, int v) {
  for (int k = 0; k < 3; ++k) {
    if (F(f, k) == v) return 3 * f + k;
  }
  return -1;  // unreachable for a face incident to v
}

// Finite coordinates and indices in range: the preconditions of every other check.
Status check_basic(const Positions& V, const Triangles& F) {
  if (V.rows() == 0) return invalid("mesh has no vertices");
  if (F.rows() == 0) return invalid("mesh has no faces (#V=" + std::to_string(V.rows()) + ")");
  static constexpr std::array<char, 3> kAxis = {'x', 'y', 'z'};
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    for (int c = 0; c < 3; ++c) {
      if (!std::isfinite(V(i, c))) {
        return invalid("vertex " + std::to_string(i) + " has a non-finite " + kAxis[c] +
                       " coordinate (" + format_double(V(i, c)) + ")");
      }
    }
  }
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      const int v = F(f, k);
      if (v < 0 || v >= V.rows()) {
        return invalid("face " + std::to_string(f) + " references vertex " + std::to_string(v) +
                       " (#V=" + std::to_string(V.rows()) + ")");
      }
    }
  }
  return Status::success();
}

}  // namespace

Status validate_triangle_mesh(const Positions& V, const Triangles& F) {
  MD_RETURN_IF_ERROR(check_basic(V, F));
  const Eigen::Index nv = V.rows();
  const Eigen::Index nf = F.rows();

  // Degenerate faces. The area threshold is relative to the squared bounding-box diagonal so that
  // the test is invariant to the model's unit; 1e-14 is far below any meaningful triangle but well
  // above the round-off of a cross product of exactly collinear points.
  const double diag2 = (V.colwise().maxCoeff() - V.colwise().minCoeff()).squaredNorm();
  constexpr double kRelativeAreaTol = 1e-14;
  for (Eigen::Index f = 0; f < nf; ++f) {
    const int a = F(f, 0);
    const int b = F(f, 1);
    const int c = F(f, 2);
    if (a == b || b == c || a == c) {
      const int repeated = (a == b || a == c) ? a : b;
      return invalid(face_text(F, f) + " repeats vertex " + std::to_string(repeated));
    }
    for (int k = 0; k < 3; ++k) {
      const int p = F(f, k);
      const int q = F(f, (k + 1) % 3);
      if (V.row(p) == V.row(q)) {
        return invalid(face_text(F, f) + " has a zero-length edge: vertices " + std::to_string(p) +
                       " and " + std::to_string(q) + " coincide");
      }
    }
    const Eigen::RowVector3d e1 = V.row(b) - V.row(a);
    const Eigen::RowVector3d e2 = V.row(c) - V.row(a);
    const double area = 0.5 * e1.cross(e2).norm();
    if (!(area >= kRelativeAreaTol * diag2)) {
      return invalid(face_text(F, f) + " has (near) zero area " + format_double(area) +
                     " (bounding-box diagonal " + format_double(std::sqrt(diag2)) + ")");
    }
  }

  // Duplicate faces: same vertex set in any order or orientation. Sorted (set, face) rows: the
  // first face (in face order) whose set an earlier face has, reported with the earliest one.
  {
    std::vector<std::array<int, 4>> sets(static_cast<std::size_t>(nf));
    for (Eigen::Index f = 0; f < nf; ++f) {
      std::array<int, 4>& row = sets[static_cast<std::size_t>(f)];
      row = {F(f, 0), F(f, 1), F(f, 2), static_cast<int>(f)};
      std::sort(row.begin(), row.begin() + 3);
    }
    std::sort(sets.begin(), sets.end());
    Eigen::Index duplicate = -1, original = -1;
    for (std::size_t r = 1; r < sets.size(); ++r) {
      const bool same = std::equal(sets[r].begin(), sets[r].begin() + 3, sets[r - 1].begin());
      // The second row of a run is its earliest duplicate; the run's first row its original.
      if (same && (r < 2 || !std::equal(sets[r - 1].begin(), sets[r - 1].begin() + 3,
                                         sets[r - 2].begin()))) {
        if (duplicate < 0 || sets[r][3] < duplicate) {
          duplicate = sets[r][3];
          original = sets[r - 1][3];
        }
      }
    }
    if (duplicate >= 0) {
      return invalid(face_text(F, duplicate) + " duplicates face " + std::to_string(original));
    }
  }

  // Edge table: the half-edges (corners 3 f + k, from F(f, k) to F(f, k + 1)) of every
  // undirected edge, in corner order.
  const EdgeTable edges = build_edge_table(F, static_cast<int>(nv));
  auto face_of = [&edges](int e, int i) {
    return edges.corners[static_cast<std::size_t>(edges.offsets[e] + i)] / 3;
  };
  auto forward = [&edges, &F](int e, int i) {
    const int c = edges.corners[static_cast<std::size_t>(edges.offsets[e] + i)];
    return F(c / 3, c % 3) < F(c / 3, (c % 3 + 1) % 3);
  };
  // Report in face order so that the first offending element is deterministic.
  for (Eigen::Index f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k) {
      const int p = F(f, k);
      const int q = F(f, (k + 1) % 3);
      const int e = edges.edge_of[static_cast<std::size_t>(3 * f + k)];
      const int count = edges.half_edge_count(e);
      if (count > 2) {
        return invalid("non-manifold edge (" + std::to_string(std::min(p, q)) + ", " +
                       std::to_string(std::max(p, q)) + ") is shared by " +
                       std::to_string(count) + " faces (" + std::to_string(face_of(e, 0)) + ", " +
                       std::to_string(face_of(e, 1)) + ", " + std::to_string(face_of(e, 2)) +
                       (count > 3 ? ", ..." : "") + ")");
      }
    }
  }
  for (Eigen::Index f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k) {
      const int e = edges.edge_of[static_cast<std::size_t>(3 * f + k)];
      if (edges.half_edge_count(e) == 2 && forward(e, 0) == forward(e, 1)) {
        return invalid("edge (" + std::to_string(F(f, k)) + ", " +
                       std::to_string(F(f, (k + 1) % 3)) +
                       ") is traversed in the same direction by faces " +
                       std::to_string(face_of(e, 0)) + " and " + std::to_string(face_of(e, 1)) +
                       " (inconsistent orientation)");
      }
    }
  }

  // Non-manifold vertices: corners around a vertex are joined across each interior edge; a
  // vertex whose corners fall into more than one set has more than one fan (e.g. two cones
  // touching at their apex).
  CornerSets corners(3 * nf);
  for (int e = 0; e < edges.edge_count(); ++e) {
    if (edges.half_edge_count(e) != 2) continue;
    const int p = edges.lo[static_cast<std::size_t>(e)];
    const int q = edges.hi[static_cast<std::size_t>(e)];
    corners.unite(corner_of(F, face_of(e, 0), p), corner_of(F, face_of(e, 1), p));
    corners.unite(corner_of(F, face_of(e, 0), q), corner_of(F, face_of(e, 1), q));
  }
  std::vector<int> fan_root(static_cast<std::size_t>(nv), -1);
  std::vector<int> fan_count(static_cast<std::size_t>(nv), 0);
  for (Eigen::Index f = 0; f < nf; ++f) {
    for (int k = 0; k < 3; ++k) {
      const auto v = static_cast<std::size_t>(F(f, k));
      const int root = corners.find(static_cast<int>(3 * f + k));
      if (fan_root[v] == -1) {
        fan_root[v] = root;
        fan_count[v] = 1;
      } else if (fan_root[v] != root) {
        // All unions are done, so roots are final: a second root means a second fan.
        fan_count[v] = 2;
      }
    }
  }
  for (Eigen::Index v = 0; v < nv; ++v) {
    if (fan_count[static_cast<std::size_t>(v)] > 1) {
      return invalid("vertex " + std::to_string(v) +
                     " is non-manifold: its incident faces form more than one fan");
    }
  }

  for (Eigen::Index v = 0; v < nv; ++v) {
    if (fan_count[static_cast<std::size_t>(v)] == 0) {
      return invalid("vertex " + std::to_string(v) +
                     " is not referenced by any face (#F=" + std::to_string(nf) + ")");
    }
  }
  return Status::success();
}

Result<CleanReport> clean_mesh(MeshData& mesh, bool weld, std::stop_token stop) {
  const auto cancelled = [] {
    return Error(ErrorCode::Cancelled, "cleaning the mesh was cancelled (deadline or client)");
  };
  // Remapping needs indices in range; report those on the input numbering.
  if (mesh.V.rows() == 0 || mesh.F.rows() == 0) return check_basic(mesh.V, mesh.F);
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      if (mesh.F(f, k) < 0 || mesh.F(f, k) >= mesh.V.rows()) return check_basic(mesh.V, mesh.F);
    }
  }
  const Eigen::Index nv = mesh.V.rows();

  // representative[i]: the first vertex at exactly the same position (itself if none).
  std::vector<int> representative(static_cast<std::size_t>(nv));
  std::iota(representative.begin(), representative.end(), 0);
  CleanReport report;
  if (weld) {
    std::map<std::array<double, 3>, int> first_at;
    for (Eigen::Index i = 0; i < nv; ++i) {
      if ((i & 4095) == 0 && stop.stop_requested()) return cancelled();
      // Non-finite positions are never welded (NaN != NaN); validation reports them below.
      if (!mesh.V.row(i).allFinite()) continue;
      // + 0.0 maps -0.0 to +0.0, which compare equal as doubles.
      const std::array<double, 3> key = {mesh.V(i, 0) + 0.0, mesh.V(i, 1) + 0.0,
                                         mesh.V(i, 2) + 0.0};
      const auto [it, inserted] = first_at.emplace(key, static_cast<int>(i));
      if (!inserted) {
        representative[static_cast<std::size_t>(i)] = it->second;
        ++report.welded_vertices;
      }
    }
  }

  std::vector<char> referenced(static_cast<std::size_t>(nv), 0);
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      referenced[static_cast<std::size_t>(representative[static_cast<std::size_t>(mesh.F(f, k))])] =
          1;
    }
  }
  std::vector<int> new_index(static_cast<std::size_t>(nv), -1);
  int kept = 0;
  for (Eigen::Index i = 0; i < nv; ++i) {
    const auto si = static_cast<std::size_t>(i);
    if (representative[si] != i) continue;
    if (referenced[si]) {
      new_index[si] = kept++;
    } else {
      ++report.dropped_unreferenced;
    }
  }

  MeshData cleaned;
  cleaned.V.resize(kept, 3);
  report.old_to_new.resize(nv);
  for (Eigen::Index i = 0; i < nv; ++i) {
    const int target =
        new_index[static_cast<std::size_t>(representative[static_cast<std::size_t>(i)])];
    report.old_to_new(i) = target;
    if (target >= 0 && representative[static_cast<std::size_t>(i)] == i) {
      cleaned.V.row(target) = mesh.V.row(i);
    }
  }
  cleaned.F.resize(mesh.F.rows(), 3);
  for (Eigen::Index f = 0; f < mesh.F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) cleaned.F(f, k) = report.old_to_new(mesh.F(f, k));
  }

  if (stop.stop_requested()) return cancelled();
  const Status status = validate_triangle_mesh(cleaned.V, cleaned.F);
  if (!status.ok()) {
    if (report.welded_vertices == 0 && report.dropped_unreferenced == 0) return status;
    return Error(status.code(),
                 "after cleaning (" + std::to_string(report.welded_vertices) + " welded, " +
                     std::to_string(report.dropped_unreferenced) +
                     " unreferenced dropped; indices renumbered): " + status.message());
  }
  mesh = std::move(cleaned);
  return report;
}

}  // namespace meshdeform::core
