// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Deprecated path: the branch-and-bound matcher is part of the registration layer
/// (iwlomap::registration). Include <iwlomap/registration/correlative_scan_matcher.h> and link
/// iwlomap::registration; the old names below are deprecated aliases.

#include <iwlomap/registration/correlative_scan_matcher.h>

namespace iwlomap {

using SearchWindow3D [[deprecated("use iwlomap::registration::SearchWindow3D")]] = registration::SearchWindow3D;
using CoarseMatch [[deprecated("use iwlomap::registration::CoarseMatch")]] = registration::CoarseMatch;
using CorrelativeScanMatcher3D [[deprecated("use iwlomap::registration::CorrelativeScanMatcher3D")]] =
    registration::CorrelativeScanMatcher3D;

}  // namespace iwlomap
