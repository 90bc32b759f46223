// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The batch kernel of the backends that keep voxels in block grids (RAM, and the Disk backend's
// resident tiles): applies a batch's observations in call order, each as one IWLO observation
// (the RAM backend sends large batches of scattered points to block_sorted_batch.h instead).
// Where a block lives is the caller's policy (Locate); which rows are applied and their keys come
// from a Rows source. In groups of kGroupRows observations:
//   1. resolve: every observation's block (created if missing) and in-block index, computed for a
//      chunk of rows at a time (ChunkTargets), noting in each block the cells it lacks;
//   2. allocate: those cells, once per block and group (one allocation per block instead of one
//      per cell, and a block's cell array grows once);
//   3. update: in order, with the voxel of a later observation prefetched. When step 2 added
//      cells, which may move a block's cells, addresses are taken again kAhead observations ahead.
// Only steps 1 and 2 can fail (std::bad_alloc); groups before the failing one stay applied and
// the map stays consistent. Invariant: between calls no block holds a pending note
// (VoxelBlock::pending is empty); a scope guard clears the notes on every exit.

#include "integrate/batch_input.h"
#include "integrate/updater.h"
#include "integrate/voxel_update.h"
#include "storage/block_grid.h"

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <utility>

namespace iwlomap::detail {

/// Where each row of a chunk of up to ChunkKeys::kRows goes: its block, index in the block and
/// slot in the block grid's cache of recent blocks (BlockGrid::recent_slot()).
class ChunkTargets {
 public:
  /// From the coordinates of rows [begin, begin + rows) in one pass that vectorises, without
  /// keeping the keys; a chunk with a value that needs FloorDivider's exact division takes
  /// ChunkKeys::compute() and a second pass. The batch's row loop then reads three arrays instead
  /// of computing keys, blocks, indices and hashes one row at a time.
  void compute(const Eigen::MatrixXd& points, Eigen::Index begin, std::size_t rows, const FloorDivider& divide) noexcept;
  /// The same from keys already computed.
  void derive(std::size_t r, const VoxelKey& key) noexcept {
    const VoxelKey b = block_of(key);
    block_[0][r] = b.x;
    block_[1][r] = b.y;
    block_[2][r] = b.z;
    index_[r] = index_in_block(key);
    slot_[r] = static_cast<std::uint32_t>(BlockGrid::recent_slot(b));
  }
  [[nodiscard]] VoxelKey block(std::size_t r) const noexcept { return {block_[0][r], block_[1][r], block_[2][r]}; }
  [[nodiscard]] int index(std::size_t r) const noexcept { return index_[r]; }
  [[nodiscard]] std::size_t slot(std::size_t r) const noexcept { return slot_[r]; }

 private:
  ChunkKeys keys_;  // the exact path's keys
  std::array<std::array<std::int32_t, ChunkKeys::kRows>, 3> block_;
  std::array<std::int32_t, ChunkKeys::kRows> index_;
  std::array<std::uint32_t, ChunkKeys::kRows> slot_;
};

/// Working memory of one batch: a group's targets and the blocks with cells to add. One per
/// thread, kept for the thread's life and shared by all its maps (a batch never runs inside
/// another on one thread), so no map pays for fresh scratch pages in its first batch.
struct BatchScratch {
  static constexpr std::size_t kGroupRows = 16 * ChunkKeys::kRows;  // 8,192
  struct Target {
    VoxelBlock* block;
    Voxel* voxel;  // taken in the update step
    int index;     // index_in_block()
    std::uint32_t row;
  };
  ChunkTargets chunk;
  std::array<Target, kGroupRows> targets;
  std::array<std::pair<VoxelBlock*, BlockGrid*>, kGroupRows> pending;  // blocks with noted cells
};

/// The calling thread's BatchScratch.
[[nodiscard]] BatchScratch& batch_scratch();

/// Step 3 of apply_batch(): the updates of \p count targets in order, with the voxel kAhead
/// targets ahead prefetched; when \p cells_moved (cells were added, which may move a block's
/// cells) every address is taken again there. Returns how many voxels became known. It cannot
/// fail, so it is compiled per CPU level (IWLOMAP_CPU_CLONES), with the update math inlined.
std::size_t update_targets(BatchScratch::Target* targets, std::size_t count, bool cells_moved, const BatchValues& in,
                           const Updater& u) noexcept;

/// Clears the pending notes of the listed blocks when it goes out of scope, whether the group was
/// applied or an allocation failed: no note outlives the call.
class PendingNotes {
 public:
  explicit PendingNotes(BatchScratch& s) : list_(s.pending) {}
  ~PendingNotes() {
    for (std::size_t i = 0; i < count_; ++i) list_[i].first->pending = {};
  }
  PendingNotes(const PendingNotes&) = delete;
  PendingNotes& operator=(const PendingNotes&) = delete;

  /// Notes that \p b (in \p grid) lacks \p cell. The list has room for a block per observation of
  /// a group, so noting never allocates; a block is listed once, at its first note.
  void note(VoxelBlock& b, BlockGrid& grid, int cell) noexcept {
    list_[count_] = {&b, &grid};
    count_ += b.pending.any() ? 0 : 1;
    b.note_pending(cell);
  }
  /// Allocates every noted cell; returns whether there were any.
  bool allocate() {
    for (std::size_t i = 0; i < count_; ++i) list_[i].second->ensure_cells(*list_[i].first, list_[i].first->pending);
    return count_ != 0;
  }

 private:
  std::array<std::pair<VoxelBlock*, BlockGrid*>, BatchScratch::kGroupRows>& list_;
  std::size_t count_ = 0;
};

/// The totals a backend keeps, updated by apply_batch() after each group it applied.
struct BatchTotals {
  std::size_t& known;    // voxels that became known
  std::size_t& skipped;  // rows skipped as non-finite
};

/// Applies observations 0 .. n-1 in order, adding to \p totals group by group.
///
/// Rows (the observations' source):
///   void load(std::size_t begin, std::size_t count, ChunkTargets& chunk): fills chunk's entry
///     j - begin for observations [begin, begin + count) (count <= ChunkKeys::kRows)
///   bool skip(std::size_t j): observation j is not applied (a non-finite row)
///   std::uint32_t row(std::size_t j): its row in the batch
/// Locate (where the blocks live):
///   VoxelBlock& block(std::size_t j, const VoxelKey& block_key, std::size_t recent_slot): found
///     or created (may throw)
///   BlockGrid& grid(std::size_t j): the grid that holds observation j's block
template <class Rows, class Locate>
void apply_batch(Rows&& rows, std::size_t n, Locate&& locate, const BatchValues& in, const Updater& u,
                 const BatchTotals& totals) {
  BatchScratch& work = batch_scratch();
  auto& targets = work.targets;
  for (std::size_t group = 0; group < n; group += BatchScratch::kGroupRows) {
    const std::size_t group_end = std::min(n, group + BatchScratch::kGroupRows);
    std::size_t count = 0;
    std::size_t skipped = 0;
    PendingNotes pending(work);
    for (std::size_t begin = group; begin < group_end; begin += ChunkKeys::kRows) {
      const std::size_t end = std::min(group_end, begin + ChunkKeys::kRows);
      rows.load(begin, end - begin, work.chunk);
      for (std::size_t j = begin; j < end; ++j) {
        if (rows.skip(j)) {
          ++skipped;
          continue;
        }
        const std::size_t r = j - begin;
        VoxelBlock& b = locate.block(j, work.chunk.block(r), work.chunk.slot(r));
        const int index = work.chunk.index(r);
        const int cell = index >> kCellShift;
        Voxel* v = nullptr;
        if (b.has_cell(cell))
          v = &b.existing(index);
        else
          pending.note(b, locate.grid(j), cell);
        targets[count++] = {&b, v, index, rows.row(j)};
      }
    }
    const std::size_t newly_known = update_targets(targets.data(), count, pending.allocate(), in, u);
    totals.known += newly_known;
    totals.skipped += skipped;
  }
}

/// Rows straight from a batch's points: keys by ChunkKeys::compute(), rows in call order;
/// non-finite rows (only when validate_batch() counted some) are skipped.
class PointRows {
 public:
  PointRows(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities, double resolution, bool any_skipped)
      : points_(points), intensities_(intensities), divide_(resolution), any_skipped_(any_skipped) {}
  void load(std::size_t begin, std::size_t count, ChunkTargets& chunk) {
    chunk.compute(points_, static_cast<Eigen::Index>(begin), count, divide_);
  }
  [[nodiscard]] bool skip(std::size_t j) const {
    return any_skipped_ && !row_is_finite(points_, intensities_, static_cast<Eigen::Index>(j));
  }
  [[nodiscard]] std::uint32_t row(std::size_t j) const { return static_cast<std::uint32_t>(j); }

 private:
  const Eigen::MatrixXd& points_;
  const Eigen::VectorXd& intensities_;
  FloorDivider divide_;
  bool any_skipped_;
};

/// Rows from prepared observations (prepare_batch()), all applied: observation j is
/// obs[order[j]], or obs[j] without an order.
class ObservationRows {
 public:
  ObservationRows(const Observation* obs, const std::uint32_t* order) : obs_(obs), order_(order) {}
  void load(std::size_t begin, std::size_t count, ChunkTargets& chunk) const noexcept {
    for (std::size_t r = 0; r < count; ++r) chunk.derive(r, at(begin + r).key);
  }
  [[nodiscard]] bool skip(std::size_t) const { return false; }
  [[nodiscard]] std::uint32_t row(std::size_t j) const { return at(j).row; }

 private:
  [[nodiscard]] const Observation& at(std::size_t j) const { return obs_[order_ != nullptr ? order_[j] : j]; }
  const Observation* obs_;
  const std::uint32_t* order_;
};

}  // namespace iwlomap::detail
