// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// iwlomap keys and OctoMap keys: the one place where they are converted, and the range check.

#include "iwlomap/voxel_key.h"
#include "storage/block_grid.h"

#include <octomap/OcTree.h>
#include <octomap/OcTreeKey.h>

#include <Eigen/Core>

#include <cstdint>
#include <sstream>
#include <stdexcept>
#include <string>

namespace iwlomap::detail {

// OctoMap's 16-level tree: key = floor(coordinate / resolution) + 32768, in 0..65535.
inline constexpr std::int32_t kKeyOffset = 32768;
inline constexpr std::int32_t kMinKey = -kKeyOffset;
inline constexpr std::int32_t kMaxKey = kKeyOffset - 1;
inline constexpr unsigned kTreeDepth = 16;
// Range of block keys (8^3 voxels) whose voxels all lie inside the key range; the range is
// block-aligned, so a block is either wholly inside or wholly outside.
inline constexpr std::int32_t kMinBlock = kMinKey >> kBlockShift;
inline constexpr std::int32_t kMaxBlock = kMaxKey >> kBlockShift;

inline bool in_octomap_range(const VoxelKey& k) noexcept {
  return k.x >= kMinKey && k.x <= kMaxKey && k.y >= kMinKey && k.y <= kMaxKey && k.z >= kMinKey && k.z <= kMaxKey;
}
inline bool block_in_octomap_range(const VoxelKey& b) noexcept {
  return b.x >= kMinBlock && b.x <= kMaxBlock && b.y >= kMinBlock && b.y <= kMaxBlock && b.z >= kMinBlock &&
         b.z <= kMaxBlock;
}
inline octomap::OcTreeKey to_octomap(const VoxelKey& k) noexcept {
  return octomap::OcTreeKey(static_cast<octomap::key_type>(k.x + kKeyOffset),
                            static_cast<octomap::key_type>(k.y + kKeyOffset),
                            static_cast<octomap::key_type>(k.z + kKeyOffset));
}
inline VoxelKey from_octomap(const octomap::OcTreeKey& k) noexcept {
  return {static_cast<std::int32_t>(k[0]) - kKeyOffset, static_cast<std::int32_t>(k[1]) - kKeyOffset,
          static_cast<std::int32_t>(k[2]) - kKeyOffset};
}

inline std::string describe_key(const VoxelKey& k) {
  return "(" + std::to_string(k.x) + ", " + std::to_string(k.y) + ", " + std::to_string(k.z) + ")";
}
inline std::string describe_point(const Eigen::Vector3d& p) {
  std::ostringstream s;
  s.precision(17);
  s << "(" << p.x() << ", " << p.y() << ", " << p.z() << ")";
  return s.str();
}

// \p what names the offending input, e.g. "point 3 (x, y, z)".
[[noreturn]] inline void throw_outside_octomap(const std::string& what, const VoxelKey& key, double resolution) {
  std::ostringstream s;
  s << "iwlomap: OctoMap backend: " << what << " falls in voxel " << describe_key(key)
    << ", outside OctoMap's key range [" << kMinKey << ", " << kMaxKey << "] per axis (+-"
    << static_cast<double>(kKeyOffset) * resolution << " m at resolution " << resolution
    << " m); nothing was changed";
  throw std::out_of_range(s.str());
}

// Writes \p value into the leaf of \p key, creating the path to it. setNodeValue() clamps to the
// tree's clamping thresholds, which belong to OctoMap's own model; the mirror must hold the IWLO
// value itself, so the leaf is set again unclamped. lazy_eval: inner nodes are refreshed once
// before the tree is read (updateInnerOccupancy()), not on every write.
inline void set_leaf(octomap::OcTree& tree, const VoxelKey& key, float value) {
  octomap::OcTreeNode* leaf = tree.setNodeValue(to_octomap(key), value, /*lazy_eval=*/true);
  leaf->setLogOdds(value);
}

}  // namespace iwlomap::detail
