// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Per-voxel mean colours: the running mean of the 8-bit RGB colours of the hits that fell in
/// each voxel, for coloured clouds (an RGB-D camera, a lidar coloured from a camera). Kept beside
/// a map rather than in it, so any backend can have colours and a map without colour input pays
/// nothing: VoxelColorMeans counts a hit exactly where IMapperBackend::insert_scan() or
/// batch_update_iwlo() counts one (the same clipping, thresholds and skipped points), and
/// colors_at() then colours the rows of get_occupied_voxels() or get_occupied_mean_positions().

#include <iwlomap/iwlo.h>

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <vector>

namespace iwlomap {

/// One 8-bit colour.
struct Rgb8 {
  std::uint8_t r = 0;
  std::uint8_t g = 0;
  std::uint8_t b = 0;
  friend bool operator==(const Rgb8& a, const Rgb8& b) { return a.r == b.r && a.g == b.g && a.b == b.b; }
  friend bool operator!=(const Rgb8& a, const Rgb8& b) { return !(a == b); }
};

/// N x 3 colours, one row (r, g, b) per point or voxel.
using ColorMatrix = Eigen::Matrix<std::uint8_t, Eigen::Dynamic, 3, Eigen::RowMajor>;

/// The running mean colour of the hits in each voxel of a grid of edge resolution() metres (the
/// same voxels as a map of that resolution). Each channel's mean is the sum of the hits' values
/// divided by their count, rounded to the nearest integer (halves up). Per voxel it holds three
/// 64-bit sums and a 64-bit count (32 bytes plus its index entry), only for voxels that got a
/// coloured hit; the memory is not counted by set_map_memory_limit(). Not thread-safe: one writer,
/// or readers only.
class VoxelColorMeans {
 public:
  /// \p resolution: voxel edge in metres, finite and > 0 (std::invalid_argument otherwise).
  explicit VoxelColorMeans(double resolution);
  ~VoxelColorMeans();
  VoxelColorMeans(VoxelColorMeans&&) noexcept;
  VoxelColorMeans& operator=(VoxelColorMeans&&) noexcept;

  [[nodiscard]] double resolution() const noexcept { return resolution_; }

  /// Adds one hit of colour \p color at \p point (metres, map frame). Returns false (and adds
  /// nothing) when the point is not finite.
  bool add(const Eigen::Vector3d& point, Rgb8 color);

  /// Adds the hits of one scan as IMapperBackend::insert_scan(origin, points, intensities,
  /// max_range) counts them under \p params: a point is a hit when it and its intensity are
  /// finite, its intensity exceeds params.intensity_threshold, it lies within \p max_range of
  /// \p origin (when max_range > 0) and its ray is not longer than kMaxRayVoxels voxels. Every
  /// hit counts, also several in one voxel (the map counts one observation per voxel per scan).
  /// \p colors has one row per point. Throws std::invalid_argument when the sizes disagree or the
  /// origin is not finite.
  void add_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                const ColorMatrix& colors, const IwloParams& params, double max_range = -1.0);

  /// Adds the occupied observations of IMapperBackend::batch_update_iwlo(points, intensities,
  /// is_occupied): rows with the flag set, finite values and an intensity above
  /// params.intensity_threshold. Throws std::invalid_argument when the sizes disagree.
  void add_observations(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                        const std::vector<bool>& is_occupied, const ColorMatrix& colors, const IwloParams& params);

  /// The mean colour of the voxel containing \p point (metres, map frame); nullopt when it got no
  /// coloured hit or the point is not finite.
  [[nodiscard]] std::optional<Rgb8> mean(const Eigen::Vector3d& point) const;
  /// The number of coloured hits in the voxel containing \p point (0 for a non-finite point).
  [[nodiscard]] std::uint64_t hits(const Eigen::Vector3d& point) const;

  /// The mean colour of the voxel of each row of \p positions (at least 3 columns, x y z in
  /// metres: e.g. get_occupied_voxels() or get_occupied_mean_positions()); \p missing for a voxel
  /// without coloured hits. Throws std::invalid_argument for fewer than 3 columns.
  [[nodiscard]] ColorMatrix colors_at(const Eigen::MatrixXd& positions, Rgb8 missing = {}) const;

  /// Voxels with at least one coloured hit.
  [[nodiscard]] std::size_t size() const noexcept;
  /// Bytes held (sums and index).
  [[nodiscard]] std::size_t memory_bytes() const noexcept;
  /// Forgets every colour.
  void clear();

 private:
  struct Impl;
  double resolution_;
  std::unique_ptr<Impl> impl_;
};

}  // namespace iwlomap
