// SPDX-License-Identifier: BSD-3-Clause
// The RAM backend's insert_scan(): its semantics on hand-built scans (one update per voxel, the
// largest intensity, the range limit, skipped points, bad origins, the key range), random scans
// against a reference built from compute_ray_keys(), and the same map for any thread count.

#include "iwlomap/probability_updater.h"
#include "iwlomap/ray_caster.h"
#include "iwlomap/synthetic_scan.h"

#include "ram_test_support.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <map>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

namespace iwlomap {
namespace {

using ram_test::kInf;
using ram_test::kNaN;
using ram_test::RefVoxel;
using ram_test::rows;
using ram_test::single_observation;
using ram_test::Snapshot;
using ram_test::snapshot;
using ram_test::state_at;
using ram_test::values;

// ---- insert_scan -----------------------------------------------------------------------------

TEST(ProbabilityUpdaterInsertScan, UpdatesEachVoxelOnceWhenRaysShareVoxels) {
  ProbabilityUpdater map(1.0);
  const Eigen::Vector3d origin(0.5, 0.5, 0.5);  // centre of voxel (0, 0, 0)
  // Ray 1 along +x to (5, 0, 0); ray 2 along +x to (3, 0, 0), which ray 1 crosses; ray 3 along -y
  // to (0, -4, 0). The origin voxel is crossed by all three.
  map.insert_scan(origin, rows({{5.5, 0.5, 0.5}, {3.5, 0.5, 0.5}, {0.5, -3.5, 0.5}}), values({200, 200, 100}));

  // Free (one observation, L = 0 -> -3): (0..2, 0, 0), (4, 0, 0), (0, -1..-3, 0).
  const std::vector<VoxelKey> free = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {4, 0, 0}, {0, -1, 0}, {0, -2, 0}, {0, -3, 0}};
  for (const VoxelKey& k : free) {
    SCOPED_TRACE(std::to_string(k.x) + " " + std::to_string(k.y) + " " + std::to_string(k.z));
    EXPECT_EQ(state_at(map, k.x, k.y, k.z), std::make_pair(-3.0, 1u));
  }
  // Occupied wins over free at (3, 0, 0). I = 200: u = 165 / 220 = 0.75,
  // w = 1 / (1 + exp(-0.1 * 0.25)) = 0.5062496744995104, L = 3.5 * w = 1.7718738607482865.
  // Stored to the nearest 2^-19 (iwlo::VoxelFormat of the defaults).
  const iwlo::VoxelFormat format;
  const double l200 = format.quantize(1.7718738607482865);
  EXPECT_NEAR(l200, 1.7718738607482865, 0x1p-20);
  EXPECT_EQ(state_at(map, 5, 0, 0), std::make_pair(l200, 1u));
  EXPECT_EQ(state_at(map, 3, 0, 0), std::make_pair(l200, 1u));
  EXPECT_EQ(state_at(map, 0, -4, 0),
            std::make_pair(static_cast<double>(single_observation(100.0, true, IwloParams{})), 1u));
  EXPECT_EQ(map.get_num_known_voxels(), 10u);
  EXPECT_FALSE(map.query(Eigen::Vector3d(6.5, 0.5, 0.5)).has_value());
  EXPECT_FALSE(map.query(Eigen::Vector3d(0.5, 0.5, 1.5)).has_value());

  // A second scan is a second observation: n = 2, alpha = 1 / 1.1, P(-3) = 0.047 -> s = 1:
  // L = -3 - 3 / 1.1 = -5.727272727272727 for the free voxels.
  map.insert_scan(origin, rows({{5.5, 0.5, 0.5}}), values({200}));
  EXPECT_EQ(state_at(map, 1, 0, 0), std::make_pair(static_cast<double>(format.quantize(-3.0 - 3.0 / 1.1)), 2u));
  EXPECT_EQ(state_at(map, 0, -1, 0), std::make_pair(-3.0, 1u));  // not on this scan's ray
}

TEST(ProbabilityUpdaterInsertScan, TakesLargestIntensityWhenSeveralHitsInOneVoxel) {
  ProbabilityUpdater map(1.0);
  const IwloParams p;
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{5.2, 0.5, 0.5}, {5.8, 0.6, 0.4}, {5.5, 0.5, 0.5}}),
                  values({80, 220, 150}));
  const auto s = map.query(Eigen::Vector3d(5.5, 0.5, 0.5));
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->count, 1u);
  EXPECT_EQ(s->log_odds, static_cast<double>(single_observation(220.0, true, p)));
  // Neither the first nor the last hit's intensity, and not three observations.
  EXPECT_NE(s->log_odds, static_cast<double>(single_observation(80.0, true, p)));
  EXPECT_NE(s->log_odds, static_cast<double>(single_observation(150.0, true, p)));
  EXPECT_EQ(map.get_num_known_voxels(), 6u);  // (0..4, 0, 0) free + the hit
}

TEST(ProbabilityUpdaterInsertScan, FreeObservationWhenHitIntensityAtOrBelowThreshold) {
  ProbabilityUpdater map(1.0);
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{0.5, 0.5, 4.5}, {0.5, 2.5, 0.5}}), values({35, 20}));
  for (int z = 0; z <= 4; ++z) EXPECT_EQ(state_at(map, 0, 0, z), std::make_pair(-3.0, 1u)) << "z = " << z;
  for (int y = 1; y <= 2; ++y) EXPECT_EQ(state_at(map, 0, y, 0), std::make_pair(-3.0, 1u)) << "y = " << y;
  EXPECT_EQ(map.get_num_known_voxels(), 7u);
  EXPECT_EQ(map.get_occupied_voxels(0.0).rows(), 7);
  EXPECT_EQ(map.get_occupied_voxels(0.5).rows(), 0);
}

TEST(ProbabilityUpdaterInsertScan, ClipsFreeRayWithoutHitWhenBeyondMaxRange) {
  ProbabilityUpdater map(1.0);
  // (10.5, 0.5, 0.5) is 10 m away, beyond 4 m: free ray to (4.5, 0.5, 0.5), i.e. voxels 0..3; the
  // clipped end voxel (4, 0, 0) and the point's voxel (10, 0, 0) stay unknown.
  // (0.5, 2.5, 0.5) is 2 m away: a normal ray and hit.
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{10.5, 0.5, 0.5}, {0.5, 2.5, 0.5}}), values({200, 200}), 4.0);
  for (int x = 0; x <= 3; ++x) EXPECT_EQ(state_at(map, x, 0, 0), std::make_pair(-3.0, 1u)) << "x = " << x;
  EXPECT_FALSE(map.query(Eigen::Vector3d(4.5, 0.5, 0.5)).has_value());
  EXPECT_FALSE(map.query(Eigen::Vector3d(10.5, 0.5, 0.5)).has_value());
  EXPECT_EQ(state_at(map, 0, 1, 0), std::make_pair(-3.0, 1u));
  EXPECT_EQ(state_at(map, 0, 2, 0).second, 1u);
  EXPECT_GT(state_at(map, 0, 2, 0).first, 0.0);
  EXPECT_EQ(map.get_num_known_voxels(), 6u);
  // Without a limit (max_range <= 0) the same far point is a hit.
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{10.5, 0.5, 0.5}}), values({200}), -1.0);
  EXPECT_TRUE(map.query(Eigen::Vector3d(10.5, 0.5, 0.5)).has_value());
}

TEST(ProbabilityUpdaterInsertScan, SkipsAndCountsWhenPointsNotFinite) {
  ProbabilityUpdater map(1.0);
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5),
                  rows({{kNaN, 0.5, 0.5}, {2.5, 0.5, 0.5}, {0.5, kInf, 0.5}, {0.5, 0.5, 2.5}}),
                  values({200, 200, 200, kNaN}));
  EXPECT_EQ(map.get_num_skipped_points(), 3u);  // NaN x, infinite y, NaN intensity
  // Only the second point: (0, 0, 0), (1, 0, 0) free, (2, 0, 0) hit.
  EXPECT_EQ(map.get_num_known_voxels(), 3u);
  EXPECT_TRUE(map.query(Eigen::Vector3d(2.5, 0.5, 0.5)).has_value());
  EXPECT_FALSE(map.query(Eigen::Vector3d(0.5, 0.5, 1.5)).has_value());
  // Batches count their skipped points into the same total.
  map.batch_update_iwlo(rows({{kNaN, 0, 0}, {0.5, 0.5, 0.5}}), values({10, 10}), {true, true});
  EXPECT_EQ(map.get_num_skipped_points(), 4u);
}

TEST(ProbabilityUpdaterInsertScan, ThrowsInvalidArgumentWhenOriginNotFinite) {
  ProbabilityUpdater map(1.0);
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{2.5, 0.5, 0.5}}), values({200}));
  const Snapshot before = snapshot(map);
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d(kNaN, 0, 0), rows({{2.5, 0.5, 0.5}}), values({200})),
               std::invalid_argument);
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d(0, kInf, 0), rows({{2.5, 0.5, 0.5}}), values({200})),
               std::invalid_argument);
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{2.5, 0.5, 0.5}}), values({200}), kNaN),
               std::invalid_argument);
  EXPECT_EQ(snapshot(map), before);
  EXPECT_EQ(map.get_num_skipped_points(), 0u);
}

TEST(ProbabilityUpdaterInsertScan, ThrowsOutOfRangeAndKeepsMapWhenPointBeyondInt32) {
  ProbabilityUpdater map(0.05);
  map.insert_scan(Eigen::Vector3d(0.01, 0.01, 0.01), rows({{1.0, 0.0, 0.0}}), values({200}));
  const Snapshot before = snapshot(map);
  ASSERT_FALSE(before.empty());
  // The first ray is valid; the second endpoint's key does not fit in int32 (the origin lies 10
  // voxels from the end of the key range, the point 20 voxels beyond it).
  const double edge = 2147483647.0 * 0.05;
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d(edge - 0.5, 0.01, 0.01), rows({{edge - 1.0, 1.0, 0.0}, {edge + 1.0, 0.0, 0.0}}),
                               values({200, 200})),
               std::out_of_range);
  // A point far beyond the range (1e9 / 0.05 = 2e10) is past the longest ray: skipped, counted.
  const std::size_t skipped = map.get_num_skipped_points();
  EXPECT_NO_THROW(map.insert_scan(Eigen::Vector3d(0.01, 0.01, 0.01), rows({{1e9, 0.0, 0.0}}), values({200})));
  EXPECT_EQ(map.get_num_skipped_points(), skipped + 1);
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d(-1e9, 0.0, 0.0), rows({{0.0, 1.0, 0.0}}), values({200})),
               std::out_of_range);
  EXPECT_EQ(snapshot(map), before);
}

// insert_scan against a reference built from the model's ray walk (compute_ray_keys() or
// cast_line()): many rays over many blocks.
void expect_scans_match_the_ray_reference(RayModel model) {
  const double r = 0.1;
  const double max_range = 1.6;
  ProbabilityUpdater map(r);
  map.set_ray_model(model);
  const IwloParams params;
  std::map<VoxelKey, RefVoxel> ref;
  std::mt19937 rng(31337u);
  std::uniform_real_distribution<double> pos(-2.0, 2.0);
  std::uniform_real_distribution<double> intensity(0.0, 255.0);
  for (int scan = 0; scan < 4; ++scan) {
    const Eigen::Vector3d origin(pos(rng) * 0.3, pos(rng) * 0.3, pos(rng) * 0.3);
    const int n = 1500;
    Eigen::MatrixXd points(n, 3);
    Eigen::VectorXd intens(n);
    for (int i = 0; i < n; ++i) {
      points.row(i) << pos(rng), pos(rng), pos(rng);
      intens[i] = intensity(rng);
    }
    // Reference: free = voxels the rays cross; hits keep the largest intensity; occupied wins.
    std::set<VoxelKey> free;
    std::map<VoxelKey, double> hits;
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector3d p = points.row(i).transpose();
      const Eigen::Vector3d d = p - origin;
      const double range = d.norm();
      const bool beyond = range > max_range;
      const Eigen::Vector3d end = beyond ? Eigen::Vector3d(origin + d * (max_range / range)) : p;
      cast_ray(origin, end, r, model, [&free](const VoxelKey& k) { free.insert(k); });
      if (!beyond) {
        const VoxelKey k = world_to_key(p, r);
        auto it = hits.find(k);
        if (it == hits.end())
          hits.emplace(k, intens[i]);
        else if (intens[i] > it->second)
          it->second = intens[i];
      }
    }
    for (const VoxelKey& k : free) {
      if (hits.count(k) != 0) continue;
      RefVoxel& v = ref[k];
      iwlo::apply_observation(v.L, v.count, 0.0, false, 1.0, params);
    }
    for (const auto& [k, I] : hits) {
      RefVoxel& v = ref[k];
      iwlo::apply_observation(v.L, v.count, I, true, 1.0, params);
    }
    map.insert_scan(origin, points, intens, max_range);

    Snapshot want;
    for (const auto& [k, v] : ref) want.emplace(k, std::make_pair(static_cast<double>(v.L), v.count));
    const Snapshot got = snapshot(map);
    ASSERT_EQ(got.size(), want.size()) << "scan " << scan;
    std::size_t mismatches = 0;
    for (const auto& [k, v] : want) {
      const auto it = got.find(k);
      if ((it == got.end() || it->second != v) && ++mismatches <= 10)
        ADD_FAILURE() << "scan " << scan << ": voxel (" << k.x << ", " << k.y << ", " << k.z << ") differs";
    }
    EXPECT_EQ(mismatches, 0u);
    EXPECT_EQ(map.get_num_known_voxels(), want.size());
  }
}

TEST(ProbabilityUpdaterInsertScan, MatchesRayReferenceWhenRandomScans) {
  expect_scans_match_the_ray_reference(RayModel::kExact);
}

TEST(ProbabilityUpdaterInsertScan, MatchesLineReferenceWhenRandomScansUseFastRays) {
  expect_scans_match_the_ray_reference(RayModel::kFast);
}

// ---- threads ----

// Every known voxel of a map, in a canonical order, with its exact stored state.
std::vector<std::tuple<VoxelKey, double, std::uint32_t>> snapshot(const ProbabilityUpdater& m) {
  std::vector<std::tuple<VoxelKey, double, std::uint32_t>> out;
  m.for_each_voxel([&](const VoxelKey& k, const VoxelState& s) { out.emplace_back(k, s.log_odds, s.count); });
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return std::get<0>(a) < std::get<0>(b); });
  return out;
}

TEST(ProbabilityUpdaterThreads, InsertScanIsBitIdenticalForAnyThreadCount) {
  std::vector<SyntheticScan> scans;
  for (int k = 0; k < 3; ++k) {
    SyntheticScanOptions o;
    o.rings = 32;
    o.columns = 512;  // 16,384 rays: enough for every thread count to get work
    o.sensor_xy = Eigen::Vector2d(1.5 * k, 0.7 * k);
    o.seed = static_cast<std::uint32_t>(10 + k);
    scans.push_back(make_synthetic_scan(o));
  }
  scans[1].points(5, 0) = std::numeric_limits<double>::quiet_NaN();  // skipped the same way
  std::vector<std::tuple<VoxelKey, double, std::uint32_t>> reference;
  std::vector<VoxelKey> reference_order;
  for (int threads : {1, 2, 3, 8}) {
    ProbabilityUpdater m(0.15);
    m.set_num_threads(threads);
    EXPECT_EQ(m.get_num_threads(), threads);
    for (const auto& s : scans) m.insert_scan(s.origin, s.points, s.intensities, 18.0);
    const auto state = snapshot(m);
    EXPECT_EQ(m.get_num_skipped_points(), 1u);
    EXPECT_EQ(m.get_num_known_voxels(), state.size());
    std::vector<VoxelKey> order;  // iteration order must not depend on the thread count either
    m.for_each_voxel([&](const VoxelKey& k, const VoxelState&) { order.push_back(k); });
    if (threads == 1) {
      reference_order = order;
      reference = state;
      ASSERT_GT(reference.size(), 100000u);
      continue;
    }
    ASSERT_EQ(state.size(), reference.size()) << threads << " threads";
    EXPECT_TRUE(state == reference) << threads << " threads give a different map";
    EXPECT_TRUE(order == reference_order) << threads << " threads visit the voxels in another order";
  }
}

TEST(ProbabilityUpdaterThreads, ZeroMeansAllHardwareThreadsAndNegativeThrows) {
  ProbabilityUpdater m(0.1);
  EXPECT_EQ(m.get_num_threads(), 1);
  m.set_num_threads(0);
  EXPECT_GE(m.get_num_threads(), 1);
  EXPECT_THROW(m.set_num_threads(-1), std::invalid_argument);
}

TEST(ProbabilityUpdaterThreads, OutOfRangePointThrowsTheFirstErrorAndKeepsTheMap) {
  const SyntheticScan s = make_synthetic_scan();
  // The scan moved next to the end of the int32 key range (60 m from it at 0.1 m), and two points
  // moved past it (within the longest ray).
  const Eigen::RowVector3d shift(2147483647.0 * 0.1 - 60.0, 0.0, 0.0);
  Eigen::MatrixXd pts = s.points.rowwise() + shift;
  pts(100, 0) += 100.0;    // in the first thread's range
  pts(60000, 0) += 100.0;  // in the last thread's range
  ProbabilityUpdater m(0.1);
  m.set_num_threads(4);
  try {
    m.insert_scan(s.origin + shift.transpose(), pts, s.intensities);
    FAIL() << "no exception";
  } catch (const std::out_of_range& e) {
    EXPECT_NE(std::string(e.what()).find("point 100 "), std::string::npos) << e.what();
  }
  EXPECT_EQ(m.get_num_known_voxels(), 0u);
}

}  // namespace
}  // namespace iwlomap
