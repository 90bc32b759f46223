// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Amanatides-Woo voxel traversal of a segment, in the keys of voxel_key.h.

#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

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
template <class Visitor>
void cast_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& end, double resolution, Visitor&& visit) {
  const VoxelKey start_key = world_to_key(origin, resolution);
  const VoxelKey end_key = world_to_key(end, resolution);
  const std::int64_t dx = static_cast<std::int64_t>(end_key.x) - start_key.x;
  const std::int64_t dy = static_cast<std::int64_t>(end_key.y) - start_key.y;
  const std::int64_t dz = static_cast<std::int64_t>(end_key.z) - start_key.z;
  std::int64_t nx = std::llabs(dx), ny = std::llabs(dy), nz = std::llabs(dz);
  const std::int64_t total = nx + ny + nz;
  if (total == 0) return;

  constexpr double kInf = std::numeric_limits<double>::infinity();
  // Parameter t in [0, 1] along origin -> end at which the walk next crosses a boundary of each
  // axis (t_*), and the parameter span of one voxel along it (d_*). An axis with no step left
  // gets t = inf, so it can never be chosen.
  const auto setup = [&](std::int64_t diff, std::int32_t k, double o, double e, double& t, double& delta) {
    if (diff == 0) {
      t = kInf;
      delta = kInf;
      return;
    }
    const double d = e - o;
    const double boundary = (static_cast<double>(k) + (diff > 0 ? 1.0 : 0.0)) * resolution;
    t = (boundary - o) / d;
    delta = resolution / std::abs(d);
  };
  double tx, ty, tz, ddx, ddy, ddz;
  setup(dx, start_key.x, origin.x(), end.x(), tx, ddx);
  setup(dy, start_key.y, origin.y(), end.y(), ty, ddy);
  setup(dz, start_key.z, origin.z(), end.z(), tz, ddz);
  const std::int32_t sx = dx > 0 ? 1 : -1, sy = dy > 0 ? 1 : -1, sz = dz > 0 ? 1 : -1;

  VoxelKey key = start_key;
  visit(static_cast<const VoxelKey&>(key));
  for (std::int64_t s = 1; s < total; ++s) {
    // Ties go to x, then y, then z (documented above).
    if (tx <= ty && tx <= tz) {
      key.x += sx;
      tx = --nx == 0 ? kInf : tx + ddx;
    } else if (ty <= tz) {
      key.y += sy;
      ty = --ny == 0 ? kInf : ty + ddy;
    } else {
      key.z += sz;
      tz = --nz == 0 ? kInf : tz + ddz;
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
