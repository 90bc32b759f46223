// SPDX-License-Identifier: BSD-3-Clause
// The Disk backend (OutofcoreTileMapper) against the RAM backend on the same seeded input, with a
// cache that fits and with constant eviction, across flush, destruction and reopening, and when
// another process wrote the map; its crash safety under SIGKILL; and its storage error contract:
// damaged files, newer formats, failed writes, locking and clear().

#include "backend_test_support.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"

#include "tile_test_inputs.h"

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

#ifndef IWLOMAP_TILE_WRITER_HELPER
#error "IWLOMAP_TILE_WRITER_HELPER must name the tile_writer_helper executable"
#endif

namespace iwlomap {
namespace {

using test_support::Batch;
using test_support::Snapshot;
using test_support::TempDir;
using test_support::snapshot;
using test_support::sorted_rows;

namespace fs = std::filesystem;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// ---- fixtures and helpers ----

// Per-voxel log-odds and counts, occupied voxels and point queries: all exactly equal.
void expect_same_map(IMapperBackend& got, IMapperBackend& want) {
  const Snapshot g = snapshot(got), w = snapshot(want);
  ASSERT_FALSE(w.empty());
  EXPECT_EQ(g.size(), w.size());
  std::size_t mismatches = 0;
  for (const auto& [k, v] : w) {
    const auto it = g.find(k);
    if ((it == g.end() || it->second != v) && ++mismatches <= 5)
      ADD_FAILURE() << "voxel (" << k.x << ", " << k.y << ", " << k.z << "): RAM L = " << v.first << " n = " << v.second
                    << (it == g.end() ? ", Disk does not know it"
                                      : ", Disk L = " + std::to_string(it->second.first) + " n = " +
                                            std::to_string(it->second.second));
  }
  EXPECT_EQ(mismatches, 0u);
  EXPECT_EQ(got.get_num_nodes(), want.get_num_nodes());
  for (double p : {0.0, 0.5, 0.7, 0.95})
    EXPECT_EQ(sorted_rows(got.get_occupied_voxels(p)), sorted_rows(want.get_occupied_voxels(p))) << "min_probability " << p;
  const double r = want.get_resolution();
  int n = 0;
  for (const auto& [k, v] : w) {
    if (++n % 7 != 0) continue;  // a sample, spread over the map
    const auto s = got.query(key_to_center(k, r));
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->log_odds, v.first);
    EXPECT_EQ(s->count, v.second);
  }
}

Batch random_batch(std::mt19937& rng, int n, double half_extent, const Eigen::Vector3d& centre = Eigen::Vector3d::Zero()) {
  return test_support::random_batch(rng, n, half_extent, centre, test_support::BadRows::kNaNPoints);
}

std::vector<std::uint8_t> read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}
void write_bytes(const std::string& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

// Every file of a directory with its bytes: "nothing on disk is lost" means this stays equal.
std::map<std::string, std::vector<std::uint8_t>> directory_image(const std::string& dir) {
  std::map<std::string, std::vector<std::uint8_t>> image;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file()) image[e.path().filename().string()] = read_bytes(e.path().string());
  return image;
}

std::vector<std::string> tile_files(const std::string& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("tile_", 0) == 0 && name.size() > 4 && name.compare(name.size() - 4, 4, ".iwt") == 0)
      names.push_back(name);
  }
  std::sort(names.begin(), names.end());
  return names;
}

// Files that hold no committed state: temporary tiles and the staging file of evicted tiles.
std::size_t count_scratch_files(const std::string& dir) {
  std::size_t n = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    n += (name.size() > 4 && name.compare(name.size() - 4, 4, ".tmp") == 0) || name.rfind("iwlomap_map.staging", 0) == 0
             ? 1
             : 0;
  }
  return n;
}

// Runs \p call and returns the StorageError it throws (fails the test when it throws nothing or
// something else).
template <class Call>
StorageError expect_storage_error(Call&& call, StorageError::Kind kind) {
  try {
    call();
  } catch (const StorageError& e) {
    EXPECT_EQ(static_cast<int>(e.kind()), static_cast<int>(kind)) << e.what();
    EXPECT_NE(std::string(e.what()).find(e.path()), std::string::npos) << "the message must name the file: " << e.what();
    return e;
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected StorageError, got " << e.what();
    return StorageError(StorageError::Kind::kIo, "", "");
  }
  ADD_FAILURE() << "expected StorageError, nothing was thrown";
  return StorageError(StorageError::Kind::kIo, "", "");
}

// A map of a few tiles, flushed and closed: the starting point of the storage error tests.
void write_small_map(const std::string& dir, int steps) {
  OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 16);
  for (int k = 1; k <= steps; ++k) tile_test::apply_step(map, k);
  map.flush();
}

ProbabilityUpdater ram_after_steps(int steps) {
  ProbabilityUpdater ram(tile_test::kResolution);
  for (int k = 1; k <= steps; ++k) tile_test::apply_step(ram, k);
  return ram;
}

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
  EXPECT_EQ(reopened.get_num_nodes(), 1u);
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
      (void)disk.get_num_nodes();
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

// ---- another process, crashes ----

TEST(OutofcoreTileMapper, OpensMapWrittenByAnotherProcessWithSameContents) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  const int steps = 12;
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    ::execl(IWLOMAP_TILE_WRITER_HELPER, IWLOMAP_TILE_WRITER_HELPER, "write", dir.c_str(), std::to_string(steps).c_str(),
            "3", static_cast<char*>(nullptr));
    ::_exit(127);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status)) << "helper did not exit normally";
  ASSERT_EQ(WEXITSTATUS(status), 0) << "helper failed (127: could not run " << IWLOMAP_TILE_WRITER_HELPER << ")";

  ProbabilityUpdater ram = ram_after_steps(steps);
  OutofcoreTileMapper disk(dir, tile_test::kResolution, tile_test::kTileSize, 4);
  EXPECT_GT(disk.get_num_tiles(), 4u);
  expect_same_map(disk, ram);
  EXPECT_EQ(count_scratch_files(dir), 0u);
}

using TileSnapshots = std::map<VoxelKey, Snapshot>;  // tile coordinate -> its voxels

TileSnapshots by_tile(const Snapshot& s) {
  const auto edge = static_cast<std::int32_t>(std::lround(tile_test::kTileSize / tile_test::kResolution));
  const auto floor_div = [edge](std::int32_t a) { return a >= 0 ? a / edge : -((-a + edge - 1) / edge); };
  TileSnapshots t;
  for (const auto& [k, v] : s) t[VoxelKey{floor_div(k.x), floor_div(k.y), floor_div(k.z)}].emplace(k, v);
  return t;
}

// The child integrates step k (two calls: a scan, then a batch) and flushes, for k = 1, 2, ...,
// and reports each completed flush; it is killed at a random moment. If c is the last step
// reported, the child was between the report of c and that of c + 1: integrating step c + 1,
// flushing it, or about to report it. So after reopening, each tile must hold exactly its state
// after step c or after step c + 1, both flushed states (tiles are committed one by one, so they
// may mix), never a torn or partial one, and never the state between the two calls of a step.
// Odd rounds give the child 3 resident tiles, so evictions write staged tiles between flushes:
// they must never show through.
TEST(OutofcoreTileMapper, ReopensWithCompleteTilesWhenWriterKilledAtRandomMoments) {
  const TempDir tmp;
  const int kRounds = 22;
  std::mt19937 rng(20261121u);
  std::uniform_int_distribution<int> delay_ms(2, 300);
  int mixed_rounds = 0, mid_step_rounds = 0, max_steps = 0;
  for (int round = 0; round < kRounds; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    const bool evicting = round % 2 == 1;
    const std::string dir = tmp.sub("crash" + std::to_string(round));
    int fds[2];
    ASSERT_EQ(::pipe(fds), 0);
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      ::dup2(fds[1], STDOUT_FILENO);
      ::close(fds[0]);
      ::close(fds[1]);
      ::execl(IWLOMAP_TILE_WRITER_HELPER, IWLOMAP_TILE_WRITER_HELPER, "loop", dir.c_str(), "100000",
              evicting ? "3" : "1000", static_cast<char*>(nullptr));
      ::_exit(127);
    }
    ::close(fds[1]);
    std::this_thread::sleep_for(std::chrono::milliseconds(delay_ms(rng)));
    ::kill(pid, SIGKILL);
    int status = 0;
    ASSERT_EQ(::waitpid(pid, &status, 0), pid);
    ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL)
        << "the helper ended on its own (exit " << (WIFEXITED(status) ? WEXITSTATUS(status) : -1) << ")";
    std::int32_t last = 0, value = 0;
    while (::read(fds[0], &value, sizeof value) == static_cast<ssize_t>(sizeof value)) last = value;
    ::close(fds[0]);
    max_steps = std::max(max_steps, static_cast<int>(last));

    std::unique_ptr<OutofcoreTileMapper> disk;
    ASSERT_NO_THROW(disk = std::make_unique<OutofcoreTileMapper>(dir, tile_test::kResolution, tile_test::kTileSize, 4));
    EXPECT_EQ(count_scratch_files(dir), 0u) << "leftover temporary files are removed when the map is opened";
    const TileSnapshots got = by_tile(snapshot(*disk));
    ProbabilityUpdater ram(tile_test::kResolution);
    for (int k = 1; k <= last; ++k) tile_test::apply_step(ram, k);
    const TileSnapshots before = by_tile(snapshot(ram));
    tile_test::apply_step(ram, last + 1);
    const TileSnapshots after = by_tile(snapshot(ram));

    std::map<VoxelKey, int> tiles;  // every tile any of the states knows
    for (const auto* m : {&got, &before, &after})
      for (const auto& [t, s] : *m) tiles[t] = 0;
    int at_before = 0, at_after = 0, bad = 0;
    for (const auto& entry : tiles) {
      const VoxelKey& t = entry.first;
      const Snapshot none;
      const auto state = [&](const TileSnapshots& m) -> const Snapshot& {
        const auto it = m.find(t);
        return it == m.end() ? none : it->second;
      };
      const Snapshot& g = state(got);
      const bool is_before = g == state(before), is_after = g == state(after);
      if (!is_before && !is_after && ++bad <= 3)
        ADD_FAILURE() << "tile (" << t.x << ", " << t.y << ", " << t.z << ") holds " << g.size()
                      << " voxels, neither its state after step " << last << " (" << state(before).size()
                      << " voxels) nor after step " << last + 1 << " (" << state(after).size() << ")";
      at_before += is_before && !is_after ? 1 : 0;
      at_after += is_after && !is_before ? 1 : 0;
    }
    EXPECT_EQ(bad, 0);
    mixed_rounds += at_before > 0 && at_after > 0 ? 1 : 0;
    mid_step_rounds += at_after > 0 ? 1 : 0;
  }
  std::cout << "[          ] " << kRounds << " kills; up to " << max_steps << " steps flushed; " << mid_step_rounds
            << " rounds with tiles of the step in progress, " << mixed_rounds << " of them mixing two states"
            << std::endl;
  EXPECT_GT(max_steps, 0) << "the writer never completed a flush: the kills came too early to test anything";
}

// ---- damaged and foreign files ----

class DamagedTile : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = tmp_.sub("map");
    write_small_map(dir_, 4);
    tiles_ = tile_files(dir_);
    ASSERT_GE(tiles_.size(), 3u);
    victim_ = (fs::path(dir_) / tiles_[tiles_.size() / 2]).string();
  }
  // Applies \p damage to the victim tile and returns the image of the directory after it.
  std::map<std::string, std::vector<std::uint8_t>> damage(const std::function<void(std::vector<std::uint8_t>&)>& f) {
    std::vector<std::uint8_t> bytes = read_bytes(victim_);
    f(bytes);
    write_bytes(victim_, bytes);
    return directory_image(dir_);
  }
  void expect_open_fails(StorageError::Kind kind, const std::string& text) {
    const auto image = directory_image(dir_);
    const StorageError e = expect_storage_error(
        [&] { OutofcoreTileMapper map(dir_, tile_test::kResolution, tile_test::kTileSize, 4); }, kind);
    EXPECT_EQ(e.path(), victim_);
    EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    EXPECT_EQ(directory_image(dir_), image) << "a failed open must not change any file";
  }

  TempDir tmp_;
  std::size_t remaining_ = 0;
  std::string dir_;
  std::vector<std::string> tiles_;
  std::string victim_;
};

TEST_F(DamagedTile, ThrowsNamingFileAndNeverReplacesItWhenPayloadByteFlipped) {
  const auto image = damage([](std::vector<std::uint8_t>& b) { b[b.size() - 3] ^= 0x10; });
  const ProbabilityUpdater ram = ram_after_steps(4);
  {
    OutofcoreTileMapper map(dir_, tile_test::kResolution, tile_test::kTileSize, 4);  // headers are fine
    EXPECT_EQ(map.get_num_nodes(), ram.get_num_nodes());
    const StorageError e = expect_storage_error([&] { (void)snapshot(map); }, StorageError::Kind::kCorrupt);
    EXPECT_EQ(e.path(), victim_);
    EXPECT_NE(std::string(e.what()).find("checksum"), std::string::npos) << e.what();
    (void)expect_storage_error([&] { (void)map.get_occupied_voxels(); }, StorageError::Kind::kCorrupt);

    // A voxel of the damaged tile and one of a healthy tile.
    VoxelKey in_victim{}, healthy{};
    bool have_victim = false, have_healthy = false;
    std::size_t victim_voxels = 0;
    const std::string victim_name = fs::path(victim_).filename().string();
    ram.for_each_voxel([&](const VoxelKey& k, const VoxelState&) {
      constexpr std::int32_t edge = 32;
      const auto fd = [](std::int32_t a) { return a >= 0 ? a / edge : -((-a + edge - 1) / edge); };
      const std::string name =
          "tile_" + std::to_string(fd(k.x)) + "_" + std::to_string(fd(k.y)) + "_" + std::to_string(fd(k.z)) + ".iwt";
      victim_voxels += name == victim_name ? 1 : 0;
      if (name == victim_name && !have_victim) {
        in_victim = k;
        have_victim = true;
      } else if (name != victim_name && !have_healthy) {
        healthy = k;
        have_healthy = true;
      }
    });
    ASSERT_TRUE(have_victim && have_healthy);
    const Eigen::Vector3d pv = key_to_center(in_victim, tile_test::kResolution);
    const Eigen::Vector3d ph = key_to_center(healthy, tile_test::kResolution);
    (void)expect_storage_error([&] { (void)map.query(pv); }, StorageError::Kind::kCorrupt);
    const auto healthy_before = map.query(ph);
    ASSERT_TRUE(healthy_before.has_value());
    // An update touching both tiles fails before it changes anything.
    Eigen::MatrixXd points(2, 3);
    points.row(0) = ph.transpose();
    points.row(1) = pv.transpose();
    EXPECT_THROW(map.batch_update_iwlo(points, Eigen::Vector2d(200, 200), {true, true}), StorageError);
    EXPECT_EQ(map.query(ph)->count, healthy_before->count);
    EXPECT_EQ(map.query(ph)->log_odds, healthy_before->log_odds);
    EXPECT_EQ(map.get_num_nodes(), ram.get_num_nodes());
    // The healthy part still takes updates, and is written by flush.
    map.batch_update_iwlo(points.topRows(1), Eigen::VectorXd::Constant(1, 200.0), {true});
    map.flush();
    remaining_ = ram.get_num_nodes() - victim_voxels;
  }  // destruction flushes too
  EXPECT_EQ(read_bytes(victim_), image.at(fs::path(victim_).filename().string())) << "the damaged tile was replaced";
  // Moved away, the rest of the map opens.
  fs::rename(victim_, victim_ + ".bad");
  OutofcoreTileMapper map(dir_, tile_test::kResolution, tile_test::kTileSize, 4);
  EXPECT_EQ(map.get_num_nodes(), remaining_);
  EXPECT_EQ(snapshot(map).size(), remaining_);
}

TEST_F(DamagedTile, ThrowsAtOpenNamingFileWhenHeaderByteFlipped) {
  (void)damage([](std::vector<std::uint8_t>& b) { b[30] ^= 0x01; });  // inside the resolution field
  expect_open_fails(StorageError::Kind::kCorrupt, "header checksum");
}

TEST_F(DamagedTile, ThrowsAtOpenNamingFileWhenTruncated) {
  (void)damage([](std::vector<std::uint8_t>& b) { b.resize(b.size() - 7); });
  expect_open_fails(StorageError::Kind::kCorrupt, "truncated");
  (void)damage([](std::vector<std::uint8_t>& b) { b.resize(12); });
  expect_open_fails(StorageError::Kind::kCorrupt, "truncated");
  (void)damage([](std::vector<std::uint8_t>& b) { b.clear(); });
  expect_open_fails(StorageError::Kind::kCorrupt, "truncated");
}

TEST_F(DamagedTile, ThrowsAtOpenNamingFileWhenMagicWrong) {
  (void)damage([](std::vector<std::uint8_t>& b) { b[0] = 'X'; });
  expect_open_fails(StorageError::Kind::kCorrupt, "wrong magic");
}

TEST_F(DamagedTile, ThrowsNewerVersionAtOpenWhenTileFormatIsNewer) {
  (void)damage([](std::vector<std::uint8_t>& b) { b[8] = 3; });  // version 3, header checksum left stale
  expect_open_fails(StorageError::Kind::kNewerVersion, "format version 3");
}

TEST_F(DamagedTile, ThrowsNewerVersionAtOpenWhenMetadataFormatIsNewer) {
  const std::string meta = (fs::path(dir_) / "iwlomap_map.meta").string();
  std::vector<std::uint8_t> bytes = read_bytes(meta);
  std::string text(bytes.begin(), bytes.end());
  const auto at = text.find("format_version 1");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 16, "format_version 7");
  write_bytes(meta, {text.begin(), text.end()});
  const auto image = directory_image(dir_);
  const StorageError e = expect_storage_error(
      [&] { OutofcoreTileMapper map(dir_, tile_test::kResolution, tile_test::kTileSize, 4); },
      StorageError::Kind::kNewerVersion);
  EXPECT_EQ(e.path(), meta);
  EXPECT_EQ(directory_image(dir_), image);
}

// ---- failed writes ----

// Root ignores directory permissions, so "the directory cannot be written" is made real another
// way: the map directory is moved aside and a regular file takes its path. Every open() under the
// path then fails with ENOTDIR, for root too, while the tiles themselves sit untouched in the moved
// directory; moving it back is "the administrator fixed the disk".
TEST(OutofcoreTileMapper, KeepsPreviousTilesAndDirtyStateWhenDirectoryUnwritable) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map"), aside = tmp.sub("map.aside");
  auto map = std::make_unique<OutofcoreTileMapper>(dir, tile_test::kResolution, tile_test::kTileSize, 16);
  for (int k = 1; k <= 3; ++k) tile_test::apply_step(*map, k);
  map->flush();
  const auto flushed = directory_image(dir);
  tile_test::apply_step(*map, 4);  // dirty tiles in RAM

  fs::rename(dir, aside);
  write_bytes(dir, {'x'});
  const StorageError e = expect_storage_error([&] { map->flush(); }, StorageError::Kind::kIo);
  EXPECT_EQ(e.path().rfind(dir + "/tile_", 0), 0u) << e.path();
  EXPECT_NE(std::string(e.what()).find("Not a directory"), std::string::npos) << e.what();
  EXPECT_NE(std::string(e.what()).find("previous file is unchanged"), std::string::npos) << e.what();
  fs::remove(dir);
  fs::rename(aside, dir);
  EXPECT_EQ(directory_image(dir), flushed) << "the previous tiles must be intact";

  ProbabilityUpdater ram = ram_after_steps(4);
  expect_same_map(*map, ram);  // the failed flush lost nothing in RAM
  map->flush();                // and a later flush succeeds
  map.reset();
  OutofcoreTileMapper reopened(dir, tile_test::kResolution, tile_test::kTileSize, 4);
  expect_same_map(reopened, ram);
}

// A full disk, made real with RLIMIT_FSIZE (root is bound by it too): writes beyond the limit fail
// with EFBIG. SIGXFSZ is ignored while the limit is set, so the write returns the error instead.
class FileSizeLimit {
 public:
  explicit FileSizeLimit(rlim_t bytes) {
    ::getrlimit(RLIMIT_FSIZE, &saved_);
    old_handler_ = ::signal(SIGXFSZ, SIG_IGN);
    rlimit l = saved_;
    l.rlim_cur = bytes;
    ::setrlimit(RLIMIT_FSIZE, &l);
  }
  ~FileSizeLimit() {
    ::setrlimit(RLIMIT_FSIZE, &saved_);
    ::signal(SIGXFSZ, old_handler_);
  }
  FileSizeLimit(const FileSizeLimit&) = delete;
  FileSizeLimit& operator=(const FileSizeLimit&) = delete;

 private:
  rlimit saved_{};
  sighandler_t old_handler_;
};

TEST(OutofcoreTileMapper, KeepsPreviousTilesAndDirtyStateWhenDiskFull) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 16);
  for (int k = 1; k <= 3; ++k) tile_test::apply_step(map, k);
  map.flush();
  const auto flushed = directory_image(dir);
  tile_test::apply_step(map, 4);
  {
    const FileSizeLimit full(100);  // smaller than any tile
    const StorageError e = expect_storage_error([&] { map.flush(); }, StorageError::Kind::kIo);
    EXPECT_NE(std::string(e.what()).find("File too large"), std::string::npos) << e.what();
  }
  EXPECT_EQ(directory_image(dir), flushed) << "the previous tiles must be intact, and no temporary file left";
  ProbabilityUpdater ram = ram_after_steps(4);
  expect_same_map(map, ram);
  map.flush();
  EXPECT_EQ(count_scratch_files(dir), 0u);
}

// An evicted dirty tile is appended to the staging file, not fsync'ed; the tile file changes only
// at flush(), so a crash between flushes leaves the last flushed state.
TEST(OutofcoreTileMapper, StagesEvictedTilesAndCommitsThemOnlyAtFlush) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, 0.1, 0.8, 1);
  const Eigen::MatrixXd a = (Eigen::MatrixXd(1, 3) << 0.15, 0.15, 0.15).finished();  // tile (0, 0, 0)
  const Eigen::MatrixXd b = (Eigen::MatrixXd(1, 3) << 2.05, 0.15, 0.15).finished();  // tile (2, 0, 0)
  const Eigen::VectorXd intensity = Eigen::VectorXd::Constant(1, 200.0);
  map.batch_update_iwlo(a, intensity, {true});
  map.flush();
  const std::string tile_a = (fs::path(dir) / "tile_0_0_0.iwt").string();
  const std::string staging = (fs::path(dir) / "iwlomap_map.staging").string();
  const std::vector<std::uint8_t> flushed = read_bytes(tile_a);
  EXPECT_FALSE(fs::exists(staging));
  map.batch_update_iwlo(a, intensity, {true});  // count 2, in RAM
  map.batch_update_iwlo(b, intensity, {true});  // evicts tile (0, 0, 0): staged
  EXPECT_TRUE(fs::exists(staging));
  EXPECT_EQ(read_bytes(tile_a), flushed);
  EXPECT_FALSE(fs::exists(fs::path(dir) / "tile_2_0_0.iwt"));
  EXPECT_EQ(map.query(a.row(0).transpose())->count, 2u);  // read back from the staging file
  std::size_t files = 0;  // tile (0, 0, 0), the staging file (now also with (2, 0, 0)), metadata
  for (const auto& [name, bytes] : directory_image(dir)) files += bytes.size();
  EXPECT_EQ(map.get_disk_usage(), files);
  map.flush();
  EXPECT_EQ(count_scratch_files(dir), 0u);
  EXPECT_NE(read_bytes(tile_a), flushed);
  EXPECT_EQ(tile_files(dir).size(), 2u);
}

// The record layout is part of the file format (src/backends/disk/tile_file.h), whatever the in-memory
// layout of a block: a mask bit x + 8 y + 64 z inside the block, the voxels in that order.
TEST(OutofcoreTileMapper, WritesBlockRecordsInTheDocumentedVoxelOrder) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  {
    OutofcoreTileMapper map(dir, 1.0, 8.0, 4);  // one 8^3 block per tile
    // Voxels (1, 2, 3) twice and (7, 0, 5) once, given in the opposite order of the file.
    const Eigen::MatrixXd pts = (Eigen::MatrixXd(3, 3) << 7.5, 0.5, 5.5, 1.5, 2.5, 3.5, 1.5, 2.5, 3.5).finished();
    map.batch_update_iwlo(pts, Eigen::VectorXd::Constant(3, 200.0), {true, true, true});
    map.flush();
  }
  const std::vector<std::uint8_t> f = read_bytes((fs::path(dir) / "tile_0_0_0.iwt").string());
  const auto u32 = [&f](std::size_t at) {
    return static_cast<std::uint32_t>(f[at]) | static_cast<std::uint32_t>(f[at + 1]) << 8 |
           static_cast<std::uint32_t>(f[at + 2]) << 16 | static_cast<std::uint32_t>(f[at + 3]) << 24;
  };
  const auto u64 = [&u32](std::size_t at) { return static_cast<std::uint64_t>(u32(at)) | static_cast<std::uint64_t>(u32(at + 4)) << 32; };
  const std::size_t rec = 80;  // header bytes
  ASSERT_EQ(f.size(), rec + 12 + 4 + 64 + 2 * 6);
  EXPECT_EQ(u32(rec), 0u);       // block (0, 0, 0)
  EXPECT_EQ(u32(rec + 12), 2u);  // known voxels
  const std::size_t a = 1 + 8 * 2 + 64 * 3, b = 7 + 8 * 0 + 64 * 5;  // 209, 327
  for (std::size_t w = 0; w < 8; ++w) {
    std::uint64_t want = 0;
    if (a / 64 == w) want |= std::uint64_t{1} << (a % 64);
    if (b / 64 == w) want |= std::uint64_t{1} << (b % 64);
    EXPECT_EQ(u64(rec + 16 + 8 * w), want) << "mask word " << w;
  }
  const auto u16 = [&f](std::size_t at) { return static_cast<unsigned>(f[at]) | static_cast<unsigned>(f[at + 1]) << 8; };
  const std::size_t v = rec + 80;  // voxels: f32 log-odds, u16 count
  EXPECT_EQ(u16(v + 4), 2u);       // (1, 2, 3): seen twice
  EXPECT_EQ(u16(v + 6 + 4), 1u);   // (7, 0, 5): once
}

// Tiles evicted again and again leave dead images in the staging file; it is rewritten with the
// live ones when it is mostly dead, and the map stays equal to the RAM map throughout.
TEST(OutofcoreTileMapper, CompactsStagingFileWhenTilesEvictedRepeatedly) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, 0.1, 3.2, 1);  // 32-voxel tiles, one resident
  ProbabilityUpdater ram(0.1);
  std::mt19937 rng(12u);
  const std::string staging = (fs::path(dir) / "iwlomap_map.staging").string();
  std::uintmax_t largest = 0;
  for (int round = 0; round < 12; ++round) {
    for (const double x : {1.6, 4.8}) {  // tiles (0, 0, 0) and (1, 0, 0) take turns
      const Batch batch = random_batch(rng, 20000, 1.5, Eigen::Vector3d(x, 1.6, 1.6));
      map.batch_update_iwlo(batch.points, batch.intensities, batch.flags);
      ram.batch_update_iwlo(batch.points, batch.intensities, batch.flags);
    }
    if (fs::exists(staging)) largest = std::max(largest, fs::file_size(staging));
  }
  // Each image is about 150 kB and 23 were appended: about 3.4 MB without compaction.
  EXPECT_GT(largest, 400000u);
  EXPECT_LT(largest, 1600000u);
  expect_same_map(map, ram);
  map.flush();
  EXPECT_EQ(count_scratch_files(dir), 0u);
  expect_same_map(map, ram);
}

TEST(OutofcoreTileMapper, ChangesNothingWhenEvictionWriteFails) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, 0.1, 0.8, 1);  // one resident tile: every other tile evicts it
  ProbabilityUpdater ram(0.1);
  std::mt19937 rng(4u);
  const Batch a = random_batch(rng, 500, 0.3, Eigen::Vector3d(0.4, 0.4, 0.4));  // tile (0, 0, 0)
  const Batch b = random_batch(rng, 500, 0.3, Eigen::Vector3d(2.0, 0.4, 0.4));  // tile (2, 0, 0)
  map.batch_update_iwlo(a.points, a.intensities, a.flags);
  ram.batch_update_iwlo(a.points, a.intensities, a.flags);
  {
    const FileSizeLimit full(100);
    (void)expect_storage_error([&] { map.batch_update_iwlo(b.points, b.intensities, b.flags); }, StorageError::Kind::kIo);
  }
  expect_same_map(map, ram);  // b was not applied, a is still there (dirty, in RAM)
  EXPECT_EQ(map.get_num_resident_tiles(), 1u);
  map.batch_update_iwlo(b.points, b.intensities, b.flags);
  ram.batch_update_iwlo(b.points, b.intensities, b.flags);
  expect_same_map(map, ram);
}

TEST(OutofcoreTileMapper, DestructorSwallowsWriteErrorsAndKeepsLastFlushedState) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map"), aside = tmp.sub("map.aside");
  {
    OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 16);
    for (int k = 1; k <= 3; ++k) tile_test::apply_step(map, k);
    map.flush();
    tile_test::apply_step(map, 4);
    fs::rename(dir, aside);
    write_bytes(dir, {'x'});
  }  // the flush of the destructor fails: no exception escapes
  fs::remove(dir);
  fs::rename(aside, dir);
  OutofcoreTileMapper reopened(dir, tile_test::kResolution, tile_test::kTileSize, 4);
  ProbabilityUpdater ram = ram_after_steps(3);
  expect_same_map(reopened, ram);
}

TEST(OutofcoreTileMapper, ThrowsIoErrorWhenDirectoryReadOnlyForNonRoot) {
  if (::geteuid() == 0)
    GTEST_SKIP() << "running as root, which ignores directory permissions; the unwritable-directory and full-disk "
                    "tests above cover failed writes for root";
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 16);
  tile_test::apply_step(map, 1);
  map.flush();
  const auto flushed = directory_image(dir);
  tile_test::apply_step(map, 2);
  fs::permissions(dir, fs::perms::owner_read | fs::perms::owner_exec);
  (void)expect_storage_error([&] { map.flush(); }, StorageError::Kind::kIo);
  fs::permissions(dir, fs::perms::owner_all);
  EXPECT_EQ(directory_image(dir), flushed);
  map.flush();
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
  EXPECT_NE(message([&] { OutofcoreTileMapper m(dir, 0.0); }).find("resolution = 0"), std::string::npos);
  EXPECT_NE(message([&] { OutofcoreTileMapper m(dir, 0.05, 10.0, 0); }).find("cache_tiles"), std::string::npos);
  EXPECT_NE(message([&] { OutofcoreTileMapper m(dir, 0.05, kNaN); }).find("tile_size"), std::string::npos);
  EXPECT_NE(message([&] { OutofcoreTileMapper m(dir, 0.05, 0.0); }).find("tile_size = 0"), std::string::npos);
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
  EXPECT_EQ(map.get_num_nodes(), 0u);
  EXPECT_EQ(map.get_num_tiles(), 0u);
  EXPECT_EQ(map.get_num_skipped_points(), 0u);
  EXPECT_EQ(map.get_occupied_voxels(0.0).rows(), 0);
  EXPECT_EQ(map.get_disk_usage(), fs::file_size(fs::path(dir) / "iwlomap_map.meta"));
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
  EXPECT_EQ(map.get_num_nodes(), ram.get_num_nodes());  // from the headers, no tile read
  EXPECT_EQ(map.get_num_resident_tiles(), 0u);
  EXPECT_EQ(snapshot(map), snapshot(ram));
  EXPECT_EQ(sorted_rows(map.get_occupied_voxels()), sorted_rows(ram.get_occupied_voxels()));
  EXPECT_EQ(map.get_num_resident_tiles(), 0u);
  EXPECT_EQ(map.get_peak_resident_tiles(), 0u);
  const MemoryStats m = map.get_memory_usage();
  EXPECT_EQ(m.num_nodes, ram.get_num_nodes());
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
  EXPECT_THROW((void)a.get_num_nodes(), std::logic_error);  // NOLINT(bugprone-use-after-move)
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
