// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// DistributedMapper: one IWLO map sharded by tile over the ranks of an MPI communicator, equal
/// voxel for voxel (log-odds and counts) to the map one process builds from the same scans.

#include "iwlomap/iwlo.h"
#include "iwlomap/mapper_backend.h"
#include "iwlomap/voxel_key.h"

#include <mpi.h>

#include <Eigen/Core>

#include <cstdint>
#include <memory>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap::detail {
class ScanScratch;
}  // namespace iwlomap::detail

namespace iwlomap::mpi {

/// An error that every rank of a collective call throws together: one rank's input or storage
/// failed, and the others learn which rank and why, so that no rank waits for the others forever.
/// what() starts with "rank K: ".
class DistributedError : public std::runtime_error {
 public:
  DistributedError(int rank, const std::string& message);
  /// The lowest rank that failed.
  [[nodiscard]] int failed_rank() const noexcept { return rank_; }

 private:
  int rank_;
};

/// Where this rank's time went and what it sent, over all rounds so far (DistributedMapper::stats()).
struct DistributedStats {
  std::uint64_t rounds = 0;        ///< rounds this rank took part in
  double cast_seconds = 0.0;       ///< casting its scans' rays and packing the observations
  double exchange_seconds = 0.0;   ///< in the exchange, including waiting for slower ranks
  double apply_seconds = 0.0;      ///< applying the observations it owns to its shard
  std::uint64_t bytes_sent = 0;    ///< bytes sent to other ranks (its own observations stay local)
};

/// The default shard edge of Disk shards, in metres: each shard is a Disk tile, one file.
inline constexpr double kDiskShardSize = 6.4;

/// Where each rank keeps its shard.
struct DistributedOptions {
  /// "RAM" or "Disk" (case-insensitive).
  std::string backend = "RAM";
  /// Disk: the distributed map directory. Rank K keeps its tiles in the Disk map directory
  /// `<directory>/rank-K` (a complete Disk map of its own tiles); flush() writes the manifest
  /// `<directory>/iwlomap_distributed.manifest` naming the ranks and each rank's tiles.
  std::string directory;
  /// Edge of a shard in metres: the unit of ownership, and the Disk tile size. Rounded to a whole
  /// number of 8-voxel blocks (as the Disk backend rounds its tile size). 0 (the default): one
  /// block (8 voxels) for RAM shards, the finest split, which balances the ranks best (a block
  /// travels as one unit anyway); kDiskShardSize for Disk shards, whose tiles are files.
  double tile_size = 0.0;
  /// Disk: resident tiles per rank (>= 1).
  std::size_t cache_tiles = 64;
  /// Threads each rank uses to cast the rays of its scans (>= 1): the map does not depend on it.
  int threads = 1;
  /// The voxels each ray marks free (IMapperBackend::set_ray_model()); the same on every rank.
  RayModel rays = RayModel::kExact;
};

/// The shard (tile coordinates) holding \p voxel, for shards of \p tile_voxels voxels a side
/// (DistributedMapper::tile_voxels()): the voxel key floor-divided by it.
[[nodiscard]] VoxelKey tile_of_voxel(const VoxelKey& voxel, std::uint32_t tile_voxels) noexcept;

/// The rank that owns the shard \p tile (tile coordinates: voxel key floor-divided by the shard
/// edge in voxels) among \p ranks ranks: a fixed hash, the same on every machine and run.
[[nodiscard]] int owner_of_tile(const VoxelKey& tile, int ranks) noexcept;

/// One IWLO map sharded over the ranks of \p comm. Each rank owns the shards (cubic tiles of
/// DistributedOptions::tile_size) whose coordinate hashes to it (owner_of_tile()) and keeps them
/// in a local backend (RAM, or Disk in its own directory).
///
/// Integration is in rounds. In one round every rank passes its own scan (insert_scan()), its own
/// batch (batch_update_iwlo()) or nothing (pass()); a rank turns its scan into at most one
/// observation per voxel (the per-scan rule of IMapperBackend::insert_scan(): occupied wins over
/// free, the largest intensity of the hits in a voxel), sends each observation to the owner of its
/// voxel (one MPI_Alltoallv per round), and each owner applies the round's observations in rank
/// order. So the map equals the one a single process builds by integrating the round's scans in
/// rank order, round after round: round robin of files over ranks (file i on rank i mod N in round
/// i / N) keeps the files' order. On the wire a scan's free voxels go as 8^3 blocks with a
/// 512-bit mask (80 bytes a block) and its hits and a batch's observations as 24-byte records.
/// Memory per round: the observations of one scan per rank, sent and received.
///
/// Every method here is collective (all ranks call it, in the same order) except local(),
/// stats(), rank(), ranks() and options(). A rank whose input or storage fails makes every rank throw
/// DistributedError naming it, after nothing of that round was applied anywhere (a storage error
/// while applying leaves the Disk backend's guarantees: each tile has all or none of the round).
/// A rank that dies is the MPI runtime's matter: with the default error handler mpirun ends the
/// job and names the rank.
///
/// Hit statistics and per-point weights are not distributed.
class DistributedMapper {
 public:
  /// Opens (Disk: creates or reopens) this rank's shard. \p params must be the same on every rank.
  /// A Disk directory written by a run with another number of ranks, or holding a shard at another
  /// resolution or tile size, throws DistributedError on every rank.
  DistributedMapper(MPI_Comm comm, double resolution, const IwloParams& params = {}, DistributedOptions options = {});
  ~DistributedMapper();
  DistributedMapper(const DistributedMapper&) = delete;
  DistributedMapper& operator=(const DistributedMapper&) = delete;

  /// This rank's part of one round: a scan taken from \p origin (metres, map frame), as
  /// IMapperBackend::insert_scan() (max_range, skipped points, one observation per voxel per scan).
  void insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                   double max_range = -1.0);
  /// This rank's part of a round in which all ranks integrate ONE scan together, each passing a
  /// part of its points (for example a range of the points of one big file): the observations of
  /// all parts are merged by the owners under the per-scan rule (one observation per voxel;
  /// occupied wins over free; the largest intensity of a voxel's hits) and applied once, so the
  /// map equals one process integrating the whole scan with insert_scan(). Every rank passes the
  /// same \p origin and \p max_range (else every rank throws DistributedError); a rank
  /// without points passes an empty part (0 x 3). In one round either every rank calls this (or
  /// pass()) or none does: a round that mixes it with insert_scan() or batch_update_iwlo()
  /// throws DistributedError on every rank, and nothing of it is applied.
  void insert_scan_part(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                        const Eigen::VectorXd& intensities, double max_range = -1.0);
  /// This rank's part of one round: one observation per point in call order, as
  /// IMapperBackend::batch_update_iwlo() (non-finite points skipped and counted).
  void batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                         const std::vector<bool>& is_occupied);
  /// This rank's part of a round in which it has nothing to add.
  void pass();

  /// Every known voxel with its state, gathered on \p root sorted by key (empty on other ranks).
  [[nodiscard]] std::vector<std::pair<VoxelKey, VoxelState>> gather_voxels(int root = 0) const;
  /// Occupied voxels (p > \p min_probability, rows x, y, z, p as IMapperBackend::get_occupied_voxels())
  /// gathered on \p root, sorted by key (a 0 x 4 matrix on other ranks).
  [[nodiscard]] Eigen::MatrixXd gather_occupied_voxels(double min_probability = 0.5, int root = 0);
  /// Known voxels over all ranks (the same on every rank).
  [[nodiscard]] std::size_t num_nodes() const;
  /// Points skipped over all ranks (the same on every rank).
  [[nodiscard]] std::size_t num_skipped_points() const;
  /// This rank's time and traffic so far (not collective).
  [[nodiscard]] const DistributedStats& stats() const noexcept { return stats_; }

  /// Disk: every rank flushes its shard (crash-safe as the Disk backend's flush()), then rank 0
  /// rewrites the manifest. RAM: nothing to write.
  void flush();

  [[nodiscard]] int rank() const noexcept { return rank_; }
  [[nodiscard]] int ranks() const noexcept { return size_; }
  [[nodiscard]] double resolution() const noexcept { return resolution_; }
  /// Shard edge in voxels.
  [[nodiscard]] std::uint32_t tile_voxels() const noexcept { return tile_voxels_; }
  [[nodiscard]] const DistributedOptions& options() const noexcept { return options_; }
  /// This rank's shard (read it freely; updating it directly breaks the equality with one process).
  [[nodiscard]] IMapperBackend& local() noexcept { return *local_; }
  [[nodiscard]] const IMapperBackend& local() const noexcept { return *local_; }

 private:
  struct Record;
  struct FreeBlock;
  struct Outgoing;
  enum class Kind : std::uint64_t;
  void cast_and_apply(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                      double max_range, Kind kind);
  void exchange_and_apply(std::vector<Outgoing>& outgoing);
  [[nodiscard]] int owner_of_voxel(const VoxelKey& key) const noexcept;

  MPI_Comm comm_ = MPI_COMM_NULL;
  int rank_ = 0;
  int size_ = 1;
  double resolution_ = 0.0;
  std::uint32_t tile_voxels_ = 0;
  DistributedOptions options_;
  std::unique_ptr<IMapperBackend> local_;
  std::unique_ptr<detail::ScanScratch> scratch_;  // kept between rounds (its buffers are reused)
  std::size_t skipped_ = 0;
  DistributedStats stats_;
};

/// The name of the manifest file in a distributed map directory.
inline constexpr const char* kManifestName = "iwlomap_distributed.manifest";

/// What a distributed map directory's manifest says.
struct DistributedManifest {
  int ranks = 0;
  double resolution = 0.0;
  double tile_size = 0.0;  ///< the effective shard edge in metres
  std::uint32_t tile_voxels = 0;
  /// Per rank, the tile files of its shard (names as the Disk backend writes them).
  std::vector<std::vector<std::string>> tiles;
};

/// Reads the manifest of the distributed map in \p directory. Throws StorageError naming the file
/// when it is missing or damaged.
[[nodiscard]] DistributedManifest read_manifest(const std::string& directory);

/// Makes the distributed map in \p directory (flushed) one Disk map directory \p target (created;
/// it must not hold a map) that one process opens with OutofcoreTileMapper: its metadata and every
/// rank's tiles (hard links where the file system allows, copies otherwise). No MPI needed.
void merge_distributed_map(const std::string& directory, const std::string& target);

/// The converse: splits the Disk map in \p directory (closed, flushed) into the distributed map
/// directory \p target for \p ranks ranks, each tile going to its owner (owner_of_tile()). The
/// tile size stays that of the Disk map; open \p target with that tile size. No MPI needed.
void split_map(const std::string& directory, const std::string& target, int ranks);

}  // namespace iwlomap::mpi
