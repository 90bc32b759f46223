// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The slab test shared by the synthetic scenes.

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

namespace iwlomap::detail {

/// Where the ray o + t d (t >= 0) enters the box [lo, hi]: returns false when it misses or when
/// o lies inside the box (surfaces are seen from outside only, so a sensor inside a box is not
/// blinded by it); otherwise sets \p t and the index of the axis whose face it enters.
inline bool ray_box_entry(const Eigen::Vector3d& o, const Eigen::Vector3d& d, const Eigen::Vector3d& lo,
                          const Eigen::Vector3d& hi, double& t, int& axis) {
  double t0 = 0.0, t1 = std::numeric_limits<double>::infinity();
  axis = -1;
  for (int i = 0; i < 3; ++i) {
    if (std::abs(d[i]) < 1e-12) {
      if (o[i] < lo[i] || o[i] > hi[i]) return false;
      continue;
    }
    double a = (lo[i] - o[i]) / d[i], c = (hi[i] - o[i]) / d[i];
    if (a > c) std::swap(a, c);
    if (a > t0) {
      t0 = a;
      axis = i;
    }
    t1 = std::min(t1, c);
    if (t0 > t1) return false;
  }
  if (axis < 0) return false;
  t = t0;
  return true;
}

}  // namespace iwlomap::detail
