// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Where one ray of a scan ends: the single definition that ScanScratch (the map's observations)
// and HitAccumulator (the hit statistics, which cast the rays again) both use, so that the two
// always agree on which points are cast, which are clipped and where.

#include "iwlomap/ray_caster.h"

#include <Eigen/Core>

namespace iwlomap::detail {

struct ScanRayEnd {
  bool cast = false;     // false: the ray is longer than kMaxRayVoxels edges; skip the point
  bool clipped = false;  // the point lies beyond max_range: a free ray ending there, no hit
  Eigen::Vector3d end = Eigen::Vector3d::Zero();  // metres, map frame
};

/// The ray from \p origin to the finite point \p p, clipped at \p max_range when that is > 0;
/// \p longest is kMaxRayVoxels * resolution.
inline ScanRayEnd scan_ray_end(const Eigen::Vector3d& origin, const Eigen::Vector3d& p, double max_range,
                               double longest) {
  ScanRayEnd r;
  const Eigen::Vector3d d = p - origin;
  const double range = d.norm();
  r.clipped = max_range > 0.0 && range > max_range;
  r.cast = (r.clipped ? max_range : range) <= longest;
  r.end = r.clipped ? Eigen::Vector3d(origin + d * (max_range / range)) : p;
  return r;
}

}  // namespace iwlomap::detail
