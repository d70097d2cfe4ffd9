#pragma once
/// @file curve2d_svg.h
/// The comparison figure of 2D curve editing (paper Fig. 9): the rest curve and each method's
/// result side by side, as one self-contained SVG document.

#include <string>
#include <vector>

#include "core/curves/curve2d.h"

namespace meshdeform::core {

/// One panel of the comparison figure.
struct CurvePanel {
  std::string title;   ///< e.g. "ARAP"
  Points2 P;           ///< #P x 2 positions (same connectivity as the edit's rest curve)
  double e_theta = 0;  ///< printed in the caption
};

/// A self-contained SVG (Fig. 9-like): the rest curve with its fixed points in green and the
/// handle in red (at rest, with an arrow to its target), then one panel per result side by side
/// with the constrained targets marked and "E_theta = ... rad" in the caption. All panels share
/// one scale. Every curve is one <polyline> element: 1 + panels.size() in all.
/// @param[in] edit    the edit (rest curve, constrained points, targets).
/// @param[in] panels  the results to draw.
/// @return the SVG document text.
std::string curve_comparison_svg(const CurveEdit& edit, const std::vector<CurvePanel>& panels);

}  // namespace meshdeform::core
