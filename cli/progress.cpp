#include "cli/progress.h"

#include <unistd.h>

#include <algorithm>
#include <cstring>
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

void ProgressPrinter::enter(const char* phase) {
  if (phase_ != nullptr && std::strcmp(phase_, phase) != 0) {
    if (style_ == ProgressStyle::Bar && has_drawn_) {
      // The phase is over: complete its bar, keep its line.
      draw(phase_, 1.0, last_text_, last_seconds_);
      std::fputc('\n', stream_);
    }
    has_drawn_ = false;
    level_iterations_ = 0;
  }
  phase_ = phase;
}

void ProgressPrinter::draw(const char* phase, double fraction, const std::string& text,
                           double seconds) {
  constexpr int kWidth = 30;
  const int done = std::clamp(static_cast<int>(fraction * kWidth + 1e-9), 0, kWidth);
  const std::string bar = std::string(static_cast<size_t>(done), '#') +
                          std::string(static_cast<size_t>(kWidth - done), '.');
  // \r and clear-to-end-of-line redraw the same terminal line.
  std::fprintf(stream_, "\r%s  %-6s [%s] %s  %.2f s\033[K", label_.c_str(), phase, bar.c_str(),
               text.c_str(), seconds);
  std::fflush(stream_);
  has_drawn_ = true;
  last_text_ = text;
  last_seconds_ = seconds;
}

void ProgressPrinter::update_build(std::string_view phase, double fraction) {
  if (style_ == ProgressStyle::None) return;
  const double seconds = std::chrono::duration<double>(Clock::now() - created_).count();
  if (fraction >= 1.0) setup_seconds_ = seconds;
  enter("setup");
  if (style_ == ProgressStyle::Lines) {
    if (fraction <= 0.0 || fraction >= 1.0) {
      std::fprintf(stream_, "%s: setup %.*s %s  %.3f s\n", label_.c_str(),
                   static_cast<int>(phase.size()), phase.data(),
                   fraction <= 0.0 ? "started" : "done", seconds);
      std::fflush(stream_);
    }
    return;
  }
  char text[96];
  std::snprintf(text, sizeof text, "%-17.*s %3d%%", static_cast<int>(std::min<size_t>(phase.size(), 17)),
                phase.data(), static_cast<int>(fraction * 100.0 + 0.5));
  // The precompute's phases run one after the other; the bar shows the current one.
  draw("setup", fraction, text, seconds);
}

void ProgressPrinter::update(const core::IterationInfo& info) {
  if (style_ == ProgressStyle::None) return;
  const char* phase = core::solve_phase_name(info.phase);
  enter(phase);
  if (info.phase != core::SolvePhase::Fine) {
    levels_ = std::max(levels_, info.level + 1);
    if (info.iteration > 0) ++level_iterations_;
  }
  // Solve times count from the solve's start; the setup before it is added so that the bar's
  // clock is the run's.
  const double seconds = setup_seconds_ + info.elapsed_seconds;
  if (style_ == ProgressStyle::Lines) {
    if (info.phase == core::SolvePhase::Fine) {
      std::fprintf(stream_,
                   "%s: %s iteration %d  energy %.6g  E_theta %.6g  E_phi %.6g  pcg %d  sweeps "
                   "%d%s  %.3f s\n",
                   label_.c_str(), phase, info.iteration, info.energy, info.e_theta, info.e_phi,
                   info.pcg_iterations, info.normal_sweeps, info.refactored ? "  refactored" : "",
                   seconds);
    } else {
      std::fprintf(stream_, "%s: %s level %d (%d vertices) iteration %d  energy %.6g  %.3f s\n",
                   label_.c_str(), phase, info.level, info.level_vertices, info.iteration,
                   info.energy, seconds);
    }
    std::fflush(stream_);
    return;
  }
  char text[160];
  if (info.phase == core::SolvePhase::Fine) {
    const double fraction = static_cast<double>(info.iteration) / max_iterations_;
    std::snprintf(text, sizeof text, "%d/%d  E_theta %.4g  E_phi %.4g", info.iteration,
                  max_iterations_, info.e_theta, info.e_phi);
    draw(phase, std::min(fraction, 1.0), text, seconds);
    return;
  }
  // Start and levels run their levels coarsest first: the fraction is the levels finished.
  // The start covers every level down to full resolution (level 0), the levels phase the
  // coarse ones (down to level 1).
  const int total = info.phase == core::SolvePhase::Start ? levels_ : std::max(levels_ - 1, 1);
  const int finished = levels_ - 1 - info.level;
  std::snprintf(text, sizeof text, "level %d/%d (%d vertices), %s iteration %d", finished + 1,
                total, info.level_vertices,
                info.phase == core::SolvePhase::Start ? "ARAP" : "scale-aware", info.iteration);
  draw(phase, static_cast<double>(finished) / total, text, seconds);
}

void ProgressPrinter::finish() {
  if (style_ == ProgressStyle::Bar && has_drawn_) {
    std::fputc('\n', stream_);
    std::fflush(stream_);
  }
  has_drawn_ = false;
  phase_ = nullptr;
}

core::ProgressCallback ProgressPrinter::callback() {
  return [this](const core::IterationInfo& info) { update(info); };
}

core::BuildProgress ProgressPrinter::build_callback() {
  return [this](std::string_view phase, double fraction) { update_build(phase, fraction); };
}

}  // namespace meshdeform::cli
