#include "cli/progress.h"

#include <unistd.h>

#include <algorithm>
#include <utility>

namespace meshdeform::cli {

ProgressStyle choose_progress_style(bool is_verbose) {
  if (isatty(STDERR_FILENO) != 0) return ProgressStyle::Bar;
  return is_verbose ? ProgressStyle::Lines : ProgressStyle::None;
}

ProgressPrinter::ProgressPrinter(ProgressStyle style, int max_iterations, std::string label,
                                 std::FILE* stream)
    : style_(style),
      max_iterations_(std::max(max_iterations, 1)),
      label_(std::move(label)),
      stream_(stream) {}

void ProgressPrinter::update(const core::IterationInfo& info) {
  switch (style_) {
    case ProgressStyle::None:
      return;
    case ProgressStyle::Lines:
      std::fprintf(stream_,
                   "%s: iteration %d  energy %.6g  E_theta %.6g  E_phi %.6g  pcg %d  sweeps %d%s  "
                   "%.3f s\n",
                   label_.c_str(), info.iteration, info.energy, info.e_theta, info.e_phi,
                   info.pcg_iterations, info.normal_sweeps, info.refactored ? "  refactored" : "",
                   info.elapsed_seconds);
      std::fflush(stream_);
      return;
    case ProgressStyle::Bar: {
      constexpr int kWidth = 30;
      const int done = std::clamp(info.iteration * kWidth / max_iterations_, 0, kWidth);
      const std::string bar = std::string(static_cast<size_t>(done), '#') +
                              std::string(static_cast<size_t>(kWidth - done), '.');
      // \r and clear-to-end-of-line redraw the same terminal line.
      std::fprintf(stream_, "\r%s [%s] %d/%d  E_theta %.4g  E_phi %.4g  %.2f s\033[K",
                   label_.c_str(), bar.c_str(), info.iteration, max_iterations_, info.e_theta,
                   info.e_phi, info.elapsed_seconds);
      std::fflush(stream_);
      has_drawn_ = true;
      return;
    }
  }
}

void ProgressPrinter::finish() {
  if (style_ == ProgressStyle::Bar && has_drawn_) {
    std::fputc('\n', stream_);
    std::fflush(stream_);
  }
  has_drawn_ = false;
}

core::ProgressCallback ProgressPrinter::callback() {
  return [this](const core::IterationInfo& info) { update(info); };
}

}  // namespace meshdeform::cli
