// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The Disk backend's resident tiles: at most `capacity` tiles in RAM between calls, each a block
// grid, evicted least recently used first. A dirty tile is staged (TileStore::stage()) when it is
// evicted. Tiles that a call needs are pinned for the call's duration and never evicted by it.

#include "backends/disk/tile_store.h"
#include "iwlomap/voxel_key.h"
#include "storage/block_grid.h"

#include <cstddef>
#include <cstdint>
#include <memory>
#include <unordered_map>
#include <vector>

namespace iwlomap::detail {

struct Tile {
  explicit Tile(const VoxelKey& k) : key(k) {}
  VoxelKey key;
  BlockGrid grid;
  bool dirty = false;   // the grid is newer than the tile's newest image on disk
  bool pinned = false;  // needed by the call in progress
  std::uint64_t last_used = 0;
};

class TileCache {
 public:
  /// \p known_total is the map's count of known voxels: reading a tile corrects it when the file
  /// changed since its header was read.
  TileCache(TileStore& store, std::size_t capacity, double resolution, std::uint32_t tile_voxels,
            std::size_t& known_total)
      : store_(store), capacity_(capacity), resolution_(resolution), tile_voxels_(tile_voxels),
        known_total_(known_total) {}

  /// The resident tile \p key, or null.
  [[nodiscard]] Tile* find(const VoxelKey& key) const;
  [[nodiscard]] const std::vector<std::unique_ptr<Tile>>& resident() const noexcept { return resident_; }
  [[nodiscard]] std::size_t capacity() const noexcept { return capacity_; }
  [[nodiscard]] std::size_t peak() const noexcept { return peak_; }
  /// Bytes of the reusable I/O buffer.
  [[nodiscard]] std::size_t buffer_bytes() const noexcept { return io_buffer_.capacity(); }

  /// Makes the tiles \p keys (at most capacity(), distinct) resident and pinned; out[i] is
  /// keys[i]'s tile. Tiles on disk are read (and checked) before any new tile is created, so a
  /// corrupt tile makes the call fail before a voxel changes. Unpin with a PinScope.
  void make_resident(const std::vector<VoxelKey>& keys, std::vector<Tile*>& out);
  /// Marks \p t as just used.
  void touch(Tile& t) noexcept { t.last_used = ++tick_; }

  /// Drops every resident tile without writing it.
  void clear() noexcept;
  /// Shrinks every resident tile's grid (BlockGrid::prune()); returns the voxel slots freed.
  std::size_t prune();

  /// Unpins every tile when it goes out of scope: on every exit path of a call.
  class PinScope {
   public:
    explicit PinScope(TileCache& c) : c_(c) {}
    ~PinScope() {
      for (auto& t : c_.resident_) t->pinned = false;
    }
    PinScope(const PinScope&) = delete;
    PinScope& operator=(const PinScope&) = delete;

   private:
    TileCache& c_;
  };

 private:
  std::unique_ptr<Tile> read_tile(const VoxelKey& key);
  void make_room();
  Tile& insert(std::unique_ptr<Tile> tile);

  TileStore& store_;
  std::size_t capacity_;
  double resolution_;
  std::uint32_t tile_voxels_;
  std::size_t& known_total_;
  std::vector<std::unique_ptr<Tile>> resident_;
  std::unordered_map<VoxelKey, Tile*, VoxelKeyHash> index_;  // of resident_
  std::uint64_t tick_ = 0;
  std::size_t peak_ = 0;
  std::vector<std::uint8_t> io_buffer_;  // reused between reads and evictions
};

}  // namespace iwlomap::detail
