// SPDX-License-Identifier: BSD-3-Clause
// Progress reports (iwlomap/progress.h) of insert_scan() on every backend, of the Disk backend's
// flush() and of export_octomap(): the stages in order, from 0 to their total without going back,
// on the calling thread, many reports within one large scan, and maps identical to those made
// without a callback. A callback that throws cancels a scan while rays are cast (map unchanged)
// or an export (no file), and does not cut a voxel update short. The phases of the last scan
// (get_last_scan_phases()) on every backend and on the default insert_scan() of a backend of one's
// own, and Amdahl's arithmetic on them.

#include "backend_test_support.h"
#include "reference_api_double.h"

#include <iwlomap/outofcore_tile_mapper.h>
#include <iwlomap/probability_updater.h>
#include <iwlomap/progress.h>
#include <iwlomap/scan_phases.h>
#include <iwlomap/synthetic_scan.h>
#ifdef IWLOMAP_TEST_WITH_OCTOMAP
#include <iwlomap/octomap/octree_mapper.h>
#endif

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <iterator>
#include <functional>
#include <memory>
#include <stdexcept>
#include <string>
#include <thread>
#include <vector>

namespace iwlomap {
namespace {

using test_support::snapshot;
using test_support::TempDir;

// Every report a callback heard, and whether all came on the thread that set it up.
struct Recorder {
  std::vector<ProgressReport> reports;
  std::thread::id thread = std::this_thread::get_id();
  bool other_thread = false;
  ProgressCallback callback() {
    return [this](const ProgressReport& r) {
      other_thread = other_thread || std::this_thread::get_id() != thread;
      reports.push_back(r);
    };
  }
  // The reports of \p stage, checked to start at 0, end at their total and never go back.
  std::vector<ProgressReport> stage(ProgressStage stage) const {
    std::vector<ProgressReport> out;
    for (const ProgressReport& r : reports)
      if (r.stage == stage) out.push_back(r);
    if (out.empty()) return out;
    EXPECT_EQ(out.front().done, 0u) << progress_stage_name(stage);
    EXPECT_EQ(out.back().done, out.back().total) << progress_stage_name(stage);
    for (std::size_t i = 1; i < out.size(); ++i) {
      EXPECT_GT(out[i].done, out[i - 1].done) << progress_stage_name(stage) << " report " << i;
      EXPECT_EQ(out[i].total, out[0].total) << progress_stage_name(stage);
    }
    return out;
  }
};

std::string bytes_of(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// A lidar scan of 65,536 rays (64 rings x 1,024 columns).
const SyntheticScan& scan() {
  static const SyntheticScan s = make_synthetic_scan();
  return s;
}

// Stages of one insert_scan(): rays (many reports, total = points), then the voxel update.
void expect_scan_reports(IMapperBackend& map, std::size_t min_update_reports) {
  Recorder rec;
  map.set_progress_callback(rec.callback());
  map.insert_scan(scan().origin, scan().points, scan().intensities, -1.0);
  EXPECT_FALSE(rec.other_thread) << map.get_backend_type();
  const auto rays = rec.stage(ProgressStage::kCastingRays);
  const auto voxels = rec.stage(ProgressStage::kUpdatingVoxels);
  ASSERT_FALSE(rays.empty()) << map.get_backend_type();
  ASSERT_FALSE(voxels.empty()) << map.get_backend_type();
  EXPECT_EQ(rays.back().total, static_cast<std::size_t>(scan().points.rows()));
  EXPECT_GE(rays.size(), 10u) << map.get_backend_type() << ": the bar must move within the scan";
  EXPECT_GE(voxels.size(), min_update_reports) << map.get_backend_type();
  // Rays first, then voxels.
  EXPECT_EQ(rec.reports.front().stage, ProgressStage::kCastingRays);
  EXPECT_EQ(rec.reports.back().stage, ProgressStage::kUpdatingVoxels);
}

TEST(Progress, RamScanReportsRaysThenVoxelsAndMapsTheSame) {
  for (const int threads : {1, 2}) {
    ProbabilityUpdater reported(0.2);
    ProbabilityUpdater plain(0.2);
    reported.set_num_threads(threads);
    expect_scan_reports(reported, 3);
    plain.insert_scan(scan().origin, scan().points, scan().intensities, -1.0);
    EXPECT_EQ(snapshot(reported), snapshot(plain)) << threads << " thread(s)";
  }
}

TEST(Progress, DiskScanReportsTilesAndFlushReportsTileWrites) {
  TempDir dir;
  OutofcoreTileMapper map(dir.sub("map"), 0.2, 5.0);
  expect_scan_reports(map, 3);
  Recorder rec;
  map.set_progress_callback(rec.callback());
  map.flush();
  const auto writes = rec.stage(ProgressStage::kWritingTiles);
  ASSERT_FALSE(writes.empty());
  EXPECT_GE(writes.back().total, 4u) << "the scan spans several 5 m tiles";
  EXPECT_EQ(writes.size(), writes.back().total + 1) << "one report per tile, and the start";
  ProbabilityUpdater ram(0.2);
  ram.insert_scan(scan().origin, scan().points, scan().intensities, -1.0);
  EXPECT_EQ(snapshot(map), snapshot(ram));
}

TEST(Progress, RemovedCallbackReportsNothing) {
  ProbabilityUpdater map(0.2);
  Recorder rec;
  map.set_progress_callback(rec.callback());
  map.set_progress_callback({});
  map.insert_scan(scan().origin, scan().points, scan().intensities, -1.0);
  EXPECT_TRUE(rec.reports.empty());
}

// A callback that throws while rays are cast cancels the scan: the map is as before. One that
// throws during the voxel update is heard once the scan is in, whole.
TEST(Progress, ThrowingCallbackCancelsRaysButNotTheUpdate) {
  for (const int threads : {1, 2}) {
    ProbabilityUpdater map(0.2);
    map.set_num_threads(threads);
    map.set_progress_callback([](const ProgressReport& r) {
      if (r.stage == ProgressStage::kCastingRays && r.done > 0) throw std::runtime_error("cancelled");
    });
    EXPECT_THROW(map.insert_scan(scan().origin, scan().points, scan().intensities, -1.0), std::runtime_error);
    EXPECT_EQ(map.get_num_known_voxels(), 0u) << "a cancelled scan changes nothing";

    int heard = 0;
    map.set_progress_callback([&heard](const ProgressReport& r) {
      if (r.stage == ProgressStage::kUpdatingVoxels && r.done > 0) {
        ++heard;
        throw std::runtime_error("late");
      }
    });
    EXPECT_THROW(map.insert_scan(scan().origin, scan().points, scan().intensities, -1.0), std::runtime_error);
    EXPECT_EQ(heard, 1) << "the first exception stops the reports";
    ProbabilityUpdater whole(0.2);
    whole.insert_scan(scan().origin, scan().points, scan().intensities, -1.0);
    EXPECT_EQ(snapshot(map), snapshot(whole)) << "the scan went in whole, " << threads << " thread(s)";
  }
}

#ifdef IWLOMAP_TEST_WITH_OCTOMAP
TEST(Progress, OctomapBackendScanReports) {
  OctreeMapper map(0.2);
  expect_scan_reports(map, 3);
}

TEST(Progress, ExportReportsBlocksAndAThrowLeavesNoFile) {
  ProbabilityUpdater map(0.1);
  map.insert_scan(scan().origin, scan().points, scan().intensities, -1.0);
  TempDir dir;
  Recorder rec;
  export_octomap(map, dir.sub("map.bt"), 0.7, rec.callback());
  const auto blocks = rec.stage(ProgressStage::kWritingFile);
  ASSERT_GE(blocks.size(), 10u);
  EXPECT_FALSE(rec.other_thread);
  // The same bytes as without a callback.
  export_octomap(map, dir.sub("plain.bt"), 0.7);
  EXPECT_EQ(bytes_of(dir.sub("map.bt")), bytes_of(dir.sub("plain.bt")));

  EXPECT_THROW(export_octomap(map, dir.sub("cancelled.bt"), 0.7,
                              [](const ProgressReport& r) {
                                if (r.done > 0) throw std::runtime_error("cancelled");
                              }),
               std::runtime_error);
  EXPECT_FALSE(std::filesystem::exists(dir.sub("cancelled.bt")));
  EXPECT_FALSE(std::filesystem::exists(dir.sub("cancelled.bt.part")));
}
#endif

// The phases of one scan of \p map on \p threads threads: each measured, none longer than the call,
// the parallel ones and the serial rest adding up to the call, and the merge only where there is
// one (threads, or hit statistics).
void expect_scan_phases(IMapperBackend& map, int threads) {
  map.set_num_threads(threads);
  map.insert_scan(scan().origin, scan().points, scan().intensities, -1.0);
  const ScanPhaseTimes& p = map.get_last_scan_phases();
  const std::string what = map.get_backend_type() + ", " + std::to_string(threads) + " thread(s)";
  EXPECT_EQ(p.threads, threads) << what;
  EXPECT_GT(p.total, 0.0) << what;
  EXPECT_GT(p.casting_rays, 0.0) << what;
  EXPECT_GT(p.allocating, 0.0) << what << ": a fresh map gains blocks";
  EXPECT_GT(p.preparing, 0.0) << what;
  EXPECT_GT(p.updating, 0.0) << what;
  for (const double phase : {p.casting_rays, p.merging, p.allocating, p.preparing, p.updating})
    EXPECT_LE(phase, p.total) << what;
  EXPECT_LE(p.casting_rays + p.merging + p.allocating + p.preparing + p.updating, p.total * (1.0 + 1e-9)) << what;
  EXPECT_NEAR(p.serial() + p.casting_rays + p.preparing + p.updating, p.total, 1e-9) << what;
  EXPECT_GE(p.serial(), p.merging + p.allocating - 1e-9) << what;
  if (threads == 1 && !map.get_hit_accumulation())
    EXPECT_EQ(p.merging, 0.0) << what;
  else
    EXPECT_GT(p.merging, 0.0) << what;
}

TEST(ScanPhases, EveryBackendTimesItsPhases) {
  TempDir dir;
  for (const int threads : {1, 2}) {
    std::vector<std::unique_ptr<IMapperBackend>> maps;
    maps.push_back(std::make_unique<ProbabilityUpdater>(0.2));
    maps.push_back(std::make_unique<OutofcoreTileMapper>(dir.sub("map" + std::to_string(threads)), 0.2, 5.0));
#ifdef IWLOMAP_TEST_WITH_OCTOMAP
    maps.push_back(std::make_unique<OctreeMapper>(0.2));
#endif
    for (const auto& map : maps) {
      EXPECT_EQ(map->get_last_scan_phases().total, 0.0) << map->get_backend_type() << ": no scan yet";
      expect_scan_phases(*map, threads);
    }
  }
  // With hit statistics the ray ends are merged into them on the calling thread.
  ProbabilityUpdater with_hits(0.2);
  with_hits.set_hit_accumulation(true);
  expect_scan_phases(with_hits, 1);
}

TEST(ScanPhases, DefaultInsertScanTimesRaysAndBatches) {
  test_support::ReferenceApiDouble map(0.2);
  map.insert_scan(scan().origin, scan().points, scan().intensities, -1.0);
  const ScanPhaseTimes& p = map.get_last_scan_phases();
  EXPECT_GT(p.casting_rays, 0.0);
  EXPECT_GT(p.updating, 0.0) << "the batch calls";
  EXPECT_EQ(p.allocating, 0.0);
  EXPECT_LE(p.casting_rays + p.updating, p.total);
}

TEST(ScanPhases, SerialShareAndAmdahl) {
  ScanPhaseTimes p;
  EXPECT_EQ(p.serial_share(), 0.0);
  EXPECT_EQ(p.amdahl_speedup(8), 1.0);
  p.casting_rays = 0.6;
  p.preparing = 0.1;
  p.updating = 0.2;
  p.merging = 0.02;
  p.allocating = 0.05;
  p.total = 1.0;
  EXPECT_NEAR(p.serial(), 0.1, 1e-12);
  EXPECT_NEAR(p.serial_share(), 0.1, 1e-12);
  EXPECT_NEAR(p.amdahl_speedup(1), 1.0, 1e-12);
  EXPECT_NEAR(p.amdahl_speedup(2), 1.0 / (0.1 + 0.45), 1e-12);
  EXPECT_NEAR(p.amdahl_speedup(64), 1.0 / (0.1 + 0.9 / 64), 1e-12);
  EXPECT_NEAR(p.amdahl_speedup(0), 1.0, 1e-12) << "fewer than one thread counts as one";
  p.total = 0.5;  // clock reads can make the parts add up to more than the call
  EXPECT_EQ(p.serial(), 0.0);
}

}  // namespace
}  // namespace iwlomap
