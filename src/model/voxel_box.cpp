// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/voxel_box.h"


#include <algorithm>
#include <limits>
#include <stdexcept>
#include <string>

namespace iwlomap {

namespace {
std::string key_text(const VoxelKey& k) {
  return "(" + std::to_string(k.x) + ", " + std::to_string(k.y) + ", " + std::to_string(k.z) + ")";
}
}  // namespace

VoxelBox VoxelBox::from_world(const Eigen::Vector3d& min_corner, const Eigen::Vector3d& max_corner,
                              double resolution) {
  for (int a = 0; a < 3; ++a)
    if (min_corner[a] > max_corner[a])
      throw std::invalid_argument("iwlomap: box min corner exceeds max corner on axis " + std::to_string(a) + ": " +
                                  std::to_string(min_corner[a]) + " > " + std::to_string(max_corner[a]));
  VoxelBox box{world_to_key_checked(min_corner, resolution), world_to_key_checked(max_corner, resolution)};
  box.validate();
  return box;
}

std::uint64_t VoxelBox::num_voxels() const noexcept {
  const auto e = extent();
  if (e.x() <= 0 || e.y() <= 0 || e.z() <= 0) return 0;
  // Each extent is at most 2^32, so even two of them can overflow 64 bits.
  constexpr std::uint64_t kMax = std::numeric_limits<std::uint64_t>::max();
  std::uint64_t n = 1;
  for (int a = 0; a < 3; ++a) {
    const auto f = static_cast<std::uint64_t>(e[a]);
    if (n > kMax / f) return kMax;
    n *= f;
  }
  return n;
}

void VoxelBox::validate() const {
  if (min.x > max.x || min.y > max.y || min.z > max.z)
    throw std::invalid_argument("iwlomap: voxel box min key " + key_text(min) + " exceeds max key " + key_text(max));
}

}  // namespace iwlomap
