// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// OutofcoreTileMapper: the Disk backend, an IWLO map kept on disk in cubic tiles with a bounded
/// cache of resident tiles, for maps larger than RAM.

#include "iwlomap/mapper_backend.h"

#include <cstddef>
#include <memory>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap {

namespace detail {
struct BackendAccess;
}  // namespace detail

/// A map directory or tile file that cannot be used. The message names the file; path() returns
/// it alone, and kind() says what went wrong, so a caller can tell a full disk from a damaged map.
class StorageError : public std::runtime_error {
 public:
  enum class Kind {
    kIo,            ///< a read, write, rename, fsync or unlink failed (full disk, unwritable path, ...)
    kCorrupt,       ///< a file is damaged: wrong magic, checksum mismatch, truncated, inconsistent
    kNewerVersion,  ///< a file was written by a newer iwlomap (format version above this build's)
    kLocked,        ///< another mapper (this process or another) has the directory open
  };
  StorageError(Kind kind, std::string path, const std::string& message);
  [[nodiscard]] Kind kind() const noexcept { return kind_; }
  /// The file or directory the error is about.
  [[nodiscard]] const std::string& path() const noexcept { return path_; }

 private:
  Kind kind_;
  std::string path_;
};

/// What the metadata of a map directory says (OutofcoreTileMapper::read_map_info()).
struct DiskMapInfo {
  double resolution = 0.0;    ///< voxel edge in metres
  double tile_size = 0.0;     ///< tile edge in metres
  size_t tile_voxels = 0;     ///< tile edge in voxels
  unsigned format_version = 0;
};

/// What OutofcoreTileMapper::repair() did.
struct DiskMapRepair {
  /// One line per tile file set aside (moved into `<directory>/damaged/`) or forgotten (missing),
  /// naming it and why; empty when every tile was sound.
  std::vector<std::string> set_aside;
  size_t tiles_kept = 0;  ///< sound tiles, now the map
};

/// The out-of-core backend. Space is cut into cubic tiles of `tile_size` metres; each tile that
/// holds a known voxel is one file `tile_<x>_<y>_<z>.g<c>.iwt` of sparse 8^3 block records in the
/// map directory (c is the commit that wrote it), beside a small metadata file `iwlomap_map.meta`
/// (format version, resolution, tile size), the manifest `iwlomap_map.manifest` (which file holds
/// each tile, the parameters), the lock files `iwlomap_map.lock` and `iwlomap_map.readers` and,
/// between flushes, the staging file described below. At most `cache_tiles` tiles are resident in
/// RAM between calls (the least recently used one is evicted; a tile is read and checked before a
/// victim is chosen, so for a moment there may be one more). Updates go to resident tiles with
/// exactly the RAM backend's math, so both backends give the same per-voxel log-odds and counts,
/// bit for bit, for the same input.
///
/// Commits: the map on disk changes only at flush(), all at once. A dirty tile that is evicted is
/// appended to the staging file `iwlomap_map.staging` (one file for all evicted tiles, not
/// fsync'ed: creating a file per eviction would cost more than the update itself); evicted tiles
/// are read back from there. flush() writes every tile whose newest state is not committed (dirty
/// resident tiles, staged tiles) to a new file of the next commit, fsyncs it, syncs the directory
/// and then replaces the manifest (temporary file, fsync, rename): that rename is the commit. So
/// a flush that fails (full disk, a damaged staged image) leaves the map exactly as the previous
/// commit left it, and a crash or kill at any moment leaves the map of the last commit that
/// completed, never a mix of two; the next open removes the files of an unfinished commit and the
/// staging file. Files a commit no longer needs are removed once no read-only mapper holds the
/// map (they may be reading them). The staging file is rewritten without dead images when more
/// than half of it is dead (and it is 1 MiB or more); between flushes it holds at most about twice
/// the evicted tiles. rollback() returns to the last commit without writing anything. The
/// destructor flushes; it never throws, so a failure there is swallowed and the unwritten changes
/// are lost while the map keeps its last commit: call flush() first to see errors, or rollback()
/// to give the changes up (as the tool does when a run fails).
///
/// Reopening: a mapper constructed on an existing map directory continues that map with the same
/// contents. The constructor reads the metadata, the manifest and the header of every tile file
/// the manifest names (not the whole tiles): a resolution other than the stored one, or a tile
/// size that does not round to the stored number of voxels, throws std::invalid_argument; a
/// damaged manifest or header, a missing, truncated or replaced tile file, or a tile file the
/// manifest does not name (copied in from elsewhere) throws StorageError (kCorrupt) naming the
/// file; a file of a newer
/// format throws StorageError (kNewerVersion). A map written before manifests (format 1 or 2) is
/// read from its tile files and gets a manifest, and format 3, at its first commit; older builds then refuse it as newer. A tile's header, checksums
/// and identity (the header checksum the manifest recorded) are verified whenever the tile is
/// read; a mismatch throws StorageError (kCorrupt) naming the file, and the tile is never replaced
/// by an empty one: every later call that needs it throws the same way until clear(). The IWLO
/// parameters and the hit-statistics setting belong to the map: set_params() (or a grouped
/// setter) and set_hit_accumulation() take effect at once and are recorded by the next commit, in
/// the manifest, and restored on reopen: a map always states the parameters its latest updates
/// used (changing them mid-survey, for a new sensor setting, is legitimate, and a map that refused
/// it would have to be rebuilt). The skipped-point count belongs to the object.
///
/// I/O errors: a failed write (unwritable directory, full disk) throws StorageError (kIo) naming
/// the file; the map keeps its last commit and every tile its newest state (dirty in RAM, or
/// staged), so a later flush() can still write it. A staged image is checked (checksum)
/// before it replaces a tile file. Input errors (sizes, weights, keys) throw before anything
/// changes, as in every backend. An update whose tiles fit in the cache loads them all before it
/// changes any voxel, so a read or eviction error leaves the map unchanged; an update that spans
/// more tiles than the cache is applied tile group by tile group, and an I/O error in a later group
/// leaves the earlier groups applied (each tile either has all of the call's observations or none).
///
/// Thread safety: every public method locks one internal mutex (once per call, so once per batch),
/// so calls from several threads are safe and serialised. The visitor of for_each_voxel() runs
/// under that lock and must not call back into this mapper. set_num_threads() (a base-class
/// setter) is not covered: set it before sharing the mapper; it sets the threads insert_scan() uses
/// to cast rays (applying them is single-threaded). One directory can be open in one mapper at a
/// time: a second mapper on it, in this or another process, throws StorageError (kLocked).
///
/// Non-copyable, movable; a moved-from object throws std::logic_error from every method except
/// destruction and assignment. Moving is not synchronised: do not move a mapper other threads use.
class OutofcoreTileMapper final : public BackendBase {
 public:
  /// Reads the metadata of the map in \p directory without opening the map (no lock, no tiles),
  /// so that a tool can open a map it did not create with the stored resolution and tile size.
  /// Throws StorageError naming the file when there is no map there (kIo) or the metadata is
  /// damaged (kCorrupt) or newer (kNewerVersion).
  [[nodiscard]] static DiskMapInfo read_map_info(const std::string& directory);

  /// For resolution and tile_size: the stored value of an existing map, the default of a new one.
  static constexpr double kStored = 0.0;
  static constexpr double kDefaultResolution = 0.05;  ///< metres, for a new map
  static constexpr double kDefaultTileSize = 10.0;    ///< metres, for a new map

  /// Opens the map in \p directory (created, with its parents, when missing) or creates a new one.
  /// `OutofcoreTileMapper(dir)` opens an existing map with its stored resolution and tile size,
  /// or creates one with the defaults (0.05 m, 10 m).
  /// \param directory   map directory (not empty)
  /// \param resolution  voxel edge in metres (> 0, finite), or kStored
  /// \param tile_size   tile edge in metres (> 0, finite), rounded to the nearest whole number of
  ///                    8^3 blocks: at least one block (8 voxels), at most 1,024 (8,192 voxels).
  ///                    The effective size is what get_tile_size() returns and the metadata
  ///                    stores (the defaults give 200 voxels = 25 blocks = 10 m; at 0.1 m,
  ///                    10 m is 12.5 blocks, rounded to 13: 104 voxels = 10.4 m). Reopening a
  ///                    map accepts any tile_size that rounds to the stored number of voxels.
  ///                    kStored as for resolution.
  /// \param cache_tiles resident tiles (>= 1)
  /// Throws std::invalid_argument for an invalid argument or one that differs from the stored map,
  /// StorageError for a directory or file that cannot be used (see the class comment).
  explicit OutofcoreTileMapper(const std::string& directory, double resolution = kStored, double tile_size = kStored,
                               size_t cache_tiles = 16);
  /// Opens the map in \p directory read-only, at its stored resolution and tile size, keeping at
  /// most \p cache_tiles tiles (>= 1) in RAM: it reads the last commit and sees exactly that map
  /// for its whole life, while a writer may go on committing beside it (the writer keeps the
  /// files of that commit until every reader has closed: a shared lock on `iwlomap_map.readers`,
  /// which it creates, empty, when missing and it can). Nothing else in the directory is created,
  /// removed or written, so a map can be read on a read-only file system too. Every method that
  /// would change the map (updates, scans, parameters, hit accumulation, set_log_odds, clear)
  /// throws std::logic_error; flush() does nothing. Throws StorageError when there is no
  /// map in \p directory or it is damaged.
  [[nodiscard]] static OutofcoreTileMapper open_read_only(const std::string& directory, size_t cache_tiles = 16);
  /// Makes a usable map of the sound tiles of the map in \p directory: every tile is read and
  /// checked completely (header, payload checksum and records, and that it is the file the last
  /// commit wrote); the damaged ones, and tile files the map does not name, are moved into
  /// `<directory>/damaged/` (a missing one is forgotten), and one commit makes the map of the
  /// others. Voxels of those tiles are lost from the map; nothing else changes. Needs the
  /// directory's lock, like a mapper (StorageError kLocked while one has it open). Throws
  /// StorageError when the metadata or manifest itself is damaged (restore them from a copy).
  static DiskMapRepair repair(const std::string& directory);
  /// True for a mapper from open_read_only().
  [[nodiscard]] bool is_read_only() const;

  /// Flushes; never throws (see the class comment).
  ~OutofcoreTileMapper() override;
  OutofcoreTileMapper(const OutofcoreTileMapper&) = delete;
  OutofcoreTileMapper& operator=(const OutofcoreTileMapper&) = delete;
  OutofcoreTileMapper(OutofcoreTileMapper&&) noexcept;
  /// The map held before is flushed (errors swallowed, as by the destructor) and closed.
  OutofcoreTileMapper& operator=(OutofcoreTileMapper&&) noexcept;

  void batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                         const std::vector<bool>& is_occupied) override;
  void batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                         const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights) override;
  void insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                   const Eigen::VectorXd& intensities, double max_range = -1.0) override;

  /// Validated, recorded in the metadata (StorageError kIo when it cannot be written: nothing
  /// changes), then used.
  void set_params(const IwloParams& params) override;
  [[nodiscard]] IwloParams get_params() const override;
  void set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) override;

  /// Covers every tile: resident tiles from RAM, the others streamed from disk one at a time
  /// without entering the cache.
  [[nodiscard]] Eigen::MatrixXd get_occupied_voxels(double min_probability = 0.5) const override;
  /// Loads the voxel's tile into the cache when it is on disk (which may evict and write another).
  [[nodiscard]] std::optional<VoxelState> query(const Eigen::Vector3d& point) const override;
  /// Every known voxel, tile by tile in (x, y, z) order of tile coordinates; tiles on disk are
  /// streamed as in get_occupied_voxels().
  void for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>& visit) const override;

  /// Hit statistics (hit_statistics.h), stored in the tiles and equal to the RAM backend's. The
  /// setting is part of the map (metadata), kept on reopen; turning accumulation on starts from
  /// empty statistics (those still in tile files from an earlier time are void).
  void set_hit_accumulation(bool enabled) override;
  [[nodiscard]] bool get_hit_accumulation() const override;
  /// Loads the voxel's tile into the cache when it is on disk, as query() does.
  [[nodiscard]] std::optional<HitStatistics> hit_statistics(const Eigen::Vector3d& point) const override;
  /// Covers every tile as get_occupied_voxels() does (rows in the same order).
  [[nodiscard]] Eigen::MatrixXd get_occupied_mean_positions(double min_probability = 0.5) override;

  /// Not in RAM: throws std::logic_error; copy_to() copies the map to another directory.
  [[nodiscard]] std::unique_ptr<IMapperBackend> clone() const override;
  /// Every feature but BackendFeature::kClone.
  [[nodiscard]] bool supports(BackendFeature feature) const override;

  /// num_nodes counts the whole map; memory_mb counts what is resident (tiles, tile index, scratch
  /// buffers); memory_efficiency = known voxels / allocated voxel slots of the resident tiles.
  [[nodiscard]] MemoryStats get_memory_usage() const override;
  [[nodiscard]] double get_resolution() const override;
  /// Known voxels of the whole map, resident or on disk (kept as a running count: no I/O).
  [[nodiscard]] size_t get_num_nodes() const override;
  [[nodiscard]] size_t get_num_skipped_points() const override;
  /// Forgets every voxel: a commit of an empty map (unflushed changes are dropped either way; on
  /// failure the map keeps its last commit). The map's tile files are removed as a commit's retired
  /// files are; files in the directory that are not this map's tiles are left alone. The
  /// parameters stay.
  void clear() override;
  [[nodiscard]] std::string get_backend_type() const override { return "Disk"; }

  /// Makes every change durable in one commit (see the class comment): dirty resident tiles,
  /// staged tiles and the parameters. All or nothing: on failure it throws and the map on disk is
  /// the previous commit's; the changes stay in the mapper for another flush() or a rollback().
  void flush() override;
  /// Gives up every change since the last commit (or since opening): resident tiles are dropped,
  /// staged images forgotten, and the parameters and hit-statistics setting are the committed ones
  /// again; nothing on disk changes. Read-only: does nothing.
  void rollback();
  /// Loads the tiles on disk that intersect the box [min_bound, max_bound] (metres), in (x, y, z)
  /// order of tile coordinates, at most cache_tiles of them. Throws std::invalid_argument for a
  /// non-finite bound or min > max on an axis.
  void preload_region(const Eigen::Vector3d& min_bound, const Eigen::Vector3d& max_bound) override;
  /// Bytes of the map's files on disk: committed tile files, staging file, manifest and metadata
  /// (resident dirty tiles not yet written and retired files not yet removed are not counted).
  [[nodiscard]] size_t get_disk_usage() const override;
  /// Frees the scratch buffers and the empty blocks of resident tiles; returns the voxel slots
  /// freed (known voxels are never removed).
  size_t prune() override;
  [[nodiscard]] bool supports_persistence() const override { return true; }

  // ---- Disk-specific ----

  /// The map directory.
  [[nodiscard]] std::string get_directory() const;
  /// Tile edge in metres: get_tile_voxels() * resolution, the requested size rounded to whole
  /// blocks.
  [[nodiscard]] double get_tile_size() const;
  /// Tile edge in voxels (a multiple of 8).
  [[nodiscard]] size_t get_tile_voxels() const;
  [[nodiscard]] size_t get_cache_tiles() const;
  /// Tiles resident in RAM now (<= cache_tiles between calls).
  [[nodiscard]] size_t get_num_resident_tiles() const;
  /// Tiles of the map (resident or on disk).
  [[nodiscard]] size_t get_num_tiles() const;
  /// Largest number of tiles resident at once since construction (or the last clear()).
  [[nodiscard]] size_t get_peak_resident_tiles() const;

  /// Flushes, then copies the map (metadata, manifest and the committed tile files) to
  /// \p directory, created when
  /// missing; a directory that already holds a map is refused (StorageError kIo naming it). The
  /// copy is an independent map with the same contents: open it with another mapper.
  void copy_to(const std::string& directory);

 protected:
  /// The read and the write of the parameters under the mapper's lock.
  void modify_params(const std::function<void(IwloParams&)>& change) override;

 private:
  friend struct detail::BackendAccess;  // the library's own layers (the OctoMap writer)
  struct Impl;
  OutofcoreTileMapper(std::unique_ptr<Impl> impl);
  Impl& impl();
  const Impl& impl() const;
  std::unique_ptr<Impl> impl_;
};

}  // namespace iwlomap
