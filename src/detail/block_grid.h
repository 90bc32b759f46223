// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The sparse block grid of the RAM backend (and of the Disk backend's tiles): voxels live in dense
// 8x8x8 blocks, allocated on first touch; blocks are found through a FlatKeyMap keyed by block
// coordinate. A voxel costs 8 bytes inside a block: float log-odds, uint16 count and 2 spare
// bytes. Log-odds and count share a cache line, so an update costs one cache miss, not two
// (measured: the separate arrays of a 6-byte layout made batch updates ~30% slower). A count of 0
// means "unknown"; every observed voxel has count >= 1.

#include "detail/flat_key_map.h"
#include "iwlomap/iwlo.h"
#include "iwlomap/voxel_key.h"

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <type_traits>
#include <vector>

namespace iwlomap::detail {

inline constexpr int kBlockShift = 3;
inline constexpr int kBlockEdge = 1 << kBlockShift;                 // voxels along a block edge
inline constexpr int kBlockVoxels = kBlockEdge * kBlockEdge * kBlockEdge;  // 512

// Arithmetic right shift is floor division by 8 for negative keys too (guaranteed by GCC and
// Clang, and by the standard from C++20).
static_assert((-1 >> 1) == -1, "iwlomap needs arithmetic right shift of negative integers");

[[nodiscard]] inline VoxelKey block_of(const VoxelKey& k) noexcept {
  return {k.x >> kBlockShift, k.y >> kBlockShift, k.z >> kBlockShift};
}
[[nodiscard]] inline int index_in_block(const VoxelKey& k) noexcept {
  constexpr int m = kBlockEdge - 1;
  return (k.x & m) | ((k.y & m) << kBlockShift) | ((k.z & m) << (2 * kBlockShift));
}
[[nodiscard]] inline VoxelKey voxel_of(const VoxelKey& block, int index) noexcept {
  constexpr int m = kBlockEdge - 1;
  return {block.x * kBlockEdge + (index & m), block.y * kBlockEdge + ((index >> kBlockShift) & m),
          block.z * kBlockEdge + ((index >> (2 * kBlockShift)) & m)};
}

struct Voxel {
  float log_odds = 0.0f;
  std::uint16_t count = 0;
  std::uint16_t spare = 0;
};
static_assert(sizeof(Voxel) == 8, "a voxel must stay within 8 bytes");

struct VoxelBlock {
  explicit VoxelBlock(const VoxelKey& k) : key(k) {}
  std::array<Voxel, kBlockVoxels> voxels{};
  std::uint32_t known = 0;  // voxels with count > 0
  VoxelKey key;
};

// Blocks are carved out of slabs rather than allocated one by one: a map of millions of voxels
// allocates thousands of blocks per scan, and one heap allocation per block cost more than
// updating it. Slabs grow from 64 KiB to 2 MiB and come from mmap (see block_grid.cpp).
// The two ways a stored voxel changes, shared by every backend. Each returns true when the voxel
// was unknown before, so the caller can count it in its own totals (the block's count is kept here).

/// One IWLO observation of voxel \p v of block \p b.
inline bool observe_voxel(VoxelBlock& b, Voxel& v, double intensity, bool occupied_flag, double weight,
                          const iwlo::Updater& updater) {
  const bool was_unknown = v.count == 0;
  if (was_unknown) ++b.known;
  iwlo::apply_observation(v.log_odds, v.count, intensity, occupied_flag, weight, updater);
  return was_unknown;
}

/// Absolute log-odds (IMapperBackend::set_log_odds()): an unknown voxel becomes known with count 1.
inline bool set_voxel_log_odds(VoxelBlock& b, Voxel& v, float log_odds) {
  const bool was_unknown = v.count == 0;
  if (was_unknown) {
    ++b.known;
    v.count = 1;
  }
  v.log_odds = log_odds;
  return was_unknown;
}

static_assert(std::is_trivially_destructible_v<VoxelBlock>, "BlockPool releases slabs without destroying blocks");

class BlockPool {
 public:
  BlockPool() = default;
  BlockPool(const BlockPool&) = delete;
  BlockPool& operator=(const BlockPool&) = delete;
  ~BlockPool() { release(); }

  VoxelBlock* allocate(const VoxelKey& key);
  void release() noexcept;
  [[nodiscard]] std::size_t bytes() const noexcept { return bytes_; }

 private:
  struct Slab {
    void* memory;
    std::size_t size;
  };
  std::vector<Slab> slabs_;
  std::size_t used_ = 0;      // bytes used in the last slab
  std::size_t capacity_ = 0;  // bytes in the last slab
  std::size_t bytes_ = 0;     // all slabs
};

class BlockGrid {
 public:
  BlockGrid() = default;
  BlockGrid(const BlockGrid&) = delete;
  BlockGrid& operator=(const BlockGrid&) = delete;
  // Moving keeps every block where it is (the pool moves as a pointer).
  BlockGrid(BlockGrid&&) noexcept = default;
  BlockGrid& operator=(BlockGrid&&) noexcept = default;

  [[nodiscard]] VoxelBlock* find(const VoxelKey& block_key) const noexcept {
    const std::uint32_t i = index_.find(block_key);
    return i == FlatKeyMap::kEmpty ? nullptr : blocks_[i];
  }

  VoxelBlock& get_or_create(const VoxelKey& block_key) {
    const auto next = static_cast<std::uint32_t>(blocks_.size());
    const std::uint32_t i = index_.insert(block_key, next);
    if (i == next) blocks_.push_back(pool_->allocate(block_key));
    return *blocks_[i];
  }

  [[nodiscard]] const std::vector<VoxelBlock*>& blocks() const noexcept { return blocks_; }
  [[nodiscard]] std::size_t num_blocks() const noexcept { return blocks_.size(); }

  /// Drops blocks without known voxels (copying the others into fresh slabs, so the memory is
  /// given back) and shrinks the index to fit; returns the voxel slots freed.
  std::size_t prune() {
    auto pool = std::make_unique<BlockPool>();
    std::vector<VoxelBlock*> kept;
    std::size_t freed = 0;
    for (VoxelBlock* b : blocks_) {
      if (b->known == 0) {
        freed += kBlockVoxels;
        continue;
      }
      VoxelBlock* copy = pool->allocate(b->key);
      *copy = *b;
      kept.push_back(copy);
    }
    kept.shrink_to_fit();
    blocks_.swap(kept);
    pool_ = std::move(pool);
    index_.reset(blocks_.size());
    for (std::uint32_t i = 0; i < blocks_.size(); ++i) index_.insert(blocks_[i]->key, i);
    return freed;
  }

  void clear() {
    blocks_.clear();
    blocks_.shrink_to_fit();
    pool_ = std::make_unique<BlockPool>();
    index_.reset();
  }

  /// Bytes held: block slabs, the block pointer array and the index.
  [[nodiscard]] std::size_t bytes() const noexcept {
    return pool_->bytes() + blocks_.capacity() * sizeof(blocks_[0]) + index_.bytes();
  }

 private:
  std::unique_ptr<BlockPool> pool_ = std::make_unique<BlockPool>();
  std::vector<VoxelBlock*> blocks_;
  FlatKeyMap index_;
};

/// Writing accessor with a last-block cache: consecutive updates in one block skip the hash look-up.
class BlockAccessor {
 public:
  explicit BlockAccessor(BlockGrid& grid) : grid_(&grid) {}
  VoxelBlock& block(const VoxelKey& block_key) {
    if (last_ == nullptr || last_->key != block_key) last_ = &grid_->get_or_create(block_key);
    return *last_;
  }

 private:
  BlockGrid* grid_;
  VoxelBlock* last_ = nullptr;
};

/// Reading accessor with a last-block cache that also caches a miss as a miss (never as a block).
class ConstBlockAccessor {
 public:
  explicit ConstBlockAccessor(const BlockGrid& grid) : grid_(&grid) {}
  [[nodiscard]] const VoxelBlock* block(const VoxelKey& block_key) {
    if (!valid_ || last_key_ != block_key) {
      last_ = grid_->find(block_key);
      last_key_ = block_key;
      valid_ = true;
    }
    return last_;
  }

 private:
  const BlockGrid* grid_;
  const VoxelBlock* last_ = nullptr;
  VoxelKey last_key_{};
  bool valid_ = false;
};

}  // namespace iwlomap::detail
