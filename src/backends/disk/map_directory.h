// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// A Disk backend's map directory: the names of its files, its metadata file and its locks.
//
//   iwlomap_map.meta      text: format version, resolution and tile size (hex floats, exact)
//   iwlomap_map.manifest  the last commit: which file holds each tile, parameters (map_manifest.h)
//   iwlomap_map.lock      flock()ed (exclusive) while a mapper has the map open for writing
//   iwlomap_map.readers   flock()ed (shared) by every read-only mapper; a writer removes files
//                         that a commit retired only while it can lock it exclusively
//   tile_<x>_<y>_<z>.g<c>.iwt  a tile as written by commit c (tile_file.h); tile_<x>_<y>_<z>.iwt
//                         in a map written before manifests
//   iwlomap_map.staging   images of evicted tiles since the last flush (tile_store.h)
//   *.tmp                 writes in progress; a crash may leave them, the next open removes them

#include "iwlomap/iwlo.h"
#include "iwlomap/voxel_key.h"

#include <cstdint>
#include <string>
#include <vector>

namespace iwlomap::detail {

inline constexpr const char* kStagingName = "iwlomap_map.staging";
inline constexpr const char* kTempSuffix = ".tmp";
/// The metadata format this build writes: 3, maps with a manifest. 1 and 2 (before manifests;
/// 2 with hit statistics) are read, and become 3 at their first commit.
inline constexpr std::uint32_t kMapFormatVersion = 3;

/// "tile_<x>_<y>_<z>.g<generation>.iwt", or "tile_<x>_<y>_<z>.iwt" for generation 0.
[[nodiscard]] std::string tile_file_name(const VoxelKey& t, std::uint64_t generation = 0);
/// True, with the tile and generation, for exactly the names tile_file_name() produces.
/// Whether \p directory holds a map (its metadata file exists).
[[nodiscard]] bool holds_map(const std::string& directory);

[[nodiscard]] bool parse_tile_file_name(const std::string& name, VoxelKey& t, std::uint64_t& generation);

/// A tile file found in the directory.
struct ListedTile {
  std::string name;
  VoxelKey key{};
  std::uint64_t generation = 0;
};

/// The 13 IWLO parameters in the order the metadata and the manifest store them.
void params_to_array(const IwloParams& p, double (&v)[13]);
[[nodiscard]] IwloParams params_from_array(const double (&v)[13]);

/// The tile edge in voxels for \p tile_size metres at \p resolution: a whole multiple of 8
/// between 8 and kMaxTileVoxels. Throws std::invalid_argument otherwise.
[[nodiscard]] std::uint32_t tile_voxels_for(double resolution, double tile_size);

/// The contents of the metadata file.
struct MapMeta {
  std::uint32_t version = 0;
  double resolution = 0.0;
  double tile_size = 0.0;  // the effective size, tile_voxels * resolution
  std::uint32_t tile_voxels = 0;
  // What the map held when the metadata was last written; the manifest's state (map_manifest.h)
  // takes precedence once there is one.
  IwloParams params;             // the reference defaults in a file written before they were stored
  bool hit_statistics = false;   // accumulation on
  std::uint32_t hit_epoch = 0;   // incremented each time accumulation is turned on (tile_file.h)
};

/// An open map directory: created (with its parents) when missing, locked against a second
/// mapper, its metadata read (and checked against the requested geometry) or written, its tile
/// files listed. Nothing in the directory changes when the constructor throws, but for a
/// directory it creates and the lock files. Read-only, it takes the readers' lock (shared, held
/// until destruction: the files of the commit it reads stay) and writes nothing else (it creates
/// the empty readers' lock file when it is missing and can); the directory and its metadata must
/// exist.
class MapDirectory {
 public:
  /// Throws StorageError (kIo, kLocked, kCorrupt, kNewerVersion) naming the file, or
  /// std::invalid_argument when the stored resolution or tile size differ from the requested.
  MapDirectory(std::string directory, double resolution, double tile_size, std::uint32_t tile_voxels,
               bool read_only = false);
  ~MapDirectory();
  MapDirectory(const MapDirectory&) = delete;
  MapDirectory& operator=(const MapDirectory&) = delete;

  [[nodiscard]] const std::string& path() const noexcept { return dir_; }
  [[nodiscard]] std::string path_of(const std::string& name) const;
  [[nodiscard]] std::string tile_path(const VoxelKey& t, std::uint64_t generation) const {
    return path_of(tile_file_name(t, generation));
  }
  /// The tile files found when the directory was opened, sorted by name.
  [[nodiscard]] const std::vector<ListedTile>& tile_files() const noexcept { return tile_files_; }
  /// Bytes of the metadata file.
  [[nodiscard]] std::uint64_t meta_bytes() const noexcept { return meta_bytes_; }
  /// The metadata as read or written when the directory was opened, or as last written.
  [[nodiscard]] const MapMeta& meta() const noexcept { return meta_; }
  [[nodiscard]] bool read_only() const noexcept { return read_only_; }
  /// Replaces the metadata file durably (temporary file, fsync, rename, directory fsync); on
  /// failure the old file stays and StorageError (kIo) names it.
  void write_meta(const MapMeta& meta);
  /// Removes what interrupted writes and the last session's staging file left behind. Call once
  /// the tiles checked out, so that an open that fails changes no file.
  void remove_leftovers();
  /// Writer: takes the readers' lock exclusively if no reader holds it (never waits); true when
  /// taken. release_readers() gives it back.
  [[nodiscard]] bool exclude_readers() noexcept;
  void release_readers() noexcept;

  /// Writes \p meta (as format kMapFormatVersion) as the metadata of \p directory, durably, with
  /// no lock: for a directory being assembled that is not a map yet.
  static void write_meta_file(const std::string& directory, const MapMeta& meta);
  /// The metadata of the map in \p directory, without opening it (no lock). Throws StorageError
  /// naming the file when there is no map there (kIo) or it is damaged or newer.
  [[nodiscard]] static MapMeta read_meta(const std::string& directory);

 private:
  void lock();
  void open_readers_lock();

  std::string dir_;
  bool read_only_ = false;
  int lock_fd_ = -1;
  int readers_fd_ = -1;
  std::vector<ListedTile> tile_files_;
  std::vector<std::string> leftovers_;
  std::uint64_t meta_bytes_ = 0;
  MapMeta meta_;
};

}  // namespace iwlomap::detail
