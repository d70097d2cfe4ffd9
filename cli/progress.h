#pragma once
/// @file progress.h
/// Solver progress on stderr: a redrawn bar when stderr is a terminal, one plain line per outer
/// iteration when asked for (--verbose), nothing otherwise.

#include <cstdio>
#include <string>

#include "core/methods/deform_types.h"

namespace meshdeform::cli {

/// How progress is shown.
enum class ProgressStyle { None, Bar, Lines };

/// Bar when stderr is a terminal; Lines when `is_verbose` and stderr is not a terminal; else None.
ProgressStyle choose_progress_style(bool is_verbose);

/// Prints solver progress; pass `callback()` to ScaleAwareSolver::solve and call finish() after.
class ProgressPrinter {
 public:
  /// @param[in] style           how to print.
  /// @param[in] max_iterations  the outer-iteration budget (length of the bar).
  /// @param[in] label           shown before the bar, e.g. the mesh name.
  ProgressPrinter(ProgressStyle style, int max_iterations, std::string label,
                  std::FILE* stream = stderr);

  /// Records one outer iteration.
  void update(const core::IterationInfo& info);
  /// Ends the bar line (no-op for the other styles).
  void finish();
  /// A callback bound to this printer (which must outlive the solve).
  core::ProgressCallback callback();

 private:
  ProgressStyle style_;
  int max_iterations_;
  std::string label_;
  std::FILE* stream_;
  bool has_drawn_ = false;
};

}  // namespace meshdeform::cli
