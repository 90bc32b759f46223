// SPDX-License-Identifier: BSD-3-Clause
// The storage room on its own: the block layout, the key map, the cell pool and the slab cache,
// each against a plain reference.

#include "iwlomap/map_memory.h"
#include "iwlomap/probability_updater.h"
#include "storage/block_grid.h"
#include "storage/flat_key_map.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <cstring>
#include <map>
#include <random>
#include <set>
#include <unordered_map>
#include <vector>

namespace iwlomap {
namespace {

// The block layout behind the RAM grid: index_in_block() and voxel_of() are inverse, a cell is
// 2 x 2 x 1 voxels at four consecutive indices, and cells_of_mask_word() finds, for any 64-bit
// word of a 512-bit block mask, exactly the cells holding a set bit (checked bit by bit).
TEST(BlockLayout, CellsOfIndicesAndMaskWordsMatchBitByBit) {
  using namespace detail;
  const VoxelKey block{-3, 5, -1};
  std::set<int> seen;
  for (int x = 0; x < 8; ++x)
    for (int y = 0; y < 8; ++y)
      for (int z = 0; z < 8; ++z) {
        const VoxelKey k{block.x * 8 + x, block.y * 8 + y, block.z * 8 + z};
        const int i = index_in_block(k);
        ASSERT_TRUE(i >= 0 && i < kBlockVoxels);
        EXPECT_EQ(voxel_of(block, i), k);
        seen.insert(i);
        // The voxels of one cell share x / 2, y / 2 and z.
        EXPECT_EQ(i >> kCellShift, ((x >> 1) & 3) | (((y >> 1) & 3) << 2) | (z << 4));
      }
  EXPECT_EQ(seen.size(), static_cast<std::size_t>(kBlockVoxels));
  std::mt19937_64 rng(5u);
  for (int round = 0; round < 2000; ++round) {
    // Sparse and dense words: a few random bits, or all but a few.
    std::uint64_t word = 0;
    const int bits = static_cast<int>(rng() % 6);
    for (int b = 0; b < bits; ++b) word |= std::uint64_t{1} << (rng() % 64);
    if (round % 3 == 0) word = ~word;
    const int w = round % 8;
    const CellMask got = cells_of_mask_word(word, w);
    CellMask want;
    for (int b = 0; b < 64; ++b)
      if ((word >> b) & 1u) want |= CellMask::of((w * 64 + b) >> kCellShift);
    ASSERT_EQ(got.word, want.word) << "word " << word << " at " << w;
  }
}

// The key map against std::unordered_map on keys spread over the whole int32 range (negative
// ones included), through several rounds of growth, then reset and reuse.
TEST(FlatKeyMap, AgreesWithUnorderedMapWhenGrowing) {
  std::mt19937_64 rng(3u);
  detail::FlatKeyMap map;
  std::unordered_map<VoxelKey, std::uint32_t, VoxelKeyHash> ref;
  const auto random_key = [&] {
    // Half clustered (neighbouring blocks), half anywhere.
    if (rng() % 2 == 0)
      return VoxelKey{static_cast<std::int32_t>(rng() % 40) - 20, static_cast<std::int32_t>(rng() % 40) - 20,
                      static_cast<std::int32_t>(rng() % 8) - 4};
    return VoxelKey{static_cast<std::int32_t>(rng()), static_cast<std::int32_t>(rng()), static_cast<std::int32_t>(rng())};
  };
  for (std::uint32_t i = 0; i < 50000; ++i) {
    const VoxelKey k = random_key();
    const auto [it, inserted] = ref.emplace(k, i);
    EXPECT_EQ(map.insert(k, i), it->second);  // an existing key keeps its first value
    (void)inserted;
  }
  EXPECT_EQ(map.size(), ref.size());
  for (const auto& [k, v] : ref) ASSERT_EQ(map.find(k), v);
  for (int i = 0; i < 1000; ++i) {
    const VoxelKey k = random_key();
    const auto it = ref.find(k);
    EXPECT_EQ(map.find(k), it == ref.end() ? detail::FlatKeyMap::kEmpty : it->second);
  }
  map.clear_keep_capacity();
  EXPECT_EQ(map.size(), 0u);
  for (const auto& [k, v] : ref) ASSERT_EQ(map.find(k), detail::FlatKeyMap::kEmpty);
  map.reset(10);
  EXPECT_EQ(map.insert({1, 2, 3}, 7u), 7u);
  EXPECT_EQ(map.find({1, 2, 3}), 7u);
  EXPECT_LE(map.bytes(), 64u * 16u);  // shrunk to a small table
}

// Size classes hold 1, 2, 4, ... 128 cells; a freed array is handed out again for its class only,
// and arrays in use never overlap.
TEST(CellPool, ReusesFreedArraysOfTheSameClassOnly) {
  using detail::CellPool;
  EXPECT_EQ(CellPool::class_of(1), 0);
  EXPECT_EQ(CellPool::class_of(2), 1);
  EXPECT_EQ(CellPool::class_of(3), 2);
  EXPECT_EQ(CellPool::class_of(4), 2);
  EXPECT_EQ(CellPool::class_of(5), 3);
  EXPECT_EQ(CellPool::class_of(128), 7);
  CellPool pool;
  detail::Cell* a = pool.allocate(3);  // 8 cells
  detail::Cell* b = pool.allocate(3);
  detail::Cell* c = pool.allocate(0);
  const auto overlap = [](const detail::Cell* x, int nx, const detail::Cell* y, int ny) {
    return x < y + ny && y < x + nx;
  };
  EXPECT_FALSE(overlap(a, 8, b, 8));
  EXPECT_FALSE(overlap(a, 8, c, 1));
  EXPECT_FALSE(overlap(b, 8, c, 1));
  std::memset(static_cast<void*>(a), 0xab, 8 * sizeof(detail::Cell));
  pool.free(a, 3);
  EXPECT_NE(pool.allocate(2), a);  // another class never gets it
  EXPECT_EQ(pool.allocate(3), a);  // the freed array of class 3 comes back for class 3
  EXPECT_NE(pool.allocate(3), a);
}

// A grid against a dense reference: cells added in any order keep every voxel where it was.
TEST(BlockGrid, KeepsVoxelsWhenCellsAreAddedInAnyOrder) {
  std::mt19937 rng(9u);
  detail::BlockGrid grid;
  std::map<VoxelKey, std::uint32_t> ref;  // the grid keeps words; here each word counts visits
  for (int i = 0; i < 20000; ++i) {
    const VoxelKey k{static_cast<std::int32_t>(rng() % 48) - 24, static_cast<std::int32_t>(rng() % 48) - 24,
                     static_cast<std::int32_t>(rng() % 16) - 8};
    detail::VoxelBlock& b = grid.get_or_create(detail::block_of(k));
    detail::Voxel& v = grid.voxel(b, detail::index_in_block(k));
    if (!v.known()) ++b.known;
    ++v.word;
    ++ref[k];
  }
  std::size_t known = 0;
  for (const auto& [k, n] : ref) {
    const detail::VoxelBlock* b = grid.find(detail::block_of(k));
    ASSERT_NE(b, nullptr);
    const detail::Voxel* v = b->find(detail::index_in_block(k));
    ASSERT_NE(v, nullptr);
    EXPECT_EQ(v->word, n);
    ++known;
  }
  EXPECT_EQ(grid.known_voxels(), known);
  // Every allocated cell holds a known voxel, so pruning frees nothing and moves everything.
  EXPECT_EQ(grid.prune(), 0u);
  EXPECT_EQ(grid.known_voxels(), known);
  for (const auto& [k, n] : ref) ASSERT_EQ(grid.find(detail::block_of(k))->find(detail::index_in_block(k))->word, n);
}

// The slab cache keeps the memory of destroyed maps only while another map lives, unless the
// process asks to retain some (map_memory.h).
TEST(MapMemory, ReleasedWhenLastMapIsDestroyedUnlessRetained) {
  Eigen::MatrixXd pts(20000, 3);
  std::mt19937 rng(1u);
  std::uniform_real_distribution<double> pos(-10.0, 10.0);
  for (Eigen::Index i = 0; i < pts.rows(); ++i) pts.row(i) << pos(rng), pos(rng), pos(rng);
  const Eigen::VectorXd in = Eigen::VectorXd::Constant(pts.rows(), 200.0);
  const std::vector<bool> occ(static_cast<std::size_t>(pts.rows()), true);
  const auto fill_and_destroy = [&] {
    ProbabilityUpdater m(0.1);
    m.batch_update_iwlo(pts, in, occ);
  };
  ASSERT_EQ(get_retained_map_memory(), 0u);
  {
    const ProbabilityUpdater keeper(0.1);
    fill_and_destroy();
    EXPECT_GT(get_cached_map_memory(), 0u);  // kept for the next map while one lives
  }
  EXPECT_EQ(get_cached_map_memory(), 0u);  // the last map went: everything given back
  set_retained_map_memory(std::size_t{64} << 20);
  fill_and_destroy();
  EXPECT_GT(get_cached_map_memory(), 0u);
  EXPECT_LE(get_cached_map_memory(), std::size_t{64} << 20);
  set_retained_map_memory(0);  // lowering the limit with no map alive trims at once
  EXPECT_EQ(get_cached_map_memory(), 0u);
}

}  // namespace
}  // namespace iwlomap
