#pragma once
/// @file koch.h
/// The Koch curve, the test shape of the paper's 2D curve edit (Section 6.1, Fig. 9), and that
/// edit: both ends fixed, the apex of the central bump pulled up.

#include "core/curves/curve2d.h"
#include "core/base/status.h"

namespace meshdeform::core {

/// The Koch curve of a level: an open polyline from (0,0) to (1,0) with 4^level + 1 points
/// (level 0: the segment; level 4: 257 points), bumps pointing up (+y).
/// @param[in] level  0 .. 10.
/// @return the curve; InvalidArgument for a level outside [0, 10] (4^10 segments is the cap).
[[nodiscard]] Result<Polyline> make_koch_curve(int level);

/// The paper's Fig. 9 edit: the Koch curve of `level` with both end points fixed and the middle
/// point pulled up by `pull` (in curve units; the curve spans x in [0, 1], so 0.3 is 0.3 of its
/// width). The middle point is index n/2 = 2 * 4^(level-1), the middle by index and by arc length
/// (all segments have the same length); by symmetry it is the apex (1/2, sqrt(3)/6) of the
/// central (largest) bump at every level >= 1. Constrained = {0, n/2, n}, in that order.
/// @param[in] level  1 .. 10.
/// @param[in] pull   finite upward displacement of the middle point.
/// @return the edit; InvalidArgument for a level outside [1, 10] (level 0 has no middle point) or
///         a non-finite pull.
[[nodiscard]] Result<CurveEdit> make_koch_edit(int level, double pull = 0.3);

}  // namespace meshdeform::core
