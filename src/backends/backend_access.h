// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// What the library's own layers may do to a backend beyond its public API.

#include "integrate/scan_scratch.h"
#include "iwlomap/probability_updater.h"

namespace iwlomap::detail {

struct BackendAccess {
  /// Applies a scan already collected into \p scratch (at most one observation per voxel) to \p map
  /// exactly as its insert_scan() applies the scratch it collects itself, so the voxels come out
  /// bit-identical; the skipped-point count is the caller's. Throws std::logic_error when \p map
  /// gathers hit statistics (the points they need are not in a scratch), and MemoryLimitError as
  /// insert_scan() does, before changing the map.
  static void apply_collected_scan(ProbabilityUpdater& map, const ScanScratch& scratch);
};

}  // namespace iwlomap::detail
