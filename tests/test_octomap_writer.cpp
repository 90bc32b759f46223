// SPDX-License-Identifier: BSD-3-Clause
// export_octomap() writes the OctoMap stream straight from the map's blocks. These tests hold it
// to the bytes OctoMap itself writes for the same voxels (an OcTree with a leaf per voxel,
// updateInnerOccupancy(), prune(), then writeBinaryConst() or write()), for every backend (the
// RAM and Disk backends are read block by block, the OctoMap backend through for_each_voxel()),
// maps whose pruning reaches above the 8^3 blocks, keys at both ends of OctoMap's range, and any
// threshold.

#include "backend_test_support.h"
#include "iwlomap/octomap/octree_mapper.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"

#include <octomap/OcTree.h>

#include <gtest/gtest.h>

#include <cstdlib>
#include <fstream>
#include <memory>
#include <optional>
#include <iterator>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace iwlomap {
namespace {

using test_support::TempDir;

std::string bytes_of(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// What OctoMap writes for the voxels of \p map: .bt holds each voxel's maximum-likelihood value
// by \p threshold, .ot its log-odds.
std::string octree_bytes(const IMapperBackend& map, bool binary, double threshold) {
  octomap::OcTree tree(map.get_resolution());
  const float occupied = tree.getClampingThresMaxLog();
  const float free = tree.getClampingThresMinLog();
  map.for_each_voxel([&](const VoxelKey& k, const VoxelState& v) {
    const octomap::OcTreeKey key(static_cast<octomap::key_type>(k.x + 32768),
                                 static_cast<octomap::key_type>(k.y + 32768),
                                 static_cast<octomap::key_type>(k.z + 32768));
    const float value = binary ? (v.probability > threshold ? occupied : free) : static_cast<float>(v.log_odds);
    tree.setNodeValue(key, value, /*lazy_eval=*/true)->setLogOdds(value);
  });
  tree.updateInnerOccupancy();
  tree.prune();
  std::ostringstream out;
  EXPECT_TRUE(binary ? tree.writeBinaryConst(out) : tree.write(out));
  return out.str();
}

// Exports \p map to both formats and compares each with OctoMap's bytes; returns the .bt bytes.
std::string expect_octree_bytes(const IMapperBackend& map, double threshold, const std::string& what) {
  TempDir dir;
  export_octomap(map, dir.sub("map.bt"), threshold);
  export_octomap(map, dir.sub("map.ot"), threshold);
  const std::string bt = bytes_of(dir.sub("map.bt"));
  EXPECT_TRUE(bt == octree_bytes(map, true, threshold)) << what << ": .bt differs from OctoMap's";
  EXPECT_TRUE(bytes_of(dir.sub("map.ot")) == octree_bytes(map, false, threshold)) << what << ": .ot differs";
  return bt;
}

// The size of a file's node data (after its header's "data" line).
std::size_t data_bytes(const std::string& file) {
  const std::size_t at = file.find("\ndata\n");
  EXPECT_NE(at, std::string::npos);
  return file.size() - (at + 6);
}

Eigen::Vector3d center(const VoxelKey& k, double r) { return key_to_center(k, r); }

// Sets voxels of \p map: a 32^3 cube of free space aligned to 32 voxels (pruned up to its own
// node, 2 levels above a block), an 8^3 occupied block inside it, one voxel of another value in
// a second cube, keys at both ends of OctoMap's range, and scattered voxels of random log-odds.
void fill_pattern(IMapperBackend& map, std::uint32_t seed, int scattered = 20000) {
  const double r = map.get_resolution();
  std::vector<Eigen::Vector3d> points;
  std::vector<double> values;
  const auto add = [&](const VoxelKey& k, double l) {
    points.push_back(center(k, r));
    values.push_back(l);
  };
  for (int z = 0; z < 32; ++z)
    for (int y = 0; y < 32; ++y)
      for (int x = 0; x < 32; ++x) {
        add({-64 + x, -32 + y, 32 + z}, -1.5);
        const bool inner = x >= 8 && x < 16 && y >= 8 && y < 16 && z >= 16 && z < 24;
        add({x, 64 + y, -32 + z}, inner ? 2.0 : -1.5);
      }
  add({5, 64 + 7, -32 + 9}, 0.25);  // breaks the second cube's pruning at every level
  for (const VoxelKey& k : {VoxelKey{-32768, -32768, -32768}, VoxelKey{32767, 32767, 32767},
                            VoxelKey{-32768, 32767, 0}, VoxelKey{32767, -1, -32768}})
    add(k, 1.0);
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> key(-3000, 3000);
  std::uniform_real_distribution<double> l(-2.0, 3.5);
  for (int i = 0; i < scattered; ++i) add({key(rng), key(rng), 100 + std::abs(key(rng)) / 10}, l(rng));  // above the cubes
  Eigen::MatrixXd p(static_cast<Eigen::Index>(points.size()), 3);
  for (std::size_t i = 0; i < points.size(); ++i) p.row(static_cast<Eigen::Index>(i)) = points[i].transpose();
  map.set_log_odds(p, Eigen::Map<const Eigen::VectorXd>(values.data(), static_cast<Eigen::Index>(values.size())));
}

TEST(OctomapWriter, RamMapOfAScanEqualsOctoMapsBytes) {
  ProbabilityUpdater map(0.2);
  const SyntheticScan scan = make_synthetic_scan();
  map.insert_scan(scan.origin, scan.points, scan.intensities);
  const std::string bt = expect_octree_bytes(map, map.get_params().occupied_threshold, "synthetic scan");
  EXPECT_GT(bt.size(), 10000u);
}

TEST(OctomapWriter, PrunedCubesRangeEndsAndRandomValuesEqualOctoMapsBytes) {
  ProbabilityUpdater map(0.1);
  fill_pattern(map, 7);
  for (const double threshold : {0.7, 0.5, 0.3, 0.9})
    expect_octree_bytes(map, threshold, "pattern, threshold " + std::to_string(threshold));
}

TEST(OctomapWriter, PruningAboveBlocksShrinksTheFile) {
  // The check can fail: the free cube must collapse into one leaf, so one changed voxel in it
  // (a cube of 32^3 no longer uniform) makes the file larger by the nodes down to that voxel.
  ProbabilityUpdater a(0.1), b(0.1);
  fill_pattern(a, 3);
  fill_pattern(b, 3);
  Eigen::MatrixXd p(1, 3);
  p.row(0) = center({-64 + 17, -32 + 3, 32 + 30}, 0.1).transpose();
  b.set_log_odds(p, Eigen::VectorXd::Constant(1, 3.0));
  const std::string bt_a = expect_octree_bytes(a, 0.7, "pattern");
  const std::string bt_b = expect_octree_bytes(b, 0.7, "pattern with one occupied voxel");
  // 5 levels down from the cube's node (depth 11 to 16): 5 inner nodes of 2 bytes each.
  EXPECT_EQ(data_bytes(bt_b), data_bytes(bt_a) + 10);
}

TEST(OctomapWriter, DiskMapReadFromItsTilesEqualsOctoMapsBytes) {
  TempDir dir;
  OutofcoreTileMapper map(dir.sub("tiles"), 0.1, 1.6, 1);  // 16-voxel tiles, one resident
  fill_pattern(map, 11, 500);
  map.flush();
  expect_octree_bytes(map, 0.7, "disk map, one tile resident");
  ProbabilityUpdater ram(0.1);
  fill_pattern(ram, 11, 500);
  EXPECT_TRUE(bytes_of([&] {
                const std::string path = dir.sub("disk.bt");
                export_octomap(map, path, 0.7);
                return path;
              }()) == bytes_of([&] {
                const std::string path = dir.sub("ram.bt");
                export_octomap(ram, path, 0.7);
                return path;
              }()));
}

TEST(OctomapWriter, OctoMapBackendThroughForEachVoxelEqualsOctoMapsBytes) {
  OctreeMapper map(0.1);
  fill_pattern(map, 5);
  expect_octree_bytes(map, 0.7, "OctoMap backend");
}

TEST(OctomapWriter, EmptyMapEqualsOctoMapsEmptyTree) {
  ProbabilityUpdater map(0.05);
  const std::string bt = expect_octree_bytes(map, 0.7, "empty map");
  EXPECT_NE(bt.find("size 0\n"), std::string::npos);
}

// import_octomap(path) opens the file as a new RAM map at the file's resolution: the voxels of an
// exported .ot come back with their float log-odds.
TEST(OctomapWriter, ImportWithoutAMapOpensTheFileAtItsResolution) {
  TempDir dir;
  ProbabilityUpdater map(0.1);
  fill_pattern(map, 13, 2000);
  export_octomap(map, dir.sub("m.ot"));
  const std::unique_ptr<ProbabilityUpdater> opened = import_octomap(dir.sub("m.ot"));
  ASSERT_NE(opened, nullptr);
  EXPECT_DOUBLE_EQ(opened->get_resolution(), 0.1);
  EXPECT_EQ(opened->get_num_known_voxels(), map.get_num_known_voxels());
  std::size_t compared = 0;
  map.for_each_voxel([&](const VoxelKey& k, const VoxelState& v) {
    const std::optional<VoxelState> o = opened->query(center(k, 0.1));
    ASSERT_TRUE(o.has_value());
    EXPECT_EQ(static_cast<float>(o->log_odds), static_cast<float>(v.log_odds));
    ++compared;
  });
  EXPECT_GT(compared, 30000u);
  EXPECT_THROW((void)import_octomap(dir.sub("missing.ot")), std::runtime_error);
}

}  // namespace
}  // namespace iwlomap
