#include "core/linalg/split_cholesky.h"

#include <cholmod.h>

#include <Eigen/Cholesky>
#include <Eigen/CholmodSupport>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <exception>
#include <numeric>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "core/mesh/median_split.h"

namespace meshdeform::core {
namespace {

/// Runs body(0) on the calling thread and body(1) on a second one; rethrows the first exception.
template <typename Body>
void on_two_threads(const Body& body) {
  std::exception_ptr failure;
  std::thread second([&] {
    try {
      body(1);
    } catch (...) {
      failure = std::current_exception();
    }
  });
  try {
    body(0);
  } catch (...) {
    second.join();
    throw;
  }
  second.join();
  if (failure) std::rethrow_exception(failure);
}

/// One CHOLMOD workspace for the duration of a call (so const solves may run concurrently).
struct Workspace {
  cholmod_common common{};
  Workspace() { cholmod_start(&common); }
  ~Workspace() { cholmod_finish(&common); }
  Workspace(const Workspace&) = delete;
  Workspace& operator=(const Workspace&) = delete;
};

}  // namespace

/// One half: M = [A_i B_i; B_i' D_i] over its interior (local 0..ni-1) and the separator
/// (local ni..ni+m-1), factored with the separator last.
struct SplitCholesky::Half {
  std::vector<int> interior;  // rows of A, ascending
  int m = 0;
  SparseMatrix M;  // lower triangle
  cholmod_common common{};
  cholmod_factor* factor = nullptr;
  Eigen::MatrixXd L33;         // trailing m x m block of the factor (lower triangular)
  Eigen::MatrixXd L33_L33t;    // L33 L33' (lower triangle), until the Schur complement is formed
  std::vector<int> sep_order;  // factor column ni + k holds separator unknown sep_order[k]

  Half() {
    cholmod_start(&common);
    common.print = 0;  // failures are returned (and the whole system factored instead)
  }
  ~Half() {
    if (factor != nullptr) cholmod_free_factor(&factor, &common);
    cholmod_finish(&common);
  }
  Half(const Half&) = delete;
  Half& operator=(const Half&) = delete;

  int ni() const { return static_cast<int>(interior.size()); }

  /// CAMD ordering with the separator last, LL' factor (supernodal, then kept in simplicial form
  /// for the solves), L33. False when M is not positive definite or CHOLMOD did not keep the
  /// separator last.
  bool factorize() {
    const int n = ni() + m;
    cholmod_sparse view = Eigen::viewAsCholmod(std::as_const(M).selfadjointView<Eigen::Lower>());
    std::vector<int> member(static_cast<size_t>(n), 0);
    std::fill(member.begin() + ni(), member.end(), 1);
    std::vector<int> perm(static_cast<size_t>(n));
    if (cholmod_camd(&view, nullptr, 0, member.data(), perm.data(), &common) == 0) return false;
    common.nmethods = 1;
    common.method[0].ordering = CHOLMOD_GIVEN;
    common.postorder = 0;  // a postorder could move trees of the interior after the separator
    // Supernodal (BLAS-3) then simplicial without the amalgamation's zeros: on Spot 187k's
    // prolongation halves (86k unknowns, 0.6-1.0 GFlop each) the numeric factorization took
    // 0.18-0.30 s against 0.27-0.54 s simplicially, the conversion 0.02 s, and the solves read
    // the same entries as the simplicial factor's.
    common.supernodal = CHOLMOD_SUPERNODAL;
    common.final_ll = 1;
    factor = cholmod_analyze_p(&view, perm.data(), nullptr, 0, &common);
    if (factor == nullptr) return false;
    cholmod_factorize(&view, factor, &common);
    if (common.status != CHOLMOD_OK || factor->minor != static_cast<size_t>(n) ||
        !supernodal_to_simplicial(factor, &view, &common) || factor->is_super ||
        !factor->is_ll) {
      return false;
    }
    const int* Perm = static_cast<const int*>(factor->Perm);
    const int* Lp = static_cast<const int*>(factor->p);
    const int* Li = static_cast<const int*>(factor->i);
    const int* Lnz = static_cast<const int*>(factor->nz);
    const double* Lx = static_cast<const double*>(factor->x);
    L33.setZero(m, m);
    sep_order.resize(static_cast<size_t>(m));
    for (int k = 0; k < m; ++k) {
      const int column = ni() + k;
      sep_order[static_cast<size_t>(k)] = Perm[column] - ni();
      if (Perm[column] < ni()) return false;
      for (int p = Lp[column]; p < Lp[column] + Lnz[column]; ++p) L33(Li[p] - ni(), k) = Lx[p];
    }
    L33_L33t.setZero(m, m);
    if (m > 0) L33_L33t.selfadjointView<Eigen::Lower>().rankUpdate(L33);  // (Eigen: no empties)
    return true;
  }

  /// Forward substitution of [b_I; 0]: returns y (n x k, factor order); g = B_i' A_i^-1 b_I in
  /// factor order of the separator.
  Eigen::MatrixXd forward(const Eigen::MatrixXd& b, Eigen::MatrixXd& g) const {
    const int n = ni() + m;
    const auto k = static_cast<int>(b.cols());
    const int* Perm = static_cast<const int*>(factor->Perm);
    Eigen::MatrixXd z(n, k);
    for (int c = 0; c < k; ++c) {
      for (int j = 0; j < n; ++j) {
        const int local = Perm[j];
        z(j, c) = local < ni() ? b(interior[static_cast<size_t>(local)], c) : 0.0;
      }
    }
    Workspace work;
    cholmod_dense view = Eigen::viewAsCholmod(z);
    cholmod_dense* y = cholmod_solve(CHOLMOD_L, factor, &view, &work.common);
    if (y == nullptr) throw std::bad_alloc();
    Eigen::MatrixXd out = Eigen::Map<const Eigen::MatrixXd>(static_cast<const double*>(y->x), n, k);
    cholmod_free_dense(&y, &work.common);
    g.setZero(m, k);
    if (m > 0) g.noalias() -= L33.triangularView<Eigen::Lower>() * out.bottomRows(m);
    return out;
  }

  /// Back substitution of [y_I; L33' x_S] into x's interior rows.
  void back(Eigen::MatrixXd& y, const Eigen::MatrixXd& x_separator_factor_order,
            Eigen::MatrixXd& x) const {
    const int n = ni() + m;
    const auto k = static_cast<int>(y.cols());
    if (m > 0) {
      y.bottomRows(m) = L33.triangularView<Eigen::Lower>().transpose() * x_separator_factor_order;
    }
    Workspace work;
    cholmod_dense view = Eigen::viewAsCholmod(y);
    cholmod_dense* w = cholmod_solve(CHOLMOD_Lt, factor, &view, &work.common);
    if (w == nullptr) throw std::bad_alloc();
    const auto* wx = static_cast<const double*>(w->x);
    const int* Perm = static_cast<const int*>(factor->Perm);
    for (int c = 0; c < k; ++c) {
      for (int j = 0; j < n; ++j) {
        const int local = Perm[j];
        if (local < ni())
          x(interior[static_cast<size_t>(local)], c) = wx[static_cast<size_t>(c) * n + j];
      }
    }
    cholmod_free_dense(&w, &work.common);
  }
};

struct SplitCholesky::Impl {
  SparseCholesky whole;
  bool split = false;
  bool factorized = false;
  std::unique_ptr<Half> halves[2];
  std::vector<int> separator;  // rows of A, ascending
  Eigen::LLT<Eigen::MatrixXd> schur;

  /// The split factorization; false (and nothing kept) when the system should be factored whole.
  Result<bool> try_split(const SparseMatrix& A, const Positions& points,
                         const SplitCholeskySettings& settings, const std::stop_token& stop);
};

Result<bool> SplitCholesky::Impl::try_split(const SparseMatrix& A, const Positions& points,
                                            const SplitCholeskySettings& settings,
                                            const std::stop_token& stop) {
  const auto n = static_cast<int>(A.rows());
  std::vector<int> all(static_cast<size_t>(n));
  std::iota(all.begin(), all.end(), 0);
  // 0, 1: the interiors; 2: the separator, side 0's unknowns with a neighbour on side 1.
  std::vector<std::uint8_t> part = median_sides(points, std::move(all));
  for (int v = 0; v < n; ++v) {
    if (part[static_cast<size_t>(v)] != 0) continue;
    for (SparseMatrix::InnerIterator e(A, v); e; ++e) {
      if (part[static_cast<size_t>(e.row())] == 1) {
        part[static_cast<size_t>(v)] = 2;
        break;
      }
    }
  }
  std::vector<int> local(static_cast<size_t>(n));
  halves[0] = std::make_unique<Half>();
  halves[1] = std::make_unique<Half>();
  for (int v = 0; v < n; ++v) {
    const auto p = part[static_cast<size_t>(v)];
    std::vector<int>& list = p == 2 ? separator : halves[p]->interior;
    local[static_cast<size_t>(v)] = static_cast<int>(list.size());
    list.push_back(v);
  }
  const auto m = static_cast<int>(separator.size());
  if (m > settings.max_separator || m > n / 16) return false;

  // The halves' lower triangles, the separator block C and the diagonals D_i.
  std::vector<Eigen::Triplet<double>> entries[2];
  Eigen::MatrixXd schur_matrix = Eigen::MatrixXd::Zero(m, m);
  Eigen::VectorXd coupling[2] = {Eigen::VectorXd::Zero(m), Eigen::VectorXd::Zero(m)};
  for (int c = 0; c < n; ++c) {
    const auto pc = part[static_cast<size_t>(c)];
    const int lc = local[static_cast<size_t>(c)];
    for (SparseMatrix::InnerIterator e(A, c); e; ++e) {
      const auto r = static_cast<int>(e.row());
      if (r < c) continue;
      const auto pr = part[static_cast<size_t>(r)];
      const int lr = local[static_cast<size_t>(r)];
      if (pr == 2 && pc == 2) {
        schur_matrix(lr, lc) = e.value();
        schur_matrix(lc, lr) = e.value();
        continue;
      }
      const int h = pr == 2 ? pc : pr;  // no entry couples the two interiors
      const int ni = halves[h]->ni();
      const int row = pr == 2 ? ni + lr : lr;
      const int col = pc == 2 ? ni + lc : lc;
      entries[h].emplace_back(std::max(row, col), std::min(row, col), e.value());
      if (pr == 2) coupling[h](lr) += std::abs(e.value());
      if (pc == 2) coupling[h](lc) += std::abs(e.value());
    }
  }
  for (int h = 0; h < 2; ++h) {
    Half& half = *halves[h];
    half.m = m;
    const int ni = half.ni();
    for (int k = 0; k < m; ++k) {
      const double d = coupling[h](k) > 0 ? 2 * coupling[h](k) : 1.0;
      entries[h].emplace_back(ni + k, ni + k, d);
      schur_matrix(k, k) -= d;
    }
    half.M.resize(ni + m, ni + m);
    half.M.setFromTriplets(entries[h].begin(), entries[h].end());
    half.M.makeCompressed();
    entries[h] = {};
  }
  if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "factorization cancelled");

  bool ok[2] = {false, false};
  on_two_threads([&](int h) {
    ok[h] = halves[h]->factorize();
    halves[h]->M = SparseMatrix();  // CHOLMOD's factor holds what the solves need
  });
  if (!ok[0] || !ok[1]) return false;
  if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "factorization cancelled");

  // Schur = C - sum D_i + sum L33_i L33_i' (in separator order).
  for (int h = 0; h < 2; ++h) {
    Half& half = *halves[h];
    for (int b = 0; b < m; ++b) {
      for (int a = b; a < m; ++a) {
        const int i = half.sep_order[static_cast<size_t>(a)];
        const int j = half.sep_order[static_cast<size_t>(b)];
        schur_matrix(i, j) += half.L33_L33t(a, b);
        if (i != j) schur_matrix(j, i) += half.L33_L33t(a, b);
      }
    }
    half.L33_L33t = Eigen::MatrixXd();
  }
  if (m == 0) return true;  // two components: nothing couples the halves
  schur.compute(schur_matrix);
  return schur.info() == Eigen::Success;
}

SplitCholesky::SplitCholesky() : impl_(std::make_unique<Impl>()) {}
SplitCholesky::SplitCholesky(SplitCholesky&&) noexcept = default;
SplitCholesky& SplitCholesky::operator=(SplitCholesky&&) noexcept = default;
SplitCholesky::~SplitCholesky() = default;

Status SplitCholesky::factorize(const SparseMatrix& A, const Positions& points,
                                const SplitCholeskySettings& settings,
                                const std::stop_token& stop) {
  MD_ASSERT(A.rows() == A.cols() && points.rows() == A.rows());
  impl_ = std::make_unique<Impl>();
  if (settings.threads >= 2 && A.rows() >= settings.min_rows && A.rows() >= 32) {
    MD_ASSIGN_OR_RETURN(const bool split, impl_->try_split(A, points, settings, stop));
    if (split) {
      impl_->split = true;
      impl_->factorized = true;
      return Status::success();
    }
    impl_ = std::make_unique<Impl>();
  }
  impl_->whole.set_simplicial_solves(true);
  MD_RETURN_IF_ERROR(impl_->whole.analyze(A));
  if (stop.stop_requested()) return Error(ErrorCode::Cancelled, "factorization cancelled");
  MD_RETURN_IF_ERROR(impl_->whole.factorize(A));
  impl_->factorized = true;
  return Status::success();
}

Eigen::MatrixXd SplitCholesky::solve(const Eigen::MatrixXd& b) const {
  MD_ASSERT(impl_->factorized);
  if (!impl_->split) return impl_->whole.solve(b);
  const Impl& s = *impl_;
  const auto m = static_cast<Eigen::Index>(s.separator.size());
  Eigen::MatrixXd y[2], g[2];
  on_two_threads([&](int h) { y[h] = s.halves[h]->forward(b, g[h]); });
  Eigen::MatrixXd rhs(m, b.cols());
  for (Eigen::Index k = 0; k < m; ++k) rhs.row(k) = b.row(s.separator[static_cast<size_t>(k)]);
  for (int h = 0; h < 2; ++h) {
    for (Eigen::Index k = 0; k < m; ++k) {
      rhs.row(s.halves[h]->sep_order[static_cast<size_t>(k)]) -= g[h].row(k);
    }
  }
  const Eigen::MatrixXd x_separator = m > 0 ? Eigen::MatrixXd(s.schur.solve(rhs)) : rhs;
  Eigen::MatrixXd x(b.rows(), b.cols());
  on_two_threads([&](int h) {
    const Half& half = *s.halves[h];
    Eigen::MatrixXd in_factor_order(m, b.cols());
    for (Eigen::Index k = 0; k < m; ++k) {
      in_factor_order.row(k) = x_separator.row(half.sep_order[static_cast<size_t>(k)]);
    }
    half.back(y[h], in_factor_order, x);
  });
  for (Eigen::Index k = 0; k < m; ++k)
    x.row(s.separator[static_cast<size_t>(k)]) = x_separator.row(k);
  return x;
}

bool SplitCholesky::is_factorized() const { return impl_->factorized; }
bool SplitCholesky::is_split() const { return impl_->split; }
int SplitCholesky::separator_size() const {
  return impl_->split ? static_cast<int>(impl_->separator.size()) : 0;
}

}  // namespace meshdeform::core
