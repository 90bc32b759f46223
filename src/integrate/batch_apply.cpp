// SPDX-License-Identifier: BSD-3-Clause
#include "integrate/batch_apply.h"

#include "integrate/cpu_clones.h"

#include <algorithm>
#include <memory>

namespace iwlomap::detail {

IWLOMAP_CPU_CLONES
void ChunkTargets::compute(const Eigen::MatrixXd& points, Eigen::Index begin, std::size_t rows,
                           const FloorDivider& divide) noexcept {
  if (divide.fast()) {
    const double* x = points.col(0).data() + begin;
    const double* y = points.col(1).data() + begin;
    const double* z = points.col(2).data() + begin;
    std::int64_t any = 0;
    for (std::size_t r = 0; r < rows; ++r) {
      std::int64_t fx, fy, fz;
      const VoxelKey k{static_cast<std::int32_t>(divide.fast_floor(x[r], fx)),
                       static_cast<std::int32_t>(divide.fast_floor(y[r], fy)),
                       static_cast<std::int32_t>(divide.fast_floor(z[r], fz))};
      any |= fx | fy | fz;
      derive(r, k);
    }
    if (any >= 0) return;
  }
  keys_.compute(points, begin, rows, divide);
  for (std::size_t r = 0; r < rows; ++r) derive(r, keys_[r]);
}

IWLOMAP_CPU_CLONES
std::size_t update_targets(BatchScratch::Target* targets, std::size_t count, bool cells_moved, const BatchValues& in,
                           const Updater& u) noexcept {
  std::size_t newly_known = 0;
  const auto update = [&](const BatchScratch::Target& t) {
    if (observe_voxel(*t.block, *t.voxel, in.intensity(t.row), in.occupied_flag(t.row), in.weight(t.row), u))
      ++newly_known;
  };
  constexpr std::size_t kAhead = 64;
  if (cells_moved) {
    const auto address = [](BatchScratch::Target& t) { t.voxel = &t.block->existing(t.index); };
    for (std::size_t j = 0; j < std::min(count, kAhead); ++j) address(targets[j]);
    for (std::size_t j = 0; j < count; ++j) {
      if (j + kAhead < count) {
        address(targets[j + kAhead]);
        __builtin_prefetch(targets[j + kAhead].voxel, 1);
      }
      update(targets[j]);
    }
  } else {
    for (std::size_t j = 0; j < count; ++j) {
      if (j + kAhead < count) __builtin_prefetch(targets[j + kAhead].voxel, 1);
      update(targets[j]);
    }
  }
  return newly_known;
}

BatchScratch& batch_scratch() {
  // On the heap (its arrays take about 330 KiB), allocated on a thread's first batch.
  thread_local const std::unique_ptr<BatchScratch> scratch = std::make_unique<BatchScratch>();
  return *scratch;
}

}  // namespace iwlomap::detail
