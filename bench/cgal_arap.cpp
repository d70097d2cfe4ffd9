#include "bench/cgal_arap.h"

#include <chrono>
#include <cstdint>
#include <string>
#include <vector>

#include <CGAL/Deformation_Eigen_polar_closest_rotation_traits_3.h>
#include <CGAL/Simple_cartesian.h>
#include <CGAL/Surface_mesh.h>
#include <CGAL/Surface_mesh_deformation.h>

namespace meshdeform::bench {
namespace {

// Simple_cartesian<double>: ARAP needs no exact predicates, and a plain double kernel is what a
// speed-minded CGAL user would pick.
using Kernel = CGAL::Simple_cartesian<double>;
using Point = Kernel::Point_3;
using Mesh = CGAL::Surface_mesh<Point>;
using VertexIndex = Mesh::Vertex_index;

// CGAL's deform(iterations, tolerance) does not say how many iterations it ran and its energy() is
// private. Every iteration computes one closest rotation per region-of-solution vertex through
// these traits, so counting those calls counts iterations without touching the algorithm.
struct CountingRotationTraits : CGAL::Deformation_Eigen_polar_closest_rotation_traits_3 {
  using Base = CGAL::Deformation_Eigen_polar_closest_rotation_traits_3;
  static inline std::int64_t calls = 0;
  void compute_close_rotation(const Matrix& m, Matrix& R) {
    ++calls;
    Base::compute_close_rotation(m, R);
  }
};

double seconds_since(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

Positions read_positions(const Mesh& mesh, int vertex_count) {
  Positions V(vertex_count, 3);
  for (int i = 0; i < vertex_count; ++i) {
    const Point& p = mesh.point(VertexIndex(static_cast<Mesh::size_type>(i)));
    V.row(i) << p.x(), p.y(), p.z();
  }
  return V;
}

template <typename Deformation>
void set_targets(Deformation& deformation, const Eigen::VectorXi& constrained,
                 const Positions& targets) {
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    deformation.set_target_position(VertexIndex(static_cast<Mesh::size_type>(constrained(j))),
                                    Point(targets(j, 0), targets(j, 1), targets(j, 2)));
  }
}

template <CGAL::Deformation_algorithm_tag kTag>
Result<CgalArapResult> run_variant(Mesh& mesh, int vertex_count, const Eigen::VectorXi& constrained,
                                   const Positions& targets, const Positions& move_targets,
                                   const CgalArapOptions& options, CgalArapResult result) {
  using Deformation = CGAL::Surface_mesh_deformation<Mesh, CGAL::Default, CGAL::Default, kTag,
                                                     CGAL::Default, CGAL::Default,
                                                     CountingRotationTraits>;
  auto start = std::chrono::steady_clock::now();
  Deformation deformation(mesh);
  deformation.insert_roi_vertices(mesh.vertices().begin(), mesh.vertices().end());
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    deformation.insert_control_vertex(VertexIndex(static_cast<Mesh::size_type>(constrained(j))));
  }
  if (!deformation.preprocess()) {
    return Error(ErrorCode::NumericalFailure,
                 "CGAL Surface_mesh_deformation::preprocess() failed (" +
                     std::to_string(vertex_count) + " vertices, " +
                     std::to_string(constrained.size()) + " control vertices)");
  }
  result.preprocess_seconds = seconds_since(start);

  // The timed run: a fixed iteration count with tolerance 0, so CGAL computes no energy and the
  // time is iterations only. set_target_position is part of every edit and is timed with it.
  const auto fixed_iterations = static_cast<unsigned int>(options.fixed_iterations);
  CountingRotationTraits::calls = 0;
  start = std::chrono::steady_clock::now();
  set_targets(deformation, constrained, targets);
  deformation.deform(fixed_iterations, 0.0);
  result.fixed_seconds = seconds_since(start);
  result.fixed_iterations = options.fixed_iterations;
  const std::int64_t calls_per_iteration =
      options.fixed_iterations > 0 ? CountingRotationTraits::calls / options.fixed_iterations : 0;
  result.V_fixed = read_positions(mesh, vertex_count);

  // The interactive figure: move the handles a little further and run a small budget, warm from
  // the fixed run's positions and rotations (CGAL keeps both between deform() calls).
  if (move_targets.rows() > 0) {
    start = std::chrono::steady_clock::now();
    set_targets(deformation, constrained, move_targets);
    deformation.deform(static_cast<unsigned int>(options.move_iterations), 0.0);
    result.move_seconds = seconds_since(start);
    result.V_move = read_positions(mesh, vertex_count);
  }

  // To convergence from the rest pose with CGAL's own energy-change test (energy computed every
  // iteration, as a user calling deform(n, tolerance) pays).
  if (options.run_convergence && calls_per_iteration > 0) {
    deformation.reset();  // rest positions and identity rotations, targets included
    CountingRotationTraits::calls = 0;
    start = std::chrono::steady_clock::now();
    set_targets(deformation, constrained, targets);
    deformation.deform(static_cast<unsigned int>(options.max_converge_iterations),
                       options.converge_tolerance);
    result.converge_seconds = seconds_since(start);
    result.converge_iterations = static_cast<int>(CountingRotationTraits::calls / calls_per_iteration);
    result.V_converged = read_positions(mesh, vertex_count);
  }
  return result;
}

}  // namespace

const char* cgal_arap_variant_name(CgalArapVariant variant) {
  switch (variant) {
    case CgalArapVariant::SpokesAndRims:
      return "spokes_and_rims";
    case CgalArapVariant::Original:
      return "original";
    case CgalArapVariant::Sre:
      return "sre";
  }
  return "unknown";
}

Result<CgalArapVariant> parse_cgal_arap_variant(const std::string& name) {
  if (name == "spokes_and_rims" || name == "spokes") return CgalArapVariant::SpokesAndRims;
  if (name == "original") return CgalArapVariant::Original;
  if (name == "sre" || name == "sre_arap") return CgalArapVariant::Sre;
  return Error(ErrorCode::InvalidArgument,
               "unknown CGAL ARAP variant '" + name + "' (spokes_and_rims, original, sre)");
}

Result<CgalArapResult> run_cgal_arap(const Positions& V, const Triangles& F,
                                     const Eigen::VectorXi& constrained, const Positions& targets,
                                     const Positions& move_targets,
                                     const CgalArapOptions& options) {
  const auto vertex_count = static_cast<int>(V.rows());
  if (targets.rows() != constrained.size()) {
    return Error(ErrorCode::InvalidArgument,
                 "targets has " + std::to_string(targets.rows()) + " rows for " +
                     std::to_string(constrained.size()) + " constrained vertices");
  }
  if (move_targets.rows() != 0 && move_targets.rows() != constrained.size()) {
    return Error(ErrorCode::InvalidArgument,
                 "move_targets has " + std::to_string(move_targets.rows()) + " rows for " +
                     std::to_string(constrained.size()) + " constrained vertices");
  }
  for (Eigen::Index j = 0; j < constrained.size(); ++j) {
    if (constrained(j) < 0 || constrained(j) >= vertex_count) {
      return Error(ErrorCode::InvalidArgument,
                   "constrained vertex " + std::to_string(constrained(j)) + " out of range (#V=" +
                       std::to_string(vertex_count) + ")");
    }
  }

  CgalArapResult result;
  auto start = std::chrono::steady_clock::now();
  Mesh mesh;
  mesh.reserve(static_cast<Mesh::size_type>(vertex_count),
               static_cast<Mesh::size_type>(3 * F.rows() / 2 + vertex_count),
               static_cast<Mesh::size_type>(F.rows()));
  for (int i = 0; i < vertex_count; ++i) mesh.add_vertex(Point(V(i, 0), V(i, 1), V(i, 2)));
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    for (int k = 0; k < 3; ++k) {
      if (F(f, k) < 0 || F(f, k) >= vertex_count) {
        return Error(ErrorCode::InvalidArgument,
                     "face " + std::to_string(f) + " references vertex " + std::to_string(F(f, k)) +
                         " (#V=" + std::to_string(vertex_count) + ")");
      }
    }
    const Mesh::Face_index face = mesh.add_face(VertexIndex(F(f, 0)), VertexIndex(F(f, 1)),
                                                VertexIndex(F(f, 2)));
    if (face == Mesh::null_face()) {
      return Error(ErrorCode::InvalidArgument,
                   "CGAL Surface_mesh rejected face " + std::to_string(f) +
                       " (non-manifold or inconsistently oriented)");
    }
  }
  result.build_seconds = seconds_since(start);

  switch (options.variant) {
    case CgalArapVariant::SpokesAndRims:
      return run_variant<CGAL::SPOKES_AND_RIMS>(mesh, vertex_count, constrained, targets,
                                                move_targets, options, std::move(result));
    case CgalArapVariant::Original:
      return run_variant<CGAL::ORIGINAL_ARAP>(mesh, vertex_count, constrained, targets,
                                              move_targets, options, std::move(result));
    case CgalArapVariant::Sre:
      return run_variant<CGAL::SRE_ARAP>(mesh, vertex_count, constrained, targets, move_targets,
                                         options, std::move(result));
  }
  return Error(ErrorCode::Internal, "unhandled CGAL ARAP variant");
}

}  // namespace meshdeform::bench
