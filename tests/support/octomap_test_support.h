// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Helpers of the OctoMap backend's tests (test_octree_mapper.cpp, test_octomap_files.cpp): the
// voxels of an OctoMap tree through OctoMap's own key conversion, reading an .ot file, a map filled
// with a few synthetic scans, and the message of an exception.

#include "iwlomap/mapper_backend.h"
#include "iwlomap/synthetic_scan.h"
#include "iwlomap/voxel_key.h"

#include <octomap/AbstractOcTree.h>
#include <octomap/OcTree.h>

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <exception>
#include <functional>
#include <map>
#include <memory>
#include <string>

namespace iwlomap::octomap_test {

// Every voxel of an OctoMap tree (pruned leaves expanded), by iwlomap key, through OctoMap's own
// key <-> coordinate conversion, so this oracle does not share the library's key arithmetic.
inline std::map<VoxelKey, float> tree_voxels(const octomap::OcTree& tree, double r) {
  std::map<VoxelKey, float> out;
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const double size = it.getSize();
    const int side = static_cast<int>(std::lround(size / tree.getResolution()));
    const octomap::point3d c = it.getCoordinate();
    for (int dx = 0; dx < side; ++dx)
      for (int dy = 0; dy < side; ++dy)
        for (int dz = 0; dz < side; ++dz) {
          const double x = c.x() - size / 2 + (dx + 0.5) * tree.getResolution();
          const double y = c.y() - size / 2 + (dy + 0.5) * tree.getResolution();
          const double z = c.z() - size / 2 + (dz + 0.5) * tree.getResolution();
          const octomap::OcTreeKey k = tree.coordToKey(x, y, z);
          const VoxelKey key{static_cast<int>(k[0]) - 32768, static_cast<int>(k[1]) - 32768,
                             static_cast<int>(k[2]) - 32768};
          EXPECT_EQ(key, world_to_key(Eigen::Vector3d(x, y, z), r));
          out[key] = it->getLogOdds();
        }
  }
  return out;
}

inline std::unique_ptr<octomap::OcTree> read_ot(const std::string& path) {
  std::unique_ptr<octomap::AbstractOcTree> any(octomap::AbstractOcTree::read(path));
  auto* tree = dynamic_cast<octomap::OcTree*>(any.get());
  if (tree == nullptr) return nullptr;
  any.release();
  return std::unique_ptr<octomap::OcTree>(tree);
}

// A map with free space, occupied surfaces, negative keys and a few scans' worth of voxels.
inline void fill_with_scans(IMapperBackend& map, int scans = 3) {
  for (int s = 0; s < scans; ++s) {
    SyntheticScanOptions o;
    o.rings = 10;
    o.columns = 160;
    o.sensor_xy = Eigen::Vector2d(-2.0 + 2.5 * s, 1.0 - 1.5 * s);
    o.seed = 31u + static_cast<std::uint32_t>(s);
    const SyntheticScan scan = make_synthetic_scan(o);
    map.insert_scan(scan.origin, scan.points, scan.intensities, 18.0);
  }
}

inline std::string message_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "(nothing thrown)";
}

}  // namespace iwlomap::octomap_test
