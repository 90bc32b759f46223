// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Per-voxel hit statistics in the manner of GMapping's map cells: the sum of the positions of
/// the hits that fell in a voxel, the number of hits and the number of visits, giving the mean hit
/// position (a sub-voxel estimate of the surface) and the cell's entropy.
///
/// Accumulation is optional per map and off by default (IMapperBackend::set_hit_accumulation()),
/// so the default voxel stays within its 4 bytes; the RAM backend keeps the statistics in a side
/// structure (32 bytes per voxel, in 8^3 blocks allocated on a first visit) that exists only
/// while accumulation is on. What counts:
/// - insert_scan(), per ray, as GMapping counts beams: a ray whose endpoint is a hit (within
///   max_range, intensity above the threshold) adds its point to the endpoint voxel's sum and one
///   hit and one visit there; every voxel the ray crosses before its endpoint voxel gets one
///   visit, as does the endpoint voxel of a hit at or below the intensity threshold (free
///   evidence); a ray beyond max_range visits the voxels of its clipped part. So every hit point
///   counts toward the mean even though the occupancy update counts one observation per voxel per
///   scan, and a voxel crossed by one ray and hit by another in the same scan gets both.
/// - batch_update_iwlo(): each observation is a visit; an occupied observation (flag set and
///   intensity above the threshold) is also a hit and adds its point. Weights do not scale the
///   counts (a weight-0 observation still counts, as it does for the observation count).
/// - set_log_odds() (map imports) adds nothing. Observations made before accumulation was turned
///   on are not in the statistics.

#include <Eigen/Core>

#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <string>

namespace iwlomap {

/// ln 2: the entropy of an unvisited cell and the largest a cell can have.
inline constexpr double kLn2 = 0.69314718055994530942;

/// GMapping's cell entropy, in nats: with x = hits / visits,
/// H = -(x ln x + (1 - x) ln(1 - x)); 0 when x is 0 or 1; ln 2 when the cell was never visited.
/// Throws std::invalid_argument when hits > visits.
[[nodiscard]] inline double cell_entropy(std::uint64_t hits, std::uint64_t visits) {
  if (hits > visits)
    throw std::invalid_argument("iwlomap: cell_entropy: hits = " + std::to_string(hits) + " exceeds visits = " +
                                std::to_string(visits));
  if (visits == 0) return kLn2;
  if (hits == 0 || hits == visits) return 0.0;
  const double x = static_cast<double>(hits) / static_cast<double>(visits);
  return -(x * std::log(x) + (1.0 - x) * std::log(1.0 - x));
}

/// The statistics of one voxel.
struct HitStatistics {
  /// Mean of the hit positions (metres, map frame); the voxel centre when hits == 0.
  Eigen::Vector3d mean_hit_position = Eigen::Vector3d::Zero();
  std::uint32_t hits = 0;    ///< hits that fell in the voxel (saturates, never wraps)
  std::uint32_t visits = 0;  ///< rays or observations that reached the voxel, hits included (saturates)
  double entropy = kLn2;     ///< cell_entropy(hits, visits), nats
};

}  // namespace iwlomap
