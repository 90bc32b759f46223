// SPDX-License-Identifier: BSD-3-Clause
// BlockSortedBatch: which batches it takes, and that it groups rows by block stably, with
// blocks in the order of their first row.

#include "integrate/block_sorted_batch.h"
#include "iwlomap/voxel_key.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <set>
#include <vector>

namespace iwlomap {
namespace {

using detail::BlockSortedBatch;

struct Batch {
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
  std::vector<bool> occupied;
};

// n points uniform in a box of side metres, some rows repeating an earlier row's point, every
// 97th row non-finite when with_nan.
Batch scattered(Eigen::Index n, double side, bool with_nan, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> u(-0.5 * side, 0.5 * side);
  Batch b;
  b.points.resize(n, 3);
  b.intensities.resize(n);
  b.occupied.resize(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) {
    if (i > 10 && i % 7 == 0)
      b.points.row(i) = b.points.row(i - 1 - static_cast<Eigen::Index>(rng() % 10));
    else
      b.points.row(i) << u(rng), u(rng), 0.25 * u(rng);
    b.intensities[i] = static_cast<double>(rng() % 256);
    b.occupied[static_cast<std::size_t>(i)] = rng() % 3 != 0;
  }
  if (with_nan)
    for (Eigen::Index i = 5; i < n; i += 97) b.points(i, 1) = std::numeric_limits<double>::quiet_NaN();
  return b;
}

std::size_t count_skipped(const Batch& b) {
  std::size_t s = 0;
  for (Eigen::Index i = 0; i < b.points.rows(); ++i)
    if (!b.points.row(i).allFinite() || !std::isfinite(b.intensities[i])) ++s;
  return s;
}

TEST(BlockSortedBatch, GroupsEveryFiniteRowByBlockInCallOrderWithBlocksInFirstRowOrder) {
  const double r = 0.05;
  const detail::FloorDivider divide(r);
  for (const bool with_nan : {false, true}) {
    SCOPED_TRACE(with_nan ? "with non-finite rows" : "all rows finite");
    const Batch b = scattered(50000, 10.0, with_nan, 7u);
    const std::size_t skipped = count_skipped(b);
    ASSERT_EQ(skipped != 0, with_nan);
    ASSERT_TRUE(BlockSortedBatch::suits(b.points, b.intensities, skipped, divide));
    BlockSortedBatch sorted;
    ASSERT_TRUE(sorted.build(b.points, b.intensities, b.occupied, skipped, divide));

    // Expected: the blocks in the order of their first finite row, each with its rows in order.
    std::vector<VoxelKey> first_order;
    std::set<VoxelKey> seen;
    for (Eigen::Index i = 0; i < b.points.rows(); ++i) {
      if (!b.points.row(i).allFinite()) continue;
      const VoxelKey blk = detail::block_of(world_to_key(b.points.row(i).transpose(), r));
      if (seen.insert(blk).second) first_order.push_back(blk);
    }
    ASSERT_EQ(sorted.blocks(), first_order.size());
    std::size_t entries = 0;
    for (std::size_t s = 0; s < sorted.blocks(); ++s) {
      ASSERT_EQ(sorted.block(s), first_order[s]) << "slot " << s;
      std::uint32_t last_row = 0;
      for (const auto* e = sorted.first(s); e != sorted.first(s + 1); ++e, ++entries) {
        if (e != sorted.first(s)) {
          ASSERT_LT(last_row, e->row) << "rows of a block out of call order";
        }
        last_row = e->row;
        const auto i = static_cast<Eigen::Index>(e->row);
        const VoxelKey k = world_to_key(b.points.row(i).transpose(), r);
        ASSERT_EQ(detail::block_of(k), sorted.block(s));
        ASSERT_EQ(e->index, detail::index_in_block(k));
        ASSERT_EQ(e->intensity, b.intensities[i]);
        ASSERT_EQ(e->occupied_flag != 0, b.occupied[e->row]);
      }
    }
    EXPECT_EQ(entries, static_cast<std::size_t>(b.points.rows()) - skipped);
  }
}

TEST(BlockSortedBatch, LeavesScanLikeSmallAndFarSpreadBatchesToTheCallOrderPath) {
  const double r = 0.05;
  const detail::FloorDivider divide(r);
  // Consecutive rows along lines, a few centimetres apart: many rows per block.
  Batch line;
  const Eigen::Index n = 40000;
  line.points.resize(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) line.points.row(i) << 0.01 * static_cast<double>(i % 2000), 0.3 * (i / 2000), 1.0;
  line.intensities = Eigen::VectorXd::Constant(n, 100.0);
  EXPECT_FALSE(BlockSortedBatch::suits(line.points, line.intensities, 0, divide));
  // Scattered, but fewer rows than kMinRows.
  const Batch few = scattered(static_cast<Eigen::Index>(BlockSortedBatch::kMinRows) - 1, 10.0, false, 8u);
  EXPECT_FALSE(BlockSortedBatch::suits(few.points, few.intensities, 0, divide));
  EXPECT_TRUE(BlockSortedBatch::suits(scattered(static_cast<Eigen::Index>(BlockSortedBatch::kMinRows), 10.0, false, 8u)
                                          .points,
                                      Eigen::VectorXd::Zero(static_cast<Eigen::Index>(BlockSortedBatch::kMinRows)), 0,
                                      divide));
  // Scattered, but one point 10 km away: the box of blocks is far larger than the batch.
  Batch far = scattered(40000, 10.0, false, 9u);
  far.points.row(100) << 10000.0, 0.0, 0.0;
  ASSERT_TRUE(BlockSortedBatch::suits(far.points, far.intensities, 0, divide));
  BlockSortedBatch sorted;
  EXPECT_FALSE(sorted.build(far.points, far.intensities, far.occupied, 0, divide));
}

}  // namespace
}  // namespace iwlomap
