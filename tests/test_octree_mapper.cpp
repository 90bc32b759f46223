// SPDX-License-Identifier: BSD-3-Clause
// The OctoMap backend against OctoMap itself: the octree mirrors the exact map, keys map to
// OctoMap's and stop at the end of its key range, and OctoMap's own model matches a plain
// octomap::OcTree.
// (The IWLO equivalence with the RAM backend is in test_backend_contract, the files in
// test_octomap_files.)

#include "backend_test_support.h"
#include "iwlomap/octomap/octree_mapper.h"
#include "iwlomap/octree_mapper.h"  // the deprecated path still compiles
#include "iwlomap/probability_updater.h"
#include "octomap_test_support.h"

#include <octomap/OcTree.h>

#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap {
namespace {

using octomap_test::fill_with_scans;
using octomap_test::message_of;
using octomap_test::read_ot;
using octomap_test::tree_voxels;
using test_support::Snapshot;
using test_support::TempDir;
using test_support::snapshot;

namespace fs = std::filesystem;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

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
  EXPECT_EQ(map.get_num_known_voxels(), exact.size());
}

// The OctoMap backend keeps the RAM backend's exact state in the same layout, so the two list
// their occupied voxels in the same order, not only as the same set.
// get_num_nodes() counts as octomap's OcTree::size() does (a leaf at depth 16 and its 16
// ancestors); the known voxels have their own call, the same for every backend.
TEST(OctreeMapper, CountsOctreeNodesAsOctomapAndKnownVoxelsApart) {
  OctreeMapper map(0.1);
  const IMapperBackend& any = map;
  EXPECT_EQ(any.get_num_nodes(), 0u);
  Eigen::MatrixXd p(1, 3);
  p << 0.05, 0.05, 0.05;
  map.batch_update_iwlo(p, Eigen::VectorXd::Constant(1, 200.0), {true});
  EXPECT_EQ(any.get_num_nodes(), 17u);
  EXPECT_EQ(any.get_num_known_voxels(), 1u);
  p << 0.15, 0.05, 0.05;  // a sibling: one more leaf
  map.batch_update_iwlo(p, Eigen::VectorXd::Constant(1, 200.0), {true});
  EXPECT_EQ(any.get_num_nodes(), 18u);
  EXPECT_EQ(any.get_num_known_voxels(), 2u);

  // On a scan, the count is the octree's own, as an OcTree holding the same leaves counts it.
  ProbabilityUpdater ram(0.1);
  fill_with_scans(map, 1);
  fill_with_scans(ram, 1);
  octomap::OcTree tree(0.1);
  map.for_each_voxel([&tree](const VoxelKey& k, const VoxelState& v) {
    tree.setNodeValue(octomap::OcTreeKey(static_cast<octomap::key_type>(k.x + 32768),
                                         static_cast<octomap::key_type>(k.y + 32768),
                                         static_cast<octomap::key_type>(k.z + 32768)),
                      static_cast<float>(v.log_odds), /*lazy_eval=*/true);  // no pruning, as the backend
  });
  EXPECT_EQ(map.get_num_nodes(), tree.size());
  EXPECT_GT(map.get_num_nodes(), map.get_num_known_voxels());
  EXPECT_EQ(map.get_num_known_voxels(), static_cast<std::size_t>(tree.getNumLeafNodes()));
  EXPECT_EQ(map.get_num_known_voxels(), ram.get_num_known_voxels() + 2 - (ram.query({0.05, 0.05, 0.05}) ? 1 : 0) -
                                            (ram.query({0.15, 0.05, 0.05}) ? 1 : 0));
}

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
  // The exact state holds the same values, each to the nearest step of its voxel format (the
  // octree keeps OctoMap's own floats).
  const iwlo::VoxelFormat format = iwlo::voxel_format(map.get_params());
  for (const auto& [k, v] : want) {
    const auto s = map.query(key_to_center(k, r));
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->log_odds, static_cast<double>(format.quantize(v)));
  }
  EXPECT_EQ(map.get_num_known_voxels(), want.size());
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
  EXPECT_EQ(map.get_num_known_voxels(), 65u);
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
  EXPECT_EQ(map.get_num_known_voxels(), 0u);
}

TEST(OctreeMapper, KeepsMapWhenMovedAndThrowsLogicErrorWhenMovedFrom) {
  OctreeMapper a(0.1);
  a.update_point(Eigen::Vector3d(0.05, 0.05, 0.05), true);
  OctreeMapper b(std::move(a));
  EXPECT_EQ(b.get_num_known_voxels(), 1u);
  EXPECT_THROW((void)a.get_num_known_voxels(), std::logic_error);  // NOLINT(bugprone-use-after-move)
  OctreeMapper c(0.2);
  c = std::move(b);
  EXPECT_EQ(c.get_num_known_voxels(), 1u);
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

}  // namespace
}  // namespace iwlomap
