// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// ProbabilityUpdater: the RAM backend, an IWLO map on a sparse block grid.

#include "iwlomap/mapper_backend.h"

#include <memory>

namespace iwlomap {

namespace detail {
struct BackendAccess;
}  // namespace detail

/// The in-memory backend. Voxels live in 8x8x8 blocks found through a hash map keyed by block
/// coordinate; inside a block they are stored in cells of 2x2x1 voxels (16 bytes, x by y by z),
/// allocated the first time one of their voxels is observed, so a surface costs about what it
/// covers and free space fills whole blocks. A voxel costs 4 bytes (fixed-point log-odds and a
/// saturating observation count, iwlo::VoxelFormat), a block a 192-byte header. Keys are int32, so a map at 0.05 m
/// spans +-107,000 km. Memory given back by a map is reused by the process's other maps (see
/// map_memory.h).
///
/// Not thread-safe: one thread at a time may call a mutating method; const methods may run
/// concurrently with each other. Non-copyable (clone() makes an explicit deep copy), movable; a
/// moved-from object throws std::logic_error from every method that reads or changes the map
/// (get_backend_type(), the thread count and the optional defaults of IMapperBackend still answer).
class ProbabilityUpdater final : public BackendBase {
 public:
  /// \param resolution voxel edge in metres (> 0, finite); throws std::invalid_argument otherwise.
  explicit ProbabilityUpdater(double resolution = 0.05);
  ~ProbabilityUpdater() override;
  ProbabilityUpdater(const ProbabilityUpdater&) = delete;
  ProbabilityUpdater& operator=(const ProbabilityUpdater&) = delete;
  ProbabilityUpdater(ProbabilityUpdater&&) noexcept;
  ProbabilityUpdater& operator=(ProbabilityUpdater&&) noexcept;

  void batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                         const std::vector<bool>& is_occupied) override;
  void batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                         const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights) override;
  void insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                   const Eigen::VectorXd& intensities, double max_range = -1.0) override;

  void set_params(const IwloParams& params) override;
  [[nodiscard]] IwloParams get_params() const override;
  void set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) override;

  [[nodiscard]] Eigen::MatrixXd get_occupied_voxels(double min_probability = 0.5) const override;
  [[nodiscard]] std::optional<VoxelState> query(const Eigen::Vector3d& point) const override;
  void for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>& visit) const override;

  /// Hit statistics (see hit_statistics.h for what counts): kept in a side structure of 32 bytes
  /// per voxel (8^3 blocks, about 4x the map's own memory), allocated only while accumulation is
  /// on, and gathered by insert_scan() in its own ray walk, on its threads: a scan with them takes
  /// about three times as long as one without (docs/benchmarks.md).
  void set_hit_accumulation(bool enabled) override;
  [[nodiscard]] bool get_hit_accumulation() const override;
  [[nodiscard]] std::optional<HitStatistics> hit_statistics(const Eigen::Vector3d& point) const override;
  [[nodiscard]] Eigen::MatrixXd get_occupied_mean_positions(double min_probability = 0.5) override;

  /// A deep copy (a new ProbabilityUpdater): voxels in the same iteration order, parameters,
  /// skipped-point count, hit statistics and thread count.
  [[nodiscard]] std::unique_ptr<IMapperBackend> clone() const override;

  /// memory_mb counts every byte the map holds: the slabs its block headers and cells are carved
  /// from, block table, hash index and the scratch buffers kept between scans.
  /// memory_efficiency = known voxels / allocated voxel slots (4 per allocated cell).
  [[nodiscard]] MemoryStats get_memory_usage() const override;
  [[nodiscard]] double get_resolution() const override;
  [[nodiscard]] size_t get_num_nodes() const override;
  [[nodiscard]] size_t get_num_skipped_points() const override;
  void clear() override;
  [[nodiscard]] std::string get_backend_type() const override { return "RAM"; }

  /// Frees blocks and cells that hold no known voxel, compacts the rest into fresh memory, returns
  /// the scratch buffers and shrinks the block index to fit. Returns the number of voxel slots
  /// freed (each an unknown voxel; known voxels are never removed). Updates only allocate cells
  /// they write, so the count is usually 0 and the gain is the memory given back.
  size_t prune() override;

 private:
  friend struct detail::BackendAccess;  // the library's own layers (distributed mapper, writers)
  struct Impl;
  Impl& impl();
  const Impl& impl() const;
  std::unique_ptr<Impl> impl_;
};

}  // namespace iwlomap
