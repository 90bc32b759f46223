// SPDX-License-Identifier: BSD-3-Clause
#include "integrate/block_sorted_batch.h"

#include "storage/flat_key_map.h"

#include <algorithm>
#include <limits>

namespace iwlomap::detail {
namespace {

constexpr std::uint32_t kNoSlot = std::numeric_limits<std::uint32_t>::max();

}  // namespace

bool BlockSortedBatch::suits(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities, std::size_t skipped,
                             const FloorDivider& divide) {
  const auto n = static_cast<std::size_t>(points.rows());
  if (n - skipped < kMinRows) return false;
  FlatKeyMap distinct;
  std::size_t seen = 0;
  for_each_finite_key(points, intensities, std::min(n, kSampleRows), skipped != 0, divide,
                      [&](std::size_t, const VoxelKey& k) {
                        distinct.insert(block_of(k), 0);
                        ++seen;
                      });
  return distinct.size() * 4 > seen;
}

bool BlockSortedBatch::build(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                             const std::vector<bool>& is_occupied, std::size_t skipped, const FloorDivider& divide) {
  const auto n = static_cast<std::size_t>(points.rows());
  if (skipped >= n) return false;
  const bool any_skipped = skipped != 0;
  // The box of blocks, from the coordinates' extremes (floor is monotonic, so the extreme keys
  // are the keys of the extreme coordinates).
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  if (!any_skipped) {
    lo = points.colwise().minCoeff().transpose();
    hi = points.colwise().maxCoeff().transpose();
  } else {
    for (Eigen::Index i = 0; i < points.rows(); ++i)
      if (row_is_finite(points, intensities, i)) {
        lo = lo.cwiseMin(points.row(i).transpose());
        hi = hi.cwiseMax(points.row(i).transpose());
      }
  }
  const auto block_at = [&](const Eigen::Vector3d& p) {
    return block_of({static_cast<std::int32_t>(divide(p.x())), static_cast<std::int32_t>(divide(p.y())),
                     static_cast<std::int32_t>(divide(p.z()))});
  };
  const VoxelKey b0 = block_at(lo), b1 = block_at(hi);
  const std::int64_t ex = std::int64_t{b1.x} - b0.x + 1, ey = std::int64_t{b1.y} - b0.y + 1,
                     ez = std::int64_t{b1.z} - b0.z + 1;
  const auto limit = static_cast<std::int64_t>(2 * n + 65536);
  // Checked factor by factor, so that no product can overflow.
  if (ex > limit || ey > limit / ex || ez > limit / (ex * ey)) return false;

  // Slots in the order of each block's first row, and the rows of each slot counted.
  dense_.assign(static_cast<std::size_t>(ex * ey * ez), kNoSlot);
  slot_of_.assign(n, kNoSlot);
  index_of_.resize(n);
  keys_.clear();
  begin_.clear();
  for_each_finite_key(points, intensities, n, any_skipped, divide, [&](std::size_t row, const VoxelKey& k) {
    const VoxelKey b = block_of(k);
    const auto at = static_cast<std::size_t>(((b.z - b0.z) * ey + (b.y - b0.y)) * ex + (b.x - b0.x));
    std::uint32_t s = dense_[at];
    if (s == kNoSlot) {
      s = dense_[at] = static_cast<std::uint32_t>(keys_.size());
      keys_.push_back(b);
      begin_.push_back(0);
    }
    ++begin_[s];
    slot_of_[row] = s;
    index_of_[row] = static_cast<std::uint16_t>(index_in_block(k));
  });
  std::uint32_t sum = 0;
  for (std::uint32_t& c : begin_) {
    const std::uint32_t rows_of_slot = c;
    c = sum;
    sum += rows_of_slot;
  }
  begin_.push_back(sum);

  // Each row's entry at its slot's next place: a stable counting sort, from what the first pass
  // kept of each row (its slot, kNoSlot for a skipped row, and its index in the block).
  entries_.resize(sum);
  std::vector<std::uint32_t> next(begin_.begin(), begin_.end() - 1);
  for (std::size_t row = 0; row < n; ++row) {
    const std::uint32_t s = slot_of_[row];
    if (s == kNoSlot) continue;
    Entry& e = entries_[next[s]++];
    e.intensity = intensities[static_cast<Eigen::Index>(row)];
    e.row = static_cast<std::uint32_t>(row);
    e.index = index_of_[row];
    e.occupied_flag = is_occupied[row] ? 1 : 0;
  }
  return true;
}

}  // namespace iwlomap::detail
