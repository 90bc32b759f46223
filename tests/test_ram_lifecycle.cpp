// SPDX-License-Identifier: BSD-3-Clause
// The RAM backend's life: clear(), the memory report, memory reused from destroyed maps, prune(),
// moves, creation through make_backend() and the optional API it does not persist with.

#include "iwlomap/iwlo.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/voxel_key.h"

#include "ram_test_support.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <map>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap {
namespace {

using ram_test::kNaN;
using ram_test::rows;
using ram_test::Snapshot;
using ram_test::snapshot;
using ram_test::values;

// ---- lifecycle -------------------------------------------------------------------------------

TEST(ProbabilityUpdater, ForgetsVoxelsAndSkipsAndKeepsParamsWhenCleared) {
  ProbabilityUpdater map(0.1);
  IwloParams custom;
  custom.sharpness = 0.9;
  map.set_params(custom);
  map.batch_update_iwlo(rows({{0.05, 0.05, 0.05}, {kNaN, 0, 0}, {5.0, -5.0, 1.0}}), values({200, 1, 200}),
                        {true, true, true});
  ASSERT_EQ(map.get_num_known_voxels(), 2u);
  ASSERT_EQ(map.get_num_skipped_points(), 1u);
  map.clear();
  EXPECT_EQ(map.get_num_known_voxels(), 0u);
  EXPECT_EQ(map.get_num_skipped_points(), 0u);
  EXPECT_TRUE(snapshot(map).empty());
  EXPECT_FALSE(map.query(Eigen::Vector3d(0.05, 0.05, 0.05)).has_value());
  EXPECT_EQ(map.get_occupied_voxels(0.0).rows(), 0);
  EXPECT_EQ(map.get_memory_usage().num_nodes, 0u);
  EXPECT_EQ(map.get_params().sharpness, 0.9);
  // Usable again after clear().
  map.batch_update_iwlo(rows({{0.05, 0.05, 0.05}}), values({200}), {true});
  EXPECT_EQ(map.get_num_known_voxels(), 1u);
}

TEST(ProbabilityUpdater, ReportsMemoryWhenBlocksAllocated) {
  const double r = 0.1;
  ProbabilityUpdater map(r);
  const MemoryStats empty = map.get_memory_usage();
  EXPECT_EQ(empty.num_nodes, 0u);
  EXPECT_EQ(empty.num_leaf_nodes, 0u);
  EXPECT_GT(empty.memory_mb, 0.0);

  // 64 points in one 8^3 block: keys 0..3 along each axis.
  Eigen::MatrixXd a(64, 3);
  for (int i = 0; i < 64; ++i) a.row(i) << (i % 4 + 0.5) * r, (i / 4 % 4 + 0.5) * r, (i / 16 + 0.5) * r;
  map.batch_update_iwlo(a, Eigen::VectorXd::Constant(64, 200.0), std::vector<bool>(64, true));
  const MemoryStats one = map.get_memory_usage();
  EXPECT_EQ(one.num_nodes, 64u);
  EXPECT_EQ(one.num_leaf_nodes, 64u);
  // One block, its 16 cells of 2 x 2 x 1 voxels (keys 0..3) all full: efficiency = 64 / 64.
  EXPECT_DOUBLE_EQ(one.memory_efficiency, 1.0);
  EXPECT_GT(one.memory_mb, empty.memory_mb);

  // 64 more points, each in its own new block (keys multiples of 8 away).
  Eigen::MatrixXd b(64, 3);
  for (int i = 0; i < 64; ++i) b.row(i) << (8 * (i % 4) + 40.5) * r, (8 * (i / 4 % 4) + 0.5) * r, (8 * (i / 16) + 0.5) * r;
  map.batch_update_iwlo(b, Eigen::VectorXd::Constant(64, 200.0), std::vector<bool>(64, true));
  const MemoryStats many = map.get_memory_usage();
  EXPECT_EQ(many.num_nodes, 128u);
  EXPECT_EQ(many.num_leaf_nodes, map.get_num_known_voxels());
  // 16 full cells and 64 cells of one known voxel each: efficiency = 128 / (80 * 4).
  EXPECT_DOUBLE_EQ(many.memory_efficiency, 128.0 / (80.0 * 4.0));
  EXPECT_GT(many.memory_efficiency, 0.0);
  EXPECT_LE(many.memory_efficiency, 1.0);
  // At least the 65 block headers (32 bytes) and 80 cells of 4 voxels at 8 bytes are held; the
  // block index grew with the 64 new blocks.
  EXPECT_GE(many.memory_mb, (65.0 * 32 + 80.0 * 4 * 8) / (1024.0 * 1024.0));
  EXPECT_GT(many.memory_mb, one.memory_mb);
}

// Maps reuse the memory of destroyed maps while another map lives (see map_memory.h): nothing of
// an old map may show.
TEST(ProbabilityUpdater, StartsEmptyWhenMemoryOfDestroyedMapsIsReused) {
  const ProbabilityUpdater keeper(0.1);  // keeps the process's slab cache alive
  std::mt19937 rng(11u);
  std::uniform_real_distribution<double> pos(-20.0, 20.0);
  Eigen::MatrixXd big(200000, 3);
  for (Eigen::Index i = 0; i < big.rows(); ++i) big.row(i) << pos(rng), pos(rng), pos(rng);
  for (int round = 0; round < 3; ++round) {
    {
      ProbabilityUpdater old(0.1);
      old.batch_update_iwlo(big, Eigen::VectorXd::Constant(big.rows(), 250.0), std::vector<bool>(200000, true));
      ASSERT_GT(old.get_num_known_voxels(), 190000u);
    }
    ProbabilityUpdater fresh(0.1);
    EXPECT_EQ(fresh.get_num_known_voxels(), 0u);
    fresh.batch_update_iwlo(big.topRows(100), Eigen::VectorXd::Constant(100, 10.0), std::vector<bool>(100, false));
    const Snapshot s = snapshot(fresh);
    EXPECT_EQ(s.size(), fresh.get_num_known_voxels());
    std::map<VoxelKey, std::uint32_t> expected;
    for (Eigen::Index i = 0; i < 100; ++i) ++expected[world_to_key(big.row(i).transpose(), 0.1)];
    ASSERT_EQ(s.size(), expected.size());
    for (const auto& [k, v] : s) {
      EXPECT_EQ(v.second, expected.at(k));
      // Free observations only: L = L_free * alpha summed over this voxel's own observations.
      double l = 0.0;
      for (std::uint32_t n = 1; n <= v.second; ++n)
        l = static_cast<float>(iwlo::step(l, n, 10.0, false, 1.0, IwloParams{}));
      EXPECT_EQ(v.first, l);
    }
    EXPECT_EQ(fresh.get_occupied_voxels(0.5).rows(), 0);  // every known voxel is free
  }
}

TEST(ProbabilityUpdater, KeepsAllVoxelsWhenPruned) {
  ProbabilityUpdater map(0.05);
  std::mt19937 rng(5u);
  std::uniform_real_distribution<double> pos(-2.0, 2.0);
  Eigen::MatrixXd pts(3000, 3);
  for (int i = 0; i < 3000; ++i) pts.row(i) << pos(rng), pos(rng), pos(rng);
  map.insert_scan(Eigen::Vector3d(0.01, 0.02, 0.03), pts, Eigen::VectorXd::Constant(3000, 150.0));
  const Snapshot before = snapshot(map);
  const MemoryStats mem_before = map.get_memory_usage();
  ASSERT_GT(before.size(), 3000u);
  // Updates only allocate blocks they write, so no block is empty and nothing is freed.
  EXPECT_EQ(map.prune(), 0u);
  EXPECT_EQ(snapshot(map), before);
  EXPECT_EQ(map.get_num_known_voxels(), before.size());
  const MemoryStats mem_after = map.get_memory_usage();
  EXPECT_LT(mem_after.memory_mb, mem_before.memory_mb);  // the scan scratch was given back
  EXPECT_EQ(mem_after.num_nodes, mem_before.num_nodes);
  // The map still works after pruning.
  map.batch_update_iwlo(rows({{0.01, 0.02, 0.03}}), values({200}), {true});
  EXPECT_EQ(map.get_num_known_voxels(), before.size());
}

TEST(ProbabilityUpdater, KeepsMapWhenMoveConstructed) {
  ProbabilityUpdater a(0.1);
  a.batch_update_iwlo(rows({{0.05, 0.05, 0.05}, {-3.0, 2.0, 1.0}}), values({200, 10}), {true, false});
  const Snapshot s = snapshot(a);
  ProbabilityUpdater b(std::move(a));
  EXPECT_EQ(snapshot(b), s);
  EXPECT_EQ(b.get_resolution(), 0.1);
  EXPECT_EQ(b.get_num_known_voxels(), 2u);
  // The moved-from object refuses to work.
  EXPECT_THROW((void)a.get_num_known_voxels(), std::logic_error);  // NOLINT(bugprone-use-after-move)
  EXPECT_THROW((void)a.get_resolution(), std::logic_error);
  EXPECT_THROW((void)a.query(Eigen::Vector3d::Zero()), std::logic_error);
  EXPECT_THROW(a.batch_update_iwlo(rows({{0, 0, 0}}), values({1}), {true}), std::logic_error);
  EXPECT_THROW(a.insert_scan(Eigen::Vector3d::Zero(), rows({{1, 0, 0}}), values({1})), std::logic_error);
  EXPECT_THROW((void)a.get_occupied_voxels(), std::logic_error);
  EXPECT_THROW((void)a.get_memory_usage(), std::logic_error);
  EXPECT_THROW(a.for_each_voxel([](const VoxelKey&, const VoxelState&) {}), std::logic_error);
  EXPECT_THROW(a.set_occupied_threshold(0.6), std::logic_error);
  EXPECT_THROW((void)a.get_params(), std::logic_error);
  EXPECT_THROW(a.clear(), std::logic_error);
  EXPECT_THROW(a.prune(), std::logic_error);
  // Assignment revives a moved-from object.
  a = ProbabilityUpdater(0.2);
  EXPECT_EQ(a.get_num_known_voxels(), 0u);
  EXPECT_EQ(a.get_resolution(), 0.2);
}

TEST(ProbabilityUpdater, KeepsMapWhenMoveAssigned) {
  ProbabilityUpdater a(0.1);
  a.batch_update_iwlo(rows({{0.05, 0.05, 0.05}, {-3.0, 2.0, 1.0}}), values({200, 10}), {true, false});
  const Snapshot s = snapshot(a);
  ProbabilityUpdater b(0.5);
  b.batch_update_iwlo(rows({{7.0, 7.0, 7.0}}), values({200}), {true});
  b = std::move(a);
  EXPECT_EQ(snapshot(b), s);
  EXPECT_EQ(b.get_resolution(), 0.1);
  EXPECT_FALSE(b.query(Eigen::Vector3d(7.0, 7.0, 7.0)).has_value());
  EXPECT_THROW((void)a.get_num_known_voxels(), std::logic_error);  // NOLINT(bugprone-use-after-move)
  EXPECT_THROW(a.batch_update_iwlo(rows({{0, 0, 0}}), values({1}), {true}), std::logic_error);
}

// ---- factory and optional API ----------------------------------------------------------------

TEST(MakeBackend, CreatesRamBackendWhenNameMatchesIgnoringCase) {
  for (const std::string name : {"RAM", "ram", "Ram"}) {
    SCOPED_TRACE(name);
    const auto backend = make_backend(name, 0.2);
    ASSERT_NE(backend, nullptr);
    EXPECT_EQ(backend->get_backend_type(), "RAM");
    EXPECT_EQ(backend->get_resolution(), 0.2);
    EXPECT_NE(dynamic_cast<ProbabilityUpdater*>(backend.get()), nullptr);
  }
  EXPECT_EQ(make_backend("RAM")->get_resolution(), 0.05);
}

TEST(MakeBackend, ThrowsListingAvailableNamesWhenNameUnknown) {
  try {
    (void)make_backend("nope");
    ADD_FAILURE() << "unknown backend accepted";
  } catch (const std::invalid_argument& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("nope"), std::string::npos) << msg;
    for (const std::string& name : available_backends()) EXPECT_NE(msg.find(name), std::string::npos) << msg;
    EXPECT_NE(msg.find("RAM"), std::string::npos) << msg;
  }
  EXPECT_THROW((void)make_backend("RAM", 0.0), std::invalid_argument);
}

TEST(ProbabilityUpdater, ReportsRamWithoutPersistenceWhenQueried) {
  ProbabilityUpdater map;
  EXPECT_EQ(map.get_backend_type(), "RAM");
  EXPECT_FALSE(map.supports_persistence());
  EXPECT_EQ(map.get_disk_usage(), 0u);
  map.batch_update_iwlo(rows({{0.01, 0.01, 0.01}}), values({200}), {true});
  EXPECT_NO_THROW(map.flush());
  EXPECT_NO_THROW(map.preload_region(Eigen::Vector3d(-1, -1, -1), Eigen::Vector3d(1, 1, 1)));
  EXPECT_EQ(map.get_disk_usage(), 0u);
  EXPECT_EQ(map.get_num_known_voxels(), 1u);
}

}  // namespace
}  // namespace iwlomap
