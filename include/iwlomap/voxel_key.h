// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Integer voxel keys and the one place where world coordinates become keys and back.
///
/// A voxel with key (x, y, z) covers [x*r, (x+1)*r) x [y*r, (y+1)*r) x [z*r, (z+1)*r) in metres of
/// the map frame, r being the resolution. Keys are computed with floor (never rounding, never a
/// cast toward zero), so key -1 holds the coordinates just below 0. Keys are int32: at 0.05 m a map
/// spans +-107,000 km, far beyond OctoMap's +-32768 voxels.

#include <Eigen/Core>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <functional>

namespace iwlomap {

/// Integer coordinates of a voxel.
struct VoxelKey {
  std::int32_t x = 0;
  std::int32_t y = 0;
  std::int32_t z = 0;

  friend constexpr bool operator==(const VoxelKey& a, const VoxelKey& b) noexcept {
    return a.x == b.x && a.y == b.y && a.z == b.z;
  }
  friend constexpr bool operator!=(const VoxelKey& a, const VoxelKey& b) noexcept { return !(a == b); }
  /// Lexicographic (x, y, z) order, for sorted output and deterministic comparisons.
  friend constexpr bool operator<(const VoxelKey& a, const VoxelKey& b) noexcept {
    if (a.x != b.x) return a.x < b.x;
    if (a.y != b.y) return a.y < b.y;
    return a.z < b.z;
  }
};

/// A well-mixed 64-bit hash of a key (usable with std::unordered_map).
struct VoxelKeyHash {
  [[nodiscard]] std::size_t operator()(const VoxelKey& k) const noexcept {
    std::uint64_t h = static_cast<std::uint32_t>(k.x) * 0x9E3779B97F4A7C15ULL;
    h ^= static_cast<std::uint32_t>(k.y) * 0xC2B2AE3D27D4EB4FULL;
    h ^= static_cast<std::uint32_t>(k.z) * 0x165667B19E3779F9ULL;
    h ^= h >> 31;
    h *= 0xD6E8FEB86659FD93ULL;
    h ^= h >> 32;
    return static_cast<std::size_t>(h);
  }
};

/// Key of the voxel containing one coordinate: floor(coordinate / resolution).
/// Unchecked: the caller guarantees a finite coordinate whose key fits in int32.
[[nodiscard]] inline std::int32_t coordinate_to_key(double coordinate, double resolution) noexcept {
  return static_cast<std::int32_t>(std::floor(coordinate / resolution));
}

/// True when \p point is finite and its key fits in int32 at \p resolution.
[[nodiscard]] bool is_representable(const Eigen::Vector3d& point, double resolution) noexcept;

/// Key of the voxel containing \p point (metres, map frame). Unchecked, see coordinate_to_key().
[[nodiscard]] inline VoxelKey world_to_key(const Eigen::Vector3d& point, double resolution) noexcept {
  return {coordinate_to_key(point.x(), resolution), coordinate_to_key(point.y(), resolution),
          coordinate_to_key(point.z(), resolution)};
}

/// Checked variant of world_to_key(): throws std::invalid_argument for a non-finite point or a
/// non-positive resolution, std::out_of_range when a key would not fit in int32.
[[nodiscard]] VoxelKey world_to_key_checked(const Eigen::Vector3d& point, double resolution);

/// Centre of a voxel in metres, map frame: (key + 0.5) * resolution.
[[nodiscard]] inline Eigen::Vector3d key_to_center(const VoxelKey& key, double resolution) noexcept {
  return {(static_cast<double>(key.x) + 0.5) * resolution, (static_cast<double>(key.y) + 0.5) * resolution,
          (static_cast<double>(key.z) + 0.5) * resolution};
}

}  // namespace iwlomap

/// \cond
template <>
struct std::hash<iwlomap::VoxelKey> : iwlomap::VoxelKeyHash {};
/// \endcond
