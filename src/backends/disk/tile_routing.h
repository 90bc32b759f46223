// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The items (observations, voxels) of one Disk backend call sorted by tile, stably, so that each
// tile is loaded once per call and every voxel sees its observations in call order.

#include "backends/disk/tile_file.h"
#include "iwlomap/voxel_key.h"
#include "storage/block_grid.h"
#include "storage/flat_key_map.h"

#include <cstddef>
#include <cstdint>
#include <vector>

namespace iwlomap::detail {

class TileRouting {
 public:
  explicit TileRouting(std::uint32_t tile_voxels)
      : tile_voxels_(tile_voxels), tile_blocks_(static_cast<std::int32_t>(tile_voxels / kBlockEdge)) {}

  [[nodiscard]] VoxelKey tile_of_voxel(const VoxelKey& k) const noexcept {
    const auto e = static_cast<std::int32_t>(tile_voxels_);
    return {floor_div(k.x, e), floor_div(k.y, e), floor_div(k.z, e)};
  }
  [[nodiscard]] VoxelKey tile_of_block(const VoxelKey& b) const noexcept {
    return {floor_div(b.x, tile_blocks_), floor_div(b.y, tile_blocks_), floor_div(b.z, tile_blocks_)};
  }

  /// Forgets the tiles of the previous call.
  void reset() {
    slot_tiles_.clear();
    slot_index_.clear_keep_capacity();
  }
  /// The slot of \p tile, added when new.
  std::uint32_t slot(const VoxelKey& tile) {
    const auto next = static_cast<std::uint32_t>(slot_tiles_.size());
    const std::uint32_t s = slot_index_.insert(tile, next);
    if (s == next) slot_tiles_.push_back(tile);
    return s;
  }
  /// The slot of \p tile, or FlatKeyMap::kEmpty.
  [[nodiscard]] std::uint32_t find(const VoxelKey& tile) const noexcept { return slot_index_.find(tile); }

  /// reset(), then the slot of each of items 0..n-1 (voxel_key(i) is item i's key) in slot_of().
  template <class KeyOf>
  void assign(std::size_t n, KeyOf&& voxel_key) {
    reset();
    slot_of_.resize(n);
    const std::int64_t e = tile_voxels_;
    std::int64_t lo[3] = {0, 0, 0};
    std::uint32_t last = FlatKeyMap::kEmpty;
    for (std::size_t i = 0; i < n; ++i) {
      const VoxelKey k = voxel_key(i);
      // Consecutive items mostly share a tile: its bounds are checked before the hash map.
      if (last == FlatKeyMap::kEmpty || k.x < lo[0] || k.x >= lo[0] + e || k.y < lo[1] || k.y >= lo[1] + e ||
          k.z < lo[2] || k.z >= lo[2] + e) {
        const VoxelKey t = tile_of_voxel(k);
        last = slot(t);
        lo[0] = t.x * e;
        lo[1] = t.y * e;
        lo[2] = t.z * e;
      }
      slot_of_[i] = last;
    }
  }
  /// After assign(): the items sorted by slot, stably: slot s owns order()[begin(s), begin(s + 1)).
  void sort(std::size_t n) {
    const std::size_t slots = slot_tiles_.size();
    begin_.assign(slots + 1, 0);
    for (std::size_t i = 0; i < n; ++i) ++begin_[slot_of_[i] + 1];
    for (std::size_t s = 0; s < slots; ++s) begin_[s + 1] += begin_[s];
    order_.resize(n);
    std::vector<std::size_t> next(begin_.begin(), begin_.end() - 1);
    for (std::size_t i = 0; i < n; ++i) order_[next[slot_of_[i]]++] = static_cast<std::uint32_t>(i);
  }
  /// Extends the slot ranges of sort() to slots added since (they own no items).
  void close_ranges() { begin_.resize(slot_tiles_.size() + 1, begin_.back()); }

  [[nodiscard]] const std::vector<VoxelKey>& tiles() const noexcept { return slot_tiles_; }
  [[nodiscard]] std::uint32_t slot_of(std::size_t item) const noexcept { return slot_of_[item]; }
  [[nodiscard]] std::size_t begin(std::size_t slot) const noexcept { return begin_[slot]; }
  [[nodiscard]] const std::uint32_t* order() const noexcept { return order_.data(); }

  [[nodiscard]] std::size_t bytes() const noexcept {
    return slot_tiles_.capacity() * sizeof(VoxelKey) + slot_index_.bytes() +
           (slot_of_.capacity() + order_.capacity()) * sizeof(std::uint32_t) + begin_.capacity() * sizeof(std::size_t);
  }

 private:
  std::uint32_t tile_voxels_;
  std::int32_t tile_blocks_;
  std::vector<VoxelKey> slot_tiles_;  // tile coordinate of each slot
  FlatKeyMap slot_index_;             // tile coordinate -> slot
  std::vector<std::uint32_t> slot_of_;
  std::vector<std::uint32_t> order_;
  std::vector<std::size_t> begin_;
};

}  // namespace iwlomap::detail
