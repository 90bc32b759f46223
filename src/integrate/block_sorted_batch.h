// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Large batches of scattered points, regrouped by block before they are applied.
//
// apply_batch() resolves, allocates and updates in groups of kGroupRows rows in call order. That
// suits batches whose consecutive rows stay in a few blocks (a scan's points), but points spread
// over a volume touch a different block at nearly every row: each row pays a block look-up that
// misses every cache, and a block receiving a couple of rows per group regrows its cell array
// group after group. Here the batch's rows are instead sorted by block with a counting sort
// (stably, so each voxel still sees its observations in call order and the map's values are
// those of apply_batch()), and each block is then found once, its cells allocated once and its
// rows applied while its cells are in cache. Blocks are created in the order of their first row,
// as apply_batch() creates them, so the map is the same in iteration order too.
//
// The sort keys are the blocks' positions in the batch's bounding box of blocks, looked up in a
// dense table (4 bytes per block of the box) instead of a hash map: the box must therefore be
// small against the batch (see build()).

#include "integrate/batch_input.h"
#include "integrate/updater.h"
#include "integrate/voxel_update.h"
#include "storage/block_grid.h"

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <vector>

namespace iwlomap::detail {

class BlockSortedBatch {
 public:
  /// One observation: its intensity, row in the batch, voxel's index in the block and flag (the
  /// intensity is copied so that applying a block reads its entries alone; the row is for weights).
  struct Entry {
    double intensity;
    std::uint32_t row;
    std::uint16_t index;  // index_in_block()
    std::uint8_t occupied_flag;
  };

  /// Whether a validated batch (of which \p skipped rows are non-finite) should be regrouped: at
  /// least kMinRows finite rows, and the finite rows among the first kSampleRows fall in more
  /// distinct blocks than a quarter of their number (fewer than 4 rows a block; a scan's points
  /// give each block many rows).
  [[nodiscard]] static bool suits(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                  std::size_t skipped, const FloorDivider& divide);

  /// Sorts the finite rows of a validated batch by block. Returns false, leaving nothing
  /// meaningful, when the bounding box of the batch's blocks holds more than 2 * rows + 65,536
  /// blocks (the dense table would outgrow the batch); the caller then applies it in call order.
  bool build(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities, const std::vector<bool>& is_occupied,
             std::size_t skipped, const FloorDivider& divide);

  /// After build(): the number of distinct blocks, in the order of their first row.
  [[nodiscard]] std::size_t blocks() const noexcept { return keys_.size(); }
  [[nodiscard]] const VoxelKey& block(std::size_t s) const noexcept { return keys_[s]; }
  /// Block \p s's observations, in call order: [first(s), first(s + 1)).
  [[nodiscard]] const Entry* first(std::size_t s) const noexcept { return entries_.data() + begin_[s]; }

  static constexpr std::size_t kMinRows = 32768;
  static constexpr std::size_t kSampleRows = 2048;

 private:
  std::vector<VoxelKey> keys_;           // block key of each slot
  std::vector<std::uint32_t> begin_;     // slot s owns entries_[begin_[s], begin_[s + 1])
  std::vector<std::uint32_t> slot_of_;   // per row; kNoSlot for a skipped row
  std::vector<std::uint16_t> index_of_;  // per row: index_in_block()
  std::vector<std::uint32_t> dense_;     // block's position in the box -> slot
  std::vector<Entry> entries_;
};

/// Applies a batch sorted by build() block after block, adding the voxels that became known to
/// \p known. Where a block lives is the caller's policy, as for apply_batch():
///   VoxelBlock& block(const VoxelKey& block_key): found or created (may throw)
///   BlockGrid& grid(const VoxelKey& block_key): the grid that holds it
/// (RAM: one grid; Disk: the resident tile of the block). Only a block's creation and its cells'
/// allocation can fail (std::bad_alloc, MemoryLimitError): the blocks before it stay applied,
/// counted in \p known, and the map stays consistent.
template <class Locate>
void apply_block_sorted(const BlockSortedBatch& batch, Locate&& locate, const BatchValues& in, const Updater& u,
                        std::size_t& known) {
  for (std::size_t s = 0; s < batch.blocks(); ++s) {
    const VoxelKey& key = batch.block(s);
    VoxelBlock& b = locate.block(key);
    const BlockSortedBatch::Entry* const from = batch.first(s);
    const BlockSortedBatch::Entry* const to = batch.first(s + 1);
    CellMask cells;
    for (const auto* e = from; e != to; ++e) cells |= CellMask::of(e->index >> kCellShift);
    locate.grid(key).ensure_cells(b, cells);
    for (const auto* e = from; e != to; ++e)
      if (observe_voxel(b, b.existing(e->index), e->intensity, e->occupied_flag != 0, in.weight(e->row), u)) ++known;
  }
}

}  // namespace iwlomap::detail
