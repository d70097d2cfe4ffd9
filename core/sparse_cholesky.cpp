#include "core/sparse_cholesky.h"

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

}  // namespace

struct SparseCholesky::Impl {
  Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> llt;
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
  if (!impl_->analyzed) MD_RETURN_IF_ERROR(analyze(A));
  impl_->llt.factorize(A);
  impl_->factorized = impl_->llt.info() == Eigen::Success;
  if (!impl_->factorized) {
    return Error(ErrorCode::NumericalFailure,
                 "Cholesky factorization of a " + std::to_string(A.rows()) + " x " +
                     std::to_string(A.cols()) + " system failed (matrix not positive definite)");
  }
  return Status::success();
}

Eigen::MatrixXd SparseCholesky::solve(const Eigen::MatrixXd& b) const {
  MD_ASSERT(impl_->factorized);
  return impl_->llt.solve(b);
}

bool SparseCholesky::is_factorized() const { return impl_->factorized; }
double SparseCholesky::factor_flops() const { return impl_->factor_flops; }
double SparseCholesky::solve_flops() const { return 4.0 * impl_->lnz; }

}  // namespace meshdeform::core
