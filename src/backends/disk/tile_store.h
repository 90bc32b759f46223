// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// What the Disk backend holds on disk: for every tile that has been written, its committed tile
// file and possibly a staged image, a newer complete state that an eviction appended to the
// staging file (one file for all evicted tiles, not fsync'ed: appending costs no file creation,
// which dominates on many file systems). Tile files change only when a tile is committed
// (flush()): a temporary file, fsync, rename, and one directory fsync per flush, so a crash leaves
// each tile file in its previous or its new state. A crash discards the staging file: the next
// open deletes it.

#include "backends/disk/map_directory.h"
#include "backends/disk/tile_file.h"
#include "iwlomap/voxel_key.h"

#include <cstddef>
#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

namespace iwlomap::detail {

/// The on-disk images of one tile.
struct TileImage {
  bool committed = false;
  bool staged = false;
  std::uint64_t committed_bytes = 0;
  std::uint64_t staged_offset = 0;  // in the staging file
  std::uint64_t staged_bytes = 0;
  std::size_t known = 0;  // known voxels of the newest image (staged, else committed)
};

class TileStore {
 public:
  /// Reads the header of every tile file of \p dir (fully checked), so that a damaged map fails
  /// here, before anything changes. Throws StorageError naming the file.
  TileStore(MapDirectory& dir, double resolution, std::uint32_t tile_voxels);
  ~TileStore();
  TileStore(const TileStore&) = delete;
  TileStore& operator=(const TileStore&) = delete;

  /// The image of tile \p key, or null when it has none on disk.
  [[nodiscard]] TileImage* find(const VoxelKey& key);
  [[nodiscard]] const std::unordered_map<VoxelKey, TileImage, VoxelKeyHash>& images() const noexcept {
    return images_;
  }

  /// Reads the newest image of a tile and checks its header; \p bytes receives the whole image,
  /// the return value names it in messages.
  TileHeader read(const VoxelKey& key, std::vector<std::uint8_t>& bytes, std::string& where);

  /// Appends \p encoded (the tile's complete state, \p known voxels) to the staging file. On
  /// failure nothing changes: an earlier staged image of the tile stays valid.
  void stage(const VoxelKey& key, const std::vector<std::uint8_t>& encoded, std::size_t known);
  /// Writes \p encoded as the tile's file, durably (the directory is synced by finish_commits());
  /// the tile's staged image, if any, is dropped. On failure the previous file and image stay.
  void commit(const VoxelKey& key, const std::vector<std::uint8_t>& encoded, std::size_t known);
  /// Commits the tile's staged image after checking it completely (a damaged staging file must
  /// never spoil a tile file). \p image_buffer and \p check_block are scratch.
  void commit_staged(const VoxelKey& key, std::vector<std::uint8_t>& image_buffer, DenseBlock& check_block);
  /// After a series of commits: the directory fsync, and the staging file removed once no image
  /// in it is needed.
  void finish_commits();

  /// Forgets every image: tile files are removed (a file that cannot be removed stays, with the
  /// known count of its header, and the first such error is rethrown at the end), the staging file
  /// goes. The directory is synced.
  void clear();

  /// Bytes of tile files, of the staging file.
  [[nodiscard]] std::uint64_t committed_bytes() const noexcept { return committed_bytes_; }
  [[nodiscard]] std::uint64_t staging_bytes() const noexcept { return staging_size_; }
  /// Known voxels of the newest images, in all.
  [[nodiscard]] std::size_t known() const noexcept;

 private:
  void unstage(TileImage& image) noexcept;
  void compact_staging();
  void drop_staging_if_unused() noexcept;
  [[nodiscard]] std::string staging_path() const { return dir_.path_of(kStagingName); }
  [[nodiscard]] std::size_t committed_known(const VoxelKey& key) const;

  MapDirectory& dir_;
  double resolution_;
  std::uint32_t tile_voxels_;
  std::unordered_map<VoxelKey, TileImage, VoxelKeyHash> images_;
  std::uint64_t committed_bytes_ = 0;
  int staging_fd_ = -1;
  std::uint64_t staging_size_ = 0;  // bytes of the staging file
  std::uint64_t staging_live_ = 0;  // bytes of its images still needed
  bool dir_sync_pending_ = false;   // renames since the last directory fsync
};

}  // namespace iwlomap::detail
