// Tests of step one of the scale-aware solver (core/methods/normals_step.h, paper Section 4.1.1): the
// local/global update of the face normals on the Gauss map. The rest normals and any global
// rotation of them are fixed points; the output is unit length; the iteration is rotation
// equivariant, deterministic (also across thread counts) and does the number of sweeps asked;
// every sweep is a rotation fit per vertex fan then the global step (Eq. 11); the energy
// sum_v sum_{f in v} ||N_f - R_v N0_f||^2 never increases from sweep to sweep; and, with no
// constraint, the iteration reaches a zero of it: a rotation of the rest normals.
#include "core/methods/normals_step.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "core/mesh/measures.h"
#include "core/mesh/topology.h"
#include "tests/support/mesh_factories.h"

namespace meshdeform::core {
namespace {

using Quats = std::vector<Eigen::Quaterniond>;

struct Case {
  std::string name;
  MeshData mesh;
  MeshTopology topology;
  RowPositions N0;  // rest normals
  RowPositions N;   // normals of a deformed copy: a starting point away from the rest
};

/// A smooth non-rigid deformation: stretch along x, twist about z, bend in z.
Positions deform(const Positions& V) {
  Positions out(V.rows(), 3);
  for (Eigen::Index i = 0; i < V.rows(); ++i) {
    const double x = 1.4 * V(i, 0), y = V(i, 1), z = V(i, 2);
    const double a = 0.8 * z + 0.3 * x;
    out.row(i) << std::cos(a) * x - std::sin(a) * y, std::sin(a) * x + std::cos(a) * y,
        z + 0.3 * x * x;
  }
  return out;
}

Case make_case(std::string name, MeshData mesh) {
  Case c{std::move(name), std::move(mesh), {}, {}, {}};
  c.topology = *build_topology(c.mesh.F, static_cast<int>(c.mesh.V.rows()));
  c.N0 = face_normals(c.mesh.V, c.mesh.F);
  c.N = face_normals(deform(c.mesh.V), c.mesh.F);
  return c;
}

std::vector<Case> cases() {
  std::vector<Case> out;
  out.push_back(make_case("icosphere", test::make_icosphere(2)));
  out.push_back(make_case("bumpy_grid", test::make_grid(10, 0.1)));
  out.push_back(make_case("open_cone", test::make_open_cone(12)));
  return out;
}

Quats identities(int n) { return Quats(static_cast<size_t>(n), Eigen::Quaterniond::Identity()); }

Eigen::Matrix3d fan_covariance(const Case& c, const RowPositions& N, int v) {
  Eigen::Matrix3d B = Eigen::Matrix3d::Zero();
  for (int k = c.topology.vf_offsets[v]; k < c.topology.vf_offsets[v + 1]; ++k) {
    const int f = c.topology.vf_faces[k];
    B += N.row(f).transpose() * c.N0.row(f);
  }
  return B;
}

/// sum_v sum_{f in v} ||N_f - R_v N0_f||^2.
double gauss_map_energy(const Case& c, const RowPositions& N, const Quats& rotations) {
  double energy = 0;
  for (int v = 0; v < c.topology.vertex_count; ++v) {
    const Eigen::Matrix3d R = rotations[v].toRotationMatrix();
    for (int k = c.topology.vf_offsets[v]; k < c.topology.vf_offsets[v + 1]; ++k) {
      const int f = c.topology.vf_faces[k];
      energy += (N.row(f).transpose() - R * c.N0.row(f).transpose()).squaredNorm();
    }
  }
  return energy;
}

Eigen::Matrix3d skew_rotation() {
  return Eigen::AngleAxisd(1.1, Eigen::Vector3d(0.3, -0.8, 0.5).normalized()).toRotationMatrix();
}

TEST(NormalsStep, RestNormalsAreAFixedPoint) {
  for (const Case& c : cases()) {
    SCOPED_TRACE(c.name);
    RowPositions N = c.N0;
    Quats rotations = identities(c.topology.vertex_count);
    const int sweeps = update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, 4, 0.0, 1);
    EXPECT_EQ(sweeps, 4);
    EXPECT_LT((N - c.N0).cwiseAbs().maxCoeff(), 1e-13);
    // The rotations keep every normal of their fan in place.
    for (int v = 0; v < c.topology.vertex_count; ++v) {
      for (int k = c.topology.vf_offsets[v]; k < c.topology.vf_offsets[v + 1]; ++k) {
        const int f = c.topology.vf_faces[k];
        EXPECT_LT((rotations[v] * c.N0.row(f).transpose() - c.N0.row(f).transpose()).norm(), 1e-12);
      }
    }
    // With a tolerance, the first sweep already sees no change and stops.
    N = c.N0;
    EXPECT_EQ(update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, 50, 1e-12, 1), 1);
  }
}

TEST(NormalsStep, GloballyRotatedNormalsAreAFixedPoint) {
  const Eigen::Matrix3d Q = skew_rotation();
  for (const Case& c : cases()) {
    SCOPED_TRACE(c.name);
    const RowPositions rotated = c.N0 * Q.transpose();
    RowPositions N = rotated;
    Quats rotations = identities(c.topology.vertex_count);
    update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, 5, 0.0, 1);
    EXPECT_LT((N - rotated).cwiseAbs().maxCoeff(), 1e-12);
    for (int v = 0; v < c.topology.vertex_count; ++v) {
      for (int k = c.topology.vf_offsets[v]; k < c.topology.vf_offsets[v + 1]; ++k) {
        const int f = c.topology.vf_faces[k];
        EXPECT_LT((rotations[v] * c.N0.row(f).transpose() - Q * c.N0.row(f).transpose()).norm(),
                  1e-12);
      }
    }
  }
}

TEST(NormalsStep, OutputNormalsAreUnitLength) {
  for (const Case& c : cases()) {
    SCOPED_TRACE(c.name);
    for (const int max_sweeps : {1, 3, 20}) {
      RowPositions N = c.N;
      Quats rotations = identities(c.topology.vertex_count);
      update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, max_sweeps, 0.0, 1);
      EXPECT_LT((N.rowwise().norm().array() - 1.0).abs().maxCoeff(), 1e-14);
      // And they moved: the start was not a fixed point.
      EXPECT_GT((N - c.N).cwiseAbs().maxCoeff(), 1e-3);
    }
  }
}

TEST(NormalsStep, RunsExactlyTheSweepsAsked) {
  const Case c = make_case("icosphere", test::make_icosphere(2));
  for (const int max_sweeps : {0, 1, 2, 7}) {
    SCOPED_TRACE(max_sweeps);
    RowPositions N = c.N;
    Quats rotations = identities(c.topology.vertex_count);
    // Tolerance 0: no change is ever "below" it, so the budget is what stops the iteration.
    EXPECT_EQ(update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, max_sweeps, 0.0, 1),
              max_sweeps);
    if (max_sweeps == 0) {
      EXPECT_EQ(N, c.N);  // untouched
    }
  }
  // k sweeps in one call are k calls of one sweep each (warm after the first).
  RowPositions N_once = c.N, N_steps = c.N;
  Quats r_once = identities(c.topology.vertex_count), r_steps = r_once;
  update_normals(c.N0, c.mesh.F, c.topology, N_once, r_once, false, 4, 0.0, 1);
  for (int k = 0; k < 4; ++k) {
    update_normals(c.N0, c.mesh.F, c.topology, N_steps, r_steps, k > 0, 1, 0.0, 1);
  }
  EXPECT_EQ(N_once, N_steps);
  // A tolerance larger than any change of a unit vector (2) stops after the first sweep.
  RowPositions N = c.N;
  Quats rotations = identities(c.topology.vertex_count);
  EXPECT_EQ(update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, 50, 2.5, 1), 1);
}

TEST(NormalsStep, StopsOnTolerance) {
  const Case c = make_case("icosphere", test::make_icosphere(2));
  RowPositions N = c.N;
  Quats rotations = identities(c.topology.vertex_count);
  const int sweeps =
      update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, 10000, 1e-10, 1);
  EXPECT_GT(sweeps, 1);
  EXPECT_LT(sweeps, 10000);
  // One more sweep moves no normal by the tolerance or more.
  const RowPositions before = N;
  update_normals(c.N0, c.mesh.F, c.topology, N, rotations, true, 1, 0.0, 1);
  EXPECT_LT((N - before).rowwise().norm().maxCoeff(), 1e-10);
}

TEST(NormalsStep, EachSweepIsALocalRotationFitThenTheGlobalStep) {
  for (const Case& c : cases()) {
    SCOPED_TRACE(c.name);
    RowPositions N = c.N;
    Quats rotations = identities(c.topology.vertex_count);
    for (int sweep = 0; sweep < 3; ++sweep) {
      SCOPED_TRACE(sweep);
      const RowPositions before = N;
      const Quats previous = rotations;
      update_normals(c.N0, c.mesh.F, c.topology, N, rotations, sweep > 0, 1, 0.0, 1);
      // Local, on B_v = sum over the fan of N_f N0_f^T with the normals the sweep started from:
      // a cold sweep takes Kabsch's rotation, the maximiser of trace(R^T B_v) (compared through
      // the objective: where B_v has rank < 2, a one-face fan, the maximiser is not unique); a
      // warm sweep refines the previous rotation a few steps, which must not lower the objective.
      for (int v = 0; v < c.topology.vertex_count; ++v) {
        const Eigen::Matrix3d B = fan_covariance(c, before, v);
        const double got = (rotations[v].toRotationMatrix().transpose() * B).trace();
        const double reference =
            sweep == 0 ? (kabsch_rotation(B).toRotationMatrix().transpose() * B).trace()
                       : (previous[v].toRotationMatrix().transpose() * B).trace();
        EXPECT_GT(got, reference - 1e-12) << "vertex " << v;
      }
      // Global (Eq. 11): N_f = normalize(sum over the corners v of f of R_v N0_f).
      for (int f = 0; f < c.topology.face_count; ++f) {
        Eigen::Vector3d sum = Eigen::Vector3d::Zero();
        for (int k = 0; k < 3; ++k) sum += rotations[c.mesh.F(f, k)] * c.N0.row(f).transpose();
        EXPECT_LT((sum.normalized() - N.row(f).transpose()).norm(), 1e-12) << "face " << f;
      }
    }
  }
}

TEST(NormalsStep, AWarmSweepRefinesEveryRotationAsTheScalarIterationDoes) {
  // update_normals refines the fans' rotations several at a time (independent lanes side by
  // side); each must be what refine_rotation gives for that fan alone, including the fans left
  // over when the vertex count is not a multiple of the batch.
  bool remainder_seen = false;
  for (const Case& c : cases()) {
    SCOPED_TRACE(c.name);
    remainder_seen = remainder_seen || c.topology.vertex_count % 4 != 0;
    RowPositions N = c.N;
    Quats rotations = identities(c.topology.vertex_count);
    update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, 1, 0.0, 1);
    for (int sweep = 0; sweep < 3; ++sweep) {
      SCOPED_TRACE(sweep);
      const RowPositions before = N;
      Quats expected = rotations;
      for (int v = 0; v < c.topology.vertex_count; ++v) {
        refine_rotation(fan_covariance(c, before, v), expected[v], 3);
      }
      update_normals(c.N0, c.mesh.F, c.topology, N, rotations, true, 1, 0.0, 1);
      for (int v = 0; v < c.topology.vertex_count; ++v) {
        EXPECT_LT((rotations[v].coeffs() - expected[v].coeffs()).cwiseAbs().maxCoeff(), 1e-14)
            << "vertex " << v;
      }
    }
  }
  EXPECT_TRUE(remainder_seen);
}

TEST(NormalsStep, UnconstrainedItConvergesToARotationOfTheRestNormals) {
  // Step one alone has no constraint: its energy reaches zero exactly on the rotations of the
  // rest normals (one rotation for every vertex), and the iteration gets there.
  for (const Case& c : cases()) {
    SCOPED_TRACE(c.name);
    RowPositions N = c.N;
    Quats rotations = identities(c.topology.vertex_count);
    update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, 20000, 1e-14, 1);
    const Eigen::Matrix3d Q = kabsch_rotation((N.transpose() * c.N0).eval()).toRotationMatrix();
    ASSERT_GT((c.N - c.N0 * Q.transpose()).cwiseAbs().maxCoeff(), 0.5);  // it had far to go
    EXPECT_LT((N - c.N0 * Q.transpose()).cwiseAbs().maxCoeff(), 1e-6);
    EXPECT_LT(gauss_map_energy(c, N, rotations), 1e-10);
  }
}

TEST(NormalsStep, EnergyNeverIncreasesFromSweepToSweep) {
  for (const Case& c : cases()) {
    SCOPED_TRACE(c.name);
    RowPositions N = c.N;
    Quats rotations = identities(c.topology.vertex_count);
    // Before any sweep, the best rotations for the start normals (what the first sweep's Kabsch
    // step computes) give the reference energy.
    Quats start(c.topology.vertex_count);
    for (int v = 0; v < c.topology.vertex_count; ++v) {
      start[v] = kabsch_rotation(fan_covariance(c, N, v));
    }
    double previous = gauss_map_energy(c, N, start);
    const double initial = previous;
    for (int sweep = 0; sweep < 30; ++sweep) {
      update_normals(c.N0, c.mesh.F, c.topology, N, rotations, sweep > 0, 1, 0.0, 1);
      const double energy = gauss_map_energy(c, N, rotations);
      EXPECT_LE(energy, previous * (1 + 1e-12) + 1e-15) << "sweep " << sweep;
      previous = energy;
    }
    EXPECT_LT(previous, initial);
  }
}

TEST(NormalsStep, RotatingRestAndCurrentNormalsRotatesTheResult) {
  const Eigen::Matrix3d Q = skew_rotation();
  for (const Case& c : cases()) {
    SCOPED_TRACE(c.name);
    RowPositions N = c.N;
    Quats rotations = identities(c.topology.vertex_count);
    update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, 6, 0.0, 1);

    // Both rotated: the problem is the same one seen in a rotated frame.
    const RowPositions N0_rotated = c.N0 * Q.transpose();
    RowPositions N_both = c.N * Q.transpose();
    Quats r_both = identities(c.topology.vertex_count);
    update_normals(N0_rotated, c.mesh.F, c.topology, N_both, r_both, false, 6, 0.0, 1);
    EXPECT_LT((N_both - N * Q.transpose()).cwiseAbs().maxCoeff(), 1e-10);

    // Only the current normals rotated: every R_v picks up Q on the left, so the result does too.
    RowPositions N_left = c.N * Q.transpose();
    Quats r_left = identities(c.topology.vertex_count);
    update_normals(c.N0, c.mesh.F, c.topology, N_left, r_left, false, 6, 0.0, 1);
    EXPECT_LT((N_left - N * Q.transpose()).cwiseAbs().maxCoeff(), 1e-10);
  }
}

TEST(NormalsStep, IsDeterministicAcrossRunsAndThreadCounts) {
  // Above 2000 vertices the loops run in parallel when threads > 1.
  const Case c = make_case("icosphere_2562", test::make_icosphere(4));
  ASSERT_GT(c.topology.vertex_count, 2000);
  auto run = [&](int threads) {
    RowPositions N = c.N;
    Quats rotations = identities(c.topology.vertex_count);
    const int sweeps =
        update_normals(c.N0, c.mesh.F, c.topology, N, rotations, false, 8, 1e-9, threads);
    return std::make_pair(sweeps, N);
  };
  const auto first = run(1);
  const auto again = run(1);
  const auto parallel = run(2);
  EXPECT_EQ(first.first, again.first);
  EXPECT_EQ(first.first, parallel.first);
  EXPECT_EQ(first.second, again.second);
  EXPECT_EQ(first.second, parallel.second);
}

TEST(Rotations, KabschRecoversTheRotationOfAPolarDecomposition) {
  std::mt19937 rng(7);
  std::normal_distribution<double> gauss;
  for (int trial = 0; trial < 20; ++trial) {
    const Eigen::Quaterniond q_true =
        Eigen::Quaterniond(gauss(rng), gauss(rng), gauss(rng), gauss(rng)).normalized();
    Eigen::Matrix3d M;
    for (int i = 0; i < 9; ++i) M(i / 3, i % 3) = gauss(rng);
    const Eigen::Matrix3d S = M * M.transpose() + 0.1 * Eigen::Matrix3d::Identity();  // SPD
    const Eigen::Matrix3d B = q_true.toRotationMatrix() * S;
    const Eigen::Matrix3d R = kabsch_rotation(B).toRotationMatrix();
    EXPECT_LT((R - q_true.toRotationMatrix()).norm(), 1e-10);
    // Warm-started 0.3 rad away (its documented use), the cheap iteration reaches it too.
    Eigen::Quaterniond q =
        q_true * Eigen::Quaterniond(Eigen::AngleAxisd(
                     0.3, Eigen::Vector3d(gauss(rng), gauss(rng), gauss(rng)).normalized()));
    refine_rotation(B, q, 200);
    EXPECT_LT((q.toRotationMatrix() - R).norm(), 1e-7) << "trial " << trial;
  }
}

TEST(Rotations, KabschIsAProperRotationMaximisingTheTrace) {
  std::mt19937 rng(11);
  std::normal_distribution<double> gauss;
  for (int trial = 0; trial < 20; ++trial) {
    Eigen::Matrix3d B;
    for (int i = 0; i < 9; ++i) B(i / 3, i % 3) = gauss(rng);
    if (trial % 2 == 0 && B.determinant() > 0) B.col(0) *= -1.0;  // half with det B < 0
    const Eigen::Matrix3d R = kabsch_rotation(B).toRotationMatrix();
    EXPECT_NEAR(R.determinant(), 1.0, 1e-12);
    EXPECT_LT((R.transpose() * R - Eigen::Matrix3d::Identity()).norm(), 1e-12);
    const double best = (R.transpose() * B).trace();
    for (int k = 0; k < 200; ++k) {
      const Eigen::Matrix3d other =
          Eigen::Quaterniond(gauss(rng), gauss(rng), gauss(rng), gauss(rng))
              .normalized()
              .toRotationMatrix();
      EXPECT_LE((other.transpose() * B).trace(), best + 1e-12);
    }
  }
}

}  // namespace
}  // namespace meshdeform::core
