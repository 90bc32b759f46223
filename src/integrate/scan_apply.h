// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The one way a collected scan (ScanScratch) reaches voxel storage, for every backend. Where a
// block lives is the backend's policy (Locate), as in batch_apply.h:
//   RAM, OctoMap: one grid (OneGrid below);
//   Disk: the grid of the resident tile that holds the block, for the tiles of the tile group
//     being applied; blocks of other tiles give nullptr and wait for their own group.
// In two steps:
//   1. allocate_scan(): every block and cell the scan will update, created on the calling thread
//      in the scratch's order, which depends on the scan only: a grid's iteration order then does
//      not depend on the thread count either. The cells' masks and their zero-filling run on the
//      threads.
//   2. apply_scan(): every observation (free and hit) of the chosen chunks, on up to `threads`
//      threads. A chunk's blocks belong to no other chunk, so no two threads touch one block; a
//      voxel gets one observation per scan (the scratch made sure of it), so the order between
//      voxels does not change the map, and the map is the same for any thread count.
// The hit statistics of a scan are gathered by ScanScratch::collect() in its own ray walk
// (RayStatistics), not by a second cast.
//
// Locate (where the blocks live):
//   BlockGrid* grid_of(const VoxelKey& block_key): the grid that holds the block when this pass
//     applies it, else nullptr
//   VoxelBlock* find(const VoxelKey& block_key) const: the block when this pass applies it, else
//     nullptr; called from several threads at once, so it must not write
// Observe:
//   bool operator()(VoxelBlock& b, int index_in_block, const VoxelKey& key, double intensity,
//     bool occupied): one observation, true when the voxel was unknown before; called for
//     disjoint blocks from several threads at once when threads > 1

#include "integrate/parallel_pieces.h"
#include "integrate/phase_clock.h"
#include "integrate/progress_report.h"
#include "integrate/scan_scratch.h"
#include "storage/block_grid.h"
#include "storage/memory_limit.h"

#include <algorithm>
#include <atomic>
#include <cstddef>
#include <exception>
#include <thread>
#include <vector>

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

/// The Locate of a map held in one grid (RAM, OctoMap), for the scan kernel below and for
/// apply_block_sorted() (block(), grid()).
class OneGrid {
 public:
  explicit OneGrid(BlockGrid& grid) : grid_(grid), acc_(grid) {}
  [[nodiscard]] BlockGrid* grid_of(const VoxelKey&) noexcept { return &grid_; }
  [[nodiscard]] VoxelBlock* find(const VoxelKey& block_key) const noexcept { return grid_.find(block_key); }
  VoxelBlock& block(const VoxelKey& block_key) { return acc_.block(block_key); }
  BlockGrid& grid(const VoxelKey&) noexcept { return grid_; }

 private:
  BlockGrid& grid_;
  BlockAccessor acc_;
};

namespace scan_apply_detail {

// Threads worth using on n chunks: a thread pays off from a few chunks each (the chunks near the
// sensor hold far more voxels than the others).
inline std::size_t useful_threads(int threads, std::size_t n) noexcept {
  return std::min<std::size_t>(static_cast<std::size_t>(std::max(threads, 1)), n / 4 + 1);
}

// Finishes the reserved growths [begin, end) of \p work (BlockGrid::finish_cells()): a block gains
// the cells of its mask that it lacks.
inline void finish_growths(const ScanScratch::AllocationWork& work, std::size_t begin, std::size_t end) noexcept {
  for (std::size_t i = begin; i < end; ++i) {
    const BlockGrid::CellGrowth& g = work.growths[i];
    BlockGrid::finish_cells(g, work.masks[g.tag].without(g.block->cell_mask));
  }
}

// Gives the old arrays of every growth of \p work back to the pools of the grids that hold them.
template <class Locate>
void release_growths(ScanScratch::AllocationWork& work, Locate& locate) noexcept {
  for (const BlockGrid::CellGrowth& g : work.growths)
    if (g.from != nullptr && g.from != g.block->cells) locate.grid_of(g.block->key)->release_old_cells(g);
  work.growths.clear();
}

}  // namespace scan_apply_detail

/// Step 1: every block and cell of the scan that \p locate places. Only the map's bookkeeping
/// runs on the calling thread:
///   a. each chunk's blocks' cell masks, gathered from the scratch's bits (up to \p threads
///      threads);
///   b. in the scratch's block order (for_each_block()), each new block created and each block
///      that gains cells given room for them (BlockGrid::reserve_cells(): no cell written), on the
///      calling thread, so that block and array order depend on the scan only;
///   c. the cells moved and zero-filled (BlockGrid::finish_cells(), up to \p threads threads, each
///      block on one), then the old arrays given back.
/// Step c is where a new map's cell memory (most of its memory) is first touched, so those page
/// faults run on every thread.
/// With \p phases, adds the time of a and c to phases->preparing, of b to phases->allocating. On
/// an exception (std::bad_alloc, MemoryLimitError) every block keeps what it had and what it got.
template <class Locate>
void allocate_scan(const ScanScratch& s, Locate& locate, int threads = 1, ScanPhaseTimes* phases = nullptr) {
  constexpr int kBlocks = ScanScratch::kBlocksPerChunk;
  ScanScratch::AllocationWork& work = s.allocation_work();
  const std::size_t n = s.num_chunks();
  const std::size_t t = scan_apply_detail::useful_threads(threads, n);
  {
    PhaseClock clock(phases ? &phases->preparing : nullptr);
    work.masks.resize(n * kBlocks);
    parallel_pieces(n, 16, t, [&](std::size_t, std::size_t begin, std::size_t end) {
      for (std::size_t ci = begin; ci < end; ++ci)
        for (int b = 0; b < kBlocks; ++b) work.masks[ci * kBlocks + static_cast<std::size_t>(b)] = s.block_cells(ci, b);
    });
  }
  {
    PhaseClock clock(phases ? &phases->allocating : nullptr);
    work.growths.clear();
    try {
      for (const std::size_t ci : s.chunk_order()) {
        for (int b = 0; b < kBlocks; ++b) {
          const std::size_t at = ci * kBlocks + static_cast<std::size_t>(b);
          const CellMask& cells = work.masks[at];
          if (!cells.any()) continue;
          const VoxelKey key = s.block_key(ci, b);
          BlockGrid* const grid = locate.grid_of(key);
          if (grid == nullptr) continue;
          VoxelBlock& block = grid->get_or_create(key);
          const CellMask added = cells.without(block.cell_mask);
          if (!added.any()) continue;
          // Room first: once reserved, a growth must be recorded (push_back then cannot throw).
          if (work.growths.size() == work.growths.capacity()) work.growths.reserve(2 * work.growths.size() + 256);
          work.growths.push_back(grid->reserve_cells(block, added));
          work.growths.back().tag = static_cast<std::uint32_t>(at);
        }
      }
    } catch (...) {
      scan_apply_detail::finish_growths(work, 0, work.growths.size());
      scan_apply_detail::release_growths(work, locate);
      throw;
    }
  }
  {
    PhaseClock clock(phases ? &phases->preparing : nullptr);
    parallel_pieces(work.growths.size(), 512, t, [&](std::size_t, std::size_t begin, std::size_t end) {
      scan_apply_detail::finish_growths(work, begin, end);
    });
  }
  PhaseClock clock(phases ? &phases->allocating : nullptr);
  scan_apply_detail::release_growths(work, locate);
}

/// Step 1 for a map in one grid. With a map memory limit, first works out the most the
/// allocation can take and throws MemoryLimitError before changing the grid when that would pass
/// the limit (see scan_growth_bound()).
inline void allocate_scan(const ScanScratch& s, BlockGrid& grid, OneGrid& locate, int threads = 1,
                          ScanPhaseTimes* phases = nullptr) {
  if (map_memory_limit() != 0) {
    PhaseClock clock(phases ? &phases->allocating : nullptr);
    check_map_memory(scan_growth_bound(s, grid), "the scan's voxels");
  }
  allocate_scan(s, locate, threads, phases);
}

/// Which of the scratch's chunks a pass applies: all, or a sorted list.
struct ChunkSelection {
  const std::vector<std::size_t>* list = nullptr;  // null: every chunk

  [[nodiscard]] std::size_t size(const ScanScratch& s) const noexcept { return list ? list->size() : s.num_chunks(); }
  [[nodiscard]] std::size_t chunk(std::size_t i) const noexcept { return list ? (*list)[i] : i; }
};

namespace scan_apply_detail {

// Every observation of selected chunks [begin, end) on this thread; returns the voxels that became
// known.
template <class Locate, class Observe>
std::size_t apply_chunks(const ScanScratch& s, ChunkSelection chunks, std::size_t begin, std::size_t end,
                         const Locate& locate, Observe& observe) {
  std::size_t known = 0;
  VoxelBlock* block = nullptr;
  VoxelKey last{};
  bool have_last = false;
  const auto block_of_key = [&](const VoxelKey& block_key) {
    if (!have_last || last != block_key) {
      block = locate.find(block_key);
      last = block_key;
      have_last = true;
    }
    return block;
  };
  for (std::size_t i = begin; i < end; ++i) {
    const std::size_t c = chunks.chunk(i);
    s.for_each_observation_in(
        c, c + 1,
        [&](const VoxelKey& block_key, int index) {
          if (VoxelBlock* b = block_of_key(block_key); b != nullptr && observe(*b, index, voxel_of(block_key, index), 0.0, false))
            ++known;
        },
        [&](const VoxelKey& block_key, int index, double intensity) {
          if (VoxelBlock* b = block_of_key(block_key);
              b != nullptr && observe(*b, index, voxel_of(block_key, index), intensity, true))
            ++known;
        });
  }
  return known;
}

}  // namespace scan_apply_detail

/// Step 2: the observations of \p chunks on up to \p threads threads, each free voxel free and
/// each hit occupied with its largest intensity; voxels whose block \p locate does not find are
/// left out. Reports ProgressStage::kUpdatingVoxels to \p report as report_base + the chunks
/// applied, and one more unit at the end; only the calling thread reports. Returns the voxels that
/// became known. Only \p observe and \p report can throw; an exception of a worker thread is
/// rethrown here once all have joined. With \p updating, adds the call's time to it.
template <class Locate, class Observe>
std::size_t apply_scan(const ScanScratch& s, ChunkSelection chunks, int threads, const Locate& locate,
                       Observe&& observe, StageProgress& report, std::size_t report_base = 0,
                       double* updating = nullptr) {
  PhaseClock clock(updating);
  const std::size_t n = chunks.size(s);
  const std::size_t t = scan_apply_detail::useful_threads(threads, n);
  // One thread reports every kReportGrain chunks; threads take a few chunks at a time.
  constexpr std::size_t kReportGrain = 64;
  constexpr std::size_t kGrain = 4;
  std::vector<std::size_t> newly_known(t, 0);
  std::atomic<std::size_t> finished{0};  // chunks applied, for the reports of the calling thread
  const std::size_t grain = t > 1 ? kGrain : report.active() ? kReportGrain : std::max<std::size_t>(n, 1);
  parallel_pieces(n, grain, t, [&](std::size_t k, std::size_t begin, std::size_t end) {
    newly_known[k] += scan_apply_detail::apply_chunks(s, chunks, begin, end, locate, observe);
    const std::size_t applied = finished.fetch_add(end - begin, std::memory_order_relaxed) + (end - begin);
    if (k == 0) report.report(report_base + applied);
  });
  std::size_t known = 0;
  for (const std::size_t v : newly_known) known += v;
  report.report(report_base + n + 1);
  return known;
}

}  // namespace iwlomap::detail
