// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// A Disk backend's map directory: the names of its files, its metadata file and its lock.
//
//   iwlomap_map.meta      text: format version, resolution and tile size (hex floats, exact)
//   iwlomap_map.lock      flock()ed while a mapper has the map open
//   tile_<x>_<y>_<z>.iwt  one file per tile (tile_file.h)
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

/// "tile_<x>_<y>_<z>.iwt".
[[nodiscard]] std::string tile_file_name(const VoxelKey& t);
/// True, with the tile in \p t, for exactly the names tile_file_name() produces.
[[nodiscard]] bool parse_tile_file_name(const std::string& name, VoxelKey& t);

/// The tile edge in voxels for \p tile_size metres at \p resolution: a whole multiple of 8
/// between 8 and kMaxTileVoxels. Throws std::invalid_argument otherwise.
[[nodiscard]] std::uint32_t tile_voxels_for(double resolution, double tile_size);

/// The contents of the metadata file.
struct MapMeta {
  std::uint32_t version = 0;
  double resolution = 0.0;
  double tile_size = 0.0;  // the effective size, tile_voxels * resolution
  std::uint32_t tile_voxels = 0;
  IwloParams params;             // the reference defaults in a file written before they were stored
  bool hit_statistics = false;   // accumulation on
  std::uint32_t hit_epoch = 0;   // incremented each time accumulation is turned on (tile_file.h)
};

/// An open map directory: created (with its parents) when missing, locked against a second
/// mapper, its metadata read (and checked against the requested geometry) or written, its tile
/// files listed. Nothing in the directory changes when the constructor throws, but for a
/// directory it creates and the lock file. Read-only, it creates, locks and writes nothing: the
/// directory and its metadata must exist.
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
  [[nodiscard]] std::string tile_path(const VoxelKey& t) const { return path_of(tile_file_name(t)); }
  /// The tile files found when the directory was opened, sorted by name.
  [[nodiscard]] const std::vector<std::string>& tile_names() const noexcept { return tile_names_; }
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

  /// The metadata of the map in \p directory, without opening it (no lock). Throws StorageError
  /// naming the file when there is no map there (kIo) or it is damaged or newer.
  [[nodiscard]] static MapMeta read_meta(const std::string& directory);

 private:
  void lock();

  std::string dir_;
  bool read_only_ = false;
  int lock_fd_ = -1;
  std::vector<std::string> tile_names_;
  std::vector<std::string> leftovers_;
  std::uint64_t meta_bytes_ = 0;
  MapMeta meta_;
};

}  // namespace iwlomap::detail
