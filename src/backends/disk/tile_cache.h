// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The Disk backend's resident tiles: at most `capacity` tiles in RAM between calls, each a block
// grid, evicted least recently used first. A dirty tile is staged (TileStore::stage()) when it is
// evicted. Tiles that a call needs are pinned for the call's duration and never evicted by it.

#include "backends/disk/tile_store.h"
#include "integrate/hit_accumulator.h"
#include "iwlomap/voxel_key.h"
#include "storage/block_grid.h"

#include <cstddef>
#include <cstdint>
#include <memory>
#include <unordered_map>
#include <vector>

namespace iwlomap::detail {

/// Whether tiles accumulate hit statistics, and the epoch of the map's statistics (tile_file.h).
struct HitSettings {
  bool enabled = false;
  std::uint32_t epoch = 0;
};

struct Tile {
  explicit Tile(const VoxelKey& k) : key(k) {}
  VoxelKey key;
  BlockGrid grid;
  std::unique_ptr<HitAccumulator> hits;  // while accumulation is on
  bool dirty = false;   // the grid is newer than the tile's newest image on disk
  bool pinned = false;  // needed by the call in progress
  std::uint64_t last_used = 0;
};

class TileCache {
 public:
  /// \p known_total is the map's count of known voxels: reading a tile corrects it when the file
  /// changed since its header was read.
  /// \p hits is the map's setting, read whenever a tile is made or written; \p format is the
  /// map's voxel format (the Updater's, which outlives the cache), the one of every resident tile.
  TileCache(TileStore& store, std::size_t capacity, double resolution, std::uint32_t tile_voxels,
            std::size_t& known_total, const HitSettings& hits, const iwlo::VoxelFormat& format)
      : store_(store), capacity_(capacity), resolution_(resolution), tile_voxels_(tile_voxels),
        known_total_(known_total), hits_(hits), format_(format) {}

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
  /// Reads and fully checks the newest image of tile \p key (which must be on disk) into a tile
  /// that is not cached. Nothing changes when it throws.
  [[nodiscard]] std::unique_ptr<Tile> load(const VoxelKey& key);
  /// Encodes \p t with its statistics into \p out; returns its known voxels.
  std::uint64_t encode(const Tile& t, std::vector<std::uint8_t>& out) const;
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
  [[nodiscard]] std::unique_ptr<Tile> new_tile(const VoxelKey& key) const;
  void make_room();
  Tile& insert(std::unique_ptr<Tile> tile);

  TileStore& store_;
  std::size_t capacity_;
  double resolution_;
  std::uint32_t tile_voxels_;
  std::size_t& known_total_;
  const HitSettings& hits_;
  const iwlo::VoxelFormat& format_;
  std::vector<std::unique_ptr<Tile>> resident_;
  std::unordered_map<VoxelKey, Tile*, VoxelKeyHash> index_;  // of resident_
  std::uint64_t tick_ = 0;
  std::size_t peak_ = 0;
  std::vector<std::uint8_t> io_buffer_;  // reused between reads and evictions
};

}  // namespace iwlomap::detail
