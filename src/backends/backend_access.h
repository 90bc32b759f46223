// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// What the library's own layers may do to a backend beyond its public API.

#include "integrate/scan_scratch.h"
#include "iwlomap/mapper_backend.h"
#include "iwlomap/probability_updater.h"

namespace iwlomap::detail {

/// Applies a collected scan (at most one observation per voxel) to any backend the way
/// IMapperBackend's default insert_scan() does: every voxel's observation at its centre through
/// the unweighted batch_update_iwlo() (free voxels with intensity 0, not occupied), in batches.
void apply_scratch_by_batches(IMapperBackend& map, const ScanScratch& scratch);

struct BackendAccess {
  /// Applies a scan already collected into \p scratch (at most one observation per voxel) to
  /// \p map, so that its voxels come out bit-identical to \p map's own insert_scan() of that scan;
  /// the skipped-point count is the caller's. A RAM backend applies it through its own scan path
  /// (throwing std::logic_error when it gathers hit statistics, which need the points, and
  /// MemoryLimitError as insert_scan() does, before changing the map); any other backend gets
  /// apply_scratch_by_batches().
  static void apply_collected_scan(IMapperBackend& map, const ScanScratch& scratch);

 private:
  static void apply_to_ram(ProbabilityUpdater& map, const ScanScratch& scratch);
};

}  // namespace iwlomap::detail
