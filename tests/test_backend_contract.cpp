// SPDX-License-Identifier: BSD-3-Clause
// The backend contract, once for every backend: on the same seeded input, each backend must give
// the RAM backend's (ProbabilityUpdater) per-voxel log-odds and counts, occupied voxels, skipped
// points and exceptions. The RAM backend is the reference because its math is checked against
// hand-computed values and a dense array elsewhere (test_iwlo, test_probability_updater).
//
// Adding a backend is one more factory struct in BackendFactories: it needs kType and make(); a
// factory is an object, created per test, so one that needs a directory (Disk) can own it.

#include "backend_test_support.h"
#include "reference_api_double.h"
#include "iwlomap/mapper_backend.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"
#ifdef IWLOMAP_TEST_WITH_OCTOMAP
#include "iwlomap/octomap/octree_mapper.h"
#endif

#include <gtest/gtest.h>


#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <tuple>
#include <type_traits>
#include <typeinfo>
#include <utility>
#include <vector>

namespace iwlomap {
namespace {

using test_support::Batch;
using test_support::Snapshot;
using test_support::TempDir;
using test_support::snapshot;
using test_support::sorted_rows;

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---- backends under test ----

struct RamFactory {
  static constexpr const char* kType = "RAM";
  std::unique_ptr<IMapperBackend> make(double resolution) { return std::make_unique<ProbabilityUpdater>(resolution); }
};

// 64-voxel tiles and 2 resident tiles: the suite's maps span several tiles, so tiles are evicted,
// written and read back while the suite runs. The factory owns a temporary directory per test.
struct DiskFactory {
  static constexpr const char* kType = "Disk";
  BackendOptions options(double resolution) {
    BackendOptions o;
    o.directory = dir_.sub("map" + std::to_string(maps_++));
    o.tile_size = 64 * resolution;
    o.cache_tiles = 2;
    return o;
  }
  std::unique_ptr<IMapperBackend> make(double resolution) {
    const BackendOptions o = options(resolution);
    return std::make_unique<OutofcoreTileMapper>(o.directory, resolution, o.tile_size, o.cache_tiles);
  }
  TempDir dir_;
  int maps_ = 0;
};

#ifdef IWLOMAP_TEST_WITH_OCTOMAP
struct OctoMapFactory {
  static constexpr const char* kType = "OctoMap";
  std::unique_ptr<IMapperBackend> make(double resolution) { return std::make_unique<OctreeMapper>(resolution); }
};
using BackendFactories = ::testing::Types<RamFactory, DiskFactory, OctoMapFactory>;
#else
using BackendFactories = ::testing::Types<RamFactory, DiskFactory>;
#endif

struct FactoryNames {
  template <class T>
  static std::string GetName(int) {
    return T::kType;
  }
};

template <class F, class = void>
struct HasOptions : std::false_type {};
template <class F>
struct HasOptions<F, std::void_t<decltype(std::declval<F&>().options(1.0))>> : std::true_type {};

template <class Factory>
class BackendContract : public ::testing::Test {
 protected:
  std::unique_ptr<IMapperBackend> make(double resolution) { return factory_.make(resolution); }
  // make_backend() options: the factory's own when it has them (Disk needs a directory).
  BackendOptions options(double resolution) {
    if constexpr (HasOptions<Factory>::value)
      return factory_.options(resolution);
    else
      return {};
  }
  static std::unique_ptr<IMapperBackend> make_reference(double resolution) {
    return std::make_unique<ProbabilityUpdater>(resolution);
  }

 private:
  Factory factory_;
};
TYPED_TEST_SUITE(BackendContract, BackendFactories, FactoryNames);

// ---- comparison helpers ----

// Everything observable must be equal, bit for bit: the backends share the update math.
void expect_same_map(IMapperBackend& got, IMapperBackend& want) {
  const Snapshot g = snapshot(got), w = snapshot(want);
  EXPECT_EQ(g.size(), w.size());
  std::size_t mismatches = 0;
  for (const auto& [k, v] : w) {
    const auto it = g.find(k);
    const bool ok = it != g.end() && it->second == v;
    if (!ok && ++mismatches <= 5)
      ADD_FAILURE() << "voxel (" << k.x << ", " << k.y << ", " << k.z << "): reference L = " << v.first
                    << " n = " << v.second << ", " << got.get_backend_type()
                    << (it == g.end() ? " does not know it" : " L = " + std::to_string(it->second.first) +
                                                                  " n = " + std::to_string(it->second.second));
  }
  EXPECT_EQ(mismatches, 0u);
  EXPECT_EQ(got.get_num_known_voxels(), want.get_num_known_voxels());
  EXPECT_EQ(got.get_num_skipped_points(), want.get_num_skipped_points());
  for (double p : {-1.0, 0.0, 0.3, 0.5, 0.7, 0.95})
    EXPECT_EQ(sorted_rows(got.get_occupied_voxels(p)), sorted_rows(want.get_occupied_voxels(p))) << "min_probability " << p;
  // query() agrees with the visitor.
  const double r = want.get_resolution();
  int checked = 0;
  for (const auto& [k, v] : w) {
    if (++checked > 2000) break;
    const auto s = got.query(key_to_center(k, r));
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->log_odds, v.first);
    EXPECT_EQ(s->count, v.second);
  }
}

// Points in a small box around the origin, with NaN and infinite coordinates and NaN intensities.
Batch random_batch(std::mt19937& rng, int n, double half_extent) {
  return test_support::random_batch(rng, n, half_extent, Eigen::Vector3d::Zero(), test_support::BadRows::kNaNInfAndIntensity);
}

// ---- the suite ----

TYPED_TEST(BackendContract, ReportsTypeResolutionAndEmptyMapWhenNew) {
  auto map = this->make(0.25);
  EXPECT_EQ(map->get_backend_type(), TypeParam::kType);
  EXPECT_EQ(map->get_resolution(), 0.25);
  EXPECT_EQ(map->get_num_known_voxels(), 0u);
  EXPECT_EQ(map->get_num_skipped_points(), 0u);
  EXPECT_EQ(map->get_occupied_voxels().rows(), 0);
  EXPECT_EQ(map->get_occupied_voxels().cols(), 4);
  EXPECT_FALSE(map->query(Eigen::Vector3d(1.0, 2.0, 3.0)).has_value());
  EXPECT_TRUE(snapshot(*map).empty());
}

TYPED_TEST(BackendContract, CreatedByMakeBackendWhenNamed) {
  const auto map = make_backend(TypeParam::kType, 0.3, this->options(0.3));
  EXPECT_EQ(map->get_backend_type(), TypeParam::kType);
  EXPECT_EQ(map->get_resolution(), 0.3);
  const auto names = available_backends();
  EXPECT_NE(std::find(names.begin(), names.end(), std::string(TypeParam::kType)), names.end());
}

TYPED_TEST(BackendContract, MatchesRamWhenBatchesWithoutWeights) {
  auto map = this->make(0.25);
  auto ref = this->make_reference(0.25);
  std::mt19937 rng(20240601u);
  for (int b = 0; b < 6; ++b) {
    const Batch batch = random_batch(rng, 20000, 3.0);
    map->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
    ref->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  }
  EXPECT_GT(ref->get_num_skipped_points(), 0u);
  EXPECT_GT(ref->get_occupied_voxels().rows(), 0);
  expect_same_map(*map, *ref);
}

TYPED_TEST(BackendContract, MatchesRamWhenBatchesWithWeights) {
  auto map = this->make(0.2);
  auto ref = this->make_reference(0.2);
  std::mt19937 rng(777u);
  for (int b = 0; b < 6; ++b) {
    const Batch batch = random_batch(rng, 15000, 2.0);
    if (b % 2 == 0) {
      map->batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
      ref->batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
    } else {
      map->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
      ref->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
    }
  }
  expect_same_map(*map, *ref);
}

TYPED_TEST(BackendContract, MatchesRamWhenScansWithMaxRange) {
  auto map = this->make(0.2);
  auto ref = this->make_reference(0.2);
  const Eigen::Vector2d positions[] = {{0.0, 0.0}, {3.0, -2.0}, {-6.0, 4.5}, {8.0, 6.0}};
  const double max_ranges[] = {-1.0, 12.0, 0.0, 7.5};
  for (int s = 0; s < 4; ++s) {
    SyntheticScanOptions o;
    o.rings = 12;
    o.columns = 180;
    o.sensor_xy = positions[s];
    o.seed = 100u + static_cast<std::uint32_t>(s);
    SyntheticScan scan = make_synthetic_scan(o);
    if (s == 2) {  // non-finite points and intensities are skipped and counted
      scan.points(5, 1) = kNaN;
      scan.points(17, 0) = kInf;
      scan.intensities[40] = kNaN;
    }
    map->insert_scan(scan.origin, scan.points, scan.intensities, max_ranges[s]);
    ref->insert_scan(scan.origin, scan.points, scan.intensities, max_ranges[s]);
  }
  EXPECT_EQ(ref->get_num_skipped_points(), 3u);
  EXPECT_GT(ref->get_occupied_voxels().rows(), 100);
  expect_same_map(*map, *ref);
}

TYPED_TEST(BackendContract, MatchesSingleThreadRamWhenScansUseThreads) {
  auto map = this->make(0.2);
  auto ref = this->make_reference(0.2);
  map->set_num_threads(3);
  EXPECT_EQ(map->get_num_threads(), 3);
  for (int s = 0; s < 2; ++s) {
    SyntheticScanOptions o;
    o.rings = 16;
    o.columns = 256;
    o.sensor_xy = Eigen::Vector2d(-4.0 * s, 2.0 * s);
    o.seed = 50u + static_cast<std::uint32_t>(s);
    const SyntheticScan scan = make_synthetic_scan(o);
    map->insert_scan(scan.origin, scan.points, scan.intensities, 20.0);
    ref->insert_scan(scan.origin, scan.points, scan.intensities, 20.0);
  }
  expect_same_map(*map, *ref);
}

// The fast ray model: every backend marks the same line's voxels as RAM does, with threads and
// with hit statistics (whose visits follow the same line).
TYPED_TEST(BackendContract, MatchesSingleThreadRamWhenFastRaysUseThreadsAndHitStatistics) {
  auto map = this->make(0.2);
  auto ref = this->make_reference(0.2);
  auto exact = this->make_reference(0.2);
  EXPECT_EQ(map->get_ray_model(), RayModel::kExact);  // the default
  map->set_ray_model(RayModel::kFast);
  ref->set_ray_model(RayModel::kFast);
  EXPECT_EQ(map->get_ray_model(), RayModel::kFast);
  map->set_num_threads(3);
  for (IMapperBackend* m : {map.get(), ref.get(), exact.get()}) m->set_hit_accumulation(true);
  for (int s = 0; s < 2; ++s) {
    SyntheticScanOptions o;
    o.rings = 16;
    o.columns = 256;
    o.sensor_xy = Eigen::Vector2d(3.0 * s, -2.0 * s);
    o.seed = 70u + static_cast<std::uint32_t>(s);
    const SyntheticScan scan = make_synthetic_scan(o);
    for (IMapperBackend* m : {map.get(), ref.get(), exact.get()})
      m->insert_scan(scan.origin, scan.points, scan.intensities, 20.0);
  }
  expect_same_map(*map, *ref);
  EXPECT_EQ(sorted_rows(map->get_occupied_mean_positions(0.5)), sorted_rows(ref->get_occupied_mean_positions(0.5)));
  // The line visits fewer voxels than the exact walk: fewer are known.
  EXPECT_LT(ref->get_num_known_voxels(), exact->get_num_known_voxels());
  EXPECT_GT(ref->get_num_known_voxels(), exact->get_num_known_voxels() / 2);
}

TYPED_TEST(BackendContract, MatchesRamWhenScansAndBatchesMixWithChangedParams) {
  auto map = this->make(0.3);
  auto ref = this->make_reference(0.3);
  std::mt19937 rng(99u);
  IwloParams p;
  p.adaptive_enabled = false;
  p.intensity_threshold = 0.0;  // every return with a positive intensity is a hit
  p.sharpness = 4.0;
  p.L_min = -5.0;
  p.L_max = 7.0;
  map->set_params(p);
  ref->set_params(p);
  for (int s = 0; s < 3; ++s) {
    SyntheticScanOptions o;
    o.rings = 8;
    o.columns = 120;
    o.sensor_xy = Eigen::Vector2d(1.5 * s, -1.0 * s);
    o.seed = 7u + static_cast<std::uint32_t>(s);
    const SyntheticScan scan = make_synthetic_scan(o);
    map->insert_scan(scan.origin, scan.points, scan.intensities, 15.0);
    ref->insert_scan(scan.origin, scan.points, scan.intensities, 15.0);
    const Batch batch = random_batch(rng, 5000, 6.0);
    map->batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
    ref->batch_update_iwlo(batch.points, batch.intensities, batch.flags, batch.weights);
  }
  map->set_adaptive_params(true, 0.4, 0.5);
  ref->set_adaptive_params(true, 0.4, 0.5);
  map->set_iwlo_params(0.2, 0.3, 0.25, -6.0, 6.0);
  ref->set_iwlo_params(0.2, 0.3, 0.25, -6.0, 6.0);
  map->set_log_odds_params(2.5, -1.5);
  ref->set_log_odds_params(2.5, -1.5);
  map->set_intensity_params(20.0, 200.0);
  ref->set_intensity_params(20.0, 200.0);
  map->set_occupied_threshold(0.8);
  ref->set_occupied_threshold(0.8);
  // Slower decays widen the count (12, then 13 bits, steps of 2^-15 and 2^-14), then back to 8
  // bits: each change converts every voxel from what the last one left, in RAM and in tiles on
  // disk alike (the second change comes with no update between).
  for (const double decay : {0.001, 0.0005, 0.3}) {
    map->set_iwlo_params(0.2, decay, 0.25, -6.0, 6.0);
    ref->set_iwlo_params(0.2, decay, 0.25, -6.0, 6.0);
    if (decay == 0.0005) continue;
    const Batch batch = random_batch(rng, 8000, 6.0);
    map->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
    ref->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  }
  EXPECT_EQ(map->get_params().occupied_threshold, 0.8);
  EXPECT_EQ(map->get_params().L_min, -6.0);
  EXPECT_EQ(map->get_params().log_odds_free, -1.5);
  expect_same_map(*map, *ref);
}

TYPED_TEST(BackendContract, MatchesRamWhenLogOddsSetAbsolutely) {
  auto map = this->make(0.5);
  auto ref = this->make_reference(0.5);
  // Observed first, so counts above 1 must survive an absolute set.
  const Eigen::MatrixXd seen = (Eigen::MatrixXd(3, 3) << 0.1, 0.1, 0.1, 0.2, 0.2, 0.2, 5.1, 0.1, 0.1).finished();
  const Eigen::VectorXd intensities = Eigen::VectorXd::Constant(3, 200.0);
  map->batch_update_iwlo(seen, intensities, {true, true, false});
  ref->batch_update_iwlo(seen, intensities, {true, true, false});
  Eigen::MatrixXd points(7, 3);
  points << 0.2, 0.2, 0.2,  // count 2 stays 2
      -0.3, 0.0, 7.0,       // new: count 1
      1.0, 1.0, 1.0,        // clamped to L_max
      2.0, 2.0, 2.0,        // clamped to L_min
      kNaN, 0.0, 0.0,       // skipped
      3.0, 3.0, 3.0,        // NaN value: skipped
      -0.3, 0.1, 7.2;       // same voxel as row 1: the later row wins
  Eigen::VectorXd values(7);
  values << 1.25, -0.75, 50.0, -50.0, 1.0, kNaN, 0.5;
  map->set_log_odds(points, values);
  ref->set_log_odds(points, values);
  expect_same_map(*map, *ref);
  const auto s = map->query(Eigen::Vector3d(0.2, 0.2, 0.2));
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->log_odds, 1.25);
  EXPECT_EQ(s->count, 2u);
  EXPECT_EQ(map->query(Eigen::Vector3d(-0.3, 0.0, 7.0))->log_odds, 0.5);
  EXPECT_EQ(map->query(Eigen::Vector3d(-0.3, 0.0, 7.0))->count, 1u);
  EXPECT_EQ(map->query(Eigen::Vector3d(1.0, 1.0, 1.0))->log_odds, 10.0);
  EXPECT_EQ(map->query(Eigen::Vector3d(2.0, 2.0, 2.0))->log_odds, -10.0);
  EXPECT_FALSE(map->query(Eigen::Vector3d(3.0, 3.0, 3.0)).has_value());
  EXPECT_EQ(map->get_num_skipped_points(), 2u);
}

TYPED_TEST(BackendContract, ReportsOccupiedStrictlyAboveMinProbability) {
  auto map = this->make(1.0);
  const Eigen::MatrixXd points = (Eigen::MatrixXd(2, 3) << 0.5, 0.5, 0.5, 1.5, 0.5, 0.5).finished();
  map->set_log_odds(points, Eigen::Vector2d(0.0, 1.0));  // p = 0.5 exactly, and p = 0.731
  EXPECT_EQ(map->get_occupied_voxels(0.5).rows(), 1);
  EXPECT_EQ(map->get_occupied_voxels(0.49).rows(), 2);
  EXPECT_EQ(map->get_occupied_voxels(1.0).rows(), 0);
  const Eigen::MatrixXd occ = map->get_occupied_voxels();
  ASSERT_EQ(occ.rows(), 1);
  EXPECT_EQ(occ(0, 0), 1.5);
  EXPECT_EQ(occ(0, 1), 0.5);
  EXPECT_EQ(occ(0, 2), 0.5);
  EXPECT_EQ(occ(0, 3), 1.0 / (1.0 + std::exp(-1.0)));
}

TYPED_TEST(BackendContract, ForgetsVoxelsAndKeepsParamsWhenCleared) {
  auto map = this->make(0.25);
  std::mt19937 rng(5u);
  const Batch batch = random_batch(rng, 2000, 2.0);
  map->set_occupied_threshold(0.65);
  map->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  ASSERT_GT(map->get_num_known_voxels(), 0u);
  map->clear();
  EXPECT_EQ(map->get_num_known_voxels(), 0u);
  EXPECT_EQ(map->get_num_skipped_points(), 0u);
  EXPECT_TRUE(snapshot(*map).empty());
  EXPECT_EQ(map->get_occupied_voxels(0.0).rows(), 0);
  EXPECT_EQ(map->get_params().occupied_threshold, 0.65);
  // Usable again, and equal to a fresh reference.
  auto ref = this->make_reference(0.25);
  ref->set_occupied_threshold(0.65);
  map->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  ref->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  expect_same_map(*map, *ref);
}

TYPED_TEST(BackendContract, KeepsAllVoxelsWhenPruned) {
  auto map = this->make(0.25);
  auto ref = this->make_reference(0.25);
  std::mt19937 rng(8u);
  const Batch batch = random_batch(rng, 5000, 1.0);  // a dense cube: many equal siblings to merge
  map->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  ref->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  (void)map->prune();
  expect_same_map(*map, *ref);
  map->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  ref->batch_update_iwlo(batch.points, batch.intensities, batch.flags);
  expect_same_map(*map, *ref);
}

// Points on voxel faces, a rounding error to either side of them, and in between, and the face
// at 0 above all: +-0, the 1e-16 of a beam at an azimuth of 90 degrees, the smallest doubles and
// the bound 2^-1000 of the key computation's rule for them. Every backend puts each one in the
// voxel of world_to_key(), i.e. floor(x / r) with a division.
TYPED_TEST(BackendContract, PutsPointsInVoxelOfWorldToKeyWhenOnOrNearVoxelFaces) {
  const double tiny = std::numeric_limits<double>::denorm_min();
  const double smallest_normal = std::numeric_limits<double>::min();
  const double bound = 0x1p-1000;
  for (const double r : {0.1, 0.05, 0.3, 1.0, 0.07}) {
    std::vector<double> coords = {0.0, -0.0, 1e-16, -1e-16, 6e-17, -6e-17, 1e-300, -1e-300, tiny, -tiny,
                                  smallest_normal, -smallest_normal, bound, -bound, std::nextafter(bound, 0.0),
                                  -std::nextafter(bound, 0.0), std::nextafter(0.5 * r, 0.0),
                                  -std::nextafter(0.5 * r, 0.0), 0.5 * r, -0.5 * r};
    for (int k = -300; k <= 300; ++k) {
      const double face = k * r;
      coords.insert(coords.end(), {face, std::nextafter(face, -1e9), std::nextafter(face, 1e9), face + 1e-12,
                                   face - 1e-12, (k + 0.5) * r, k / (1.0 / r)});
    }
    const auto n = static_cast<Eigen::Index>(coords.size());
    Eigen::MatrixXd pts(n, 3);
    for (Eigen::Index i = 0; i < n; ++i)  // each coordinate on every axis, in different rows
      pts.row(i) << coords[static_cast<std::size_t>(i)], coords[static_cast<std::size_t>((i * 7 + 3) % n)],
          coords[static_cast<std::size_t>((i * 13 + 5) % n)];
    std::map<VoxelKey, std::uint32_t> expected;
    for (Eigen::Index i = 0; i < n; ++i) ++expected[world_to_key(pts.row(i).transpose(), r)];
    auto map = this->make(r);
    map->batch_update_iwlo(pts, Eigen::VectorXd::Constant(n, 200.0), std::vector<bool>(static_cast<std::size_t>(n), true));
    std::map<VoxelKey, std::uint32_t> got;
    for (const auto& [k, v] : snapshot(*map)) got[k] = v.second;
    EXPECT_EQ(got, expected) << "resolution " << r;
  }
}

// Hit statistics: every backend gathers them as the RAM backend does, so mean positions, hits
// and visits agree bit for bit (the Disk backend's through evictions and tile files).
TYPED_TEST(BackendContract, MatchesRamWhenHitStatisticsAccumulate) {
  auto map = this->make(0.2);
  auto ref = this->make_reference(0.2);
  map->set_hit_accumulation(true);
  ref->set_hit_accumulation(true);
  std::mt19937 rng(61u);
  for (int step = 0; step < 4; ++step) {
    const Batch b = random_batch(rng, 3000, 14.0);
    for (IMapperBackend* m : {map.get(), ref.get()}) {
      m->batch_update_iwlo(b.points, b.intensities, b.flags);
      m->insert_scan(Eigen::Vector3d(0.3 * step, -0.2, 0.1), b.points, b.intensities, 10.0);
    }
  }
  const Eigen::MatrixXd got = map->get_occupied_mean_positions(0.5), want = ref->get_occupied_mean_positions(0.5);
  EXPECT_GT(want.rows(), 100);
  EXPECT_EQ(sorted_rows(got), sorted_rows(want));
  std::size_t compared = 0;
  ref->for_each_voxel([&](const VoxelKey& k, const VoxelState&) {
    if (++compared > 3000) return;
    const Eigen::Vector3d c = key_to_center(k, 0.2);
    const auto g = map->hit_statistics(c), w = ref->hit_statistics(c);
    ASSERT_EQ(g.has_value(), w.has_value());
    if (!w) return;
    EXPECT_EQ(g->hits, w->hits);
    EXPECT_EQ(g->visits, w->visits);
    EXPECT_EQ(g->mean_hit_position, w->mean_hit_position);
  });
  EXPECT_GT(compared, 1000u);
}

// clone() gives an independent map; a backend that cannot clone says so beforehand and throws.
TYPED_TEST(BackendContract, ClonesIndependentlyWhenSupported) {
  auto map = this->make(0.25);
  std::mt19937 rng(62u);
  const Batch a = random_batch(rng, 2000, 8.0), b = random_batch(rng, 2000, 8.0);
  map->set_hit_accumulation(true);
  map->batch_update_iwlo(a.points, a.intensities, a.flags);
  if (!map->supports(BackendFeature::kClone)) {
    EXPECT_THROW((void)map->clone(), std::logic_error);
    return;
  }
  map->set_ray_model(RayModel::kFast);
  const Snapshot before = snapshot(*map);
  const std::unique_ptr<IMapperBackend> copy = map->clone();
  EXPECT_EQ(copy->get_backend_type(), map->get_backend_type());
  EXPECT_EQ(copy->get_ray_model(), RayModel::kFast);
  EXPECT_EQ(snapshot(*copy), before);
  EXPECT_TRUE(copy->get_hit_accumulation());
  EXPECT_EQ(sorted_rows(copy->get_occupied_mean_positions(0.5)), sorted_rows(map->get_occupied_mean_positions(0.5)));
  map->batch_update_iwlo(b.points, b.intensities, b.flags);  // the original changes: the copy does not
  EXPECT_EQ(snapshot(*copy), before);
  const Snapshot changed = snapshot(*map);
  copy->clear();  // the copy changes: the original does not
  EXPECT_EQ(snapshot(*map), changed);
  EXPECT_EQ(copy->get_num_known_voxels(), 0u);
}

TYPED_TEST(BackendContract, DoesNothingWhenBatchEmpty) {
  auto map = this->make(0.25);
  map->batch_update_iwlo(Eigen::MatrixXd(0, 3), Eigen::VectorXd(0), {});
  map->batch_update_iwlo(Eigen::MatrixXd(0, 3), Eigen::VectorXd(0), {}, Eigen::VectorXd(0));
  map->insert_scan(Eigen::Vector3d::Zero(), Eigen::MatrixXd(0, 3), Eigen::VectorXd(0));
  map->set_log_odds(Eigen::MatrixXd(0, 3), Eigen::VectorXd(0));
  EXPECT_EQ(map->get_num_known_voxels(), 0u);
}

// ---- errors: the same exception, with the same message, and no change ----

struct Outcome {
  std::string type;  // "none" when nothing was thrown
  std::string message;
};

Outcome run(const std::function<void(IMapperBackend&)>& call, IMapperBackend& map) {
  try {
    call(map);
  } catch (const std::out_of_range& e) {
    return {"std::out_of_range", e.what()};
  } catch (const std::invalid_argument& e) {
    return {"std::invalid_argument", e.what()};
  } catch (const std::logic_error& e) {
    return {"std::logic_error", e.what()};
  } catch (const std::exception& e) {
    return {typeid(e).name(), e.what()};
  }
  return {"none", ""};
}

// A stray return far away (longer than kMaxRayVoxels voxel edges) is skipped and counted, not cast:
// its ray would cross millions of voxels.
TYPED_TEST(BackendContract, SkipsAndCountsScanPointsPastTheLongestRayLikeRam) {
  const double r = 0.25;
  const Eigen::MatrixXd pts =
      (Eigen::MatrixXd(4, 3) << 1.0, 0.5, 0.2, kMaxRayVoxels * r * 1.001, 0.0, 0.0, -2.0, 1.0, 0.0, 1e12, 0.0, 0.0)
          .finished();
  const Eigen::VectorXd ints = Eigen::Vector4d(100.0, 100.0, 200.0, 100.0);
  auto map = this->make(r);
  auto ref = this->make_reference(r);
  map->insert_scan(Eigen::Vector3d(0.1, 0.1, 0.1), pts, ints);
  ref->insert_scan(Eigen::Vector3d(0.1, 0.1, 0.1), pts, ints);
  EXPECT_EQ(map->get_num_skipped_points(), 2u);
  EXPECT_EQ(snapshot(*map), snapshot(*ref));
  // Only the two near points were cast.
  auto near = this->make_reference(r);
  near->insert_scan(Eigen::Vector3d(0.1, 0.1, 0.1), pts({0, 2}, Eigen::all), Eigen::Vector2d(100.0, 200.0));
  EXPECT_EQ(snapshot(*map), snapshot(*near));
  // Clipped at max_range, the same far points are cast as free rays again.
  auto clipped = this->make(r);
  clipped->insert_scan(Eigen::Vector3d(0.1, 0.1, 0.1), pts, ints, 10.0);
  EXPECT_EQ(clipped->get_num_skipped_points(), 0u);
  EXPECT_GT(snapshot(*clipped).size(), snapshot(*near).size());
}

TYPED_TEST(BackendContract, ThrowsLikeRamAndChangesNothingWhenInputInvalid) {
  const Eigen::MatrixXd pts = (Eigen::MatrixXd(3, 3) << 0.1, 0.2, 0.3, 1.0, 1.0, 1.0, -2.0, 0.5, 0.5).finished();
  const Eigen::VectorXd ints = Eigen::Vector3d(100.0, 200.0, 10.0);
  const std::vector<bool> flags = {true, true, false};
  const Eigen::MatrixXd far_pts = (Eigen::MatrixXd(2, 3) << 0.1, 0.1, 0.1, 1e12, 0.0, 0.0).finished();
  const std::vector<std::pair<const char*, std::function<void(IMapperBackend&)>>> calls = {
      {"points N x 2", [&](IMapperBackend& m) { m.batch_update_iwlo(Eigen::MatrixXd::Zero(3, 2), ints, flags); }},
      {"intensities too short", [&](IMapperBackend& m) { m.batch_update_iwlo(pts, Eigen::Vector2d(1, 2), flags); }},
      {"flags too long", [&](IMapperBackend& m) { m.batch_update_iwlo(pts, ints, {true, true, true, true}); }},
      {"weights too short", [&](IMapperBackend& m) { m.batch_update_iwlo(pts, ints, flags, Eigen::Vector2d(1, 1)); }},
      {"negative weight", [&](IMapperBackend& m) { m.batch_update_iwlo(pts, ints, flags, Eigen::Vector3d(1, -1, 1)); }},
      {"NaN weight", [&](IMapperBackend& m) { m.batch_update_iwlo(pts, ints, flags, Eigen::Vector3d(1, 1, kNaN)); }},
      {"point beyond int32 keys", [&](IMapperBackend& m) {
         m.batch_update_iwlo(far_pts, Eigen::Vector2d(100, 100), {true, true});
       }},
      {"scan points N x 4", [&](IMapperBackend& m) { m.insert_scan(Eigen::Vector3d::Zero(), Eigen::MatrixXd::Zero(3, 4), ints); }},
      {"scan intensities too long", [&](IMapperBackend& m) {
         m.insert_scan(Eigen::Vector3d::Zero(), pts, Eigen::Vector4d(1, 2, 3, 4));
       }},
      {"scan origin NaN", [&](IMapperBackend& m) { m.insert_scan(Eigen::Vector3d(kNaN, 0, 0), pts, ints); }},
      {"scan max_range NaN", [&](IMapperBackend& m) { m.insert_scan(Eigen::Vector3d::Zero(), pts, ints, kNaN); }},
      {"set_log_odds values too short", [&](IMapperBackend& m) { m.set_log_odds(pts, Eigen::Vector2d(1, 2)); }},
      {"set_log_odds points N x 1", [&](IMapperBackend& m) { m.set_log_odds(Eigen::MatrixXd::Zero(3, 1), ints); }},
      {"set_log_odds point beyond int32", [&](IMapperBackend& m) { m.set_log_odds(far_pts, Eigen::Vector2d(1, 1)); }},
      {"min_alpha 0", [](IMapperBackend& m) { m.set_iwlo_params(0.1, 0.1, 0.0, -10, 10); }},
      {"L_min >= L_max", [](IMapperBackend& m) { m.set_iwlo_params(0.1, 0.1, 0.3, 5, 5); }},
      {"log_odds_occupied inf", [](IMapperBackend& m) { m.set_log_odds_params(kInf, -3.0); }},
      {"intensity_max NaN", [](IMapperBackend& m) { m.set_intensity_params(35.0, kNaN); }},
      {"adaptive threshold 1", [](IMapperBackend& m) { m.set_adaptive_params(true, 1.0, 0.3); }},
      {"occupied threshold 0", [](IMapperBackend& m) { m.set_occupied_threshold(0.0); }},
      {"set_params decay_rate < 0", [](IMapperBackend& m) {
         IwloParams p;
         p.decay_rate = -0.5;
         m.set_params(p);
       }},
      {"occupied min_probability NaN", [](IMapperBackend& m) { (void)m.get_occupied_voxels(kNaN); }},
      {"occupied min_probability 1.5", [](IMapperBackend& m) { (void)m.get_occupied_voxels(1.5); }},
      {"query NaN", [](IMapperBackend& m) { (void)m.query(Eigen::Vector3d(0, kNaN, 0)); }},
  };
  auto map = this->make(0.25);
  auto ref = this->make_reference(0.25);
  map->batch_update_iwlo(pts, ints, flags);
  ref->batch_update_iwlo(pts, ints, flags);
  const Snapshot before = snapshot(*map);
  const IwloParams params_before = map->get_params();
  for (const auto& [what, call] : calls) {
    SCOPED_TRACE(what);
    const Outcome want = run(call, *ref);
    const Outcome got = run(call, *map);
    EXPECT_NE(want.type, "none");
    EXPECT_EQ(got.type, want.type);
    EXPECT_EQ(got.message, want.message);
    EXPECT_EQ(snapshot(*map), before);
    EXPECT_EQ(map->get_num_skipped_points(), 0u);
    EXPECT_EQ(map->get_params().L_min, params_before.L_min);
    EXPECT_EQ(map->get_params().occupied_threshold, params_before.occupied_threshold);
  }
  expect_same_map(*map, *ref);
}

// ---- a backend of the reference API alone ----

using test_support::ReferenceApiDouble;

// A backend implementing only the reference API's required methods compiles, is created by
// make_backend() once registered, and works through IMapperBackend's defaults: a scan integrated
// by the default insert_scan() gives the RAM backend's map; what cannot be derived says so.
TEST(ReferenceApiBackend, WorksThroughTheDefaultsWhenOnlyRequiredMethodsExist) {
  register_backend("ReferenceDouble", [](double resolution, const BackendOptions&) {
    return std::unique_ptr<IMapperBackend>(std::make_unique<ReferenceApiDouble>(resolution));
  });
  const std::unique_ptr<IMapperBackend> map = make_backend("referencedouble", 0.1);
  ASSERT_EQ(map->get_backend_type(), "ReferenceDouble");
  for (const BackendFeature f : {BackendFeature::kWeights, BackendFeature::kScan, BackendFeature::kQuery,
                                 BackendFeature::kParams, BackendFeature::kSetLogOdds, BackendFeature::kHitStatistics,
                                 BackendFeature::kClone})
    EXPECT_FALSE(map->supports(f));
  ProbabilityUpdater ram(0.1);
  EXPECT_TRUE(ram.supports(BackendFeature::kClone));
  IwloParams p;
  p.intensity_threshold = 20.0;
  p.decay_rate = 0.2;
  map->set_params(p);  // the default: the five grouped setters
  ram.set_params(p);
  EXPECT_EQ(map->get_params().intensity_threshold, 20.0);
  EXPECT_EQ(map->get_params().decay_rate, 0.2);
  SyntheticScanOptions o;
  o.rings = 8;
  o.columns = 256;
  const SyntheticScan scan = make_synthetic_scan(o);
  Eigen::MatrixXd points = scan.points;
  points(3, 1) = kNaN;
  for (int round = 0; round < 2; ++round) {
    map->insert_scan(scan.origin, points, scan.intensities, 18.0);
    ram.insert_scan(scan.origin, points, scan.intensities, 18.0);
  }
  const auto& voxels = dynamic_cast<ReferenceApiDouble&>(*map).voxels();
  EXPECT_EQ(voxels.size(), ram.get_num_known_voxels());
  std::size_t mismatches = 0;
  ram.for_each_voxel([&](const VoxelKey& k, const VoxelState& v) {
    const auto it = voxels.find(k);
    if (it == voxels.end() || it->second.first != static_cast<float>(v.log_odds) || it->second.second != v.count)
      ++mismatches;
  });
  EXPECT_EQ(mismatches, 0u);
  EXPECT_EQ(map->get_num_skipped_points(), 2u);
  EXPECT_EQ(sorted_rows(map->get_occupied_voxels(0.5)), sorted_rows(ram.get_occupied_voxels(0.5)));
  // Weights of 1 reach the unweighted batch; other weights are not supported.
  Eigen::MatrixXd one(1, 3);
  one << 1.05, 2.05, 0.05;
  map->batch_update_iwlo(one, Eigen::VectorXd::Constant(1, 200.0), {true}, Eigen::VectorXd::Constant(1, 1.0));
  EXPECT_THROW(map->batch_update_iwlo(one, Eigen::VectorXd::Constant(1, 200.0), {true}, Eigen::VectorXd::Constant(1, 0.5)),
               std::logic_error);
  EXPECT_THROW(map->batch_update_iwlo(one, Eigen::VectorXd::Constant(1, 200.0), {true}, Eigen::VectorXd::Constant(1, -1.0)),
               std::invalid_argument);
  for (const auto& call : std::vector<std::function<void()>>{
           [&] { (void)map->query({0, 0, 0}); },
           [&] { map->for_each_voxel([](const VoxelKey&, const VoxelState&) {}); },
           [&] { (void)map->clone(); },
           [&] { map->set_hit_accumulation(true); },
           [&] { map->set_log_odds(one, Eigen::VectorXd::Constant(1, 1.0)); }}) {
    try {
      call();
      ADD_FAILURE() << "expected std::logic_error";
    } catch (const std::logic_error& e) {
      EXPECT_NE(std::string(e.what()).find("ReferenceDouble"), std::string::npos) << e.what();
    }
  }
}

}  // namespace
}  // namespace iwlomap
