// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// What the Disk backend holds on disk: for every tile of the last commit, its tile file (named by
// the manifest, map_manifest.h), and possibly a staged image, a newer complete state that an
// eviction appended to the staging file (one file for all evicted tiles, not fsync'ed: appending
// costs no file creation, which dominates on many file systems). The map changes on disk only
// at a commit (flush()): the changed tiles are written to new files of the next generation
// (fsync'ed), the directory is synced, then the manifest is replaced; that rename is the commit.
// A failure before it removes the new files and leaves the map as it was; a crash leaves them to
// the next open, which removes them. Files a commit retired are removed once no reader holds the
// map (MapDirectory::exclude_readers()). A crash discards the staging file: the next open deletes
// it.

#include "backends/disk/map_directory.h"
#include "backends/disk/map_manifest.h"
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
  bool committed = false;  // named by the last commit
  std::uint64_t generation = 0;
  std::uint64_t committed_bytes = 0;
  std::size_t committed_known = 0;
  std::uint32_t header_crc = 0;
  bool staged = false;
  std::uint64_t staged_offset = 0;  // in the staging file
  std::uint64_t staged_bytes = 0;
  std::size_t known = 0;  // known voxels of the newest image (staged, else committed)
};

class TileStore {
 public:
  /// Reads the manifest and the header of every tile file it names, fully checked and matched
  /// against the manifest (a map without a manifest, written before them: the header of every
  /// tile file), so that a damaged map fails here, before anything changes. A tile file that is
  /// not part of the map is an error too. Throws StorageError naming the file. \p fallback is the
  /// state of a map without a manifest (its metadata's). \p collect_damage (repair()): a damaged,
  /// missing or foreign tile file is noted instead of thrown, and left out of the map.
  TileStore(MapDirectory& dir, double resolution, std::uint32_t tile_voxels, const MapState& fallback,
            bool collect_damage = false);
  ~TileStore();
  TileStore(const TileStore&) = delete;
  TileStore& operator=(const TileStore&) = delete;

  /// The image of tile \p key, or null when it has none on disk.
  [[nodiscard]] TileImage* find(const VoxelKey& key);
  [[nodiscard]] const std::unordered_map<VoxelKey, TileImage, VoxelKeyHash>& images() const noexcept {
    return images_;
  }
  /// The parameters and hit-statistics setting of the last commit.
  [[nodiscard]] const MapState& committed_state() const noexcept { return state_; }
  /// The manifest of the last commit (no retired files).
  [[nodiscard]] MapManifest committed_manifest() const;

  /// Reads the newest image of a tile and checks its header (and, for a committed file, that it
  /// is the file the manifest names); \p bytes receives the whole image, the return value names
  /// it in messages.
  TileHeader read(const VoxelKey& key, std::vector<std::uint8_t>& bytes, std::string& where);

  /// Appends \p encoded (the tile's complete state, \p known voxels) to the staging file. On
  /// failure nothing changes: an earlier staged image of the tile stays valid.
  void stage(const VoxelKey& key, const std::vector<std::uint8_t>& encoded, std::size_t known);

  // ---- a commit: write() or write_staged() per changed tile, then commit(); abort() on failure ----
  /// Writes \p encoded as the tile's file of the next commit, fsync'ed. Nothing is visible before
  /// commit().
  void write(const VoxelKey& key, const std::vector<std::uint8_t>& encoded, std::size_t known);
  /// write() of the tile's staged image after checking it completely (a damaged staging file
  /// must never spoil the map). \p image_buffer and \p check_block are scratch.
  void write_staged(const VoxelKey& key, std::vector<std::uint8_t>& image_buffer, DenseBlock& check_block);
  /// Makes the written tiles part of the map with \p state, atomically (see the file comment);
  /// \p drop_all first retires every tile (clear()). On failure, abort() before anything else.
  void commit(const MapState& state, bool drop_all = false);
  /// Forgets the tiles written since the last commit and removes their files. The map stays as
  /// the last commit left it.
  void abort() noexcept;
  /// Forgets every staged image: each tile is back to its committed state.
  void discard_staged() noexcept;
  /// After a constructor that collected damage: checks every committed tile completely (header,
  /// identity, payload), moves the damaged and foreign tile files into `damaged/` in the map
  /// directory and commits the map without them. Returns one line per file set aside (or
  /// forgotten, when missing). Writers only.
  std::vector<std::string> set_aside_damaged();
  /// Removes the files no commit names, unless a reader holds the map (then a later commit or
  /// open does). Writers only.
  void remove_retired() noexcept;

  /// Bytes of the committed tile files, of the staging file.
  [[nodiscard]] std::uint64_t committed_bytes() const noexcept { return committed_bytes_; }
  [[nodiscard]] std::uint64_t staging_bytes() const noexcept { return staging_size_; }
  /// Bytes of the manifest.
  [[nodiscard]] std::uint64_t manifest_bytes() const noexcept { return manifest_bytes_; }
  /// Known voxels of the newest images, in all.
  [[nodiscard]] std::size_t known() const noexcept;

 private:
  struct Damage {
    std::string file;  // path
    std::string what;  // the error's message
  };
  void open_manifest(const std::string& path);
  void check_named_tile(const ManifestTile& t, const std::string& tile_path, const std::string& path) const;
  void open_listed();
  void adopt(const ManifestTile& t);
  [[nodiscard]] static ManifestTile entry_of(const VoxelKey& key, const TileImage& image);
  // Runs \p check; with collect_damage_, a kCorrupt StorageError is noted for \p file instead.
  template <class Check>
  bool checked(const std::string& file, Check&& check);
  void unstage(TileImage& image) noexcept;
  void compact_staging();
  void drop_staging_if_unused() noexcept;
  [[nodiscard]] std::string staging_path() const { return dir_.path_of(kStagingName); }

  MapDirectory& dir_;
  double resolution_;
  std::uint32_t tile_voxels_;
  std::unordered_map<VoxelKey, TileImage, VoxelKeyHash> images_;
  std::uint64_t commit_ = 0;  // the last commit's number
  MapState state_;
  std::vector<ManifestTile> written_;   // files written since the last commit
  std::vector<RetiredFile> retired_;    // files no commit names, not yet removed
  bool collect_damage_ = false;
  std::vector<Damage> damage_;
  std::uint64_t committed_bytes_ = 0;
  std::uint64_t manifest_bytes_ = 0;
  int staging_fd_ = -1;
  std::uint64_t staging_size_ = 0;  // bytes of the staging file
  std::uint64_t staging_live_ = 0;  // bytes of its images still needed
};

}  // namespace iwlomap::detail
