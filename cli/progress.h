#pragma once
/// @file progress.h
/// Solver progress on stderr: a bar per phase when stderr is a terminal, one plain line per
/// outer iteration when asked for (--verbose), nothing otherwise.
///
/// Phases, in order: "setup" (the precompute: the hierarchy's decimation, prolongations,
/// factorizations), then for a multilevel solve (core/multires/multilevel.h) "start" (the rigid start's
/// ARAP on every level), "levels" (the scale-aware iteration on the coarse levels) and "fine"
/// (full resolution); a single-level solve shows "setup", "start" when it has a rigid start
/// (its ARAP iterations on the one level) and "fine". On a terminal each phase redraws one line and
/// leaves it complete when the next phase begins, so a finished run shows one line per phase.

#include <chrono>
#include <cstdio>
#include <string>
#include <string_view>

#include "core/methods/deform_types.h"

namespace meshdeform::cli {

/// How progress is shown.
enum class ProgressStyle { None, Bar, Lines };

/// Bar when stderr is a terminal; Lines when `is_verbose` and stderr is not a terminal; else None.
ProgressStyle choose_progress_style(bool is_verbose);

/// Prints solver progress; pass build_callback() to make_deformer, callback() to the solve,
/// and call finish() after.
class ProgressPrinter {
 public:
  /// @param[in] style           how to print.
  /// @param[in] max_iterations  the full-resolution outer-iteration budget (the fine bar).
  /// @param[in] label           shown before the bar, e.g. the mesh name.
  ProgressPrinter(ProgressStyle style, int max_iterations, std::string label,
                  std::FILE* stream = stderr);

  /// Records one precompute report (core::BuildProgress).
  void update_build(std::string_view phase, double fraction);
  /// Records one outer iteration (of any phase and level).
  void update(const core::IterationInfo& info);
  /// Ends the bar line (no-op for the other styles).
  void finish();
  /// Callbacks bound to this printer (which must outlive the solve).
  core::ProgressCallback callback();
  core::BuildProgress build_callback();

 private:
  using Clock = std::chrono::steady_clock;
  /// Draws one phase line: a bar of `fraction` and a free text.
  void draw(const char* phase, double fraction, const std::string& text, double seconds);
  /// Ends the current line when `phase` is another one.
  void enter(const char* phase);

  ProgressStyle style_;
  int max_iterations_;
  std::string label_;
  std::FILE* stream_;
  bool has_drawn_ = false;
  const char* phase_ = nullptr;   // the phase of the line drawn last
  Clock::time_point created_ = Clock::now();
  double setup_seconds_ = 0;      // the precompute's duration, once it ended
  int levels_ = 0;                // levels of a multilevel solve (the coarsest level + 1)
  int level_iterations_ = 0;      // iterations so far in this phase (start: ARAP, levels: scale-aware)
  std::string last_text_;         // the last line's text and time, to complete it on leaving
  double last_seconds_ = 0;
};

}  // namespace meshdeform::cli
