#pragma once
/// @file curve_command.h
/// `meshdeform-cli curve`: the paper's 2D curve-editing example (Section 6.1, Fig. 9). Builds the
/// Koch curve, fixes both ends, pulls the middle point up, deforms it with Laplacian editing,
/// ARAP and the scale-aware method, and writes a side-by-side SVG figure and a JSON report.

#include <string>
#include <vector>

namespace meshdeform::cli {

/// Runs `meshdeform-cli curve` on the words after "curve".
/// @param[in] args  e.g. {"--koch", "4", "--svg", "fig9.svg"}.
/// @return 0 on success; 1 on a runtime error (a solve that fails, an output that cannot be
///         written or whose directory does not exist); 2 on a usage error (unknown or repeated
///         option, missing --koch or --svg, a level outside [1, 7], a non-finite --pull, a
///         --lambda that is not > 0, an --iterations outside [0, 100000]).
int run_curve(const std::vector<std::string>& args);

}  // namespace meshdeform::cli
