// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/voxel_key.h"

#include "model/checks.h"

#include <cmath>
#include <limits>
#include <stdexcept>

namespace iwlomap {

namespace {
bool key_fits(double coordinate, double resolution) {
  const double k = std::floor(coordinate / resolution);
  return k >= static_cast<double>(std::numeric_limits<std::int32_t>::min()) &&
         k <= static_cast<double>(std::numeric_limits<std::int32_t>::max());
}
}  // namespace

bool is_representable(const Eigen::Vector3d& point, double resolution) noexcept {
  return point.allFinite() && key_fits(point.x(), resolution) && key_fits(point.y(), resolution) &&
         key_fits(point.z(), resolution);
}

VoxelKey world_to_key_checked(const Eigen::Vector3d& point, double resolution) {
  detail::check_resolution(resolution);
  if (!point.allFinite()) throw std::invalid_argument("iwlomap: world_to_key_checked: the point is not finite");
  if (!is_representable(point, resolution)) detail::throw_out_of_range(-2, point, resolution);
  return world_to_key(point, resolution);
}

}  // namespace iwlomap
