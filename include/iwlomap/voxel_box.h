// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// VoxelBox: an axis-aligned box of voxels given by its lowest and highest keys (both included),
/// the region that grids, entropy sums and unknown counts are taken over.

#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <cstdint>
#include <optional>

namespace iwlomap {

class IMapperBackend;

/// The voxels with min.x <= x <= max.x, min.y <= y <= max.y, min.z <= z <= max.z (keys of
/// voxel_key.h). Boxes are inclusive on both ends so that one voxel is a box with min == max.
struct VoxelBox {
  VoxelKey min;
  VoxelKey max;

  /// The voxels containing the points of the world box [min_corner, max_corner] (metres, map
  /// frame): keys from world_to_key(min_corner) to world_to_key(max_corner). Throws
  /// std::invalid_argument for a non-finite corner, a non-positive resolution or
  /// min_corner > max_corner on an axis, std::out_of_range when a key does not fit in int32.
  [[nodiscard]] static VoxelBox from_world(const Eigen::Vector3d& min_corner, const Eigen::Vector3d& max_corner,
                                           double resolution);

  [[nodiscard]] constexpr bool contains(const VoxelKey& k) const noexcept {
    return k.x >= min.x && k.x <= max.x && k.y >= min.y && k.y <= max.y && k.z >= min.z && k.z <= max.z;
  }
  /// Voxels along each axis (max - min + 1; 64-bit, since an int32 span can exceed int32).
  [[nodiscard]] Eigen::Matrix<std::int64_t, 3, 1> extent() const noexcept {
    return {static_cast<std::int64_t>(max.x) - min.x + 1, static_cast<std::int64_t>(max.y) - min.y + 1,
            static_cast<std::int64_t>(max.z) - min.z + 1};
  }
  /// Number of voxels in the box (saturates at UINT64_MAX, never wraps).
  [[nodiscard]] std::uint64_t num_voxels() const noexcept;
  /// Throws std::invalid_argument naming the keys when min > max on an axis.
  void validate() const;
};

/// The smallest box holding every known voxel of \p map, or std::nullopt for an empty map.
/// One pass over IMapperBackend::for_each_voxel().
[[nodiscard]] std::optional<VoxelBox> known_voxel_box(const IMapperBackend& map);

}  // namespace iwlomap
