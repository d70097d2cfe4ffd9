#include "core/multires/multires.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <exception>
#include <future>
#include <limits>
#include <numbers>
#include <optional>
#include <random>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include <Eigen/Geometry>
#include <OpenMesh/Tools/Decimater/BaseDecimaterT.hh>
#include <OpenMesh/Tools/Decimater/ModBaseT.hh>
#include <OpenMesh/Tools/Decimater/ModQuadricT.hh>  // QuadricT, with the traits it needs first
#include <OpenMesh/Tools/Decimater/Observer.hh>

#include "core/methods/constraints.h"
#include "core/methods/laplacian.h"
#include "core/mesh/median_split.h"
#include "core/mesh/openmesh_adapter.h"
#include "core/linalg/sparse_cholesky.h"
#include "core/linalg/split_cholesky.h"
#include "core/mesh/topology.h"
#include "core/mesh/validate.h"

namespace meshdeform::core {

namespace {

using detail::OmMesh;
using Clock = std::chrono::steady_clock;

double seconds_since(Clock::time_point start) {
  return std::chrono::duration<double>(Clock::now() - start).count();
}

Status cancelled(const char* what) {
  return Error(ErrorCode::Cancelled, std::string(what) + " cancelled (deadline or client)");
}

// ---- decimation ---------------------------------------------------------------------------------

/// The priority module: Garland-Heckbert quadrics (area-weighted face planes), plus for every
/// boundary edge the plane through it perpendicular to its face, weighted by `boundary_weight`
/// times the squared edge length, so that collapses along an open border are charged for moving
/// it. (OpenMesh's ModQuadricT has no boundary term: a flat border would erode at no cost.)
template <class MeshT>
class ModBoundaryQuadricT : public OpenMesh::Decimater::ModBaseT<MeshT> {
 public:
  DECIMATING_MODULE(ModBoundaryQuadricT, MeshT, BoundaryQuadric);

  explicit ModBoundaryQuadricT(MeshT& mesh) : Base(mesh, false) {
    Base::mesh().add_property(quadrics_);
  }
  ~ModBoundaryQuadricT() override { Base::mesh().remove_property(quadrics_); }

  void set_boundary_weight(double weight) { boundary_weight_ = weight; }

  void initialize() override {
    using Quadric = OpenMesh::Geometry::Quadricd;
    MeshT& mesh = Base::mesh();
    for (const auto v : mesh.vertices()) mesh.property(quadrics_, v).clear();
    for (const auto f : mesh.faces()) {
      auto fv = mesh.cfv_iter(f);
      const auto v0 = *fv, v1 = *(++fv), v2 = *(++fv);
      const OpenMesh::Vec3d p0 = mesh.point(v0);
      OpenMesh::Vec3d n = (mesh.point(v1) - p0) % (mesh.point(v2) - p0);
      const double twice_area = n.norm();
      if (!(twice_area > 0)) continue;
      n /= twice_area;
      Quadric q(n[0], n[1], n[2], -(p0 | n));
      q *= 0.5 * twice_area;
      mesh.property(quadrics_, v0) += q;
      mesh.property(quadrics_, v1) += q;
      mesh.property(quadrics_, v2) += q;
    }
    if (!(boundary_weight_ > 0)) return;
    for (const auto h : mesh.halfedges()) {
      if (!mesh.is_boundary(h)) continue;
      const auto inner = mesh.opposite_halfedge_handle(h);
      const auto f = mesh.face_handle(inner);
      const auto a = mesh.from_vertex_handle(h), b = mesh.to_vertex_handle(h);
      const OpenMesh::Vec3d e = mesh.point(b) - mesh.point(a);
      const OpenMesh::Vec3d n = mesh.calc_face_normal(f);
      OpenMesh::Vec3d m = e % n;
      const double length = m.norm();
      if (!(length > 0)) continue;
      m /= length;
      Quadric q(m[0], m[1], m[2], -(mesh.point(a) | m));
      q *= boundary_weight_ * e.sqrnorm();
      mesh.property(quadrics_, a) += q;
      mesh.property(quadrics_, b) += q;
    }
  }

  float collapse_priority(const CollapseInfo& ci) override {
    OpenMesh::Geometry::Quadricd q = Base::mesh().property(quadrics_, ci.v0);
    q += Base::mesh().property(quadrics_, ci.v1);
    // Round-off can make an exact fit slightly negative, which the decimater reads as illegal.
    return static_cast<float>(std::max(q(ci.p1), 0.0));
  }

  void postprocess_collapse(const CollapseInfo& ci) override {
    Base::mesh().property(quadrics_, ci.v1) += Base::mesh().property(quadrics_, ci.v0);
  }

  /// The accumulated quadric of a vertex (its fine faces' and those it absorbed).
  const OpenMesh::Geometry::Quadricd& quadric(typename MeshT::VertexHandle v) {
    return Base::mesh().property(quadrics_, v);
  }
  void set_quadric(typename MeshT::VertexHandle v, const OpenMesh::Geometry::Quadricd& q) {
    Base::mesh().property(quadrics_, v) = q;
  }

 private:
  double boundary_weight_ = 0;
  OpenMesh::VPropHandleT<OpenMesh::Geometry::Quadricd> quadrics_;
};

/// The one-ring rules of a collapse, in one pass over the faces around the removed vertex:
///  - no face normal may turn by more than the maximum deviation (OpenMesh's ModNormalFlippingT);
///  - no face may be left with an aspect ratio (longest edge over its height) above the limit,
///    unless the collapse improves the worst face of the one-ring (OpenMesh's ModAspectRatioT in
///    binary mode).
/// Both compare against the current one-ring, computed here: OpenMesh's modules read face
/// normals and ratios stored per face, which the decimater has to refresh after every collapse
/// (the normals of about six faces), and ModNormalFlippingT moves the vertex in the mesh to
/// price the collapse. This module keeps no state and writes nothing, so two decimaters over
/// disjoint parts of one mesh share nothing through it.
template <class MeshT>
class ModOneRingT : public OpenMesh::Decimater::ModBaseT<MeshT> {
 public:
  DECIMATING_MODULE(ModOneRingT, MeshT, OneRing);

  explicit ModOneRingT(MeshT& mesh) : Base(mesh, true) {}

  /// The largest rotation of a face normal, in degrees (0, 180].
  void set_max_normal_deviation(double degrees) {
    min_cos_ = std::cos(degrees * std::numbers::pi / 180.0);
  }
  /// The largest aspect ratio a collapse may create; >= 1.
  void set_max_aspect_ratio(double ratio) { min_inverse_aspect_ = 1.0 / ratio; }

  float collapse_priority(const CollapseInfo& ci) override {
    const MeshT& mesh = Base::mesh();
    double before = 1.0, after = 1.0;  // smallest inverse aspect ratio of the one-ring
    for (const auto f : mesh.vf_range(ci.v0)) {
      auto fv = mesh.cfv_iter(f);
      const auto a = *fv, b = *(++fv), c = *(++fv);
      const OpenMesh::Vec3d &pa = mesh.point(a), &pb = mesh.point(b), &pc = mesh.point(c);
      before = std::min(before, inverse_aspect(pa, pb, pc));
      if (a == ci.v1 || b == ci.v1 || c == ci.v1) continue;  // removed by the collapse
      const OpenMesh::Vec3d& qa = a == ci.v0 ? ci.p1 : pa;
      const OpenMesh::Vec3d& qb = b == ci.v0 ? ci.p1 : pb;
      const OpenMesh::Vec3d& qc = c == ci.v0 ? ci.p1 : pc;
      const double turn = OpenMesh::dot(unit_normal(pa, pb, pc), unit_normal(qa, qb, qc));
      if (turn < min_cos_) return float(Base::ILLEGAL_COLLAPSE);
      after = std::min(after, inverse_aspect(qa, qb, qc));
    }
    return after > before || after > min_inverse_aspect_ ? float(Base::LEGAL_COLLAPSE)
                                                         : float(Base::ILLEGAL_COLLAPSE);
  }

 private:
  /// The unit normal of a triangle, zero when degenerate (PolyMeshT::calc_face_normal's
  /// arithmetic).
  static OpenMesh::Vec3d unit_normal(const OpenMesh::Vec3d& p0, const OpenMesh::Vec3d& p1,
                                     const OpenMesh::Vec3d& p2) {
    OpenMesh::Vec3d n = (p2 - p1) % (p0 - p1);
    const double length = n.norm();
    return length != 0.0 ? n *= (1.0 / length) : n;
  }

  /// Height over longest edge of a triangle (1 / aspect ratio; 0 when degenerate).
  static double inverse_aspect(const OpenMesh::Vec3d& p0, const OpenMesh::Vec3d& p1,
                               const OpenMesh::Vec3d& p2) {
    const OpenMesh::Vec3d d0 = p0 - p1, d1 = p1 - p2, d2 = p2 - p0;
    const double longest = std::max({d0.sqrnorm(), d1.sqrnorm(), d2.sqrnorm()});
    const double twice_area = (d0 % d2).norm();
    return longest > 0 ? twice_area / longest : 0.0;
  }

  double min_cos_ = std::cos(std::numbers::pi / 4);
  double min_inverse_aspect_ = 0.1;
};

/// Forwards the decimater's progress and stops it on request. The collapses of every decimater
/// that shares `done` add up there; only an observer given a callback reports (the calling
/// thread's: the callback need not be thread-safe), and only when the fraction moved by
/// kMinStep since its last report: a server streams every report to the client, and at 187k
/// vertices a report every 256 collapses was 690 messages in 1.3 s.
class StopObserver : public OpenMesh::Decimater::Observer {
 public:
  StopObserver(const std::stop_token& stop, const BuildProgress* progress,
               std::atomic<size_t>& done, size_t total)
      : Observer(256), stop_(stop), progress_(progress), done_(done),
        total_(std::max<size_t>(total, 1)),
        reported_(static_cast<double>(done.load()) / static_cast<double>(total_)) {}
  void notify(size_t step) override {
    const size_t all = done_.fetch_add(step - counted_) + (step - counted_);
    counted_ = step;
    if (progress_ != nullptr && *progress_) {
      const double fraction =
          std::min(1.0, static_cast<double>(all) / static_cast<double>(total_));
      if (fraction >= reported_ + kMinStep) {
        (*progress_)("decimate", fraction);
        reported_ = fraction;
      }
    }
  }
  /// Counts the collapses after the last notification (call once the decimater returns).
  void finish(size_t collapses) {
    done_.fetch_add(collapses - counted_);
    counted_ = collapses;
  }
  bool abort() const override { return stop_.stop_requested(); }

 private:
  const std::stop_token& stop_;
  const BuildProgress* progress_;
  std::atomic<size_t>& done_;
  size_t total_;
  size_t counted_ = 0;
  static constexpr double kMinStep = 0.01;
  double reported_;  // the last fraction reported (by this observer or, before, another one)
};

/// Multiple-choice decimation (Wu & Kobbelt 2002, "Fast mesh decimation by multiple-choice
/// techniques"): each collapse is the cheapest legal one among `samples` half-edges drawn at
/// random, instead of the head of a priority queue kept over every vertex. OpenMesh's DecimaterT
/// re-evaluates every outgoing half-edge of the whole one-ring after each collapse (measured
/// ~60 us per collapse at 187k vertices, 11 s to reach 10k); this evaluates `samples` of them.
/// Deterministic: its own mt19937_64 with a fixed seed (OpenMesh's McDecimaterT draws from the
/// process-wide rand()).
template <class MeshT>
class MultipleChoiceDecimaterT : public OpenMesh::Decimater::BaseDecimaterT<MeshT> {
 public:
  using Base = OpenMesh::Decimater::BaseDecimaterT<MeshT>;
  using CollapseInfo = typename Base::CollapseInfo;

  MultipleChoiceDecimaterT(MeshT& mesh, int samples, std::uint64_t seed)
      : Base(mesh), mesh_(mesh), samples_(samples), engine_(seed) {
    use_candidates([](int) { return true; });
  }

  /// Draws from now on only the half-edges out of unlocked vertices v with from(v) true.
  template <class From>
  void use_candidates(From&& from) {
    candidates_.clear();
    for (const auto h : mesh_.halfedges()) {  // skips deleted half-edges
      const auto v = mesh_.from_vertex_handle(h);
      if (!mesh_.status(v).locked() && from(v.idx())) candidates_.push_back(h.idx());
    }
  }

  /// Collapses only into vertices v with region[v] == own (nullptr: into any vertex). A
  /// half-edge into another region is dropped from the draws for good: its target never moves
  /// while the restriction holds (the split decimation never collapses those vertices).
  void restrict_targets(const std::vector<std::uint8_t>* region, std::uint8_t own) {
    target_region_ = region;
    own_region_ = own;
  }

  /// Up to `collapses` collapses; fewer when no legal collapse turns up in many draws in a row.
  /// `cost` prices a candidate cheaply (the quadric): candidates are tried cheapest first until
  /// one passes `rules` (the binary modules) and then the topology checks (OpenMesh's link
  /// condition and boundary cases). The rules go first: at Spot 187k they refuse about 45% of
  /// the cheapest candidates, the topology 3%, and the link condition costs more than the
  /// one-ring pass of the rules. Both must pass, so the order changes no choice.
  template <class Cost, class Rules>
  size_t decimate(size_t collapses, Cost&& cost, Rules&& rules) {
    if (!this->is_initialized()) return 0;
    size_t done = 0;
    int fruitless = 0;
    std::vector<std::pair<float, int>> drawn;
    drawn.reserve(static_cast<size_t>(samples_));
    while (done < collapses && !candidates_.empty()) {
      drawn.clear();
      for (int k = 0; k < samples_ && !candidates_.empty(); ++k) {
        const size_t slot = static_cast<size_t>(engine_() % candidates_.size());
        const typename MeshT::HalfedgeHandle h(candidates_[slot]);
        if (mesh_.status(h).deleted() || mesh_.status(mesh_.from_vertex_handle(h)).locked() ||
            (target_region_ != nullptr &&
             (*target_region_)[static_cast<size_t>(mesh_.to_vertex_handle(h).idx())] !=
                 own_region_)) {
          candidates_[slot] = candidates_.back();  // gone for good
          candidates_.pop_back();
          --k;
          continue;
        }
        drawn.emplace_back(cost(CollapseInfo(mesh_, h)), h.idx());
      }
      std::sort(drawn.begin(), drawn.end());
      typename MeshT::HalfedgeHandle best;
      for (const auto& [priority, index] : drawn) {
        CollapseInfo ci(mesh_, typename MeshT::HalfedgeHandle(index));
        if (rules(ci) && this->is_collapse_legal(ci)) {
          best = typename MeshT::HalfedgeHandle(index);
          break;
        }
      }
      if (!best.is_valid()) {
        // Nothing legal in this round: after many such rounds, take it that nothing is left.
        if (++fruitless > kMaxFruitlessRounds) break;
        continue;
      }
      fruitless = 0;
      CollapseInfo ci(mesh_, best);
      this->preprocess_collapse(ci);
      mesh_.collapse(best);
      ++done;
      this->postprocess_collapse(ci);
      if (!this->notify_observer(done)) break;
    }
    return done;
  }

 private:
  static constexpr int kMaxFruitlessRounds = 1000;
  MeshT& mesh_;
  int samples_;
  std::mt19937_64 engine_;
  std::vector<int> candidates_;  // half-edges not yet known to be deleted or locked
  const std::vector<std::uint8_t>* target_region_ = nullptr;
  std::uint8_t own_region_ = 0;
};

/// A MultipleChoiceDecimaterT over a mesh with the hierarchy's modules, set from the settings.
class ConfiguredDecimater {
 public:
  ConfiguredDecimater(OmMesh& om, const MultiresSettings& settings, std::uint64_t seed)
      : decimater_(om, settings.samples, seed) {
    decimater_.add(quadric_);
    decimater_.add(one_ring_);
    decimater_.module(quadric_).set_boundary_weight(settings.boundary_weight);
    decimater_.module(one_ring_).set_max_normal_deviation(settings.max_normal_deviation_degrees);
    decimater_.module(one_ring_).set_max_aspect_ratio(settings.max_aspect_ratio);
  }
  ConfiguredDecimater(const ConfiguredDecimater&) = delete;
  ConfiguredDecimater& operator=(const ConfiguredDecimater&) = delete;

  bool initialize() { return decimater_.initialize(); }
  MultipleChoiceDecimaterT<OmMesh>& decimater() { return decimater_; }
  ModBoundaryQuadricT<OmMesh>& quadrics() { return decimater_.module(quadric_); }

  /// Up to `collapses` collapses (fewer when nothing legal is left or on a stop request).
  size_t decimate(size_t collapses, StopObserver& observer) {
    ModBoundaryQuadricT<OmMesh>& quadric_module = quadrics();
    ModOneRingT<OmMesh>& one_ring_module = decimater_.module(one_ring_);
    decimater_.set_observer(&observer);
    // The quadric is the priority module (never negative, so never illegal); the one-ring
    // module is the only binary one.
    const size_t done = decimater_.decimate(
        collapses, [&](const auto& ci) { return quadric_module.collapse_priority(ci); },
        [&](const auto& ci) { return one_ring_module.collapse_priority(ci) >= 0; });
    decimater_.set_observer(nullptr);
    observer.finish(done);
    return done;
  }

 private:
  MultipleChoiceDecimaterT<OmMesh> decimater_;
  OpenMesh::Decimater::ModHandleT<ModBoundaryQuadricT<OmMesh>> quadric_;
  OpenMesh::Decimater::ModHandleT<ModOneRingT<OmMesh>> one_ring_;
};

constexpr std::uint8_t kBand = 2;

/// The regions of a split decimation: 0 and 1 for the insides of the two halves (split at the
/// median of the unlocked vertices along the bounding box's longest axis, ties by index), kBand
/// for the vertices with a neighbour in the other half (two vertices wide: one on each side).
/// No vertex of one inside is a neighbour of the other inside or of the band vertices next to
/// it, and collapses inside a half only connect it to vertices it already touches, so the two
/// decimaters read and write disjoint elements of the mesh.
std::vector<std::uint8_t> split_regions(const Positions& V, const OmMesh& om,
                                        const MeshTopology& topology) {
  const int n = topology.vertex_count;
  std::vector<int> unlocked;
  unlocked.reserve(static_cast<size_t>(n));
  for (int v = 0; v < n; ++v) {
    if (!om.status(OmMesh::VertexHandle(v)).locked()) unlocked.push_back(v);
  }
  const std::vector<std::uint8_t> side = median_sides(V, std::move(unlocked));
  std::vector<std::uint8_t> region(side);
  for (int v = 0; v < n; ++v) {
    for (int k = topology.vv_offsets[v]; k < topology.vv_offsets[v + 1]; ++k) {
      if (side[static_cast<size_t>(topology.vv_neighbors[k])] != side[static_cast<size_t>(v)]) {
        region[static_cast<size_t>(v)] = kBand;
        break;
      }
    }
  }
  return region;
}

/// The first level's decimation in two halves (MultiresSettings::split_above_vertices): each
/// half's inside by its own decimater, on two threads when settings.threads allows, with the
/// band along the cut untouched; then the band by `decimater`. Each region loses the same
/// share of its unlocked vertices, so the density stays even across the cut.
/// @return the number of collapses; Cancelled on a stop request.
Result<size_t> decimate_in_halves(const Positions& V, OmMesh& om, const MeshTopology& topology,
                                  ConfiguredDecimater& decimater,
                                  const MultiresSettings& settings,
                                  const BuildProgress& progress, std::atomic<size_t>& done,
                                  size_t total, const std::stop_token& stop) {
  const std::vector<std::uint8_t> region = split_regions(V, om, topology);
  std::array<size_t, 3> unlocked{0, 0, 0};
  for (const auto v : om.vertices()) {
    if (!om.status(v).locked()) ++unlocked[region[static_cast<size_t>(v.idx())]];
  }
  const size_t all_unlocked = unlocked[0] + unlocked[1] + unlocked[2];
  const size_t locked = om.n_vertices() - all_unlocked;
  const auto target = static_cast<size_t>(settings.level_vertices.front());
  const double keep = target > locked && all_unlocked > 0
                          ? std::min(1.0, static_cast<double>(target - locked) /
                                              static_cast<double>(all_unlocked))
                          : 0.0;
  // Rounded towards fewer collapses, so that the halves and the band never overshoot the
  // target together; the level's own pass afterwards makes up the difference.
  const auto share = [&](size_t count) {
    const auto kept = static_cast<size_t>(std::ceil(keep * static_cast<double>(count)));
    return count - std::min(count, kept);
  };

  ConfiguredDecimater second(om, settings, settings.seed ^ 0x9e3779b97f4a7c15ULL);
  if (!second.initialize()) {
    return Error(ErrorCode::Internal, "OpenMesh decimater failed to initialise");
  }
  decimater.decimater().use_candidates(
      [&](int v) { return region[static_cast<size_t>(v)] == 0; });
  decimater.decimater().restrict_targets(&region, 0);
  second.decimater().use_candidates([&](int v) { return region[static_cast<size_t>(v)] == 1; });
  second.decimater().restrict_targets(&region, 1);

  StopObserver first_observer(stop, &progress, done, total);
  StopObserver second_observer(stop, nullptr, done, total);
  size_t first_collapses = 0, second_collapses = 0;
  std::exception_ptr second_error;
  const auto run_second = [&] {
    try {
      second_collapses = second.decimate(share(unlocked[1]), second_observer);
    } catch (...) {
      second_error = std::current_exception();
    }
  };
  if (settings.threads >= 2) {
    std::thread worker(run_second);
    try {
      first_collapses = decimater.decimate(share(unlocked[0]), first_observer);
    } catch (...) {
      worker.join();
      throw;
    }
    worker.join();
  } else {
    first_collapses = decimater.decimate(share(unlocked[0]), first_observer);
    run_second();
  }
  if (second_error) std::rethrow_exception(second_error);
  if (stop.stop_requested()) return cancelled("mesh hierarchy");

  // The first decimater goes on over the whole mesh with the second half's quadrics.
  for (const auto v : om.vertices()) {
    if (region[static_cast<size_t>(v.idx())] == 1) {
      decimater.quadrics().set_quadric(v, second.quadrics().quadric(v));
    }
  }
  decimater.decimater().restrict_targets(nullptr, 0);
  decimater.decimater().use_candidates(
      [&](int v) { return region[static_cast<size_t>(v)] == kBand; });
  const size_t alive = om.n_vertices() - first_collapses - second_collapses;
  const size_t band_share = std::min(share(unlocked[2]), alive > target ? alive - target : 0);
  StopObserver band_observer(stop, &progress, done, total);
  const size_t band_collapses = decimater.decimate(band_share, band_observer);
  if (stop.stop_requested()) return cancelled("mesh hierarchy");
  decimater.decimater().use_candidates([](int) { return true; });
  return first_collapses + second_collapses + band_collapses;
}

/// The live part of the decimated mesh as a level (vertex order = fine index order).
MeshLevel snapshot(const OmMesh& om, const std::vector<int>& constrained_row) {
  MeshLevel level;
  std::vector<int> new_index(om.n_vertices(), -1);
  std::vector<int> to_fine;
  to_fine.reserve(om.n_vertices());
  for (const auto v : om.vertices()) {  // skips deleted vertices
    new_index[static_cast<size_t>(v.idx())] = static_cast<int>(to_fine.size());
    to_fine.push_back(v.idx());
  }
  const auto n = static_cast<Eigen::Index>(to_fine.size());
  level.V.resize(n, 3);
  level.to_fine.resize(n);
  std::vector<int> constrained, rows;
  for (Eigen::Index i = 0; i < n; ++i) {
    const int fine = to_fine[static_cast<size_t>(i)];
    level.to_fine(i) = fine;
    level.V.row(i) = detail::to_eigen(om.point(OmMesh::VertexHandle(fine))).transpose();
    if (constrained_row[static_cast<size_t>(fine)] >= 0) {
      constrained.push_back(static_cast<int>(i));
      rows.push_back(constrained_row[static_cast<size_t>(fine)]);
    }
  }
  level.constrained = Eigen::Map<const Eigen::VectorXi>(
      constrained.data(), static_cast<Eigen::Index>(constrained.size()));
  level.constrained_rows =
      Eigen::Map<const Eigen::VectorXi>(rows.data(), static_cast<Eigen::Index>(rows.size()));
  std::vector<int> faces;
  faces.reserve(3 * om.n_faces());
  for (const auto f : om.faces()) {
    for (const auto v : om.fv_range(f)) faces.push_back(new_index[static_cast<size_t>(v.idx())]);
  }
  level.F = Eigen::Map<const Eigen::Matrix<int, Eigen::Dynamic, 3, Eigen::RowMajor>>(
      faces.data(), static_cast<Eigen::Index>(faces.size() / 3), 3);
  return level;
}

Status check_settings(const MultiresSettings& settings) {
  if (settings.level_vertices.empty()) {
    return Error(ErrorCode::InvalidArgument, "level_vertices is empty: give at least one level");
  }
  for (size_t k = 0; k < settings.level_vertices.size(); ++k) {
    if (settings.level_vertices[k] < 4 ||
        (k > 0 && settings.level_vertices[k] >= settings.level_vertices[k - 1])) {
      return Error(ErrorCode::InvalidArgument,
                   "level_vertices must be strictly decreasing and >= 4; entry " +
                       std::to_string(k) + " is " + std::to_string(settings.level_vertices[k]));
    }
  }
  if (!(settings.max_normal_deviation_degrees > 0) || settings.max_normal_deviation_degrees > 180) {
    return Error(ErrorCode::InvalidArgument, "max_normal_deviation_degrees must be in (0, 180]");
  }
  if (settings.samples < 1) {
    return Error(ErrorCode::InvalidArgument, "samples must be >= 1");
  }
  if (settings.split_above_vertices < 0) {
    return Error(ErrorCode::InvalidArgument, "split_above_vertices must be >= 0 (0: never split)");
  }
  if (settings.threads < 1) {
    return Error(ErrorCode::InvalidArgument, "threads must be >= 1");
  }
  if (!(settings.max_aspect_ratio >= 1) || !std::isfinite(settings.max_aspect_ratio)) {
    return Error(ErrorCode::InvalidArgument, "max_aspect_ratio must be finite and >= 1");
  }
  if (!(settings.boundary_weight >= 0) || !std::isfinite(settings.boundary_weight)) {
    return Error(ErrorCode::InvalidArgument, "boundary_weight must be finite and >= 0");
  }
  return Status::success();
}

}  // namespace

// ---- MeshHierarchy ------------------------------------------------------------------------------

Result<MeshHierarchy> MeshHierarchy::build(const Positions& V, const Triangles& F,
                                           const Eigen::VectorXi& constrained,
                                           const MultiresSettings& settings,
                                           const BuildProgress& progress, std::stop_token stop) {
  MD_RETURN_IF_ERROR(check_settings(settings));
  MD_RETURN_IF_ERROR(validate_triangle_mesh(V, F));
  MD_ASSIGN_OR_RETURN(const MeshTopology topology, build_topology(F, static_cast<int>(V.rows())));
  return build_checked(V, F, topology, constrained, settings, progress, stop);
}

Result<MeshHierarchy> MeshHierarchy::build_checked(const Positions& V, const Triangles& F,
                                                   const MeshTopology& topology,
                                                   const Eigen::VectorXi& constrained,
                                                   const MultiresSettings& settings,
                                                   const BuildProgress& progress,
                                                   const std::stop_token& stop) {
  return guard_exceptions("building the mesh hierarchy", ErrorCode::Internal,
                          [&]() -> Result<MeshHierarchy> {
    MD_RETURN_IF_ERROR(check_settings(settings));
    const int n = static_cast<int>(V.rows());
    MD_RETURN_IF_ERROR(check_constrained(constrained, topology, 0));
    if (stop.stop_requested()) return cancelled("mesh hierarchy");

    std::vector<int> constrained_row(static_cast<size_t>(n), -1);
    for (Eigen::Index j = 0; j < constrained.size(); ++j) {
      constrained_row[static_cast<size_t>(constrained(j))] = static_cast<int>(j);
    }

    MeshHierarchy hierarchy;
    {
      MeshLevel fine;
      fine.V = V;
      fine.F = F;
      fine.to_fine = Eigen::VectorXi::LinSpaced(n, 0, n - 1);
      std::vector<int> c, rows;
      for (int v = 0; v < n; ++v) {
        if (constrained_row[static_cast<size_t>(v)] >= 0) {
          c.push_back(v);
          rows.push_back(constrained_row[static_cast<size_t>(v)]);
        }
      }
      fine.constrained =
          Eigen::Map<const Eigen::VectorXi>(c.data(), static_cast<Eigen::Index>(c.size()));
      fine.constrained_rows =
          Eigen::Map<const Eigen::VectorXi>(rows.data(), static_cast<Eigen::Index>(rows.size()));
      hierarchy.levels_.push_back(std::move(fine));
    }

    OmMesh om = detail::to_openmesh(V, F, topology);
    int locked = 0;
    for (int v = 0; v < n; ++v) {
      if (constrained_row[static_cast<size_t>(v)] < 0) continue;
      bool lock = settings.constraint_levels == ConstraintLevels::KeepAll;
      for (int k = topology.vv_offsets[v]; !lock && k < topology.vv_offsets[v + 1]; ++k) {
        lock = constrained_row[static_cast<size_t>(topology.vv_neighbors[k])] < 0;
      }
      if (lock) {
        om.status(OmMesh::VertexHandle(v)).set_locked(true);
        ++locked;
      }
    }

    ConfiguredDecimater decimater(om, settings, settings.seed);
    if (!decimater.initialize()) {
      return Error(ErrorCode::Internal, "OpenMesh decimater failed to initialise");
    }

    size_t alive = static_cast<size_t>(n);
    const size_t total = alive > static_cast<size_t>(settings.level_vertices.back())
                             ? alive - static_cast<size_t>(settings.level_vertices.back())
                             : 0;
    std::atomic<size_t> done{0};
    report_progress(progress, "decimate", 0.0);
    if (settings.split_above_vertices > 0 && n > settings.split_above_vertices &&
        alive > static_cast<size_t>(settings.level_vertices.front())) {
      MD_ASSIGN_OR_RETURN(const size_t collapses,
                          decimate_in_halves(V, om, topology, decimater, settings, progress,
                                             done, total, stop));
      alive -= collapses;
    }
    std::vector<MeshLevel> coarse;
    for (size_t k = 0; k < settings.level_vertices.size(); ++k) {
      const auto target = static_cast<size_t>(settings.level_vertices[k]);
      if (alive > target) {
        StopObserver observer(stop, &progress, done, total);
        alive -= decimater.decimate(alive - target, observer);
        if (stop.stop_requested()) return cancelled("mesh hierarchy");
      }
      coarse.push_back(snapshot(om, constrained_row));
    }
    report_progress(progress, "decimate", 1.0);
    const auto must_keep = settings.constraint_levels == ConstraintLevels::KeepAll
                               ? static_cast<int>(constrained.size())
                               : locked;
    for (size_t k = 0; k < coarse.size(); ++k) {
      report_progress(progress, "validate",
                      static_cast<double>(k) / static_cast<double>(coarse.size()));
      MeshLevel& level = coarse[k];
      const Status valid = validate_triangle_mesh(level.V, level.F);
      if (!valid.ok()) {
        return Error(ErrorCode::Internal, "coarse level " + std::to_string(k + 1) + " (" +
                                              std::to_string(level.V.rows()) +
                                              " vertices) is invalid: " + valid.message());
      }
      if (level.constrained.size() < must_keep) {
        return Error(ErrorCode::Internal, "coarse level " + std::to_string(k + 1) +
                                              " lost a locked constrained vertex");
      }
      hierarchy.levels_.push_back(std::move(level));
    }
    report_progress(progress, "validate", 1.0);
    return hierarchy;
  });
}

Result<Positions> MeshHierarchy::level_targets(int k, const Positions& fine_targets) const {
  if (k < 0 || k >= level_count()) {
    return Error(ErrorCode::InvalidArgument, "level " + std::to_string(k) + " out of range [0, " +
                                                 std::to_string(level_count()) + ")");
  }
  const MeshLevel& level = levels_[static_cast<size_t>(k)];
  if (fine_targets.rows() != levels_.front().constrained.size()) {
    return Error(ErrorCode::InvalidArgument,
                 "expected " + std::to_string(levels_.front().constrained.size()) +
                     " target rows (one per constrained vertex), got " +
                     std::to_string(fine_targets.rows()));
  }
  Positions out(level.constrained_rows.size(), 3);
  for (Eigen::Index j = 0; j < level.constrained_rows.size(); ++j) {
    out.row(j) = fine_targets.row(level.constrained_rows(j));
  }
  return out;
}

// ---- Prolongation -------------------------------------------------------------------------------

struct Prolongation::Impl {
  int nv = 0, nc = 0;
  Triangles F;
  Eigen::VectorXi coarse_to_fine;
  std::vector<int> free_vertices;  // fine vertices that are not coarse, ascending
  SparseMatrix L_fc;               // #free x #coarse block of the Laplacian
  SplitCholesky cholesky;          // of the #free x #free block
  std::vector<int> tangent_neighbor;  // #V: the neighbour that fixes the tangent direction
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> detail;  // frame coords / scale

  // Row-major per-vertex arrays: the per-face passes gather and scatter whole vertices (one or
  // two cache lines a vertex instead of three or four strided ones).
  using Rows3 = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;
  /// Per vertex: the area-weighted normal sum (columns 0-2) and the one-ring area (column 3).
  using NormalsAreas = Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor>;

  /// The harmonic base surface for coarse positions.
  Rows3 base(const Positions& coarse) const;
  /// Per vertex the area-weighted normal sum and the one-ring area of B.
  NormalsAreas normals_and_areas(const Rows3& B) const;
};

Prolongation::Impl::Rows3 Prolongation::Impl::base(const Positions& coarse) const {
  Rows3 B(nv, 3);
  for (int i = 0; i < nc; ++i) B.row(coarse_to_fine(i)) = coarse.row(i);
  if (!free_vertices.empty()) {
    const Eigen::MatrixXd rhs = -(L_fc * Eigen::MatrixXd(coarse));
    const Eigen::MatrixXd solved = cholesky.solve(rhs);
    for (size_t k = 0; k < free_vertices.size(); ++k) {
      B.row(free_vertices[k]) = solved.row(static_cast<Eigen::Index>(k));
    }
  }
  return B;
}

Prolongation::Impl::NormalsAreas Prolongation::Impl::normals_and_areas(const Rows3& B) const {
  NormalsAreas out = NormalsAreas::Zero(nv, 4);
  for (Eigen::Index f = 0; f < F.rows(); ++f) {
    const Eigen::Vector3d a = B.row(F(f, 0));
    const Eigen::Vector3d cross =
        (B.row(F(f, 1)).transpose() - a).cross(B.row(F(f, 2)).transpose() - a);
    const Eigen::Vector4d add(cross(0), cross(1), cross(2), 0.5 * cross.norm());
    for (int k = 0; k < 3; ++k) out.row(F(f, k)) += add.transpose();
  }
  return out;
}

namespace {

/// The orthonormal frame (tangent, bitangent, normal) of B at vertex i with neighbour j; false
/// when the normal or the tangent is degenerate.
bool vertex_frame(const Eigen::Vector3d& normal_sum, const Eigen::Vector3d& edge,
                  Eigen::Matrix3d& frame) {
  const double normal_length = normal_sum.norm();
  if (!(normal_length > 0) || !std::isfinite(normal_length)) return false;
  const Eigen::Vector3d n = normal_sum / normal_length;
  const Eigen::Vector3d tangent = edge - n.dot(edge) * n;
  const double tangent_length = tangent.norm();
  if (!(tangent_length > 1e-12 * edge.norm())) return false;
  const Eigen::Vector3d t = tangent / tangent_length;
  frame.col(0) = t;
  frame.col(1) = n.cross(t);
  frame.col(2) = n;
  return true;
}

}  // namespace

Prolongation::Prolongation(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
Prolongation::Prolongation(Prolongation&&) noexcept = default;
Prolongation& Prolongation::operator=(Prolongation&&) noexcept = default;
Prolongation::~Prolongation() = default;

int Prolongation::fine_vertex_count() const { return impl_->nv; }
int Prolongation::coarse_vertex_count() const { return impl_->nc; }

Result<Prolongation> Prolongation::create(const Positions& V, const Triangles& F,
                                          const Eigen::VectorXi& coarse_to_fine,
                                          std::stop_token stop, int threads) {
  if (threads < 1) {
    return Error(ErrorCode::InvalidArgument,
                 "prolongation threads must be >= 1, got " + std::to_string(threads));
  }
  MD_RETURN_IF_ERROR(validate_triangle_mesh(V, F));
  MD_ASSIGN_OR_RETURN(const MeshTopology topology, build_topology(F, static_cast<int>(V.rows())));
  return create_checked(V, F, topology, coarse_to_fine, stop, threads, nullptr);
}

Result<Prolongation> Prolongation::create_checked(const Positions& V, const Triangles& F,
                                                  const MeshTopology& topology,
                                                  const Eigen::VectorXi& coarse_to_fine,
                                                  const std::stop_token& stop, int threads,
                                                  std::future<SparseMatrix>* laplacian) {
  return guard_exceptions("building the prolongation", ErrorCode::Internal,
                          [&]() -> Result<Prolongation> {
    const int n = static_cast<int>(V.rows());
    MD_RETURN_IF_ERROR(check_constrained(coarse_to_fine, topology, 1));
    if (stop.stop_requested()) return cancelled("prolongation");

    auto impl = std::make_unique<Impl>();
    Impl& s = *impl;
    s.nv = n;
    s.nc = static_cast<int>(coarse_to_fine.size());
    s.F = F;
    s.coarse_to_fine = coarse_to_fine;
    std::vector<int> coarse_index(static_cast<size_t>(n), -1);
    for (int i = 0; i < s.nc; ++i) coarse_index[static_cast<size_t>(coarse_to_fine(i))] = i;
    std::vector<int> free_index(static_cast<size_t>(n), -1);
    for (int v = 0; v < n; ++v) {
      if (coarse_index[static_cast<size_t>(v)] < 0) {
        free_index[static_cast<size_t>(v)] = static_cast<int>(s.free_vertices.size());
        s.free_vertices.push_back(v);
      }
    }

    // Split the clamped-cotangent Laplacian into its free/free and free/coarse blocks.
    const SparseMatrix L = laplacian != nullptr
                               ? laplacian->get()
                               : laplacian_matrix(V, F, topology, LaplacianWeights::Cotangent);
    const auto nf = static_cast<int>(s.free_vertices.size());
    std::vector<Eigen::Triplet<double>> ff, fc;
    for (int c = 0; c < L.outerSize(); ++c) {
      for (SparseMatrix::InnerIterator it(L, c); it; ++it) {
        const int row = free_index[static_cast<size_t>(it.row())];
        if (row < 0) continue;
        const int col_free = free_index[static_cast<size_t>(it.col())];
        if (col_free >= 0) {
          ff.emplace_back(row, col_free, it.value());
        } else {
          fc.emplace_back(row, coarse_index[static_cast<size_t>(it.col())], it.value());
        }
      }
    }
    s.L_fc.resize(nf, s.nc);
    s.L_fc.setFromTriplets(fc.begin(), fc.end());
    if (nf > 0) {
      SparseMatrix L_ff(nf, nf);
      L_ff.setFromTriplets(ff.begin(), ff.end());
      L_ff.makeCompressed();
      Positions free_points(nf, 3);
      for (int k = 0; k < nf; ++k) {
        free_points.row(k) = V.row(s.free_vertices[static_cast<size_t>(k)]);
      }
      SplitCholeskySettings split;
      split.threads = threads;
      MD_RETURN_IF_ERROR(s.cholesky.factorize(L_ff, free_points, split, stop));
    }
    if (stop.stop_requested()) return cancelled("prolongation");

    // Details of the rest mesh over its own base surface, in the base's frames.
    Positions coarse(s.nc, 3);
    for (int i = 0; i < s.nc; ++i) coarse.row(i) = V.row(coarse_to_fine(i));
    const Impl::Rows3 B = s.base(coarse);
    const Impl::NormalsAreas normals_areas = s.normals_and_areas(B);
    const auto normal_sum = normals_areas.leftCols<3>();
    const auto area = normals_areas.col(3);
    s.tangent_neighbor.assign(static_cast<size_t>(n), -1);
    s.detail.resize(n, 3);
    for (int i = 0; i < n; ++i) {
      // The most tangential neighbour: its edge direction is the least sensitive to the normal.
      // Near-ties (regular meshes are full of exact ones) go to the first neighbour, so that
      // round-off in B (e.g. one thread or two) cannot flip the choice and the frame with it.
      constexpr double kTie = 1e-9;
      const Eigen::Vector3d normal = normal_sum.row(i).normalized();
      double best = -1;
      for (int k = topology.vv_offsets[i]; k < topology.vv_offsets[i + 1]; ++k) {
        const int j = topology.vv_neighbors[k];
        const Eigen::Vector3d edge = (B.row(j) - B.row(i)).transpose();
        const double length = edge.norm();
        if (!(length > 0)) continue;
        const double tangential = (edge - normal.dot(edge) * normal).norm() / length;
        if (tangential > best + kTie) {
          best = tangential;
          s.tangent_neighbor[static_cast<size_t>(i)] = j;
        }
      }
      Eigen::Matrix3d frame;
      const int j = s.tangent_neighbor[static_cast<size_t>(i)];
      if (j < 0 || !(area(i) > 0) ||
          !vertex_frame(normal_sum.row(i).transpose(), (B.row(j) - B.row(i)).transpose(), frame)) {
        return Error(ErrorCode::NumericalFailure,
                     "the smooth base surface has a degenerate frame at vertex " +
                         std::to_string(i) + " (coarse level too sparse around it?)");
      }
      s.detail.row(i) =
          (frame.transpose() * (V.row(i) - B.row(i)).transpose()).transpose() / std::sqrt(area(i));
    }
    return Prolongation(std::move(impl));
  });
}

Result<Positions> Prolongation::apply(const Positions& coarse) const {
  const Impl& s = *impl_;
  if (coarse.rows() != s.nc || !coarse.allFinite()) {
    return Error(ErrorCode::InvalidArgument,
                 "prolongation needs " + std::to_string(s.nc) + " finite coarse rows, got " +
                     std::to_string(coarse.rows()));
  }
  return guard_exceptions("prolongation", ErrorCode::Internal, [&]() -> Result<Positions> {
    const Impl::Rows3 B = s.base(coarse);
    const Impl::NormalsAreas normals_areas = s.normals_and_areas(B);
    const auto normal_sum = normals_areas.leftCols<3>();
    const auto area = normals_areas.col(3);
    // Add each detail in B's frame. A vertex whose deformed frame collapsed keeps its base
    // position (its detail direction is undefined there).
    Positions out(s.nv, 3);
    for (int i = 0; i < s.nv; ++i) {
      const int j = s.tangent_neighbor[static_cast<size_t>(i)];
      Eigen::Matrix3d frame;
      if (area(i) > 0 &&
          vertex_frame(normal_sum.row(i).transpose(), (B.row(j) - B.row(i)).transpose(), frame)) {
        out.row(i) =
            B.row(i) + std::sqrt(area(i)) * (frame * s.detail.row(i).transpose()).transpose();
      } else {
        out.row(i) = B.row(i);
      }
    }
    // Coarse vertices carry no detail: put them exactly where they were given.
    for (int i = 0; i < s.nc; ++i) out.row(s.coarse_to_fine(i)) = coarse.row(i);
    if (!out.allFinite()) {
      return Error(ErrorCode::NumericalFailure, "prolongation produced non-finite positions");
    }
    return out;
  });
}

// ---- MultiresDeformer ---------------------------------------------------------------------------

struct MultiresDeformer::Impl {
  MultiresDeformerSettings settings;
  MeshHierarchy hierarchy;
  MeshTopology fine_topology;  // of hierarchy level 0 (the input mesh), until the fine solver has it
  int level = 1;
  std::optional<Prolongation> prolongation;
  std::optional<ScaleAwareSolver> coarse;
  std::optional<MultilevelSolver> fine;  // single level unless settings.refine_cascade
  MultiresBuildReport report;
  Positions positions;
  bool has_positions = false;  // a move or a refinement set `positions`
  bool fine_holds_positions = false;  // `positions` is the fine solver's own last result
};

MultiresDeformer::MultiresDeformer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
MultiresDeformer::MultiresDeformer(MultiresDeformer&&) noexcept = default;
MultiresDeformer& MultiresDeformer::operator=(MultiresDeformer&&) noexcept = default;
MultiresDeformer::~MultiresDeformer() = default;

Result<MultiresDeformer> MultiresDeformer::create(const Positions& V, const Triangles& F,
                                                  const Eigen::VectorXi& constrained,
                                                  const MultiresDeformerSettings& settings,
                                                  const BuildProgress& progress,
                                                  std::stop_token stop) {
  // Validate the fine mesh and build its connectivity once for the hierarchy and the
  // prolongation (a second of the set-up budget at 187k vertices otherwise).
  const auto start = Clock::now();
  MD_RETURN_IF_ERROR(validate_triangle_mesh(V, F));
  MD_ASSIGN_OR_RETURN(const MeshTopology topology, build_topology(F, static_cast<int>(V.rows())));
  const double checks = seconds_since(start);
  MD_ASSIGN_OR_RETURN(MultiresDeformer deformer,
                      create(V, F, topology, constrained, settings, progress, std::move(stop)));
  deformer.impl_->report.hierarchy_seconds += checks;  // as before the overload: validation in it
  return deformer;
}

Result<MultiresDeformer> MultiresDeformer::create(const Positions& V, const Triangles& F,
                                                  const MeshTopology& topology,
                                                  const Eigen::VectorXi& constrained,
                                                  const MultiresDeformerSettings& settings,
                                                  const BuildProgress& progress,
                                                  std::stop_token stop) {
  MD_ASSERT(topology.vertex_count == V.rows() && topology.face_count == F.rows());
  auto impl = std::make_unique<Impl>();
  Impl& s = *impl;
  s.settings = settings;
  auto start = Clock::now();
  // With two threads the prolongation's Laplacian (0.13 s at 187k vertices) is built on the
  // second while the first converts the mesh for OpenMesh, before the decimation needs both.
  std::future<SparseMatrix> laplacian;
  if (settings.hierarchy.threads >= 2) {
    laplacian = std::async(std::launch::async, [&V, &F, &topology] {
      return laplacian_matrix(V, F, topology, LaplacianWeights::Cotangent);
    });
  }
  MD_ASSIGN_OR_RETURN(s.hierarchy,
                      MeshHierarchy::build_checked(V, F, topology, constrained, settings.hierarchy,
                                                   progress, stop));
  s.report.hierarchy_seconds = seconds_since(start);
  s.fine_topology = topology;
  const int coarsest = s.hierarchy.level_count() - 1;
  s.level = settings.level < 0 ? coarsest : settings.level;
  if (s.level < 1 || s.level > coarsest) {
    return Error(ErrorCode::InvalidArgument, "coarse level " + std::to_string(settings.level) +
                                                 " out of range [1, " + std::to_string(coarsest) +
                                                 "] (or -1)");
  }
  const MeshLevel& level = s.hierarchy.level(s.level);
  s.report.coarse_vertices = static_cast<int>(level.V.rows());
  s.report.coarse_constrained = static_cast<int>(level.constrained.size());

  start = Clock::now();
  report_progress(progress, "prolongation", 0.0);
  MD_ASSIGN_OR_RETURN(Prolongation prolongation,
                      Prolongation::create_checked(V, F, topology, level.to_fine, stop,
                                                   settings.hierarchy.threads,
                                                   laplacian.valid() ? &laplacian : nullptr));
  s.prolongation.emplace(std::move(prolongation));
  report_progress(progress, "prolongation", 1.0);
  s.report.prolongation_seconds = seconds_since(start);

  start = Clock::now();
  report_progress(progress, "coarse_precompute", 0.0);
  MD_ASSIGN_OR_RETURN(ScaleAwareSolver coarse, ScaleAwareSolver::create(level.V, level.F,
                                                                        level.constrained,
                                                                        settings.solver, stop));
  s.coarse.emplace(std::move(coarse));
  report_progress(progress, "coarse_precompute", 1.0);
  s.report.coarse_solver_seconds = seconds_since(start);
  s.positions = V;
  return MultiresDeformer(std::move(impl));
}

Result<MultiresMove> MultiresDeformer::move(const Positions& targets, const SolveOptions& options,
                                            const ProgressCallback& progress,
                                            std::stop_token stop) {
  Impl& s = *impl_;
  MD_ASSIGN_OR_RETURN(const Positions coarse_targets, s.hierarchy.level_targets(s.level, targets));
  MultiresMove move;
  MD_ASSIGN_OR_RETURN(move.coarse, s.coarse->solve(coarse_targets, options, progress, stop));
  const auto start = Clock::now();
  MD_ASSIGN_OR_RETURN(move.V, s.prolongation->apply(move.coarse.V));
  move.prolong_seconds = seconds_since(start);
  s.positions = move.V;
  s.has_positions = true;
  s.fine_holds_positions = false;
  return move;
}

std::optional<MultiresDeformer::FineSolverInputs> MultiresDeformer::fine_solver_inputs(
    double rigidity) const {
  const Impl& s = *impl_;
  if (s.fine) return std::nullopt;
  const MeshLevel& fine = s.hierarchy.level(0);
  FineSolverInputs inputs;
  inputs.V = fine.V;
  inputs.F = fine.F;
  inputs.topology = s.fine_topology;
  // The fine solver takes the constrained vertices in the caller's order (targets' rows).
  inputs.constrained.resize(fine.constrained.size());
  for (Eigen::Index j = 0; j < fine.constrained.size(); ++j) {
    inputs.constrained(fine.constrained_rows(j)) = fine.constrained(j);
  }
  // Refinement always starts from the prolonged move: the Laplacian guess is built only if ever
  // asked for (a refine before any move).
  inputs.settings = s.settings.solver;
  inputs.settings.lazy_laplacian_guess = true;
  inputs.rigidity = rigidity;
  if (s.settings.refine_cascade) {
    inputs.multilevel = s.settings.cascade;
  } else {
    // No level is coarse enough to be kept: the single-level solver alone.
    inputs.multilevel.coarsest_vertices = std::numeric_limits<int>::max();
    inputs.multilevel.threads = std::max(1, s.settings.hierarchy.threads);
  }
  return inputs;
}

Result<MultilevelSolver> MultiresDeformer::build_fine_solver(const FineSolverInputs& inputs,
                                                             std::stop_token stop) {
  MultilevelSettings settings = inputs.multilevel;
  settings.solver = inputs.settings;  // lazy Laplacian guess: MultilevelSolver's fine solver has it
  MD_ASSIGN_OR_RETURN(MultilevelSolver solver,
                      MultilevelSolver::create(inputs.V, inputs.F, inputs.topology,
                                               inputs.constrained, settings, {}, stop));
  if (inputs.rigidity >= 0) {
    if (stop.stop_requested()) {
      return Error(ErrorCode::Cancelled, "precompute cancelled (deadline or client)");
    }
    MD_RETURN_IF_ERROR(solver.fine().prepare(inputs.rigidity));
  }
  return solver;
}

bool MultiresDeformer::needs_fine_solver() const { return !impl_->fine.has_value(); }

void MultiresDeformer::install_fine_solver(MultilevelSolver solver) {
  Impl& s = *impl_;
  if (s.fine) return;
  s.fine.emplace(std::move(solver));
  s.fine_topology = MeshTopology{};  // the fine solver holds its own copy now
}

Status MultiresDeformer::prepare_refinement(const BuildProgress& progress, std::stop_token stop) {
  std::optional<FineSolverInputs> inputs = fine_solver_inputs();
  if (!inputs) return Status::success();
  report_progress(progress, "fine_precompute", 0.0);
  MD_ASSIGN_OR_RETURN(MultilevelSolver solver, build_fine_solver(*inputs, std::move(stop)));
  install_fine_solver(std::move(solver));
  report_progress(progress, "fine_precompute", 1.0);
  return Status::success();
}

Result<SolveReport> MultiresDeformer::refine(const Positions& targets, const SolveOptions& options,
                                             const ProgressCallback& progress,
                                             std::stop_token stop) {
  Impl& s = *impl_;
  MD_RETURN_IF_ERROR(prepare_refinement({}, stop));
  ScaleAwareSolver& fine = s.fine->fine();
  // The cascade replaces a start from the prolonged move (and, before any move, the cold
  // single-level Auto start); the paper mode (rigidity 0) and explicit starts stay as they were.
  if (s.settings.refine_cascade && s.fine->level_count() > 1 && !s.fine_holds_positions &&
      options.start == StartFrom::Auto && options.multilevel && options.rigidity > 0) {
    MD_ASSIGN_OR_RETURN(SolveReport report, s.fine->solve(targets, options, progress, stop));
    s.positions = report.V;
    s.has_positions = true;
    s.fine_holds_positions = true;
    return report;
  }
  SolveOptions run = options;
  if (s.has_positions &&
      (options.start == StartFrom::Auto || options.start == StartFrom::Previous)) {
    // A prolonged move seeds the fine solver; its own last result it continues from as is
    // (keeping its rotations and acceleration history).
    if (!s.fine_holds_positions) MD_RETURN_IF_ERROR(fine.set_positions(s.positions));
    run.start = StartFrom::Previous;
  }
  MD_ASSIGN_OR_RETURN(SolveReport report, fine.solve(targets, run, progress, stop));
  s.positions = report.V;
  s.has_positions = true;
  s.fine_holds_positions = true;
  return report;
}

void MultiresDeformer::reset() {
  Impl& s = *impl_;
  s.positions = s.hierarchy.level(0).V;
  s.has_positions = false;
  s.fine_holds_positions = false;
  s.coarse->reset();
  if (s.fine) s.fine->fine().reset();
}

const Positions& MultiresDeformer::positions() const { return impl_->positions; }
const MeshHierarchy& MultiresDeformer::hierarchy() const { return impl_->hierarchy; }
int MultiresDeformer::coarse_level() const { return impl_->level; }
const MultiresBuildReport& MultiresDeformer::build_report() const { return impl_->report; }
ScaleAwareSolver& MultiresDeformer::coarse_solver() { return *impl_->coarse; }
ScaleAwareSolver* MultiresDeformer::fine_solver() {
  return impl_->fine ? &impl_->fine->fine() : nullptr;
}

}  // namespace meshdeform::core
