#include "core/methods/scale_aware.h"

#include "core/methods/scale_aware_impl.h"

namespace meshdeform::core {

using scale_aware_detail::seconds_since;

// Auto's cold start (solve()): another start's result replaces the best so far when it has
// fewer folds and at most this multiple of the rigid start's energy.
constexpr double kFoldFreeEnergyRatio = 1.5;

RowPositions ScaleAwareSolver::Impl::normals_of(const Eigen::VectorXd& pos,
                                                const RowPositions& fallback) const {
  RowPositions out(nf, 3);
  const bool parallel = nv > 2000 && threads > 1;
#pragma omp parallel for schedule(static) num_threads(threads) if (parallel)
  for (int f = 0; f < nf; ++f) {
    const Eigen::Vector3d a = pos.segment<3>(3 * F(f, 0));
    const Eigen::Vector3d n =
        (pos.segment<3>(3 * F(f, 1)) - a).cross(pos.segment<3>(3 * F(f, 2)) - a);
    const double len = n.norm();
    // A collapsed face has no normal: keep its previous one.
    if (len > 1e-300) {
      out.row(f) = (n / len).transpose();
    } else {
      out.row(f) = fallback.row(f);
    }
  }
  return out;
}

ScaleAwareSolver::ScaleAwareSolver(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ScaleAwareSolver::ScaleAwareSolver(ScaleAwareSolver&&) noexcept = default;
ScaleAwareSolver& ScaleAwareSolver::operator=(ScaleAwareSolver&&) noexcept = default;
ScaleAwareSolver::~ScaleAwareSolver() = default;

Result<ScaleAwareSolver> ScaleAwareSolver::create(const Positions& V0, const Triangles& F,
                                                  const Eigen::VectorXi& constrained,
                                                  const ScaleAwareSettings& settings,
                                                  std::stop_token stop,
                                                  const BuildProgress& progress) {
  auto impl = std::make_unique<Impl>();
  MD_RETURN_IF_ERROR(impl->build(V0, F, nullptr, constrained, settings, stop, progress));
  return ScaleAwareSolver(std::move(impl));
}

Result<ScaleAwareSolver> ScaleAwareSolver::create(const Positions& V0, const Triangles& F,
                                                  const MeshTopology& topology,
                                                  const Eigen::VectorXi& constrained,
                                                  const ScaleAwareSettings& settings,
                                                  std::stop_token stop,
                                                  const BuildProgress& progress) {
  MD_ASSERT(topology.vertex_count == V0.rows() && topology.face_count == F.rows());
  auto impl = std::make_unique<Impl>();
  MD_RETURN_IF_ERROR(impl->build(V0, F, &topology, constrained, settings, stop, progress));
  return ScaleAwareSolver(std::move(impl));
}

const Positions& ScaleAwareSolver::positions() const { return impl_->current; }

const Eigen::VectorXi& ScaleAwareSolver::constrained() const { return impl_->constrained; }

void ScaleAwareSolver::reset() {
  Impl& s = *impl_;
  s.x = Eigen::Map<const Eigen::VectorXd>(s.V0.data(), 3 * s.nv);
  s.current = s.V0;
  s.N = s.N0;
  s.rotations.assign(s.nv, Eigen::Quaterniond::Identity());
  s.rotations_warm = true;
  s.has_previous = false;
  s.carried_monitor.reset();
  s.carried_accelerator.reset();
}

Status ScaleAwareSolver::set_positions(const Positions& V) {
  Impl& s = *impl_;
  if (V.rows() != s.nv || !V.allFinite()) {
    return Error(ErrorCode::InvalidArgument,
                 "set_positions needs " + std::to_string(s.nv) + " finite rows, got " +
                     std::to_string(V.rows()) + (V.allFinite() ? "" : " with a non-finite value"));
  }
  const RowPositions rows = V;
  s.x = Eigen::Map<const Eigen::VectorXd>(rows.data(), 3 * s.nv);
  s.current = V;
  s.N = s.normals_of(s.x, s.N0);
  s.rotations.assign(s.nv, Eigen::Quaterniond::Identity());
  s.rotations_warm = false;
  s.has_previous = true;
  s.carried_monitor.reset();
  s.carried_accelerator.reset();
  return Status::success();
}

Status ScaleAwareSolver::prepare(double rigidity) {
  MD_RETURN_IF_ERROR(check_rigidity(rigidity));
  return impl_->prepare_rigidity(rigidity);
}

Result<ScaleAwareSolver::Impl::Candidate> ScaleAwareSolver::Impl::run_from(
    StartFrom from, const Positions& targets, const SolveOptions& options,
    const ProgressCallback& progress, const std::stop_token& stop, Clock::time_point start,
    const Candidate* state, bool until_fold_free) {
  Impl& s = *this;
  const double rho = options.rigidity;

  if (from == StartFrom::Paper) {
    // The paper's iteration first, until the Laplacian guess's folds are gone; then the
    // requested rigidity from that fold-free iterate.
    if (rho == 0) return run_from(StartFrom::Laplacian, targets, options, progress, stop, start);
    // The paper's own system: handle weight lambda and T's preconditioner (solve() prepares
    // every solve's rigidity anew, so an early return here leaves nothing wrong behind).
    SolveOptions paper = options;
    paper.rigidity = 0;
    MD_RETURN_IF_ERROR(prepare_rigidity(0));
    MD_ASSIGN_OR_RETURN(const Candidate first, run_from(StartFrom::Laplacian, targets, paper,
                                                        progress, stop, start, nullptr, true));
    MD_RETURN_IF_ERROR(prepare_rigidity(rho));
    MD_ASSIGN_OR_RETURN(Candidate second, run_from(StartFrom::Previous, targets, options,
                                                   progress, stop, start, &first));
    second.report.start = StartFrom::Paper;
    second.report.paper_iterations = first.report.iterations;
    return second;
  }

  // Work on copies: a cancelled or failed solve leaves the solver as it was.
  Eigen::VectorXd x = state != nullptr ? state->x : s.x;
  RowPositions N = state != nullptr ? state->N : s.N;
  std::vector<Eigen::Quaterniond> rotations = state != nullptr ? state->rotations : s.rotations;
  bool rotations_warm = state != nullptr ? state->rotations_warm : s.rotations_warm;

  if (from == StartFrom::Rigid) {
    if (!s.rigid_start) MD_RETURN_IF_ERROR(s.build_rigid_start());
    SolveOptions arap_options;
    arap_options.max_iterations = options.rigid_start_iterations;
    arap_options.tolerance = options.rigid_start_tolerance;
    arap_options.start = StartFrom::Laplacian;
    arap_options.track_metrics = false;
    // rigid_start_tolerance is a relative change (its documented meaning, measured so).
    arap_options.stopping_rule = StoppingRule::Change;
    // Its iterations are reported as the Start phase (level 0, this mesh): a progress display
    // sees the start, and a caller whose callback yields (the server's worker pool) yields
    // during it too, not only between the outer iterations after it.
    ProgressCallback start_progress;
    if (progress) {
      start_progress = [&progress, nv = s.nv, start](const IterationInfo& arap) {
        IterationInfo info = arap;
        info.phase = SolvePhase::Start;
        info.level = 0;
        info.level_vertices = nv;
        info.elapsed_seconds = seconds_since(start);
        progress(info);
      };
    }
    MD_ASSIGN_OR_RETURN(const SolveReport guess,
                        s.rigid_start->solve(targets, arap_options, start_progress, stop));
    // Auto's cold start: the cold solve releases the ARAP solver at its end anyway (solve());
    // free it now, so that its factor and arrays (Spot 47k: 32 MB) are not held beside the
    // scale-aware iterations and the other start candidates.
    if (options.start == StartFrom::Auto && !s.has_previous) s.rigid_start.reset();
    const RowPositions guess_rows = guess.V;
    x = Eigen::Map<const Eigen::VectorXd>(guess_rows.data(), 3 * s.nv);
    rotations_warm = false;
  }
  if (from == StartFrom::Propagated) {
    if (!s.propagated_start) {
      MD_ASSIGN_OR_RETURN(RotationPropagationStart built,
                          RotationPropagationStart::create(s.V0, s.F, s.topology, s.constrained,
                                                           s.settings.lambda));
      s.propagated_start.emplace(std::move(built));
    }
    MD_ASSIGN_OR_RETURN(Positions guess, s.propagated_start->guess(targets));
    const RowPositions guess_rows = guess;
    x = Eigen::Map<const Eigen::VectorXd>(guess_rows.data(), 3 * s.nv);
    rotations_warm = false;
  }
  if (from == StartFrom::Laplacian) {
    if (!s.laplacian) {  // ScaleAwareSettings::lazy_laplacian_guess
      MD_ASSIGN_OR_RETURN(LaplacianEditor editor,
                          LaplacianEditor::create(s.V0, s.F, s.topology, s.constrained,
                                                  LaplacianWeights::Cotangent, s.settings.lambda));
      s.laplacian.emplace(std::move(editor));
    }
    MD_ASSIGN_OR_RETURN(Positions guess, s.laplacian->solve(targets));
    const RowPositions guess_rows = guess;
    x = Eigen::Map<const Eigen::VectorXd>(guess_rows.data(), 3 * s.nv);
    rotations_warm = false;  // the guess may be far from the previous rotations
  }

  const Eigen::VectorXd b = s.rhs(targets);
  Eigen::VectorXd target_vec(3 * targets.rows());
  for (Eigen::Index j = 0; j < targets.rows(); ++j) {
    target_vec.segment<3>(3 * j) = targets.row(j).transpose();
  }
  auto record = [&](IterationInfo& info, const Eigen::VectorXd& pos) {
    if (options.track_metrics) {
      const Positions P = Eigen::Map<const RowPositions>(pos.data(), s.nv, 3);
      const AngleErrors errors = angle_errors(s.rest(), P, s.F, s.topology);
      info.e_theta = errors.e_theta;
      info.e_phi = errors.e_phi;
    }
    info.elapsed_seconds = seconds_since(start);
  };

  SolveReport report;
  // Energies are compared relative to the squared size of the mesh: a mesh that fits exactly
  // (identity or a similarity) reaches round-off, where relative changes mean nothing.
  const double scale2 = s.bbox_diagonal * s.bbox_diagonal;
  // The floor: an RMS corner residual of 1e-8 of the bounding box, where the solve's own
  // round-off (pcg_tolerance) leaves the energy fluctuating.
  // With scale control the term and the handle weight carry a factor (1 + rho), and so does the
  // round-off they leave.
  const double energy_floor = 1e-16 * scale2 * 3.0 * s.nf * (1.0 + rho);
  // The stopping rule (core/methods/convergence.h); its last relative change also sets step two's
  // inexact PCG tolerance below.
  ConvergenceMonitor monitor(options.stopping_rule, options.tolerance, energy_floor);
  const bool continues = from == StartFrom::Previous && state == nullptr && !until_fold_free &&
                         s.carried_monitor && s.carried_monitor->same_test(monitor) &&
                         s.carried_rho == rho && s.carried_targets.rows() == targets.rows() &&
                         s.carried_targets == targets;
  if (continues) {
    // The iterate is the last solve's result and its energy that solve's last: nothing to
    // measure again (0.17 s a solve at 187k vertices, a quarter of a 2-iteration slice).
    IterationInfo info;
    info.energy = s.carried_energy;
    info.energy_before = info.energy;
    record(info, x);
    report.history.push_back(info);
    if (progress) progress(info);
    monitor = *s.carried_monitor;  // the iterations before this solve count too
  } else {
    IterationInfo info;
    N = s.normals_of(x, N);
    s.assemble(N, rho);
    if (rho > 0) {
      // The scale variables are block minimisers of the current vertices: no state to carry.
      s.scale_control->reset();
      s.scale_control->set_reference(targets);
      s.scale_control->update_rotations(x, N);
      s.scale_control->update_scales(x);
    }
    info.energy = s.joint_energy(x, target_vec, rho);
    info.energy_before = info.energy;
    record(info, x);
    report.history.push_back(info);
    if (progress) progress(info);
    monitor.start(info.energy);
  }
  report.estimated_remaining = monitor.estimated_remaining();
  // A continuing solve also goes on with the last one's inexact PCG reduction.
  double previous_change = continues ? monitor.last_change() : 1.0;
  // Anderson acceleration of the outer iteration over the positions (core/linalg/anderson.h; Peng et
  // al. 2018): x -> G(x) is step one at x (normals, face frames, exact scale step) and step two.
  // Every G(x) has the same handle rows up to the soft constraint, and a mix of iterates is a
  // valid iterate. Merit, for the safeguard: the joint energy at x after its own step one and
  // scale step, a function of x alone (up to step one's warm start). An accelerated iterate whose
  // merit is not below the last accepted one is replaced by the plain update it was mixed from,
  // and the window restarts there (Peng et al., Algorithm 1). The first iteration is always the
  // plain one (a one-iteration interactive move is unchanged), and so is the returned iterate:
  // no mix is formed after the last iteration or once the tolerance is met.
  //
  // A solve that continues one which ended on its budget goes on with that one's window: it
  // forms the mix the longer solve would have formed after the returned iterate, so that short
  // solves in a row take the one long solve's steps.
  const bool accelerate = options.anderson_window > 0;
  AndersonAccelerator accelerator(std::max(options.anderson_window, 1));
  Eigen::VectorXd plain;          // G of the previous iterate, while x is an unchecked mix of it
  bool unchecked = false;         // x is an accelerated iterate whose merit is not yet known
  double accepted_merit = std::numeric_limits<double>::infinity();
  if (accelerate && continues && s.carried_accelerator &&
      s.carried_accelerator->window() == options.anderson_window && options.max_iterations > 0) {
    accelerator = *s.carried_accelerator;
    accepted_merit = s.carried_merit;
    plain = x;
    x = accelerator.compute(plain);
    unchecked = true;
  } else if (accelerate) {
    accelerator.reset(x);
  }
  bool budget_spent = false;  // the loop ran max_iterations without converging
  for (int it = 1; it <= options.max_iterations; ++it) {
    if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "solve cancelled");
    IterationInfo info;
    info.iteration = it;

    // Step one: normals from the current vertices, then local/global sweeps on the Gauss map;
    // then step two's matrix and, with scale control, the face frames that follow the normals
    // (R_f N0_f = N_f). Returns the iterate's energy with them: the block steps below (scales,
    // then PCG from x) can only lower it. Step one itself is not a minimiser of this energy (it
    // fits normals on the Gauss map), so energies of consecutive iterations are compared through
    // this value, not directly.
    // Also returns, in `merit`, the energy after the scale step (Anderson's safeguard): the
    // scale step leaves Eq. 12's part unchanged, so only the scale term is evaluated again.
    auto step_one = [&](double& merit) {
      auto phase = Clock::now();
      N = s.normals_of(x, N);
      info.normal_sweeps += update_normals(s.N0, s.F, s.topology, N, rotations, rotations_warm,
                                           options.inner_iterations, 1e-9, s.threads);
      rotations_warm = true;
      info.normals_seconds += seconds_since(phase);
      phase = Clock::now();
      s.assemble(N, rho);
      const double e12 = s.energy(x, target_vec);
      double energy_before = e12;
      merit = e12;
      if (rho > 0) {
        s.scale_control->update_rotations(x, N);
        energy_before += rho * s.scale_control->energy(x);
        // An exact scale step (a good warm start for the joint solve, never an increase).
        s.scale_control->update_scales(x);
        if (accelerate) merit += rho * s.scale_control->energy(x);
      }
      info.assemble_seconds += seconds_since(phase);
      return energy_before;
    };
    double merit = 0;
    info.energy_before = step_one(merit);
    if (accelerate) {
      if (unchecked && !(merit < accepted_merit)) {  // also rejects a non-finite mix
        x = plain;
        info.energy_before = step_one(merit);
        accelerator.reset(x);
        ++report.anderson_rejections;
      }
      accepted_merit = merit;
      unchecked = false;
    }

    // Step two: A(N) x = b by PCG with the cached factor, refactoring when that is cheaper.
    auto phase = Clock::now();
    const bool lagged = s.settings.preconditioner == StepTwoPreconditioner::LaggedCholesky;
    // With scale control, one thread solves the Schur complement (fewer steps, its two solves
    // one after the other); with the joint system's two solves side by side on two threads, the
    // joint system is faster (pcg_schur()).
    const bool schur = rho > 0 && !lagged && !s.side_by_side_solves();
    Eigen::VectorXd b_joint;  // the joint system's right-hand side (pcg_schur() forms its own)
    if (rho > 0 && !schur) {
      b_joint.resize(b.size() + s.scale_control->scale_unknowns());
      b_joint << b, rho * s.scale_control->scale_rhs();
    }
    info.assemble_seconds += seconds_since(phase);
    phase = Clock::now();
    if (lagged && s.refactor_pending) {
      MD_RETURN_IF_ERROR(s.cholesky.factorize(s.A));
      s.refactor_pending = false;
      info.refactored = true;
      ++report.factorizations;
    }
    // Inexact alternating minimisation: while the energy still moves a lot, reducing the
    // residual by a modest factor is enough; near convergence the reduction tightens.
    const double reduction =
        options.adaptive_pcg ? std::clamp(previous_change, 1e-8, 0.1) : 0.0;
    const double tolerance = options.pcg_tolerance;
    // Past this many steps a fresh factorization is cheaper than more lagged PCG: stop there,
    // refactor and finish (bounded waste instead of a fixed cap).
    // With scale control the lagged factor preconditions only the x block of the joint system,
    // so a refactorization cannot shorten the coupled part: no early stop there.
    const int max_pcg =
        lagged && rho == 0 ? std::clamp(static_cast<int>(s.settings.refactor_cost_ratio *
                                             s.cholesky.factor_flops() / s.pcg_iteration_flops),
                            4, 200)
               : 500;
    auto run_pcg = [&]() -> PcgOutcome {
      if (rho == 0) return s.pcg(b, x, reduction, tolerance, max_pcg, stop);
      if (schur) return s.pcg_schur(b, x, rho, reduction, tolerance, max_pcg, stop);
      Eigen::VectorXd joint(b_joint.size());
      joint << x, s.scale_control->scale_unknowns_vector();
      const PcgOutcome o = s.pcg_joint(b_joint, joint, rho, reduction, tolerance, max_pcg, stop);
      x = joint.head(x.size());
      s.scale_control->set_scale_unknowns(joint.tail(joint.size() - x.size()));
      return o;
    };
    PcgOutcome outcome = run_pcg();
    if (outcome.cancelled) return Error(ErrorCode::Cancelled, "solve cancelled");
    info.pcg_iterations = outcome.iterations;
    if (!outcome.converged && !lagged) {
      return Error(ErrorCode::NumericalFailure,
                   "step two did not converge at iteration " + std::to_string(it));
    }
    if (!outcome.converged) {
      // The lagged factor no longer preconditions well: refactor now and finish the solve.
      MD_RETURN_IF_ERROR(s.cholesky.factorize(s.A));
      info.refactored = true;
      ++report.factorizations;
      outcome = run_pcg();
      if (outcome.cancelled) return Error(ErrorCode::Cancelled, "solve cancelled");
      info.pcg_iterations += outcome.iterations;
      if (!outcome.converged) {
        return Error(ErrorCode::NumericalFailure,
                     "step two did not converge at iteration " + std::to_string(it));
      }
    }
    report.pcg_iterations += info.pcg_iterations;
    info.linear_seconds = seconds_since(phase);
    // Deterministic refactor rule, in flops: PCG that costs more than a fraction of a
    // factorization means the lagged factor has drifted too far from A(N).
    if (lagged && outcome.iterations * s.pcg_iteration_flops >
                      s.settings.refactor_cost_ratio * s.cholesky.factor_flops()) {
      s.refactor_pending = true;
    }
    if (!x.allFinite()) {
      return Error(ErrorCode::NumericalFailure,
                   "step two produced non-finite positions at iteration " + std::to_string(it));
    }

    info.energy = s.joint_energy(x, target_vec, rho);
    record(info, x);
    report.history.push_back(info);
    report.iterations = it;
    if (progress) progress(info);

    const bool converged = monitor.add(info.energy);
    previous_change = monitor.last_change();
    report.estimated_remaining = monitor.estimated_remaining();
    if (converged) {
      report.converged = true;
      break;
    }
    if (until_fold_free && s.folds_of(x) == 0) break;
    if (it == options.max_iterations) budget_spent = true;
    if (accelerate && it < options.max_iterations) {
      plain = x;
      x = accelerator.compute(plain);
      unchecked = true;
    }
  }

  report.start = from;
  Candidate candidate;
  candidate.report = std::move(report);
  candidate.x = std::move(x);
  candidate.N = std::move(N);
  candidate.rotations = std::move(rotations);
  candidate.rotations_warm = rotations_warm;
  candidate.monitor = monitor;
  if (accelerate && budget_spent) {
    candidate.accelerator = std::move(accelerator);
    candidate.merit = accepted_merit;
  }
  return candidate;
}

int ScaleAwareSolver::Impl::folds_of(const Eigen::VectorXd& pos) const {
  const Positions P = Eigen::Map<const RowPositions>(pos.data(), nv, 3);
  return count_folds(rest_phi, dihedral_angles(P, F, topology, threads));
}

Result<SolveReport> ScaleAwareSolver::solve(const Positions& targets, const SolveOptions& options,
                                            const ProgressCallback& progress,
                                            std::stop_token stop) {
  Impl& s = *impl_;
  const auto start = Clock::now();
  if (options.max_iterations < 0 || options.inner_iterations < 1 || !(options.tolerance >= 0) ||
      !(options.pcg_tolerance > 0) || options.rigid_start_iterations < 0 ||
      !(options.rigid_start_tolerance >= 0)) {
    return Error(ErrorCode::InvalidArgument,
                 "solve options out of range: max_iterations >= 0, inner_iterations >= 1, "
                 "tolerance >= 0, pcg_tolerance > 0, rigid_start_iterations >= 0 and "
                 "rigid_start_tolerance >= 0 are required");
  }
  MD_RETURN_IF_ERROR(check_targets(targets, s.constrained, s.topology, s.bbox_diagonal, true));
  if (options.face_scale.size() != 0) {
    if (options.face_scale.size() != s.nf) {
      return Error(ErrorCode::InvalidArgument,
                   "face_scale has " + std::to_string(options.face_scale.size()) +
                       " entries for " + std::to_string(s.nf) + " faces");
    }
    for (Eigen::Index f = 0; f < s.nf; ++f) {
      if (!(options.face_scale(f) > 0) || !std::isfinite(options.face_scale(f))) {
        return Error(ErrorCode::InvalidArgument, "face_scale of face " + std::to_string(f) +
                                                     " must be positive and finite");
      }
    }
  }
  MD_RETURN_IF_ERROR(check_rigidity(options.rigidity));
  if (options.lambda != s.settings.lambda) {
    return Error(ErrorCode::InvalidArgument,
                 "lambda is fixed when the solver is created (" + std::to_string(s.settings.lambda) +
                     "); got " + std::to_string(options.lambda));
  }

  const double rho = options.rigidity;
  MD_RETURN_IF_ERROR(s.prepare_rigidity(rho));

  // Auto's cold start: with scale control (rigidity > 0) ARAP run to convergence, whose basin the
  // scale-aware energy then refines (bench/results/rigidity_sweep.md: all three targets of issue
  // 12 on 12 of 12 edits at the default rigidity, against 9 of 12 from the Laplacian guess, which
  // leaves the 135-degree twists in a worse basin); at rigidity 0 the paper's own start, the
  // Laplacian guess (Section 5.2), so that rigidity 0 stays the paper's method.
  const bool cold = options.start == StartFrom::Auto && !s.has_previous;
  StartFrom from = options.start;
  if (from == StartFrom::Auto) {
    from = s.has_previous ? StartFrom::Previous : rho > 0 ? StartFrom::Rigid : StartFrom::Laplacian;
  }
  MD_ASSIGN_OR_RETURN(Impl::Candidate chosen,
                      s.run_from(from, targets, options, progress, stop, start));
  if (cold && rho > 0) {
    // Where converged ARAP creases (bent tubes: interior edges folded by more than 90 degrees
    // near the handles), the scale-aware iteration keeps its creases: they lower its energy, so
    // more iterations do not remove them. Then the result from the Laplacian guess is computed
    // too and, if the best result so far still has folds, the Paper start's (the paper's own
    // iteration until the Laplacian guess's folds are gone, then the rigidity: on the irregular
    // bent cylinder the Laplacian guess's result keeps 2 creases that the scale term set while
    // the guess's 64 folds were being removed). A candidate replaces the best one if it has fewer
    // folds at not much more energy than the rigid start's (or as many folds at less energy).
    // Measured on bench/results/rigidity_sweep.md's edits at rigidity 1-300: on the bent
    // cylinders the fold-free basin costs 0.77-1.31x the creased one's energy, on the Spot twist
    // the Laplacian guess's basin costs 2.1-2.6x (the worse basin of issue 12, E_theta above
    // converged ARAP's), hence kFoldFreeEnergyRatio. Where the rigid start folds nothing, nothing
    // else runs.
    chosen.report.folded_edges = s.folds_of(chosen.x);
    const double rigid_energy = chosen.report.history.back().energy;
    int candidates = 1;
    for (const StartFrom next : {StartFrom::Laplacian, StartFrom::Paper}) {
      if (chosen.report.folded_edges == 0) break;
      MD_ASSIGN_OR_RETURN(Impl::Candidate other,
                          s.run_from(next, targets, options, progress, stop, start));
      ++candidates;
      other.report.folded_edges = s.folds_of(other.x);
      const double energy = chosen.report.history.back().energy;
      const double other_energy = other.report.history.back().energy;
      const bool fewer = other.report.folded_edges < chosen.report.folded_edges &&
                         other_energy <= kFoldFreeEnergyRatio * rigid_energy;
      const bool tie_lower =
          other.report.folded_edges == chosen.report.folded_edges && other_energy < energy;
      if (fewer || tie_lower) chosen = std::move(other);
    }
    chosen.report.start_candidates = candidates;
  }
  SolveReport report = std::move(chosen.report);
  Eigen::VectorXd x = std::move(chosen.x);
  RowPositions N = std::move(chosen.N);
  std::vector<Eigen::Quaterniond> rotations = std::move(chosen.rotations);
  const bool rotations_warm = chosen.rotations_warm;

  report.V = Eigen::Map<const RowPositions>(x.data(), s.nv, 3);
  if (options.ora || options.face_scale.size() != 0) {
    // ORA / magnification (Section 5.3): the stitched mesh is what the caller gets; the solver
    // keeps its own iterate for warm starts, since the stitch is not a fixed point of it.
    const auto stitch_start = Clock::now();
    if (!s.stitcher) {
      MD_ASSIGN_OR_RETURN(RigidityStitcher built,
                          RigidityStitcher::create(s.V0, s.F, s.topology, s.constrained,
                                                   s.settings.lambda));
      s.stitcher.emplace(std::move(built));
    }
    MD_ASSIGN_OR_RETURN(Positions stitched,
                        s.stitcher->stitch(report.V, targets, options.face_scale));
    const AngleErrors before = angle_errors(s.rest(), report.V, s.F, s.topology);
    const AngleErrors after = angle_errors(s.rest(), stitched, s.F, s.topology);
    report.stitch = {true,           before.e_theta, before.e_phi, before.area_log_rms,
                     after.e_theta,  after.e_phi,    after.area_log_rms,
                     seconds_since(stitch_start)};
    report.V = std::move(stitched);
  }

  // Commit.
  s.x = x;
  s.N = N;
  s.rotations = std::move(rotations);
  s.rotations_warm = rotations_warm;
  s.has_previous = true;
  s.carried_monitor = std::move(chosen.monitor);
  s.carried_targets = targets;
  s.carried_rho = rho;
  s.carried_accelerator = std::move(chosen.accelerator);
  s.carried_merit = chosen.merit;
  s.carried_energy = report.history.back().energy;
  s.current = report.V;
  if (cold) {
    // Later Auto solves start from this result (Previous), so the cold start's solvers are
    // dead weight: the rigid start's ARAP solver (already freed after its guess where the
    // rigid start ran) and, where the start candidates built it, the Laplacian guess's editor
    // (Spot 47k: 32 and 66 MB). reset() makes the next Auto solve cold again, which builds
    // them anew (the rigid start's factorization is 0.1 s at 47k vertices; a cold solve runs up
    // to rigid_start_iterations ARAP iterations after it). Explicit starts keep what they
    // built.
    s.rigid_start.reset();
    s.laplacian.reset();
  }
  report.seconds = seconds_since(start);
  report.phases.start = report.history.empty() ? 0.0 : report.history.front().elapsed_seconds;
  report.phases.fine = report.seconds - report.phases.start;
  return report;
}

Result<SolveReport> deform_scale_aware(const Positions& V0, const Triangles& F,
                                       const Eigen::VectorXi& constrained, const Positions& targets,
                                       const SolveOptions& options,
                                       const ProgressCallback& progress) {
  ScaleAwareSettings settings;
  settings.lambda = options.lambda;
  MD_ASSIGN_OR_RETURN(ScaleAwareSolver solver,
                      ScaleAwareSolver::create(V0, F, constrained, settings));
  return solver.solve(targets, options, progress);
}

}  // namespace meshdeform::core
