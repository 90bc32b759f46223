// SPDX-License-Identifier: BSD-3-Clause
// The OctoMap backend against OctoMap itself: the octree mirrors the exact map, OctoMap's own
// model matches a plain octomap::OcTree, keys map to OctoMap's, files written by export open in
// OctoMap's readers and in Debian's octomap-tools (convert_octree, compare_octrees), imports
// restore log-odds exactly, and bad files fail with clear messages.
// (The IWLO equivalence with the RAM backend is in test_backend_contract.)

#include "backend_test_support.h"
#include "iwlomap/octree_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"

#include <octomap/AbstractOcTree.h>
#include <octomap/OcTree.h>

#include <gtest/gtest.h>

#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <sstream>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

#ifndef IWLOMAP_CONVERT_OCTREE
#define IWLOMAP_CONVERT_OCTREE ""
#endif
#ifndef IWLOMAP_COMPARE_OCTREES
#define IWLOMAP_COMPARE_OCTREES ""
#endif

namespace iwlomap {
namespace {

using test_support::Snapshot;
using test_support::TempDir;
using test_support::snapshot;

namespace fs = std::filesystem;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// Every voxel of an OctoMap tree (pruned leaves expanded), by iwlomap key, through OctoMap's own
// key <-> coordinate conversion, so this oracle does not share the library's key arithmetic.
std::map<VoxelKey, float> tree_voxels(const octomap::OcTree& tree, double r) {
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

std::unique_ptr<octomap::OcTree> read_ot(const std::string& path) {
  std::unique_ptr<octomap::AbstractOcTree> any(octomap::AbstractOcTree::read(path));
  auto* tree = dynamic_cast<octomap::OcTree*>(any.get());
  if (tree == nullptr) return nullptr;
  any.release();
  return std::unique_ptr<octomap::OcTree>(tree);
}

// A map with free space, occupied surfaces, negative keys and a few scans' worth of voxels.
void fill_with_scans(IMapperBackend& map, int scans = 3) {
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

std::string message_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "(nothing thrown)";
}

// ---- the mirror ------------------------------------------------------------------------------

TEST(OctreeMapper, MirrorsExactLogOddsIntoOctreeWhenScansAndBatches) {
  TempDir dir;
  const double r = 0.2;
  OctreeMapper map(r);
  fill_with_scans(map);
  std::mt19937 rng(4u);
  std::uniform_real_distribution<double> c(-3.0, 3.0);
  Eigen::MatrixXd pts(3000, 3);
  for (Eigen::Index i = 0; i < pts.rows(); ++i) pts.row(i) << c(rng), c(rng), c(rng);
  map.batch_update_iwlo(pts, Eigen::VectorXd::Constant(3000, 180.0), std::vector<bool>(3000, true));

  const std::string path = dir.sub("mirror.ot");
  const bool saved = map.save_to_file(path);  // the reference API's form compiles
  EXPECT_TRUE(saved);
  OctreeMapper reloaded(r);
  const bool loaded = reloaded.load_from_file(path);
  EXPECT_TRUE(loaded);
  EXPECT_EQ(reloaded.get_memory_usage().num_leaf_nodes, map.get_memory_usage().num_leaf_nodes);
  const auto tree = read_ot(path);
  ASSERT_NE(tree, nullptr);
  EXPECT_EQ(tree->getResolution(), r);
  const auto voxels = tree_voxels(*tree, r);
  const Snapshot exact = snapshot(map);
  ASSERT_EQ(voxels.size(), exact.size());
  for (const auto& [k, v] : exact) {
    const auto it = voxels.find(k);
    ASSERT_NE(it, voxels.end()) << "voxel (" << k.x << ", " << k.y << ", " << k.z << ") missing from the octree";
    EXPECT_EQ(static_cast<double>(it->second), v.first);
  }
  // The octree's figures: one leaf per known voxel while nothing is pruned.
  const MemoryStats m = map.get_memory_usage();
  EXPECT_EQ(m.num_leaf_nodes, exact.size());
  EXPECT_GT(m.num_nodes, m.num_leaf_nodes);
  EXPECT_GT(m.memory_mb, 0.0);
  EXPECT_EQ(map.get_num_nodes(), exact.size());
}

// The OctoMap backend keeps the RAM backend's exact state in the same layout, so the two list
// their occupied voxels in the same order, not only as the same set.
TEST(OctreeMapper, ListsOccupiedVoxelsInTheRamBackendsOrderWhenScansAndBatches) {
  const double r = 0.2;
  OctreeMapper octo(r);
  ProbabilityUpdater ram(r);
  fill_with_scans(octo);
  fill_with_scans(ram);
  std::mt19937 rng(9u);
  std::uniform_real_distribution<double> c(-3.0, 3.0);
  Eigen::MatrixXd pts(3000, 3);
  for (Eigen::Index i = 0; i < pts.rows(); ++i) pts.row(i) << c(rng), c(rng), c(rng);
  for (IMapperBackend* m : {static_cast<IMapperBackend*>(&octo), static_cast<IMapperBackend*>(&ram)})
    m->batch_update_iwlo(pts, Eigen::VectorXd::Constant(3000, 180.0), std::vector<bool>(3000, true));
  const Eigen::MatrixXd a = octo.get_occupied_voxels(), b = ram.get_occupied_voxels();
  ASSERT_GT(a.rows(), 100);
  EXPECT_TRUE(a == b);
}

TEST(OctreeMapper, UsesOctomapKeysOffsetByHalfRangeWhenNegativeCoordinates) {
  TempDir dir;
  const double r = 0.1;
  OctreeMapper map(r);
  // Floor keys: -0.05 is in key -1 (OctoMap key 32767), 0.0 in key 0 (32768).
  const Eigen::MatrixXd pts = (Eigen::MatrixXd(3, 3) << -0.05, 0.0, 0.05, 0.0, -0.25, 3276.75, -3276.75, 0.0, 0.0)
                                  .finished();
  map.set_log_odds(pts, Eigen::Vector3d(1.0, 2.0, 3.0));
  map.save_to_file(dir.sub("keys.ot"));
  const auto tree = read_ot(dir.sub("keys.ot"));
  ASSERT_NE(tree, nullptr);
  const auto at = [&](double x, double y, double z) {
    const octomap::OcTreeNode* n = tree->search(x, y, z);
    return n == nullptr ? kNaN : static_cast<double>(n->getLogOdds());
  };
  EXPECT_EQ(tree->coordToKey(-0.05), 32767);
  EXPECT_EQ(at(-0.05, 0.0, 0.05), 1.0);
  EXPECT_EQ(at(0.0, -0.25, 3276.75), 2.0);  // key 32767: the last one OctoMap has
  EXPECT_EQ(at(-3276.75, 0.0, 0.0), 3.0);   // key -32768: the first one
  EXPECT_EQ(tree->getNumLeafNodes(), 3u);
}

// ---- the OctoMap key range -------------------------------------------------------------------

TEST(OctreeMapper, ThrowsOutOfRangeAndChangesNothingWhenVoxelBeyondOctomapKeys) {
  const double r = 0.1;
  OctreeMapper map(r);
  ProbabilityUpdater ram(r);
  map.update_point(Eigen::Vector3d(1.0, 1.0, 1.0), true);
  const Snapshot before = snapshot(map);
  const double edge = 32768 * r;  // key 32768: one past OctoMap's last key
  const Eigen::MatrixXd pts = (Eigen::MatrixXd(2, 3) << 0.0, 0.0, 0.0, edge + 0.01, 0.0, 0.0).finished();
  const Eigen::Vector2d ints(200.0, 200.0);
  const std::vector<bool> flags = {true, true};

  EXPECT_NO_THROW(ram.batch_update_iwlo(pts, ints, flags));  // int32 keys: fine for RAM
  const std::string msg = message_of([&] { map.batch_update_iwlo(pts, ints, flags); });
  EXPECT_NE(msg.find("point 1"), std::string::npos) << msg;
  EXPECT_NE(msg.find("(32768, 0, 0)"), std::string::npos) << msg;
  EXPECT_NE(msg.find("[-32768, 32767]"), std::string::npos) << msg;
  EXPECT_THROW(map.batch_update_iwlo(pts, ints, flags), std::out_of_range);
  EXPECT_THROW(map.set_log_odds(pts, ints), std::out_of_range);
  EXPECT_THROW(map.batch_update(pts, flags), std::out_of_range);
  EXPECT_THROW(map.update_point(Eigen::Vector3d(0.0, -edge - 0.01, 0.0), true), std::out_of_range);
  // A scan or ray that reaches a voxel outside is refused before anything changes.
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d::Zero(), pts, ints), std::out_of_range);
  EXPECT_THROW(map.insert_ray(Eigen::Vector3d::Zero(), Eigen::Vector3d(edge + 1.0, 0.0, 0.0)), std::out_of_range);
  EXPECT_EQ(snapshot(map), before);
  // Cut at max_range, the same scan stays inside: accepted.
  EXPECT_NO_THROW(map.insert_scan(Eigen::Vector3d::Zero(), pts, ints, 100.0));
  // The last keys on both sides are usable.
  EXPECT_NO_THROW(map.update_point(Eigen::Vector3d(edge - 0.05, -edge + 0.05, 0.0), true));
  // A query outside is simply unknown.
  EXPECT_FALSE(map.query(Eigen::Vector3d(edge + 5.0, 0.0, 0.0)).has_value());
}

TEST(ExportOctomap, ThrowsOutOfRangeWithoutWritingWhenVoxelBeyondOctomapKeys) {
  TempDir dir;
  ProbabilityUpdater ram(0.05);
  ram.batch_update_iwlo((Eigen::MatrixXd(1, 3) << 5000.0, 0.0, 0.0).finished(), Eigen::VectorXd::Constant(1, 200.0),
                        {true});
  const std::string path = dir.sub("far.bt");
  const std::string msg = message_of([&] { export_octomap(ram, path); });
  EXPECT_NE(msg.find("(100000, 0, 0)"), std::string::npos) << msg;
  EXPECT_THROW(export_octomap(ram, path), std::out_of_range);
  EXPECT_FALSE(fs::exists(path));
  EXPECT_FALSE(fs::exists(path + ".part"));
}

// ---- OctoMap's own model ---------------------------------------------------------------------

// Builds the same map with a plain OcTree and compares every voxel's log-odds.
void expect_matches_plain_octree(OctreeMapper& map, const octomap::OcTree& plain, const TempDir& dir) {
  map.save_to_file(dir.sub("model.ot"));
  const auto tree = read_ot(dir.sub("model.ot"));
  ASSERT_NE(tree, nullptr);
  const double r = map.get_resolution();
  const auto got = tree_voxels(*tree, r);
  const auto want = tree_voxels(plain, r);
  EXPECT_EQ(got, want);
  // The exact state holds the same values.
  for (const auto& [k, v] : want) {
    const auto s = map.query(key_to_center(k, r));
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->log_odds, static_cast<double>(v));
  }
  EXPECT_EQ(map.get_num_nodes(), want.size());
}

TEST(OctreeMapper, MatchesPlainOcTreeWhenUpdatePointAndBatchUpdate) {
  TempDir dir;
  const double r = 0.1;
  OctreeMapper map(r, 0.75, 0.35, 0.1, 0.95);
  octomap::OcTree plain(r);
  plain.setProbHit(0.75);
  plain.setProbMiss(0.35);
  plain.setClampingThresMin(0.1);
  plain.setClampingThresMax(0.95);
  std::mt19937 rng(12u);
  std::uniform_real_distribution<double> c(-0.6, 0.6);
  std::bernoulli_distribution hit(0.6);
  Eigen::MatrixXd pts(4000, 3);
  std::vector<bool> flags(4000);
  for (int i = 0; i < 4000; ++i) {
    // Voxel centres: the plain tree converts in float, iwlomap in double; centres agree.
    const VoxelKey k = world_to_key(Eigen::Vector3d(c(rng), c(rng), c(rng)), r);
    pts.row(i) = key_to_center(k, r).transpose();
    flags[static_cast<std::size_t>(i)] = hit(rng);
  }
  pts(7, 0) = kNaN;  // skipped and counted
  map.batch_update(pts, flags);
  for (int i = 0; i < 4000; ++i)
    if (i != 7) plain.updateNode(pts(i, 0), pts(i, 1), pts(i, 2), static_cast<bool>(flags[static_cast<std::size_t>(i)]));
  map.update_point(Eigen::Vector3d(0.05, 0.05, 0.05), false);
  plain.updateNode(0.05, 0.05, 0.05, false);
  map.update_point(Eigen::Vector3d(kNaN, 0.0, 0.0), true);
  EXPECT_EQ(map.get_num_skipped_points(), 2u);
  expect_matches_plain_octree(map, plain, dir);
  // Counts: every update counted, including those OctoMap's clamping made no-ops.
  std::uint32_t total = 0;
  map.for_each_voxel([&](const VoxelKey&, const VoxelState& v) { total += v.count; });
  EXPECT_EQ(total, 4000u);
}

TEST(OctreeMapper, MatchesPlainOcTreeWhenInsertRay) {
  TempDir dir;
  const double r = 0.1;
  OctreeMapper map(r);
  octomap::OcTree plain(r);
  plain.setProbHit(0.7);
  plain.setProbMiss(0.3);
  plain.setClampingThresMin(0.12);
  plain.setClampingThresMax(0.97);
  std::mt19937 rng(3u);
  std::uniform_real_distribution<double> c(-4.0, 4.0);
  for (int i = 0; i < 300; ++i) {
    const Eigen::Vector3d o(0.3, -0.2, 0.1);
    const Eigen::Vector3d e(c(rng), c(rng), c(rng));
    const double max_range = i % 3 == 0 ? 2.5 : -1.0;
    map.insert_ray(o, e, max_range);
    plain.insertRay(octomap::point3d(static_cast<float>(o.x()), static_cast<float>(o.y()), static_cast<float>(o.z())),
                    octomap::point3d(static_cast<float>(e.x()), static_cast<float>(e.y()), static_cast<float>(e.z())),
                    max_range);
  }
  expect_matches_plain_octree(map, plain, dir);
  EXPECT_THROW(map.insert_ray(Eigen::Vector3d(kNaN, 0, 0), Eigen::Vector3d::Ones()), std::invalid_argument);
  EXPECT_THROW(map.insert_ray(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones(), kNaN), std::invalid_argument);
}

TEST(OctreeMapper, ValidatesModelParametersWhenConstructedOrSet) {
  EXPECT_THROW(OctreeMapper(0.0), std::invalid_argument);
  EXPECT_THROW(OctreeMapper(0.1, 0.4), std::invalid_argument);
  EXPECT_THROW(OctreeMapper(0.1, 0.7, 0.6), std::invalid_argument);
  EXPECT_THROW(OctreeMapper(0.1, 0.7, 0.3, 0.0), std::invalid_argument);
  EXPECT_THROW(OctreeMapper(0.1, 0.7, 0.3, 0.5, 0.4), std::invalid_argument);
  EXPECT_THROW(OctreeMapper(0.1, 0.7, 0.3, 0.12, 1.0), std::invalid_argument);
  const std::string msg = message_of([] { OctreeMapper m(0.1, 1.5); });
  EXPECT_NE(msg.find("prob_hit = 1.5"), std::string::npos) << msg;
  OctreeMapper map(0.1);
  EXPECT_EQ(map.get_prob_hit(), 0.7);
  EXPECT_EQ(map.get_prob_miss(), 0.3);
  EXPECT_EQ(map.get_prob_thres_min(), 0.12);
  EXPECT_EQ(map.get_prob_thres_max(), 0.97);
  map.set_probability_params(0.8, 0.2);
  map.set_occupancy_thresholds(0.2, 0.9);
  EXPECT_THROW(map.set_probability_params(0.8, kNaN), std::invalid_argument);
  EXPECT_THROW(map.set_occupancy_thresholds(0.9, 0.2), std::invalid_argument);
  EXPECT_EQ(map.get_prob_hit(), 0.8);
  EXPECT_EQ(map.get_prob_miss(), 0.2);
  EXPECT_EQ(map.get_prob_thres_min(), 0.2);
  EXPECT_EQ(map.get_prob_thres_max(), 0.9);
  EXPECT_EQ(map.get_params().occupied_threshold, 0.9);  // the reference API: max is the .bt threshold too
}

// set_occupancy_thresholds(min, max) as the reference API has it: max is also the threshold of
// occupancy in .bt output, so a voxel at p = 0.85 is written free under max = 0.9, occupied under
// max = 0.8.
TEST(OctreeMapper, WritesBtOccupancyAboveMaxThresholdWhenThresholdsSet) {
  TempDir dir;
  for (const double max : {0.8, 0.9}) {
    OctreeMapper map(0.1);
    Eigen::MatrixXd p(1, 3);
    p << 0.05, 0.05, 0.05;
    map.set_log_odds(p, Eigen::VectorXd::Constant(1, iwlo::log_odds(0.85)));
    map.set_occupancy_thresholds(0.12, max);
    const std::string path = dir.sub("t" + std::to_string(static_cast<int>(max * 10)) + ".bt");
    map.save_to_file(path);
    ProbabilityUpdater back(0.1);
    import_octomap(path, back);
    const auto v = back.query({0.05, 0.05, 0.05});
    ASSERT_TRUE(v.has_value());
    EXPECT_EQ(v->probability > 0.5, max < 0.85) << "max " << max;
  }
}

TEST(OctreeMapper, KeepsExactStateAndShrinksTreeWhenPruned) {
  TempDir dir;
  const double r = 0.1;
  OctreeMapper map(r);
  // A 4 x 4 x 4 cube aligned to OctoMap's octants, all at one value: 64 leaves fold into one node.
  Eigen::MatrixXd cube(64, 3);
  for (int i = 0; i < 64; ++i) cube.row(i) = key_to_center(VoxelKey{i % 4, (i / 4) % 4, i / 16}, r).transpose();
  map.set_log_odds(cube, Eigen::VectorXd::Constant(64, 2.0));
  map.set_log_odds((Eigen::MatrixXd(1, 3) << 1.05, 0.05, 0.05).finished(), Eigen::VectorXd::Constant(1, -1.0));
  const Snapshot before = snapshot(map);
  const MemoryStats m0 = map.get_memory_usage();
  EXPECT_EQ(m0.num_leaf_nodes, 65u);
  EXPECT_EQ(map.prune_tree(), 72u);  // 64 leaves + 8 parents of the cube
  const MemoryStats m1 = map.get_memory_usage();
  EXPECT_EQ(m1.num_leaf_nodes, 2u);
  EXPECT_EQ(m1.num_nodes, m0.num_nodes - 72);
  EXPECT_EQ(snapshot(map), before);
  EXPECT_EQ(map.get_num_nodes(), 65u);
  // Updating a voxel of the folded cube expands it again; the octree still mirrors the map.
  map.batch_update_iwlo(cube.topRows(1), Eigen::VectorXd::Constant(1, 250.0), {true});
  map.save_to_file(dir.sub("pruned.ot"));
  const auto tree = read_ot(dir.sub("pruned.ot"));
  ASSERT_NE(tree, nullptr);
  const auto voxels = tree_voxels(*tree, r);
  ASSERT_EQ(voxels.size(), 65u);
  for (const auto& [k, v] : snapshot(map)) EXPECT_EQ(static_cast<double>(voxels.at(k)), v.first);
  // Expanding unfolded only the path to the updated voxel: the seven other 2^3 octants of the
  // cube stayed folded, and the octant holding the new value cannot fold. Nothing to prune.
  EXPECT_EQ(map.prune_tree(), 0u);
  EXPECT_EQ(map.get_memory_usage().num_leaf_nodes, 1u + 7u + 8u);
}

TEST(OctreeMapper, UpdatesCachedFiguresWhenMapChanges) {
  OctreeMapper map(0.1);
  const MemoryStats empty = map.get_memory_usage();
  EXPECT_EQ(empty.num_nodes, 0u);
  map.update_point(Eigen::Vector3d(0.05, 0.05, 0.05), true);
  const MemoryStats one = map.get_memory_usage();
  EXPECT_EQ(one.num_leaf_nodes, 1u);
  EXPECT_EQ(one.num_nodes, 17u);  // root + 16 levels
  map.update_point(Eigen::Vector3d(-0.05, 0.05, 0.05), true);
  EXPECT_EQ(map.get_memory_usage().num_leaf_nodes, 2u);
  map.clear();
  EXPECT_EQ(map.get_memory_usage().num_nodes, 0u);
  EXPECT_EQ(map.get_num_nodes(), 0u);
}

TEST(OctreeMapper, KeepsMapWhenMovedAndThrowsLogicErrorWhenMovedFrom) {
  OctreeMapper a(0.1);
  a.update_point(Eigen::Vector3d(0.05, 0.05, 0.05), true);
  OctreeMapper b(std::move(a));
  EXPECT_EQ(b.get_num_nodes(), 1u);
  EXPECT_THROW((void)a.get_num_nodes(), std::logic_error);  // NOLINT(bugprone-use-after-move)
  OctreeMapper c(0.2);
  c = std::move(b);
  EXPECT_EQ(c.get_num_nodes(), 1u);
  EXPECT_EQ(c.get_resolution(), 0.1);
}

TEST(OctreeMapper, CreatedByMakeBackendWhenNameInAnyCase) {
  BackendOptions options;
  options.prob_hit = 0.8;
  options.prob_miss = 0.25;
  const auto map = make_backend("octomap", 0.2, options);
  EXPECT_EQ(map->get_backend_type(), "OctoMap");
  const auto* octree = dynamic_cast<const OctreeMapper*>(map.get());
  ASSERT_NE(octree, nullptr);
  EXPECT_EQ(octree->get_prob_hit(), 0.8);
  EXPECT_EQ(octree->get_prob_miss(), 0.25);
}

// ---- files -----------------------------------------------------------------------------------

TEST(OctoMapFiles, RestoresEveryLogOddsWhenRamMapExportedToOtAndImported) {
  TempDir dir;
  const double r = 0.15;
  ProbabilityUpdater ram(r);
  fill_with_scans(ram);
  std::mt19937 rng(6u);
  std::uniform_real_distribution<double> c(-2.0, 2.0);
  Eigen::MatrixXd pts(5000, 3);
  for (Eigen::Index i = 0; i < pts.rows(); ++i) pts.row(i) << c(rng), c(rng), c(rng);
  ram.batch_update_iwlo(pts, Eigen::VectorXd::LinSpaced(5000, 0.0, 255.0), std::vector<bool>(5000, true),
                        Eigen::VectorXd::LinSpaced(5000, 0.0, 1.5));
  const std::string path = dir.sub("map.ot");
  export_octomap(ram, path);
  ProbabilityUpdater copy(r);
  import_octomap(path, copy);
  const Snapshot want = snapshot(ram), got = snapshot(copy);
  ASSERT_EQ(got.size(), want.size());
  for (const auto& [k, v] : want) {
    const auto it = got.find(k);
    ASSERT_NE(it, got.end());
    EXPECT_EQ(it->second.first, v.first);  // float in, float out: exact
    EXPECT_EQ(it->second.second, 1u);      // .ot holds no counts: imported voxels are known once
  }
  // The OctoMap backend imports the same file to the same values.
  OctreeMapper octree(r);
  import_octomap(path, octree);
  for (const auto& [k, v] : snapshot(octree)) EXPECT_EQ(v.first, want.at(k).first);
  EXPECT_EQ(octree.get_num_nodes(), want.size());
}

TEST(OctoMapFiles, ExpandsPrunedNodesWhenImported) {
  TempDir dir;
  const double r = 0.1;
  ProbabilityUpdater ram(r);
  Eigen::MatrixXd cube(512, 3);  // 8^3 aligned voxels at one value: the export prunes them to one node
  for (int i = 0; i < 512; ++i)
    cube.row(i) = key_to_center(VoxelKey{-8 + i % 8, (i / 8) % 8, -8 + i / 64}, r).transpose();
  ram.set_log_odds(cube, Eigen::VectorXd::Constant(512, -3.25));
  export_octomap(ram, dir.sub("cube.ot"));
  const auto tree = read_ot(dir.sub("cube.ot"));
  ASSERT_NE(tree, nullptr);
  EXPECT_EQ(tree->getNumLeafNodes(), 1u);
  ProbabilityUpdater copy(r);
  import_octomap(dir.sub("cube.ot"), copy);
  EXPECT_EQ(snapshot(copy).size(), 512u);
  for (const auto& [k, v] : snapshot(ram)) EXPECT_EQ(copy.query(key_to_center(k, r))->log_odds, -3.25);
}

TEST(OctoMapFiles, ReadsSameOccupiedSetWhenBtReadBinary) {
  TempDir dir;
  const double r = 0.2;
  ProbabilityUpdater ram(r);
  fill_with_scans(ram);
  ram.set_occupied_threshold(0.8);
  const std::string path = dir.sub("map.bt");
  export_octomap(ram, path);

  octomap::OcTree tree(0.1);
  ASSERT_TRUE(tree.readBinary(path));
  EXPECT_EQ(tree.getResolution(), r);
  std::set<VoxelKey> occupied, free;
  for (const auto& [k, v] : tree_voxels(tree, r)) (v >= tree.getOccupancyThresLog() ? occupied : free).insert(k);
  std::set<VoxelKey> want_occupied;
  const Eigen::MatrixXd occ = ram.get_occupied_voxels(0.8);
  for (Eigen::Index i = 0; i < occ.rows(); ++i)
    want_occupied.insert(world_to_key(occ.row(i).head<3>().transpose(), r));
  EXPECT_GT(want_occupied.size(), 100u);
  EXPECT_EQ(occupied, want_occupied);
  EXPECT_EQ(occupied.size() + free.size(), ram.get_num_nodes());

  // Imported, .bt gives OctoMap's clamping log-odds of a fresh tree.
  ProbabilityUpdater copy(r);
  import_octomap(path, copy);
  const octomap::OcTree fresh(r);
  for (const auto& [k, v] : snapshot(copy)) {
    const bool occ_voxel = want_occupied.count(k) > 0;
    EXPECT_EQ(v.first, static_cast<double>(occ_voxel ? fresh.getClampingThresMaxLog() : fresh.getClampingThresMinLog()));
  }
  EXPECT_EQ(copy.get_num_nodes(), ram.get_num_nodes());
  // OctreeMapper::load_from_file uses its own clamping thresholds instead.
  OctreeMapper octree(0.5, 0.7, 0.3, 0.2, 0.9);
  octree.load_from_file(path);
  EXPECT_EQ(octree.get_resolution(), r);
  EXPECT_EQ(octree.get_num_nodes(), ram.get_num_nodes());
  EXPECT_EQ(octree.get_occupied_voxels(0.5).rows(), static_cast<Eigen::Index>(want_occupied.size()));
  const VoxelKey some = *want_occupied.begin();
  EXPECT_NEAR(octree.query(key_to_center(some, r))->probability, 0.9, 1e-6);
}

TEST(OctoMapFiles, RoundTripsWhenOctreeMapperSavesAndLoads) {
  TempDir dir;
  OctreeMapper map(0.25);
  fill_with_scans(map, 2);
  map.save_to_file(dir.sub("a.ot"));
  map.save_to_file(dir.sub("a.bt"));
  OctreeMapper loaded(1.0);
  loaded.load_from_file(dir.sub("a.ot"));
  EXPECT_EQ(loaded.get_resolution(), 0.25);
  const Snapshot want = snapshot(map), got = snapshot(loaded);
  ASSERT_EQ(got.size(), want.size());
  for (const auto& [k, v] : want) EXPECT_EQ(got.at(k).first, v.first);
  // The .bt and the .ot of one map hold the same voxels.
  OctreeMapper binary(1.0);
  binary.load_from_file(dir.sub("a.bt"));
  EXPECT_EQ(binary.get_num_nodes(), map.get_num_nodes());
  // An empty map is a valid (empty) file in both formats.
  OctreeMapper empty(0.25);
  empty.save_to_file(dir.sub("empty.ot"));
  empty.save_to_file(dir.sub("empty.bt"));
  loaded.load_from_file(dir.sub("empty.ot"));
  EXPECT_EQ(loaded.get_num_nodes(), 0u);
  loaded.load_from_file(dir.sub("empty.bt"));
  EXPECT_EQ(loaded.get_num_nodes(), 0u);
  EXPECT_FALSE(fs::exists(dir.sub("a.ot.part")));
}

TEST(OctoMapFiles, PrintsNothingWhenWritingAndReading) {
  TempDir dir;
  OctreeMapper map(0.25);
  fill_with_scans(map, 1);
  testing::internal::CaptureStdout();
  testing::internal::CaptureStderr();
  map.save_to_file(dir.sub("q.ot"));
  map.save_to_file(dir.sub("q.bt"));
  export_octomap(map, dir.sub("e.bt"));
  OctreeMapper other(0.25);
  other.load_from_file(dir.sub("q.ot"));
  other.load_from_file(dir.sub("q.bt"));
  ProbabilityUpdater ram(0.25);
  import_octomap(dir.sub("e.bt"), ram);
  (void)message_of([&] { import_octomap(dir.sub("missing.ot"), ram); });
  const std::string out = testing::internal::GetCapturedStdout();
  const std::string err = testing::internal::GetCapturedStderr();
  EXPECT_EQ(out, "");
  EXPECT_EQ(err, "");
  EXPECT_GT(ram.get_num_nodes(), 0u);
}

// Bad files: each gives the stated exception, names the path, and leaves the map untouched.
TEST(OctoMapFiles, ThrowsNamingPathAndKeepsMapWhenFileBad) {
  TempDir dir;
  const double r = 0.25;
  OctreeMapper good(r);
  fill_with_scans(good, 1);
  good.save_to_file(dir.sub("good.ot"));
  good.save_to_file(dir.sub("good.bt"));
  const auto bytes = [](const std::string& p) {
    std::ifstream in(p, std::ios::binary);
    return std::string(std::istreambuf_iterator<char>(in), {});
  };
  const auto write = [](const std::string& p, const std::string& content) {
    std::ofstream(p, std::ios::binary) << content;
  };
  const std::string ot = bytes(dir.sub("good.ot")), bt = bytes(dir.sub("good.bt"));
  std::mt19937 rng(1u);
  std::string garbage(4096, '\0');
  for (char& ch : garbage) ch = static_cast<char>(rng() & 0xFF);
  write(dir.sub("garbage.bt"), garbage);
  write(dir.sub("garbage.ot"), garbage);
  write(dir.sub("empty.bt"), "");
  write(dir.sub("truncated.ot"), ot.substr(0, ot.size() * 2 / 3));
  write(dir.sub("truncated.bt"), bt.substr(0, bt.size() / 2));
  write(dir.sub("swapped.bt"), ot);
  write(dir.sub("swapped.ot"), bt);
  write(dir.sub("no_data.ot"), "# Octomap OcTree file\nid OcTree\nsize 3\nres 0.25\n");
  write(dir.sub("bad_res.bt"), "# Octomap OcTree binary file\nid OcTree\nsize 1\nres -1\ndata\n\x01\x00");
  write(dir.sub("color.ot"), "# Octomap OcTree file\nid ColorOcTree\nsize 1\nres 0.25\ndata\n");
  // A valid header over data that claims more levels than an octree has.
  std::string deep = "# Octomap OcTree binary file\nid OcTree\nsize 18\nres 0.25\ndata\n";
  for (int i = 0; i < 17; ++i) deep += std::string("\x03\x00", 2);
  write(dir.sub("deep.bt"), deep);
  // The announced node count disagrees with the data.
  std::string miscount = bt;
  const std::size_t size_at = miscount.find("size ") + 5, size_end = miscount.find('\n', size_at);
  miscount.replace(size_at, size_end - size_at, std::to_string(std::stoull(miscount.substr(size_at)) + 1));
  write(dir.sub("miscount.bt"), miscount);
  // A NaN log-odds in an .ot node.
  std::string nan_ot = "# Octomap OcTree file\nid OcTree\nsize 1\nres 0.25\ndata\n";
  const float nan_value = std::numeric_limits<float>::quiet_NaN();
  nan_ot.append(reinterpret_cast<const char*>(&nan_value), sizeof(float));
  nan_ot.push_back('\0');
  write(dir.sub("nan.ot"), nan_ot);
  fs::create_directories(dir.sub("folder.ot"));

  struct Case {
    std::string file;
    std::string what;  // expected in the message
    bool invalid_argument;
  };
  const std::vector<Case> cases = {
      {dir.sub("missing.bt"), "does not exist", false},
      {dir.sub("missing.ot"), "does not exist", false},
      {dir.sub("good.txt"), "extension '.txt'", true},
      {dir.sub("noextension"), "extension ''", true},
      {dir.sub("folder.ot"), "is a directory", false},
      {dir.sub("garbage.bt"), "first line", false},
      {dir.sub("garbage.ot"), "first line", false},
      {dir.sub("empty.bt"), "first line", false},
      {dir.sub("truncated.ot"), "ends early", false},
      {dir.sub("truncated.bt"), "ends early", false},
      {dir.sub("swapped.bt"), "other OctoMap format", false},
      {dir.sub("swapped.ot"), "other OctoMap format", false},
      {dir.sub("no_data.ot"), "no 'data' line", false},
      {dir.sub("bad_res.bt"), "'res'", false},
      {dir.sub("color.ot"), "'ColorOcTree'", false},
      {dir.sub("deep.bt"), "deepest level", false},
      {dir.sub("miscount.bt"), "nodes", false},
      {dir.sub("nan.ot"), "non-finite", false},
  };
  fs::copy_file(dir.sub("good.ot"), dir.sub("good.txt"));
  write(dir.sub("noextension"), ot);

  ProbabilityUpdater ram(r);
  ram.set_log_odds((Eigen::MatrixXd(1, 3) << 0.1, 0.1, 0.1).finished(), Eigen::VectorXd::Constant(1, 1.5));
  OctreeMapper octree(r);
  octree.set_log_odds((Eigen::MatrixXd(1, 3) << 0.1, 0.1, 0.1).finished(), Eigen::VectorXd::Constant(1, 1.5));
  const Snapshot ram_before = snapshot(ram), octree_before = snapshot(octree);
  for (const Case& c : cases) {
    SCOPED_TRACE(c.file);
    for (int target = 0; target < 2; ++target) {
      const auto call = [&] {
        if (target == 0)
          import_octomap(c.file, ram);
        else
          octree.load_from_file(c.file);
      };
      const std::string msg = message_of(call);
      EXPECT_NE(msg.find("'" + c.file + "'"), std::string::npos) << msg;
      EXPECT_NE(msg.find(c.what), std::string::npos) << msg;
      if (c.invalid_argument)
        EXPECT_THROW(call(), std::invalid_argument);
      else
        EXPECT_THROW(call(), std::runtime_error);
    }
  }
  EXPECT_EQ(snapshot(ram), ram_before);
  EXPECT_EQ(snapshot(octree), octree_before);
  EXPECT_EQ(octree.get_resolution(), r);

  // A resolution mismatch on import is an invalid argument naming both values.
  ProbabilityUpdater coarse(0.5);
  const std::string msg = message_of([&] { import_octomap(dir.sub("good.ot"), coarse); });
  EXPECT_NE(msg.find("0.25"), std::string::npos) << msg;
  EXPECT_NE(msg.find("0.5"), std::string::npos) << msg;
  EXPECT_THROW(import_octomap(dir.sub("good.ot"), coarse), std::invalid_argument);
  EXPECT_EQ(coarse.get_num_nodes(), 0u);
  // Writing: a bad extension, and a directory that does not exist.
  EXPECT_THROW(export_octomap(ram, dir.sub("map.ply")), std::invalid_argument);
  EXPECT_THROW(octree.save_to_file(dir.sub("map.BTX")), std::invalid_argument);
  const std::string nowhere = dir.sub("no/such/dir/map.bt");
  const std::string wmsg = message_of([&] { export_octomap(ram, nowhere); });
  EXPECT_NE(wmsg.find("'" + nowhere + "'"), std::string::npos) << wmsg;
  EXPECT_THROW(export_octomap(ram, nowhere), std::runtime_error);
}

TEST(OctoMapFiles, ThrowsLogicErrorWhenImportTargetCannotSetLogOdds) {
  // A backend that does not override set_log_odds() keeps the interface's default.
  class NoSet final : public IMapperBackend {
   public:
    void batch_update_iwlo(const Eigen::MatrixXd&, const Eigen::VectorXd&, const std::vector<bool>&) override {}
    void set_iwlo_params(double, double, double, double, double) override {}
    void set_log_odds_params(double, double) override {}
    void set_intensity_params(double, double) override {}
    void set_adaptive_params(bool, double, double) override {}
    void set_occupied_threshold(double) override {}
    Eigen::MatrixXd get_occupied_voxels(double) const override { return Eigen::MatrixXd(0, 4); }
    MemoryStats get_memory_usage() const override { return {}; }
    double get_resolution() const override { return 0.25; }
    size_t get_num_nodes() const override { return 0; }
    void clear() override {}
    std::string get_backend_type() const override { return "Test"; }
    void batch_update_iwlo(const Eigen::MatrixXd&, const Eigen::VectorXd&, const std::vector<bool>&,
                           const Eigen::VectorXd&) override {}
    void insert_scan(const Eigen::Vector3d&, const Eigen::MatrixXd&, const Eigen::VectorXd&, double) override {}
    std::optional<VoxelState> query(const Eigen::Vector3d&) const override { return std::nullopt; }
    void for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>&) const override {}
    size_t get_num_skipped_points() const override { return 0; }
    void set_params(const IwloParams&) override {}
    IwloParams get_params() const override { return {}; }
  };
  TempDir dir;
  OctreeMapper map(0.25);
  map.update_point(Eigen::Vector3d(0.1, 0.1, 0.1), true);
  map.save_to_file(dir.sub("one.ot"));
  NoSet target;
  const std::string msg = message_of([&] { import_octomap(dir.sub("one.ot"), target); });
  EXPECT_NE(msg.find("Test backend does not implement set_log_odds"), std::string::npos) << msg;
  EXPECT_THROW(import_octomap(dir.sub("one.ot"), target), std::logic_error);
}

// ---- Debian's octomap-tools --------------------------------------------------------------------

struct ToolRun {
  int exit_code;
  std::string output;  // stdout and stderr
};

ToolRun run_tool(const std::string& command) {
  ToolRun r{-1, {}};
  FILE* pipe = ::popen((command + " 2>&1").c_str(), "r");
  if (pipe == nullptr) return r;
  std::array<char, 4096> buf{};
  std::size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), pipe)) > 0) r.output.append(buf.data(), n);
  const int status = ::pclose(pipe);
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

std::string quoted(const std::string& s) { return "'" + s + "'"; }

// The tools come from octomap-tools (scripts/setup.sh installs it); CMake passes their paths.
// Missing tools fail the test: a silent skip would let CI pass without the interop check.
std::string tool_path(const char* configured, const char* name) {
  const std::string p = configured;
  if (p.empty() || p.find("NOTFOUND") != std::string::npos || !fs::exists(p)) {
    ADD_FAILURE() << name << " was not found when CMake configured the tests (got '" << p
                  << "'): install Debian's octomap-tools (scripts/setup.sh) and reconfigure";
    return {};
  }
  return p;
}

// compare_octrees prints "KLD: <sum>" and exits 0 when the trees have the same leaves; it reports
// a missing voxel with "ERROR" and a size mismatch with a non-zero exit. No difference means: exit
// 0, no ERROR/WARNING, and a KLD of exactly 0.
struct Comparison {
  bool same;
  double kld;
  std::string output;
};
Comparison compare(const std::string& tool, const std::string& a, const std::string& b) {
  const ToolRun run = run_tool(quoted(tool) + " " + quoted(a) + " " + quoted(b));
  Comparison c{false, kNaN, run.output};
  const auto pos = run.output.find("KLD: ");
  if (pos != std::string::npos) c.kld = std::strtod(run.output.c_str() + pos + 5, nullptr);
  c.same = run.exit_code == 0 && pos != std::string::npos && c.kld == 0.0 &&
           run.output.find("ERROR") == std::string::npos && run.output.find("WARNING") == std::string::npos;
  return c;
}

TEST(OctoMapTools, ReportNoDifferenceWhenExportedBtConvertedAndComparedWithReference) {
  const std::string convert = tool_path(IWLOMAP_CONVERT_OCTREE, "convert_octree");
  const std::string compare_tool = tool_path(IWLOMAP_COMPARE_OCTREES, "compare_octrees");
  ASSERT_FALSE(convert.empty() || compare_tool.empty());
  TempDir dir;
  const double r = 0.2;
  ProbabilityUpdater ram(r);
  fill_with_scans(ram);
  const std::string exported = dir.sub("exported.bt");
  export_octomap(ram, exported);

  // convert_octree reads the .bt as OctoMap does and writes it as .ot.
  const std::string converted = dir.sub("converted.ot");
  const ToolRun conv = run_tool(quoted(convert) + " " + quoted(exported) + " " + quoted(converted));
  ASSERT_EQ(conv.exit_code, 0) << conv.output;
  ASSERT_TRUE(fs::exists(converted)) << conv.output;

  // The reference: a plain OcTree built from the same voxels with OctoMap's own coordinate
  // conversion, each voxel set to OctoMap's maximum-likelihood value of its occupancy.
  const double threshold = ram.get_params().occupied_threshold;
  octomap::OcTree reference(r);
  std::size_t occupied = 0;
  ram.for_each_voxel([&](const VoxelKey& k, const VoxelState& v) {
    const Eigen::Vector3d c = key_to_center(k, r);
    const bool occ = v.probability > threshold;
    occupied += occ ? 1 : 0;
    reference.setNodeValue(c.x(), c.y(), c.z(),
                           occ ? reference.getClampingThresMaxLog() : reference.getClampingThresMinLog());
  });
  reference.updateInnerOccupancy();
  const std::string reference_ot = dir.sub("reference.ot");  // compare_octrees needs .ot
  ASSERT_TRUE(reference.write(reference_ot));
  EXPECT_GT(occupied, 100u);

  for (const auto& [a, b] : {std::make_pair(converted, reference_ot), std::make_pair(reference_ot, converted)}) {
    const Comparison c = compare(compare_tool, a, b);
    EXPECT_TRUE(c.same) << c.output;
    EXPECT_NE(c.output.find("Expanded num. leafs: " + std::to_string(ram.get_num_nodes())), std::string::npos)
        << c.output;
  }

  // The check can fail: one voxel flipped in the reference gives a KLD above 0.
  const Eigen::Vector3d first = key_to_center(snapshot(ram).begin()->first, r);
  const octomap::OcTreeKey flip = reference.coordToKey(first.x(), first.y(), first.z());
  const octomap::OcTreeNode* n = reference.search(flip);
  ASSERT_NE(n, nullptr);
  reference.setNodeValue(flip, -n->getLogOdds());
  reference.updateInnerOccupancy();
  const std::string flipped = dir.sub("flipped.ot");
  ASSERT_TRUE(reference.write(flipped));
  const Comparison c = compare(compare_tool, converted, flipped);
  EXPECT_FALSE(c.same) << c.output;
  EXPECT_GT(c.kld, 0.0) << c.output;
}

}  // namespace
}  // namespace iwlomap
