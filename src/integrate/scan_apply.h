// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Applying a collected scan (ScanScratch) to one block grid, shared by the backends that keep the
// whole map in one grid (RAM, OctoMap). Blocks and cells come first, on the calling thread and in
// the scratch's order, which depends on the scan only: the grid's iteration order then does not
// depend on the thread count either. Then the free voxels, then the hits; a voxel gets one
// observation per scan (the scratch made sure of it), so the order between voxels is free.

#include "integrate/scan_scratch.h"
#include "storage/block_grid.h"

#include <cstddef>

namespace iwlomap::detail {

/// Allocates every block and cell the scan will update.
inline void allocate_scan(const ScanScratch& s, BlockGrid& grid) {
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
