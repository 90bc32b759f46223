// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Applying a collected scan (ScanScratch) to one block grid, shared by the backends that keep the
// whole map in one grid (RAM, OctoMap). Blocks and cells come first, on the calling thread and in
// the scratch's order, which depends on the scan only: the grid's iteration order then does not
// depend on the thread count either. Then the free voxels, then the hits; a voxel gets one
// observation per scan (the scratch made sure of it), so the order between voxels is free.

#include "integrate/progress_report.h"
#include "integrate/scan_scratch.h"
#include "storage/block_grid.h"
#include "storage/memory_limit.h"

#include <algorithm>
#include <cstddef>

namespace iwlomap::detail {

/// An upper bound on the slab bytes allocate_scan() can add to \p grid: a header for each new
/// block, and for each block whose cell array must grow the array of the new size class (the old
/// one goes to a free list, so it is not counted as freed), plus a fresh slab for the headers and
/// one for the cells when any are needed, since arenas map whole slabs. A scan over known space
/// needs nothing, and is never refused.
inline std::size_t scan_growth_bound(const ScanScratch& s, const BlockGrid& grid) {
  std::size_t headers = 0;
  std::size_t cell_arrays = 0;
  s.for_each_block([&](const VoxelKey& block_key, const CellMask& cells) {
    const VoxelBlock* b = grid.find(block_key);
    const int old_count = b == nullptr ? 0 : b->num_cells();
    const int count = b == nullptr ? cells.count() : old_count + cells.without(b->cell_mask).count();
    if (b == nullptr) headers += sizeof(VoxelBlock);
    if (count > old_count && (old_count == 0 || CellPool::class_of(count) != CellPool::class_of(old_count)))
      cell_arrays += sizeof(Cell) << CellPool::class_of(count);
  });
  return headers + cell_arrays + (headers > 0 ? kLargestSlabBytes : 0) + (cell_arrays > 0 ? kLargestSlabBytes : 0);
}

/// Allocates every block and cell the scan will update. With a map memory limit, first works out
/// the most the allocation can take and throws MemoryLimitError before changing the grid when
/// that would pass the limit (see scan_growth_bound()).
inline void allocate_scan(const ScanScratch& s, BlockGrid& grid) {
  if (map_memory_limit() != 0) check_map_memory(scan_growth_bound(s, grid), "the scan's voxels");
  BlockAccessor acc(grid);
  s.for_each_block([&](const VoxelKey& block_key, const CellMask& cells) { grid.ensure_cells(acc.block(block_key), cells); });
}

/// Calls observe(block, index_in_block, voxel key, intensity, occupied) for every free voxel of
/// chunks [begin, end) of the scratch (intensity 0, not occupied); allocate_scan() came first, so
/// every block and cell exists.
template <class Observe>
void apply_scan_free(const ScanScratch& s, const BlockGrid& grid, std::size_t begin, std::size_t end,
                     Observe&& observe) {
  VoxelBlock* last = nullptr;
  s.for_each_free(begin, end, [&](const VoxelKey& block_key, int index) {
    if (last == nullptr || last->key != block_key) last = grid.find(block_key);
    observe(*last, index, voxel_of(block_key, index), 0.0, false);
  });
}

/// apply_scan_free() over every chunk on this thread, reporting the chunks done to \p report
/// every 64 chunks (up to 32^3 voxels each) when it is active, in one pass otherwise.
template <class Observe>
void apply_scan_free_reporting(const ScanScratch& s, const BlockGrid& grid, StageProgress& report, Observe&& observe) {
  constexpr std::size_t kReportGrain = 64;
  const std::size_t chunks = s.num_chunks();
  const std::size_t step = report.active() ? kReportGrain : chunks;
  for (std::size_t c = 0; c < chunks; c += step) {
    apply_scan_free(s, grid, c, std::min(c + step, chunks), observe);
    report.report(std::min(c + step, chunks));
  }
}

/// The same for every hit voxel (its largest intensity, occupied).
template <class Observe>
void apply_scan_hits(const ScanScratch& s, const BlockGrid& grid, Observe&& observe) {
  VoxelBlock* last = nullptr;
  s.for_each_hit([&](const VoxelKey& key, double intensity) {
    const VoxelKey block_key = block_of(key);
    if (last == nullptr || last->key != block_key) last = grid.find(block_key);
    observe(*last, index_in_block(key), key, intensity, true);
  });
}

}  // namespace iwlomap::detail
