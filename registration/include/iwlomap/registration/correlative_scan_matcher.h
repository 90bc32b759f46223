// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Coarse scan-to-map registration: Cartographer's fast correlative scan matching in 3D. Over a
/// search window around an initial pose (x, y, z translations in whole voxels, yaw in steps small
/// enough that the farthest point moves at most one voxel), it finds the pose that maximises the
/// sum of the map's 8-bit occupancy values (precomputation_grid.h) at the scan's points, by
/// branch and bound over a PrecomputationStack3D: a node covering 2^k x 2^k x 2^k translations of
/// one yaw is bounded by the sum over points of level k's window maximum, which no translation in
/// the node can exceed, so the search is exact: it returns what exhaustive search over the same
/// discretised window returns (ties go to the candidate first in the order yaw, x, y, z, each
/// ascending). Roll and pitch are taken from the initial pose.
///
/// Thin surfaces (one voxel thick) score only where the scan's points fall in the same voxels, so
/// a pose half a voxel off the candidate lattice could score half of what it deserves; the
/// discretised map is therefore dilated by \p dilation voxels (each cell takes the maximum of its
/// (2 dilation + 1)^3 neighbourhood) before the max grids are built. The optimum is then a plateau
/// about a voxel wide, which is what this stage is for: ICP refines the pose.
///
/// The map is discretised once per matcher over a box (RAM: one byte per voxel per level), so a
/// matcher serves many scans of one region; the box must hold every point of a scan at every
/// candidate pose (points outside count as unknown, value 0, which keeps the search exact for the
/// grid it has).

#include <iwlomap/mapper_backend.h>
#include <iwlomap/precomputation_stack.h>
#include <iwlomap/voxel_box.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <memory>
#include <string>

namespace iwlomap::registration {

/// The poses searched around an initial pose.
struct SearchWindow3D {
  double linear_xy = 1.0;                    ///< metres each way in x and y (> 0)
  double linear_z = 0.5;                     ///< metres each way in z (> 0)
  double angular_yaw = 0.17453292519943295;  ///< radians each way about the map's z axis (> 0; 10 degrees)
  /// Throws std::invalid_argument naming the first value that is not finite and > 0.
  void validate() const;
};

/// What CorrelativeScanMatcher3D::match() found.
struct CoarseMatch {
  bool found = false;          ///< a pose scored at least min_score
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  ///< the best pose (sensor to map), or the initial one
  double score = 0.0;          ///< mean over points of value / 255, in [0, 1]
  std::uint64_t score_sum = 0; ///< sum of the points' 8-bit values at the best pose
  int yaw_steps = 0;           ///< yaw candidates each way
  double yaw_step = 0.0;       ///< radians between yaw candidates
  std::uint64_t candidates = 0;      ///< poses in the discretised window
  std::uint64_t nodes_visited = 0;   ///< branch-and-bound nodes scored (exhaustive: = candidates)
  std::string reason;          ///< why not found (empty when found)
};

/// Branch-and-bound matcher over one region of a map. Immutable after construction; match() may
/// run concurrently.
class CorrelativeScanMatcher3D {
 public:
  /// Discretises \p map over \p region (discretize_volume()) and builds \p num_levels max grids
  /// (widths 1 .. 2^(num_levels-1)). Throws std::invalid_argument for a bad box or level count and
  /// std::length_error when the grids would be too large.
  /// \p dilation: voxels (>= 0) by which the discretised map is dilated.
  CorrelativeScanMatcher3D(const IMapperBackend& map, const VoxelBox& region,
                           int num_levels = PrecomputationStack3D::kDefaultLevels, int dilation = 1);

  /// A matcher over the box holding \p scan_sensor at \p initial (sensor to map) grown by the
  /// window and the largest rotation it allows: what match() with these arguments needs.
  [[nodiscard]] static CorrelativeScanMatcher3D for_scan(const IMapperBackend& map, const Eigen::MatrixXd& scan_sensor,
                                                         const Eigen::Isometry3d& initial,
                                                         const SearchWindow3D& window,
                                                         int num_levels = PrecomputationStack3D::kDefaultLevels,
                                                         int dilation = 1);

  /// The best pose of the scan \p scan_sensor (N x 3, metres, sensor frame; non-finite rows are
  /// skipped) within \p window around \p initial (sensor to map), by branch and bound. Found when
  /// its score is at least \p min_score (in [0, 1]). Throws std::invalid_argument for an empty
  /// scan (no finite point), a non-finite or non-rigid initial pose, a bad window or min_score.
  [[nodiscard]] CoarseMatch match(const Eigen::MatrixXd& scan_sensor, const Eigen::Isometry3d& initial,
                                  const SearchWindow3D& window, double min_score = 0.0) const;

  /// The same search by trying every pose of the discretised window (for tests and checks).
  [[nodiscard]] CoarseMatch match_exhaustive(const Eigen::MatrixXd& scan_sensor, const Eigen::Isometry3d& initial,
                                             const SearchWindow3D& window, double min_score = 0.0) const;

  [[nodiscard]] const VoxelBox& region() const noexcept { return region_; }
  [[nodiscard]] double resolution() const noexcept { return resolution_; }
  [[nodiscard]] const PrecomputationStack3D& stack() const noexcept { return *stack_; }

 private:
  struct Problem;
  [[nodiscard]] Problem prepare(const Eigen::MatrixXd& scan_sensor, const Eigen::Isometry3d& initial,
                                const SearchWindow3D& window, double min_score) const;

  VoxelBox region_;
  double resolution_;
  std::shared_ptr<const PrecomputationStack3D> stack_;
};

}  // namespace iwlomap::registration
