// SPDX-License-Identifier: BSD-3-Clause
// The Disk backend (OutofcoreTileMapper) against the RAM backend on the same seeded input, with a
// cache that fits and with constant eviction, across flush, destruction and reopening; opening,
// locking, clear(), disk usage, preloading and the memory bound. Crashes, damaged files, failed
// writes and commits are in test_disk_storage.cpp.

#include "disk_test_support.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"

#include "tile_test_inputs.h"

#include "integrate/batch_input.h"
#include "integrate/block_sorted_batch.h"

#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <iterator>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

namespace iwlomap {
namespace {

using namespace disk_test;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// ---- equality with the RAM backend ----

class DiskMatchesRam : public ::testing::TestWithParam<std::size_t> {};
INSTANTIATE_TEST_SUITE_P(CacheTiles, DiskMatchesRam, ::testing::Values(1u, 2u, 16u),
                         [](const ::testing::TestParamInfo<std::size_t>& info) { return "cache" + std::to_string(info.param); });

TEST_P(DiskMatchesRam, MatchesRamWhenBatchesWithAndWithoutWeightsThenReopened) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  const double r = 0.1, tile = 1.6;  // 16-voxel tiles: the +-1.5 m box spans 8 of them
  ProbabilityUpdater ram(r);
  std::mt19937 rng(20240601u);
  {
    OutofcoreTileMapper disk(dir, r, tile, GetParam());
    for (int b = 0; b < 6; ++b) {
      const Batch batch = random_batch(rng, 8000, 1.5);
      if (b % 2 == 0) {
        disk.batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
        ram.batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
      } else {
        disk.batch_update_iwlo(batch.points, batch.intensities, batch.flags);
        ram.batch_update_iwlo(batch.points, batch.intensities, batch.flags);
      }
      EXPECT_LE(disk.get_num_resident_tiles(), GetParam());
    }
    EXPECT_EQ(disk.get_num_tiles(), 8u);
    EXPECT_EQ(disk.get_num_skipped_points(), ram.get_num_skipped_points());
    EXPECT_GT(ram.get_num_skipped_points(), 0u);
    expect_same_map(disk, ram);
    disk.flush();
    expect_same_map(disk, ram);
    EXPECT_LE(disk.get_peak_resident_tiles(), GetParam());
  }
  OutofcoreTileMapper reopened(dir, r, tile, GetParam());
  EXPECT_EQ(reopened.get_num_resident_tiles(), 0u);
  expect_same_map(reopened, ram);
  // The reopened map continues the same map.
  const Batch batch = random_batch(rng, 8000, 1.5);
  reopened.batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
  ram.batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
  expect_same_map(reopened, ram);
}

TEST_P(DiskMatchesRam, MatchesRamWhenScansWithMaxRangeThenReopened) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  const double r = 0.2, tile = 12.8;  // 64-voxel tiles: the courtyard spans about 20 of them
  ProbabilityUpdater ram(r);
  const Eigen::Vector2d positions[] = {{0.0, 0.0}, {3.0, -2.0}, {-6.0, 4.5}, {8.0, 6.0}};
  const double max_ranges[] = {-1.0, 12.0, 0.0, 7.5};
  {
    OutofcoreTileMapper disk(dir, r, tile, GetParam());
    for (int s = 0; s < 4; ++s) {
      SyntheticScanOptions o;
      o.rings = 12;
      o.columns = 180;
      o.sensor_xy = positions[s];
      o.seed = 100u + static_cast<std::uint32_t>(s);
      SyntheticScan scan = make_synthetic_scan(o);
      if (s == 2) scan.points(5, 1) = kNaN;
      disk.insert_scan(scan.origin, scan.points, scan.intensities, max_ranges[s]);
      ram.insert_scan(scan.origin, scan.points, scan.intensities, max_ranges[s]);
      EXPECT_LE(disk.get_num_resident_tiles(), GetParam());
    }
    EXPECT_GT(disk.get_num_tiles(), 8u);
    EXPECT_EQ(disk.get_num_skipped_points(), 1u);
    expect_same_map(disk, ram);
  }  // the destructor flushes
  OutofcoreTileMapper reopened(dir, r, tile, GetParam());
  expect_same_map(reopened, ram);
}

TEST(OutofcoreTileMapper, ReadMapInfoReportsTheStoredGeometryWithoutOpening) {
  const TempDir tmp;
  {
    OutofcoreTileMapper m(tmp.sub("map"), 0.1, 6.4, 2);
    Eigen::MatrixXd p(1, 3);
    p << 1.0, 2.0, 3.0;
    m.batch_update_iwlo(p, Eigen::VectorXd::Constant(1, 200.0), {true});
    m.flush();
    // Readable while the map is open (no lock taken).
    const DiskMapInfo info = OutofcoreTileMapper::read_map_info(tmp.sub("map"));
    EXPECT_DOUBLE_EQ(info.resolution, 0.1);
    EXPECT_DOUBLE_EQ(info.tile_size, 6.4);
    EXPECT_EQ(info.tile_voxels, 64u);
    EXPECT_GE(info.format_version, 1u);
  }
  const DiskMapInfo info = OutofcoreTileMapper::read_map_info(tmp.sub("map"));
  OutofcoreTileMapper reopened(tmp.sub("map"), info.resolution, info.tile_size, 2);
  EXPECT_EQ(reopened.get_num_known_voxels(), 1u);
  try {
    (void)OutofcoreTileMapper::read_map_info(tmp.sub("absent"));
    FAIL() << "no exception";
  } catch (const StorageError& e) {
    EXPECT_EQ(e.kind(), StorageError::Kind::kIo);
    EXPECT_NE(std::string(e.what()).find("holds no iwlomap map"), std::string::npos);
  }
}

TEST(OutofcoreTileMapper, ReadOnlyOpenReadsBesideAWriterChangesNoFileAndRefusesChanges) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper writer(dir, 0.2, 6.4, 4);  // holds the lock all along
  SyntheticScanOptions o;
  o.rings = 16;
  o.columns = 128;
  const SyntheticScan scan = make_synthetic_scan(o);
  writer.insert_scan(scan.origin, scan.points, scan.intensities, 9.0);
  writer.flush();
  const auto image = directory_image(dir);
  {
    OutofcoreTileMapper reader = OutofcoreTileMapper::open_read_only(dir, 2);  // 2 of the tiles
    EXPECT_TRUE(reader.is_read_only());
    EXPECT_FALSE(writer.is_read_only());
    EXPECT_DOUBLE_EQ(reader.get_resolution(), 0.2);
    expect_same_map(reader, writer);  // through evictions: 2 resident tiles of many
    const Eigen::MatrixXd p = scan.points.topRows(3);
    const Eigen::VectorXd in = scan.intensities.head(3);
    const auto refuses = [&](const std::function<void()>& call, const char* what) {
      try {
        call();
        ADD_FAILURE() << what << " did not throw";
      } catch (const std::logic_error& e) {
        EXPECT_NE(std::string(e.what()).find("read-only"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find(what), std::string::npos) << e.what();
      }
    };
    refuses([&] { reader.batch_update_iwlo(p, in, {true, true, true}); }, "batch_update_iwlo");
    refuses([&] { reader.batch_update_iwlo(p, in, {true, true, true}, Eigen::VectorXd::Ones(3)); }, "batch_update_iwlo");
    refuses([&] { reader.insert_scan(scan.origin, p, in); }, "insert_scan");
    refuses([&] { reader.set_params(IwloParams{}); }, "set_params");
    refuses([&] { reader.set_occupied_threshold(0.6); }, "modify_params");
    refuses([&] { reader.set_hit_accumulation(true); }, "set_hit_accumulation");
    refuses([&] { reader.set_log_odds(p, Eigen::VectorXd::Zero(3)); }, "set_log_odds");
    refuses([&] { reader.clear(); }, "clear");
    reader.flush();  // nothing to write
    expect_same_map(reader, writer);
  }
  EXPECT_EQ(directory_image(dir), image) << "a read-only mapper must not change any file";
  EXPECT_THROW((void)OutofcoreTileMapper::open_read_only(tmp.sub("absent")), StorageError);
  EXPECT_FALSE(fs::exists(tmp.sub("absent"))) << "a read-only open must not create the directory";
  EXPECT_THROW((void)OutofcoreTileMapper::open_read_only(dir, 0), std::invalid_argument);
}

TEST(OutofcoreTileMapper, MatchesRamWhenScansCastOnSeveralThreads) {
  const TempDir tmp;
  ProbabilityUpdater ram(0.2);
  OutofcoreTileMapper disk(tmp.sub("map"), 0.2, 6.4, 4);
  disk.set_num_threads(2);
  for (int s = 0; s < 3; ++s) {
    SyntheticScanOptions o;
    o.rings = 16;
    o.columns = 360;  // enough rays for the scratch to use both threads
    o.sensor_xy = Eigen::Vector2d(-4.0 + 4.0 * s, 1.0 * s);
    o.seed = 40u + static_cast<std::uint32_t>(s);
    const SyntheticScan scan = make_synthetic_scan(o);
    disk.insert_scan(scan.origin, scan.points, scan.intensities, 9.0);
    ram.insert_scan(scan.origin, scan.points, scan.intensities, 9.0);
  }
  expect_same_map(disk, ram);
}

// Scattered batches whose tiles fit in the cache are regrouped by block (block_sorted_batch.h),
// as the RAM backend regroups them; with or without weights the maps stay equal.
TEST(OutofcoreTileMapper, MatchesRamWhenScatteredBatchesAreRegroupedByBlock) {
  const TempDir tmp;
  ProbabilityUpdater ram(0.1);
  OutofcoreTileMapper disk(tmp.sub("map"), 0.1, 3.2, 1024);  // 32-voxel tiles, all resident
  std::mt19937 rng(404u);
  for (int b = 0; b < 3; ++b) {
    const Batch batch = random_batch(rng, 40000, 12.0);
    // The batch is one the regrouping takes (the same test as the backends').
    std::size_t bad = 0;
    for (Eigen::Index i = 0; i < batch.points.rows(); ++i) bad += batch.points.row(i).allFinite() ? 0 : 1;
    ASSERT_TRUE(detail::BlockSortedBatch::suits(batch.points, batch.intensities, bad, detail::FloorDivider(0.1)));
    if (b == 1) {
      disk.batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
      ram.batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
    } else {
      disk.batch_update_iwlo(batch.points, batch.intensities, batch.flags);
      ram.batch_update_iwlo(batch.points, batch.intensities, batch.flags);
    }
  }
  EXPECT_GT(disk.get_num_tiles(), 300u);
  expect_same_map(disk, ram);
}

TEST(OutofcoreTileMapper, MatchesRamWhenLogOddsSetAcrossTilesWithOneResidentTile) {
  const TempDir tmp;
  ProbabilityUpdater ram(0.5);
  OutofcoreTileMapper disk(tmp.sub("map"), 0.5, 4.0, 1);  // 8-voxel tiles
  // Rows alternate between tiles and repeat voxels: per voxel the last row must win.
  Eigen::MatrixXd points(8, 3);
  points << 0.1, 0.1, 0.1, 9.0, 0.0, 0.0, 0.2, 0.2, 0.2, -3.0, -3.0, -3.0, 9.1, 0.1, 0.1, 0.3, 0.3, 0.3, kNaN, 0, 0,
      -3.2, -3.1, -3.3;
  Eigen::VectorXd values(8);
  values << 1.0, 2.0, -1.5, 50.0, -2.5, 0.25, 1.0, -0.5;
  disk.set_log_odds(points, values);
  ram.set_log_odds(points, values);
  EXPECT_EQ(disk.get_num_skipped_points(), 1u);
  expect_same_map(disk, ram);
  EXPECT_EQ(disk.query(Eigen::Vector3d(0.2, 0.2, 0.2))->log_odds, 0.25);
  EXPECT_EQ(disk.query(Eigen::Vector3d(9.0, 0.0, 0.0))->log_odds, -2.5);
}

TEST(OutofcoreTileMapper, MatchesRamWhenParamsChangeBetweenCalls) {
  const TempDir tmp;
  ProbabilityUpdater ram(0.25);
  OutofcoreTileMapper disk(tmp.sub("map"), 0.25, 2.0, 2);
  std::mt19937 rng(99u);
  IwloParams p;
  p.adaptive_enabled = false;
  p.intensity_threshold = 0.0;
  p.L_min = -5.0;
  p.L_max = 7.0;
  disk.set_params(p);
  ram.set_params(p);
  Batch batch = random_batch(rng, 4000, 3.0);
  disk.batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  ram.batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  disk.set_iwlo_params(0.2, 0.3, 0.25, -6.0, 6.0);
  ram.set_iwlo_params(0.2, 0.3, 0.25, -6.0, 6.0);
  disk.set_log_odds_params(2.5, -1.5);
  ram.set_log_odds_params(2.5, -1.5);
  disk.set_intensity_params(20.0, 200.0);
  ram.set_intensity_params(20.0, 200.0);
  disk.set_adaptive_params(true, 0.4, 0.5);
  ram.set_adaptive_params(true, 0.4, 0.5);
  disk.set_occupied_threshold(0.8);
  EXPECT_EQ(disk.get_params().occupied_threshold, 0.8);
  batch = random_batch(rng, 4000, 3.0);
  disk.batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
  ram.batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
  expect_same_map(disk, ram);
  EXPECT_THROW(disk.set_iwlo_params(0.1, 0.1, 0.0, -10, 10), std::invalid_argument);
  EXPECT_EQ(disk.get_params().min_alpha, 0.25);
}

TEST(OutofcoreTileMapper, MatchesRamWhenThreadsUpdateDisjointRegionsConcurrently) {
  const TempDir tmp;
  OutofcoreTileMapper disk(tmp.sub("map"), 0.1, 1.6, 3);  // each thread's region is one tile
  ProbabilityUpdater ram(0.1);
  const int kThreads = 4, kBatches = 5;
  std::vector<std::vector<Batch>> batches(kThreads);
  for (int t = 0; t < kThreads; ++t) {
    std::mt19937 rng(300u + static_cast<std::uint32_t>(t));
    for (int b = 0; b < kBatches; ++b) batches[t].push_back(random_batch(rng, 2000, 0.7, Eigen::Vector3d(0.8 + 4.8 * t, 0.8, 0.8)));
  }
  std::atomic<bool> done{false};
  std::thread reader([&] {
    while (!done) {
      (void)disk.get_num_known_voxels();
      (void)disk.query(Eigen::Vector3d(0.85, 0.85, 0.85));
      (void)disk.get_memory_usage();
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  });
  std::vector<std::thread> writers;
  for (int t = 0; t < kThreads; ++t)
    writers.emplace_back([&, t] {
      for (const Batch& b : batches[t]) disk.batch_update_iwlo(b.points, b.intensities, b.flags, b.weights);
    });
  for (auto& w : writers) w.join();
  done = true;
  reader.join();
  // Regions are disjoint, so the order between threads does not matter to any voxel.
  for (int t = 0; t < kThreads; ++t)
    for (const Batch& b : batches[t]) ram.batch_update_iwlo(b.points, b.intensities, b.flags, b.weights);
  expect_same_map(disk, ram);
  EXPECT_LE(disk.get_peak_resident_tiles(), 3u);
}

// ---- opening ----

TEST(OutofcoreTileMapper, ThrowsInvalidArgumentWhenArgumentsInvalid) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  const auto message = [](auto&& make) -> std::string {
    try {
      make();
    } catch (const std::invalid_argument& e) {
      return e.what();
    }
    return "(nothing thrown)";
  };
  EXPECT_NE(message([&] { OutofcoreTileMapper m("", 0.05); }).find("directory"), std::string::npos);
  EXPECT_NE(message([&] { OutofcoreTileMapper m(dir, -0.05); }).find("resolution = -0.05"), std::string::npos);
  EXPECT_NE(message([&] { OutofcoreTileMapper m(dir, 0.05, 10.0, 0); }).find("cache_tiles"), std::string::npos);
  EXPECT_NE(message([&] { OutofcoreTileMapper m(dir, 0.05, kNaN); }).find("tile_size"), std::string::npos);
  EXPECT_NE(message([&] { OutofcoreTileMapper m(dir, 0.05, -1.0); }).find("tile_size = -1"), std::string::npos);
  EXPECT_FALSE(fs::exists(fs::path(dir) / "iwlomap_map.meta")) << "nothing is written for invalid arguments";
  // Defaults: 10 m / 0.05 m = 200 voxels = 25 blocks.
  const OutofcoreTileMapper defaults(dir);
  EXPECT_EQ(defaults.get_tile_voxels(), 200u);
  EXPECT_EQ(defaults.get_resolution(), 0.05);
  EXPECT_EQ(defaults.get_cache_tiles(), 16u);
  EXPECT_EQ(defaults.get_backend_type(), "Disk");
  EXPECT_TRUE(defaults.supports_persistence());
}

// OutofcoreTileMapper(dir), as the reference API opens a map: an existing map at its stored
// resolution and tile size (here not the defaults), with its voxels.
TEST(OutofcoreTileMapper, OpensAnExistingMapWithItsStoredParametersFromTheDirectoryAlone) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  Eigen::MatrixXd points(3, 3);
  points << 0.15, 0.25, 0.35, 2.0, -1.0, 0.5, -3.3, 4.4, 1.1;
  std::size_t known = 0;
  {
    OutofcoreTileMapper made(dir, 0.1, 3.2, 4);
    made.batch_update_iwlo(points, Eigen::VectorXd::Constant(3, 200.0), std::vector<bool>(3, true));
    known = made.get_num_known_voxels();
  }
  const OutofcoreTileMapper opened(dir);
  EXPECT_EQ(opened.get_resolution(), 0.1);
  EXPECT_EQ(opened.get_tile_voxels(), 32u);
  EXPECT_EQ(opened.get_num_known_voxels(), known);
  EXPECT_TRUE(opened.query(points.row(1).transpose()).has_value());
}

// Any positive tile size is rounded to whole 8^3 blocks (at least one, at most 1,024): every
// combination gives the RAM backend's map voxel for voxel, reports its effective size, and
// reopens to the same map with the size asked for first.
TEST(OutofcoreTileMapper, EqualsRamWhenAnyTileSizeAndResolution) {
  const TempDir tmp;
  // A small scene (rays up to 1.5 m), so that 0.32 m tiles at 2 cm stay a few hundred files.
  std::mt19937 rng(41u);
  std::uniform_real_distribution<double> pos(-1.0, 1.0);
  Eigen::MatrixXd points(300, 3);
  for (Eigen::Index i = 0; i < points.rows(); ++i) points.row(i) << pos(rng), pos(rng), 0.5 * pos(rng);
  Eigen::VectorXd intensities(points.rows());
  for (Eigen::Index i = 0; i < intensities.size(); ++i) intensities[i] = 40.0 + static_cast<double>(i % 200);
  const Eigen::Vector3d origin(0.05, -0.03, 0.02);
  int n = 0;
  for (const double resolution : {0.02, 0.05, 0.1, 0.15, 0.2, 0.5, 1.0}) {
    ProbabilityUpdater ram(resolution);
    ram.insert_scan(origin, points, intensities);
    ram.batch_update_iwlo(points, intensities, std::vector<bool>(300, true));
    const Snapshot want = snapshot(ram);
    for (const double tile_size : {0.3, 1.0, 7.7, 10.0, 64.0}) {
      SCOPED_TRACE("resolution " + std::to_string(resolution) + ", tile_size " + std::to_string(tile_size));
      const std::string dir = tmp.sub("map" + std::to_string(n++));
      const double blocks = std::clamp(std::round(tile_size / resolution / 8.0), 1.0, 1024.0);
      {
        OutofcoreTileMapper disk(dir, resolution, tile_size, 16);
        EXPECT_EQ(disk.get_tile_voxels(), static_cast<std::size_t>(blocks) * 8u);
        EXPECT_EQ(disk.get_tile_size(), static_cast<double>(disk.get_tile_voxels()) * resolution);
        disk.insert_scan(origin, points, intensities);
        disk.batch_update_iwlo(points, intensities, std::vector<bool>(300, true));
        EXPECT_EQ(snapshot(disk), want);
      }
      const DiskMapInfo info = OutofcoreTileMapper::read_map_info(dir);
      EXPECT_EQ(info.tile_voxels, static_cast<std::size_t>(blocks) * 8u);
      EXPECT_EQ(info.tile_size, static_cast<double>(info.tile_voxels) * resolution);
      const OutofcoreTileMapper reopened(dir, resolution, tile_size, 4);
      EXPECT_EQ(snapshot(reopened), want);
      EXPECT_EQ(reopened.get_tile_voxels(), info.tile_voxels);
    }
  }
}

// The parameters belong to the map: restored on reopen, and every change recorded at once, so a
// map continued in another process goes on with the parameters its last updates used.
TEST(OutofcoreTileMapper, RestoresParametersWhenReopenedAndRecordsChanges) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  IwloParams p;
  p.intensity_threshold = 0.0;
  p.sharpness = 8.0;
  p.decay_rate = 0.05;
  p.adaptive_enabled = false;
  p.occupied_threshold = 0.6;
  ProbabilityUpdater ram(tile_test::kResolution);
  ram.set_params(p);
  {
    OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 4);
    EXPECT_EQ(map.get_params().intensity_threshold, IwloParams{}.intensity_threshold);  // a new map: defaults
    map.set_params(p);
    tile_test::apply_step(map, 1);
    tile_test::apply_step(ram, 1);
  }
  {
    OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 4);
    const IwloParams q = map.get_params();
    EXPECT_EQ(q.intensity_threshold, 0.0);
    EXPECT_EQ(q.sharpness, 8.0);
    EXPECT_EQ(q.decay_rate, 0.05);
    EXPECT_FALSE(q.adaptive_enabled);
    EXPECT_EQ(q.occupied_threshold, 0.6);
    tile_test::apply_step(map, 2);  // continued with the stored parameters: still the RAM map
    tile_test::apply_step(ram, 2);
    EXPECT_EQ(snapshot(map), snapshot(ram));
    map.set_intensity_params(12.0, 200.0);  // a grouped setter is recorded too
  }
  const OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 4);
  EXPECT_EQ(map.get_params().intensity_threshold, 12.0);
  EXPECT_EQ(map.get_params().intensity_max, 200.0);
  EXPECT_EQ(map.get_params().sharpness, 8.0);
}

TEST(OutofcoreTileMapper, ThrowsInvalidArgumentWhenReopenedWithOtherResolutionOrTileSize) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  write_small_map(dir, 2);
  const auto image = directory_image(dir);
  try {
    OutofcoreTileMapper m(dir, 0.1, tile_test::kTileSize);
    ADD_FAILURE() << "nothing thrown";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("resolution = 0.2"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("resolution = 0.1"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(dir), std::string::npos) << e.what();
  }
  EXPECT_THROW(OutofcoreTileMapper(dir, tile_test::kResolution, 12.8), std::invalid_argument);
  EXPECT_EQ(directory_image(dir), image);
  EXPECT_NO_THROW(OutofcoreTileMapper(dir, tile_test::kResolution, tile_test::kTileSize));
}

TEST(OutofcoreTileMapper, ThrowsLockedWhenDirectoryOpenInAnotherMapper) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  {
    OutofcoreTileMapper first(dir, 0.1, 0.8);
    const StorageError e =
        expect_storage_error([&] { OutofcoreTileMapper second(dir, 0.1, 0.8); }, StorageError::Kind::kLocked);
    EXPECT_EQ(e.path(), dir);
  }
  EXPECT_NO_THROW(OutofcoreTileMapper(dir, 0.1, 0.8));
}

TEST(OutofcoreTileMapper, ThrowsWhenDirectoryIsAFileOrTilesHaveNoMetadata) {
  const TempDir tmp;
  write_bytes(tmp.sub("file"), {'x'});
  (void)expect_storage_error([&] { OutofcoreTileMapper m(tmp.sub("file"), 0.1, 0.8); }, StorageError::Kind::kIo);
  const std::string dir = tmp.sub("map");
  write_small_map(dir, 1);
  fs::remove(fs::path(dir) / "iwlomap_map.meta");
  (void)expect_storage_error([&] { OutofcoreTileMapper m(dir, tile_test::kResolution, tile_test::kTileSize); },
                             StorageError::Kind::kCorrupt);
}

// ---- clear, disk usage, preload, memory bound, factory, moves ----

TEST(OutofcoreTileMapper, ClearRemovesOnlyItsTilesAndKeepsMetadata) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  write_small_map(dir, 3);
  const std::vector<std::string> foreign = {"notes.txt", "tile_1_2.iwt", "tile_01_2_3.iwt", "tile_1_2_3.iwt.bak"};
  for (const std::string& f : foreign) write_bytes((fs::path(dir) / f).string(), {'k', 'e', 'e', 'p'});
  fs::create_directory(fs::path(dir) / "tile_9_9_9.iwt.d");
  OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 2);
  tile_test::apply_step(map, 4);  // dirty resident tiles are forgotten as well
  map.set_occupied_threshold(0.65);
  map.clear();
  EXPECT_EQ(tile_files(dir), (std::vector<std::string>{"tile_01_2_3.iwt", "tile_1_2.iwt"}));  // the foreign ones
  for (const std::string& f : foreign) EXPECT_EQ(read_bytes((fs::path(dir) / f).string()).size(), 4u) << f;
  EXPECT_TRUE(fs::is_directory(fs::path(dir) / "tile_9_9_9.iwt.d"));
  EXPECT_TRUE(fs::exists(fs::path(dir) / "iwlomap_map.meta"));
  EXPECT_EQ(map.get_num_known_voxels(), 0u);
  EXPECT_EQ(map.get_num_tiles(), 0u);
  EXPECT_EQ(map.get_num_skipped_points(), 0u);
  EXPECT_EQ(map.get_occupied_voxels(0.0).rows(), 0);
  EXPECT_EQ(map.get_disk_usage(),
            fs::file_size(fs::path(dir) / "iwlomap_map.meta") + fs::file_size(fs::path(dir) / "iwlomap_map.manifest"));
  EXPECT_EQ(map.get_params().occupied_threshold, 0.65);
  tile_test::apply_step(map, 1);
  map.flush();
  ProbabilityUpdater ram = ram_after_steps(1);
  expect_same_map(map, ram);
}

TEST(OutofcoreTileMapper, ReportsDiskUsageAsSizeOfItsFiles) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 2);
  const auto files_size = [&] {
    std::size_t n = fs::file_size(fs::path(dir) / "iwlomap_map.meta");
    if (fs::exists(fs::path(dir) / "iwlomap_map.manifest")) n += fs::file_size(fs::path(dir) / "iwlomap_map.manifest");
    for (const std::string& t : tile_files(dir)) n += fs::file_size(fs::path(dir) / t);
    return n;
  };
  EXPECT_EQ(map.get_disk_usage(), files_size());
  for (int k = 1; k <= 5; ++k) tile_test::apply_step(map, k);
  map.flush();
  EXPECT_GT(map.get_disk_usage(), 1000u);
  EXPECT_EQ(map.get_disk_usage(), files_size());
  EXPECT_EQ(tile_files(dir).size(), map.get_num_tiles());
}

TEST(OutofcoreTileMapper, PreloadsTilesOfBoxWithinCacheBound) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  {
    OutofcoreTileMapper map(dir, 0.1, 0.8, 16);
    std::mt19937 rng(6u);
    const Batch b = random_batch(rng, 3000, 1.1, Eigen::Vector3d(0.4, 0.4, 0.4));  // tiles -1..1 per axis
    map.batch_update_iwlo(b.points, b.intensities, b.flags);
  }
  OutofcoreTileMapper map(dir, 0.1, 0.8, 4);
  ASSERT_GT(map.get_num_tiles(), 8u);
  EXPECT_EQ(map.get_num_resident_tiles(), 0u);
  map.preload_region(Eigen::Vector3d(0.1, 0.1, 0.1), Eigen::Vector3d(0.2, 0.2, 0.2));
  EXPECT_EQ(map.get_num_resident_tiles(), 1u);
  map.preload_region(Eigen::Vector3d(-0.5, -0.5, 0.1), Eigen::Vector3d(0.5, 0.5, 0.2));  // 2 x 2 x 1 tiles
  EXPECT_EQ(map.get_num_resident_tiles(), 4u);
  map.preload_region(Eigen::Vector3d(-100, -100, -100), Eigen::Vector3d(100, 100, 100));
  EXPECT_EQ(map.get_num_resident_tiles(), 4u);
  map.preload_region(Eigen::Vector3d(50, 50, 50), Eigen::Vector3d(60, 60, 60));  // nothing there
  EXPECT_EQ(map.get_num_resident_tiles(), 4u);
  EXPECT_THROW(map.preload_region(Eigen::Vector3d(1, 0, 0), Eigen::Vector3d(0, 1, 1)), std::invalid_argument);
  EXPECT_THROW(map.preload_region(Eigen::Vector3d(kNaN, 0, 0), Eigen::Vector3d(0, 1, 1)), std::invalid_argument);
  EXPECT_LE(map.get_peak_resident_tiles(), 4u);
}

TEST(OutofcoreTileMapper, StreamsTilesOnDiskWithoutFillingCache) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  write_small_map(dir, 6);
  OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 2);
  ASSERT_GT(map.get_num_tiles(), 4u);
  ProbabilityUpdater ram = ram_after_steps(6);
  EXPECT_EQ(map.get_num_known_voxels(), ram.get_num_known_voxels());  // from the headers, no tile read
  EXPECT_EQ(map.get_num_resident_tiles(), 0u);
  EXPECT_EQ(snapshot(map), snapshot(ram));
  EXPECT_EQ(sorted_rows(map.get_occupied_voxels()), sorted_rows(ram.get_occupied_voxels()));
  EXPECT_EQ(map.get_num_resident_tiles(), 0u);
  EXPECT_EQ(map.get_peak_resident_tiles(), 0u);
  const MemoryStats m = map.get_memory_usage();
  EXPECT_EQ(m.num_nodes, ram.get_num_known_voxels());
  EXPECT_LT(m.memory_mb, ram.get_memory_usage().memory_mb);
}

TEST(OutofcoreTileMapper, CreatedByMakeBackendWithDirectoryOption) {
  const TempDir tmp;
  BackendOptions o;
  o.directory = tmp.sub("map");
  o.tile_size = 1.6;
  o.cache_tiles = 3;
  const auto map = make_backend("disk", 0.1, o);
  EXPECT_EQ(map->get_backend_type(), "Disk");
  EXPECT_TRUE(map->supports_persistence());
  const auto* disk = dynamic_cast<const OutofcoreTileMapper*>(map.get());
  ASSERT_NE(disk, nullptr);
  EXPECT_EQ(disk->get_tile_size(), 1.6);
  EXPECT_EQ(disk->get_cache_tiles(), 3u);
  const auto names = available_backends();
  EXPECT_NE(std::find(names.begin(), names.end(), "Disk"), names.end());
  try {
    (void)make_backend("Disk", 0.1);
    ADD_FAILURE() << "nothing thrown";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("directory"), std::string::npos) << e.what();
  }
}

TEST(OutofcoreTileMapper, KeepsMapWhenMovedAndThrowsLogicErrorWhenMovedFrom) {
  const TempDir tmp;
  OutofcoreTileMapper a(tmp.sub("a"), tile_test::kResolution, tile_test::kTileSize, 4);
  tile_test::apply_step(a, 1);
  OutofcoreTileMapper b(std::move(a));
  EXPECT_THROW((void)a.get_num_known_voxels(), std::logic_error);  // NOLINT(bugprone-use-after-move)
  EXPECT_THROW((void)a.query(Eigen::Vector3d::Zero()), std::logic_error);
  ProbabilityUpdater ram = ram_after_steps(1);
  expect_same_map(b, ram);
  OutofcoreTileMapper c(tmp.sub("c"), tile_test::kResolution, tile_test::kTileSize, 4);
  tile_test::apply_step(c, 1);
  c = std::move(b);  // c's own map is flushed and closed
  expect_same_map(c, ram);
  OutofcoreTileMapper reopened_c(tmp.sub("c"), tile_test::kResolution, tile_test::kTileSize, 4);
  expect_same_map(reopened_c, ram);
}

// prune() gives the per-call buffers back (a large batch leaves large ones), keeping every voxel.
TEST(OutofcoreTileMapper, GivesBufferMemoryBackWhenPruned) {
  const TempDir tmp;
  OutofcoreTileMapper map(tmp.sub("map"), 0.1, 6.4, 16);
  std::mt19937 rng(21u);
  std::uniform_real_distribution<double> c(0.0, 6.3);  // one tile
  const Eigen::Index n = 700000;
  Eigen::MatrixXd pts(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) pts.row(i) << c(rng), c(rng), c(rng);
  map.batch_update_iwlo(pts, Eigen::VectorXd::Constant(n, 200.0), std::vector<bool>(static_cast<std::size_t>(n), true));
  const Snapshot before = snapshot(map);
  const double mb_before = map.get_memory_usage().memory_mb;
  (void)map.prune();
  // The batch's observations (16 bytes a row) alone are 11.2 MB.
  EXPECT_LT(map.get_memory_usage().memory_mb, mb_before - 10.0);
  EXPECT_EQ(snapshot(map), before);
}

TEST(OutofcoreTileMapper, KeepsPeakResidentTilesWithinCacheWhenMapLarger) {
  const TempDir tmp;
  OutofcoreTileMapper map(tmp.sub("map"), tile_test::kResolution, tile_test::kTileSize, 2);
  ProbabilityUpdater ram(tile_test::kResolution);
  for (int k = 1; k <= 8; ++k) {
    tile_test::apply_step(map, k);
    tile_test::apply_step(ram, k);
  }
  EXPECT_GE(map.get_num_tiles(), 10u);
  EXPECT_LE(map.get_peak_resident_tiles(), 2u);
  expect_same_map(map, ram);
  EXPECT_LE(map.get_peak_resident_tiles(), 2u);
  EXPECT_EQ(map.prune(), 0u);  // updates only allocate blocks they write
  expect_same_map(map, ram);
}

}  // namespace
}  // namespace iwlomap
