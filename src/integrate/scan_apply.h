// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The one way a collected scan (ScanScratch) reaches voxel storage, for every backend. Where a
// block lives is the backend's policy (Locate), as in batch_apply.h:
//   RAM, OctoMap: one grid (OneGrid below);
//   Disk: the grid of the resident tile that holds the block, for the tiles of the tile group
//     being applied; blocks of other tiles give nullptr and wait for their own group.
// In two steps:
//   1. allocate_scan(): every block and cell the scan will update, on the calling thread and in
//      the scratch's order, which depends on the scan only: a grid's iteration order then does
//      not depend on the thread count either.
//   2. apply_scan(): the free voxels of the chosen chunks, on up to `threads` threads, then the
//      hits on the calling thread. A chunk's blocks belong to no other chunk, so no two threads
//      touch one voxel; a voxel gets one observation per scan (the scratch made sure of it), so
//      the order between voxels does not change the map, and the map is the same for any thread
//      count.
// The hit statistics of a scan are gathered by ScanScratch::collect() in its own ray walk
// (RayStatistics), not by a second cast.
//
// Locate (where the blocks live):
//   void allocate(const VoxelKey& block_key, const CellMask& cells): creates the block and the
//     cells when this pass applies the block, nothing otherwise (may throw std::bad_alloc)
//   VoxelBlock* find(const VoxelKey& block_key) const: the block when this pass applies it, else
//     nullptr; called from several threads at once, so it must not write
// Observe:
//   bool operator()(VoxelBlock& b, int index_in_block, const VoxelKey& key, double intensity,
//     bool occupied): one observation, true when the voxel was unknown before; called for
//     disjoint blocks from several threads at once when threads > 1

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
  void allocate(const VoxelKey& block_key, const CellMask& cells) { grid_.ensure_cells(acc_.block(block_key), cells); }
  [[nodiscard]] VoxelBlock* find(const VoxelKey& block_key) const noexcept { return grid_.find(block_key); }
  VoxelBlock& block(const VoxelKey& block_key) { return acc_.block(block_key); }
  BlockGrid& grid(const VoxelKey&) noexcept { return grid_; }

 private:
  BlockGrid& grid_;
  BlockAccessor acc_;
};

/// Step 1: every block and cell of the scan that \p locate places.
template <class Locate>
void allocate_scan(const ScanScratch& s, Locate& locate) {
  s.for_each_block([&](const VoxelKey& block_key, const CellMask& cells) { locate.allocate(block_key, cells); });
}

/// Step 1 for a map in one grid. With a map memory limit, first works out the most the
/// allocation can take and throws MemoryLimitError before changing the grid when that would pass
/// the limit (see scan_growth_bound()).
inline void allocate_scan(const ScanScratch& s, BlockGrid& grid, OneGrid& locate) {
  if (map_memory_limit() != 0) check_map_memory(scan_growth_bound(s, grid), "the scan's voxels");
  allocate_scan(s, locate);
}

/// Which of the scratch's chunks a pass applies: all, or a sorted list.
struct ChunkSelection {
  const std::vector<std::size_t>* list = nullptr;  // null: every chunk

  [[nodiscard]] std::size_t size(const ScanScratch& s) const noexcept { return list ? list->size() : s.num_chunks(); }
  [[nodiscard]] std::size_t chunk(std::size_t i) const noexcept { return list ? (*list)[i] : i; }
};

namespace scan_apply_detail {

// The free voxels of selected chunks [begin, end) on this thread; returns the voxels that
// became known.
template <class Locate, class Observe>
std::size_t apply_free(const ScanScratch& s, ChunkSelection chunks, std::size_t begin, std::size_t end,
                       const Locate& locate, Observe& observe) {
  std::size_t known = 0;
  VoxelBlock* block = nullptr;
  VoxelKey last{};
  bool have_last = false;
  for (std::size_t i = begin; i < end; ++i) {
    const std::size_t c = chunks.chunk(i);
    s.for_each_free(c, c + 1, [&](const VoxelKey& block_key, int index) {
      if (!have_last || last != block_key) {
        block = locate.find(block_key);
        last = block_key;
        have_last = true;
      }
      if (block != nullptr && observe(*block, index, voxel_of(block_key, index), 0.0, false)) ++known;
    });
  }
  return known;
}

}  // namespace scan_apply_detail

/// Step 2: the free voxels of \p chunks on up to \p threads threads, then every hit (its largest
/// intensity, occupied) on this thread; voxels whose block \p locate does not find are left out.
/// Reports ProgressStage::kUpdatingVoxels to \p report as report_base + the chunks applied, and
/// one more unit for the hits; only the calling thread reports. Returns the voxels that became
/// known. Only \p observe and \p report can throw; an exception of a worker thread is rethrown
/// here once all have joined.
template <class Locate, class Observe>
std::size_t apply_scan(const ScanScratch& s, ChunkSelection chunks, int threads, const Locate& locate,
                       Observe&& observe, StageProgress& report, std::size_t report_base = 0) {
  const std::size_t n = chunks.size(s);
  // A thread pays off from a few chunks each; the chunks near the sensor hold far more voxels.
  const std::size_t t = std::min<std::size_t>(static_cast<std::size_t>(std::max(threads, 1)), n / 4 + 1);
  std::size_t known = 0;
  if (t <= 1) {
    constexpr std::size_t kReportGrain = 64;
    const std::size_t step = report.active() ? kReportGrain : std::max<std::size_t>(n, 1);
    for (std::size_t c = 0; c < n; c += step) {
      known += scan_apply_detail::apply_free(s, chunks, c, std::min(c + step, n), locate, observe);
      report.report(report_base + std::min(c + step, n));
    }
  } else {
    // Threads take a few chunks at a time from a shared counter.
    constexpr std::size_t kGrain = 4;
    std::vector<std::size_t> newly_known(t, 0);
    std::vector<std::exception_ptr> failed(t);
    std::atomic<std::size_t> next{0};
    std::atomic<std::size_t> finished{0};  // chunks applied, for the reports of the calling thread
    const auto work = [&](std::size_t k) {
      try {
        for (std::size_t c = next.fetch_add(kGrain); c < n; c = next.fetch_add(kGrain)) {
          const std::size_t end = std::min(c + kGrain, n);
          newly_known[k] += scan_apply_detail::apply_free(s, chunks, c, end, locate, observe);
          const std::size_t applied = finished.fetch_add(end - c, std::memory_order_relaxed) + (end - c);
          if (k == 0) report.report(report_base + applied);
        }
      } catch (...) {
        failed[k] = std::current_exception();
        next.store(n);
      }
    };
    std::vector<std::thread> workers;
    workers.reserve(t - 1);
    for (std::size_t k = 1; k < t; ++k) workers.emplace_back(work, k);
    work(0);  // the calling thread works too
    for (auto& w : workers) w.join();
    for (const std::exception_ptr& e : failed)
      if (e) std::rethrow_exception(e);
    for (const std::size_t v : newly_known) known += v;
  }
  VoxelBlock* block = nullptr;
  VoxelKey last{};
  bool have_last = false;
  s.for_each_hit([&](const VoxelKey& key, double intensity) {
    const VoxelKey block_key = block_of(key);
    if (!have_last || last != block_key) {
      block = locate.find(block_key);
      last = block_key;
      have_last = true;
    }
    if (block != nullptr && observe(*block, index_in_block(key), key, intensity, true)) ++known;
  });
  report.report(report_base + n + 1);
  return known;
}

}  // namespace iwlomap::detail
