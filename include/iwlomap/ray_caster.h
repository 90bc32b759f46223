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
/// \param visit        callable as visit(const VoxelKey&).
template <class Visitor>
void cast_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& end, double resolution, Visitor&& visit) {
  VoxelKey key = world_to_key(origin, resolution);
  const VoxelKey end_key = world_to_key(end, resolution);
  const std::int64_t diff[3] = {static_cast<std::int64_t>(end_key.x) - key.x,
                                static_cast<std::int64_t>(end_key.y) - key.y,
                                static_cast<std::int64_t>(end_key.z) - key.z};
  const std::int64_t total = std::llabs(diff[0]) + std::llabs(diff[1]) + std::llabs(diff[2]);
  if (total == 0) return;

  constexpr double kInf = std::numeric_limits<double>::infinity();
  std::int32_t* coord[3] = {&key.x, &key.y, &key.z};
  std::int64_t remaining[3];
  int step[3];
  double t_max[3];
  double t_delta[3];
  for (int i = 0; i < 3; ++i) {
    remaining[i] = std::llabs(diff[i]);
    step[i] = diff[i] > 0 ? 1 : (diff[i] < 0 ? -1 : 0);
    const double d = end[i] - origin[i];
    if (step[i] == 0) {
      t_max[i] = kInf;
      t_delta[i] = kInf;
      continue;
    }
    const double boundary = (static_cast<double>(*coord[i]) + (step[i] > 0 ? 1.0 : 0.0)) * resolution;
    t_max[i] = (boundary - origin[i]) / d;
    t_delta[i] = resolution / std::abs(d);
  }

  visit(static_cast<const VoxelKey&>(key));
  for (std::int64_t s = 1; s < total; ++s) {
    int axis = 0;
    if (t_max[1] < t_max[axis]) axis = 1;
    if (t_max[2] < t_max[axis]) axis = 2;
    *coord[axis] += step[axis];
    t_max[axis] = --remaining[axis] == 0 ? kInf : t_max[axis] + t_delta[axis];
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
