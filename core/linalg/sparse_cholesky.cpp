#include "core/linalg/sparse_cholesky.h"

#include <mutex>
#include <string>

#include <Eigen/CholmodSupport>

// OpenBLAS's own thread pool, when CHOLMOD's BLAS is OpenBLAS (weak: absent with other BLAS).
extern "C" void openblas_set_num_threads(int) __attribute__((weak));

namespace meshdeform::core {
namespace {

// Every solve here is a sequence of small triangular solves (one PCG step each), where BLAS
// threads only contend with the caller's threads: on a 2-core machine they made step two 4x
// slower. Parallelism belongs to the caller (OpenMP loops, or many sessions on a worker pool).
void use_single_threaded_blas() {
  static std::once_flag once;
  std::call_once(once, [] {
    if (openblas_set_num_threads != nullptr) openblas_set_num_threads(1);
  });
}

// Eigen keeps the CHOLMOD factor protected; the conversion needs it.
class SupernodalLlt : public Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> {
 public:
  /// A: the matrix just factored.
  bool to_simplicial(const SparseMatrix& A) {
    if (m_cholmodFactor == nullptr) return false;
    cholmod_sparse view = Eigen::viewAsCholmod(A.selfadjointView<Eigen::Lower>());
    return supernodal_to_simplicial(m_cholmodFactor, &view, &cholmod());
  }
  bool is_simplicial() const { return m_cholmodFactor != nullptr && !m_cholmodFactor->is_super; }
  // Simplicial LL' when the analysis finds fewer than `switch_flops` flops per factor entry,
  // supernodal otherwise (CHOLMOD_AUTO); a supernodal factor stays supernodal.
  void choose_simplicial_below(double switch_flops) {
    cholmod_common& c = cholmod();
    c.supernodal = CHOLMOD_AUTO;
    c.supernodal_switch = switch_flops;
    c.final_asis = 0;
    c.final_super = 1;
    c.final_ll = 1;
    c.final_pack = 1;
    c.final_monotonic = 1;
  }
  void always_supernodal() {
    cholmod_common& c = cholmod();
    c.supernodal = CHOLMOD_SUPERNODAL;
    c.final_asis = 1;
  }
};

}  // namespace

bool supernodal_to_simplicial(cholmod_factor* factor, cholmod_sparse* A, cholmod_common* common) {
  if (!factor->is_super) return true;
  MD_ASSERT(factor->itype == CHOLMOD_INT && factor->xtype == CHOLMOD_REAL);
  if (cholmod_change_factor(CHOLMOD_REAL, /*to_ll=*/1, /*to_super=*/0, /*to_packed=*/1,
                            /*to_monotonic=*/1, factor, common) == 0) {
    return false;
  }
  // The symbolic pattern of A's factor again (what cholmod_factorize's final_resymbol does):
  // the relaxed supernodes' zeros go, entries that are zero by exact cancellation stay. The
  // simplicial solves rely on the pattern (they treat two adjacent columns with nested patterns
  // as one block), so dropping entries by value would give wrong solutions.
  if (cholmod_resymbol(A, nullptr, 0, /*pack=*/1, factor, common) == 0) return false;
  // Give back the dropped entries' share of the arrays (the conversion wrote them, so they are
  // resident).
  const auto* nz = static_cast<const int*>(factor->nz);
  size_t entries = 0;
  for (size_t j = 0; j < factor->n; ++j) entries += static_cast<size_t>(nz[j]);
  return cholmod_reallocate_factor(entries, factor, common) != 0;
}

struct SparseCholesky::Impl {
  SupernodalLlt llt;
  bool simplicial_solves = false;
  bool converted = false;  // a supernodal factor changed to simplicial: refactoring needs analysis
  bool analyzed = false;
  bool factorized = false;
  double factor_flops = 0;
  double lnz = 0;
};

SparseCholesky::SparseCholesky() : impl_(std::make_unique<Impl>()) { use_single_threaded_blas(); }
SparseCholesky::SparseCholesky(SparseCholesky&&) noexcept = default;
SparseCholesky& SparseCholesky::operator=(SparseCholesky&&) noexcept = default;
SparseCholesky::~SparseCholesky() = default;

Status SparseCholesky::analyze(const SparseMatrix& A) {
  if (impl_->simplicial_solves) {
    impl_->llt.choose_simplicial_below(kSimplicialFlopsPerEntry);
  } else {
    impl_->llt.always_supernodal();
  }
  impl_->converted = false;
  impl_->llt.analyzePattern(A);
  if (impl_->llt.info() != Eigen::Success) {
    return Error(ErrorCode::NumericalFailure, "symbolic analysis of a " + std::to_string(A.rows()) +
                                                  " x " + std::to_string(A.cols()) +
                                                  " system failed");
  }
  impl_->analyzed = true;
  impl_->factorized = false;
  impl_->factor_flops = impl_->llt.cholmod().fl;
  impl_->lnz = impl_->llt.cholmod().lnz;
  return Status::success();
}

Status SparseCholesky::factorize(const SparseMatrix& A) {
  // A converted factor would be refactored simplicially, slowly for a dense one: analyse again.
  if (!impl_->analyzed || impl_->converted) MD_RETURN_IF_ERROR(analyze(A));
  impl_->llt.factorize(A);
  impl_->factorized = impl_->llt.info() == Eigen::Success;
  if (!impl_->factorized) {
    return Error(ErrorCode::NumericalFailure,
                 "Cholesky factorization of a " + std::to_string(A.rows()) + " x " +
                     std::to_string(A.cols()) + " system failed (matrix not positive definite)");
  }
  if (impl_->simplicial_solves && !impl_->llt.is_simplicial()) {
    if (!impl_->llt.to_simplicial(A)) {
      impl_->factorized = false;
      return Error(ErrorCode::Internal, "converting the Cholesky factor of a " +
                                            std::to_string(A.rows()) + " x " +
                                            std::to_string(A.cols()) + " system failed");
    }
    impl_->converted = true;
  }
  // CHOLMOD keeps the factorization's workspace (Flag, Head, Iwork, Xwork: about 40 B per row)
  // in the Common for the next call; the solves need none of it, and a later analysis or
  // factorization allocates it again. Spot 47k: 4.7 MB over the three factors of a solver.
  cholmod_free_work(&impl_->llt.cholmod());
  return Status::success();
}

void SparseCholesky::set_simplicial_solves(bool on) { impl_->simplicial_solves = on; }

Eigen::MatrixXd SparseCholesky::solve(const Eigen::MatrixXd& b) const {
  MD_ASSERT(impl_->factorized);
  return impl_->llt.solve(b);
}

bool SparseCholesky::is_factorized() const { return impl_->factorized; }
bool SparseCholesky::factored_simplicially() const {
  return impl_->factorized && impl_->llt.is_simplicial() && !impl_->converted;
}
double SparseCholesky::factor_flops() const { return impl_->factor_flops; }
double SparseCholesky::solve_flops() const { return 4.0 * impl_->lnz; }

}  // namespace meshdeform::core
