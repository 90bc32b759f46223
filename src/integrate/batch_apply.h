// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The one batch kernel of the backends that keep voxels in block grids (RAM, and the Disk
// backend's resident tiles): applies a batch's observations in call order, each as one IWLO
// observation. Where a block lives is the caller's policy (Locate); which rows are applied and
// their keys come from a Rows source. In groups of kGroupRows observations:
//   1. resolve: every observation's block (created if missing) and in-block index, noting in each
//      block the cells it lacks;
//   2. allocate: those cells, once per block and group (one allocation per block instead of one
//      per cell, and a block's cell array grows once);
//   3. update: in order, with the voxel of a later observation prefetched. Addresses are taken
//      only here, kAhead observations ahead, because step 2 may move a block's cells.
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
  ChunkKeys keys;
  std::array<Target, kGroupRows> targets;
  std::array<std::pair<VoxelBlock*, BlockGrid*>, kGroupRows> pending;  // blocks with noted cells
};

/// The calling thread's BatchScratch.
[[nodiscard]] BatchScratch& batch_scratch();

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
///   void load(std::size_t begin, std::size_t count, ChunkKeys& keys): before observations
///     [begin, begin + count) are read (count <= ChunkKeys::kRows)
///   bool skip(std::size_t j): observation j is not applied (a non-finite row)
///   VoxelKey key(const ChunkKeys& keys, std::size_t j); std::uint32_t row(std::size_t j)
/// Locate (where the blocks live):
///   VoxelBlock& block(std::size_t j, const VoxelKey& block_key): found or created (may throw)
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
      rows.load(begin, end - begin, work.keys);
      for (std::size_t j = begin; j < end; ++j) {
        if (rows.skip(j)) {
          ++skipped;
          continue;
        }
        const VoxelKey key = rows.key(work.keys, j);
        VoxelBlock& b = locate.block(j, block_of(key));
        const int index = index_in_block(key);
        const int cell = index >> kCellShift;
        if (!b.has_cell(cell)) pending.note(b, locate.grid(j), cell);
        targets[count++] = {&b, nullptr, index, rows.row(j)};
      }
    }
    pending.allocate();
    constexpr std::size_t kAhead = 64;
    const auto address = [](BatchScratch::Target& t) { t.voxel = &t.block->existing(t.index); };
    std::size_t newly_known = 0;
    for (std::size_t j = 0; j < std::min(count, kAhead); ++j) address(targets[j]);
    for (std::size_t j = 0; j < count; ++j) {
      if (j + kAhead < count) {
        address(targets[j + kAhead]);
        __builtin_prefetch(targets[j + kAhead].voxel, 1);
      }
      const BatchScratch::Target& t = targets[j];
      if (observe_voxel(*t.block, *t.voxel, in.intensity(t.row), in.occupied_flag(t.row), in.weight(t.row), u))
        ++newly_known;
    }
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
  void load(std::size_t begin, std::size_t count, ChunkKeys& keys) {
    begin_ = begin;
    keys.compute(points_, static_cast<Eigen::Index>(begin), count, divide_);
  }
  [[nodiscard]] bool skip(std::size_t j) const {
    return any_skipped_ && !row_is_finite(points_, intensities_, static_cast<Eigen::Index>(j));
  }
  [[nodiscard]] VoxelKey key(const ChunkKeys& keys, std::size_t j) const { return keys[j - begin_]; }
  [[nodiscard]] std::uint32_t row(std::size_t j) const { return static_cast<std::uint32_t>(j); }

 private:
  const Eigen::MatrixXd& points_;
  const Eigen::VectorXd& intensities_;
  FloorDivider divide_;
  bool any_skipped_;
  std::size_t begin_ = 0;
};

/// Rows from prepared observations (prepare_batch()), all applied: observation j is
/// obs[order[j]], or obs[j] without an order.
class ObservationRows {
 public:
  ObservationRows(const Observation* obs, const std::uint32_t* order) : obs_(obs), order_(order) {}
  void load(std::size_t, std::size_t, ChunkKeys&) {}
  [[nodiscard]] bool skip(std::size_t) const { return false; }
  [[nodiscard]] VoxelKey key(const ChunkKeys&, std::size_t j) const { return at(j).key; }
  [[nodiscard]] std::uint32_t row(std::size_t j) const { return at(j).row; }

 private:
  [[nodiscard]] const Observation& at(std::size_t j) const { return obs_[order_ != nullptr ? order_[j] : j]; }
  const Observation* obs_;
  const std::uint32_t* order_;
};

}  // namespace iwlomap::detail
