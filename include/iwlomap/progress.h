// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Progress reports of long calls: a scan's rays and voxel updates, a Disk map's tile writes, an
/// OctoMap file's blocks. Set a callback on a map with IMapperBackend::set_progress_callback(), or
/// pass one to export_octomap().
///
/// The callback runs on the thread that made the call (never on a worker thread), between pieces
/// of work of a few thousand rays or a few dozen blocks, so a progress bar can advance within one
/// large scan. Each stage reports `done` = 0 first and `done` = `total` last, and `done` never goes
/// down within a stage. A call may go through several stages (insert_scan(): kCastingRays, then
/// kUpdatingVoxels); a small one may report only the ends.
///
/// Exceptions: one thrown by the callback during kCastingRays ends the call with the map unchanged,
/// and one during kWritingFile ends the export leaving no file (ways to cancel); during
/// kUpdatingVoxels and kWritingTiles the work goes on to its end, so the map stays whole, and the
/// first exception is rethrown when the call returns.

#include <cstddef>
#include <functional>

namespace iwlomap {

/// The part of a call being reported. Units are the stage's own; only done / total is comparable
/// across stages.
enum class ProgressStage {
  kCastingRays,     ///< insert_scan(): rays walked (units: points)
  kUpdatingVoxels,  ///< insert_scan(): the voxels of the walked rays updated (units: groups of voxels
                    ///< of 32^3, and one at the end; Disk backend: the same per group of tiles)
  kWritingTiles,    ///< Disk backend flush(): changed tiles written (units: tiles)
  kWritingFile,     ///< export_octomap(): the map's blocks written to the file (units: blocks of 8^3)
};

/// The stage's name as a user reads it ("casting rays", "updating voxels", "writing tiles",
/// "writing the file").
[[nodiscard]] const char* progress_stage_name(ProgressStage stage) noexcept;

/// One report: \p done of \p total units of \p stage (0 <= done <= total).
struct ProgressReport {
  ProgressStage stage;
  std::size_t done;
  std::size_t total;
};

/// A progress callback; an empty one is never called.
using ProgressCallback = std::function<void(const ProgressReport&)>;

}  // namespace iwlomap
