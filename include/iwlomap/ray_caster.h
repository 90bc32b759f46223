// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Amanatides-Woo voxel traversal of a segment, in the keys of voxel_key.h.

#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <limits>
#include <vector>

namespace iwlomap {

/// The longest ray insert_scan() casts, in voxel edges: 131,072, i.e. 13.1 km at 0.1 m, 1.3 km
/// at 1 cm. A point farther from the origin (after max_range clipping) is skipped and counted.
inline constexpr double kMaxRayVoxels = 131072.0;

/// Visits, in order from \p origin, the voxels that the segment origin -> end crosses, starting
/// with the voxel that contains \p origin and stopping before the voxel that contains \p end (the
/// endpoint voxel is never visited; a segment inside one voxel visits nothing).
///
/// The path is 6-connected and always arrives exactly at the endpoint's key: each axis takes
/// exactly |key(end) - key(origin)| steps, so rounding can never make the walk overshoot or stop
/// early. Where the segment passes exactly through a voxel edge or corner, the walk steps along x
/// before y before z and so also visits a voxel the segment only touches.
///
/// \param origin, end  metres, map frame; both must be finite and representable as keys at
///                     \p resolution (see is_representable()): this function does not check.
/// \param resolution   voxel edge in metres (> 0).
/// \param visit        callable as visit(const VoxelKey&).
namespace detail {

/// The state of cast_ray()'s walk after its set-up: the one definition of the arithmetic that
/// decides each step, shared by cast_ray() and the scan scratch's own walk so that both take
/// exactly the same steps.
struct RayWalk {
  VoxelKey key;               ///< the voxel holding the origin, where the walk starts
  std::int64_t total = 0;     ///< voxels to visit: the origin's and every one before the end's
  std::int64_t left[3]{};     ///< steps still to take along x, y, z
  double t[3]{};              ///< ray parameter in [0, 1] of the next boundary along each axis
  double dt[3]{};             ///< ray parameter span of one voxel along each axis
  std::int32_t step[3]{};     ///< +1 or -1 along each axis
};

/// Sets up the walk of the segment \p origin -> \p end (see cast_ray()). An axis with no step
/// gets t = dt = infinity, so the comparisons of a step never choose it.
[[nodiscard]] inline RayWalk start_ray_walk(const Eigen::Vector3d& origin, const Eigen::Vector3d& end,
                                            double resolution) noexcept {
  RayWalk w;
  w.key = world_to_key(origin, resolution);
  const VoxelKey end_key = world_to_key(end, resolution);
  const std::int32_t start[3] = {w.key.x, w.key.y, w.key.z};
  const std::int32_t stop[3] = {end_key.x, end_key.y, end_key.z};
  constexpr double kInf = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    const std::int64_t diff = static_cast<std::int64_t>(stop[a]) - start[a];
    w.left[a] = std::llabs(diff);
    w.total += w.left[a];
    w.step[a] = diff > 0 ? 1 : -1;
    if (diff == 0) {
      w.t[a] = kInf;
      w.dt[a] = kInf;
      continue;
    }
    const double o = origin[a];
    const double d = end[a] - o;
    const double boundary = (static_cast<double>(start[a]) + (diff > 0 ? 1.0 : 0.0)) * resolution;
    w.t[a] = (boundary - o) / d;
    w.dt[a] = resolution / std::abs(d);
  }
  return w;
}

}  // namespace detail

template <class Visitor>
void cast_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& end, double resolution, Visitor&& visit) {
  const detail::RayWalk w = detail::start_ray_walk(origin, end, resolution);
  if (w.total == 0) return;
  constexpr double kInf = std::numeric_limits<double>::infinity();
  std::int64_t nx = w.left[0], ny = w.left[1], nz = w.left[2];
  double tx = w.t[0], ty = w.t[1], tz = w.t[2];
  VoxelKey key = w.key;
  visit(static_cast<const VoxelKey&>(key));
  for (std::int64_t s = 1; s < w.total; ++s) {
    // Ties go to x, then y, then z (documented above). An axis whose steps are all taken gets
    // t = infinity, so rounding can never make it step again.
    if (tx <= ty && tx <= tz) {
      key.x += w.step[0];
      tx = --nx == 0 ? kInf : tx + w.dt[0];
    } else if (ty <= tz) {
      key.y += w.step[1];
      ty = --ny == 0 ? kInf : ty + w.dt[1];
    } else {
      key.z += w.step[2];
      tz = --nz == 0 ? kInf : tz + w.dt[2];
    }
    visit(static_cast<const VoxelKey&>(key));
  }
}

/// The keys cast_ray() visits, as a vector (convenient; the template is the fast path).
[[nodiscard]] inline std::vector<VoxelKey> compute_ray_keys(const Eigen::Vector3d& origin,
                                                            const Eigen::Vector3d& end, double resolution) {
  std::vector<VoxelKey> keys;
  cast_ray(origin, end, resolution, [&keys](const VoxelKey& k) { keys.push_back(k); });
  return keys;
}

}  // namespace iwlomap
