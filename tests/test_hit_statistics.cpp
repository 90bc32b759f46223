// SPDX-License-Identifier: BSD-3-Clause
// Hit accumulation of the RAM backend (GMapping-style mean hit positions, hit and visit counts,
// cell entropy) and map entropy, against hand-computed values.

#include "backend_test_support.h"
#include "iwlomap/hit_statistics.h"
#include "iwlomap/map_entropy.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/ray_caster.h"

#include "storage/block_grid.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <map>
#include <random>
#include <stdexcept>
#include <string>
#include <tuple>
#include <vector>

#include <unistd.h>

namespace iwlomap {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

// -(x ln x + (1 - x) ln(1 - x)) computed by hand (Python, double precision).
constexpr double kEntropyOneThird = 0.6365141682948128;   // x = 1/3 and x = 2/3
constexpr double kEntropyOneQuarter = 0.5623351446188083;  // x = 1/4
// -(p log2 p + (1 - p) log2(1 - p)) for p = 0.75 (and 0.25).
constexpr double kBitsThreeQuarters = 0.8112781244591328;

TEST(CellEntropy, MatchesHandComputedValues) {
  EXPECT_DOUBLE_EQ(cell_entropy(0, 0), std::log(2.0));  // unvisited
  EXPECT_DOUBLE_EQ(cell_entropy(0, 5), 0.0);
  EXPECT_DOUBLE_EQ(cell_entropy(5, 5), 0.0);
  EXPECT_DOUBLE_EQ(cell_entropy(1, 2), std::log(2.0));
  EXPECT_DOUBLE_EQ(cell_entropy(1, 3), kEntropyOneThird);
  EXPECT_DOUBLE_EQ(cell_entropy(2, 3), kEntropyOneThird);
  EXPECT_DOUBLE_EQ(cell_entropy(1, 4), kEntropyOneQuarter);
  EXPECT_THROW((void)cell_entropy(3, 2), std::invalid_argument);
}

TEST(HitAccumulation, IsOffByDefaultAndTheVoxelStaysWithin8Bytes) {
  static_assert(sizeof(detail::Voxel) <= 8, "the default voxel must stay within 8 bytes");
  ProbabilityUpdater map(0.1);
  EXPECT_FALSE(map.get_hit_accumulation());
  EXPECT_THROW((void)map.hit_statistics({0, 0, 0}), std::logic_error);
  EXPECT_THROW((void)map.get_occupied_mean_positions(0.5), std::logic_error);
  Eigen::MatrixXd p(1, 3);
  p << 0.05, 0.05, 0.05;
  map.batch_update_iwlo(p, Eigen::VectorXd::Constant(1, 200.0), {true});
  const double before = map.get_memory_usage().memory_mb;
  map.set_hit_accumulation(true);
  map.batch_update_iwlo(p, Eigen::VectorXd::Constant(1, 200.0), {true});
  EXPECT_GT(map.get_memory_usage().memory_mb, before);
  map.set_hit_accumulation(false);
  EXPECT_DOUBLE_EQ(map.get_memory_usage().memory_mb, before);
  EXPECT_THROW((void)map.hit_statistics({0, 0, 0}), std::logic_error);
}

// The Disk backend keeps the statistics in its tiles: through eviction, flush and reopen they stay
// the RAM backend's; the setting is part of the map; off, then on again, starts from empty ones.
TEST(HitAccumulation, DiskKeepsStatisticsInTilesAcrossEvictionAndReopen) {
  const auto dir = std::filesystem::temp_directory_path() / ("iwlomap_hits_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  ProbabilityUpdater ram(0.1);
  ram.set_hit_accumulation(true);
  std::mt19937 rng(19u);
  std::uniform_real_distribution<double> c(-6.0, 6.0);
  Eigen::MatrixXd p(4000, 3);
  for (Eigen::Index i = 0; i < p.rows(); ++i) p.row(i) << c(rng), c(rng), 0.3 * c(rng);
  const Eigen::VectorXd in = Eigen::VectorXd::LinSpaced(p.rows(), 10.0, 250.0);
  const std::vector<bool> occ(static_cast<std::size_t>(p.rows()), true);
  {
    OutofcoreTileMapper disk(dir.string(), 0.1, 1.6, 2);  // 16-voxel tiles, 2 resident: many evictions
    EXPECT_FALSE(disk.get_hit_accumulation());
    EXPECT_THROW((void)disk.hit_statistics({0, 0, 0}), std::logic_error);
    disk.set_hit_accumulation(true);
    for (IMapperBackend* m : {static_cast<IMapperBackend*>(&disk), static_cast<IMapperBackend*>(&ram)}) {
      m->insert_scan({0.1, 0.2, 0.3}, p, in, 5.0);
      m->batch_update_iwlo(p, in, occ);
    }
    EXPECT_GT(disk.get_num_tiles(), 10u);
    EXPECT_EQ(test_support::sorted_rows(disk.get_occupied_mean_positions(0.5)),
              test_support::sorted_rows(ram.get_occupied_mean_positions(0.5)));
  }
  {
    OutofcoreTileMapper reopened(dir.string(), 0.1, 1.6, 2);
    EXPECT_TRUE(reopened.get_hit_accumulation());  // the setting is the map's
    EXPECT_EQ(test_support::sorted_rows(reopened.get_occupied_mean_positions(0.5)),
              test_support::sorted_rows(ram.get_occupied_mean_positions(0.5)));
    const auto s = reopened.hit_statistics(p.row(7).transpose());
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->visits, ram.hit_statistics(p.row(7).transpose())->visits);
    reopened.set_hit_accumulation(false);
    reopened.set_hit_accumulation(true);  // a new epoch: what the tiles hold is void
    EXPECT_FALSE(reopened.hit_statistics(p.row(7).transpose()).has_value());
    const Eigen::MatrixXd centres = reopened.get_occupied_voxels(0.5);
    EXPECT_EQ(reopened.get_occupied_mean_positions(0.5), centres);
  }
  std::filesystem::remove_all(dir);
}

// One scan with rays along +x, +y and +z from the centre of voxel (0, 0, 0) at 0.1 m (see
// hit_statistics.h for the rules being checked):
//   A (0.55), B (0.57): hits in voxel (5, 0, 0); rays visit (0..4, 0, 0)
//   C (0.85): hit in (8, 0, 0); the ray visits (0..7, 0, 0), so it also visits (5, 0, 0)
//   D (0, 0.35, 0) at intensity 10 <= 35: free evidence, visits (0, 0..3, 0), no hit
//   E (0, 0, 1.55) beyond max_range 1.0: clipped ray visits (0, 0, 0..9), no hit
void insert_test_scan(ProbabilityUpdater& map) {
  Eigen::MatrixXd points(5, 3);
  points << 0.55, 0.05, 0.05,  //
      0.57, 0.05, 0.05,        //
      0.85, 0.05, 0.05,        //
      0.05, 0.35, 0.05,        //
      0.05, 0.05, 1.55;
  Eigen::VectorXd intensities(5);
  intensities << 200, 150, 200, 10, 200;
  map.insert_scan({0.05, 0.05, 0.05}, points, intensities, 1.0);
}

Eigen::Vector3d centre(int x, int y, int z) { return key_to_center({x, y, z}, 0.1); }

TEST(HitAccumulation, InsertScanCountsEveryRayAsGMappingCountsBeams) {
  ProbabilityUpdater map(0.1);
  map.set_hit_accumulation(true);
  insert_test_scan(map);

  const auto s5 = map.hit_statistics(centre(5, 0, 0));
  ASSERT_TRUE(s5.has_value());
  EXPECT_EQ(s5->hits, 2u);
  EXPECT_EQ(s5->visits, 3u);
  EXPECT_NEAR(s5->mean_hit_position.x(), 0.56, 1e-12);
  EXPECT_NEAR(s5->mean_hit_position.y(), 0.05, 1e-12);
  EXPECT_NEAR(s5->mean_hit_position.z(), 0.05, 1e-12);
  EXPECT_DOUBLE_EQ(s5->entropy, kEntropyOneThird);
  // The occupancy update still counts one observation per voxel per scan: occupied wins.
  EXPECT_EQ(map.query(centre(5, 0, 0))->count, 1u);
  EXPECT_GT(map.query(centre(5, 0, 0))->probability, 0.5);

  const auto s8 = map.hit_statistics(centre(8, 0, 0));
  ASSERT_TRUE(s8.has_value());
  EXPECT_EQ(s8->hits, 1u);
  EXPECT_EQ(s8->visits, 1u);
  EXPECT_DOUBLE_EQ(s8->entropy, 0.0);

  const auto s0 = map.hit_statistics(centre(0, 0, 0));
  ASSERT_TRUE(s0.has_value());
  EXPECT_EQ(s0->visits, 5u);  // every ray starts there
  EXPECT_EQ(s0->hits, 0u);
  EXPECT_EQ(s0->mean_hit_position, centre(0, 0, 0));  // no hit: the centre
  EXPECT_DOUBLE_EQ(s0->entropy, 0.0);

  EXPECT_EQ(map.hit_statistics(centre(4, 0, 0))->visits, 3u);
  EXPECT_EQ(map.hit_statistics(centre(6, 0, 0))->visits, 1u);
  const auto d = map.hit_statistics(centre(0, 3, 0));  // the low-intensity endpoint
  ASSERT_TRUE(d.has_value());
  EXPECT_EQ(d->hits, 0u);
  EXPECT_EQ(d->visits, 1u);
  EXPECT_EQ(map.hit_statistics(centre(0, 0, 9))->visits, 1u);  // last voxel of the clipped ray
  EXPECT_FALSE(map.hit_statistics(centre(0, 0, 10)).has_value());
  EXPECT_FALSE(map.hit_statistics(centre(0, 0, 15)).has_value());  // beyond max_range: no hit
  EXPECT_FALSE(map.hit_statistics(centre(9, 0, 0)).has_value());

  // A second scan adds to the counts; threads do not change them.
  map.set_num_threads(2);
  insert_test_scan(map);
  EXPECT_EQ(map.hit_statistics(centre(5, 0, 0))->hits, 4u);
  EXPECT_EQ(map.hit_statistics(centre(5, 0, 0))->visits, 6u);
  EXPECT_EQ(map.hit_statistics(centre(0, 0, 0))->visits, 10u);
  EXPECT_DOUBLE_EQ(map.hit_statistics(centre(5, 0, 0))->entropy, kEntropyOneThird);
}

// The statistics are gathered in the scan's own ray walk; with threads the walk is split, and the
// counts and mean positions must still be those of the rays taken one by one in order.
TEST(HitAccumulation, ScanStatisticsMatchRaysCastOneByOneForAnyThreadCountAndBackend) {
  constexpr double kRes = 0.05;
  std::mt19937 rng(23u);
  std::uniform_real_distribution<double> c(-3.0, 3.0);
  Eigen::MatrixXd p(12000, 3);  // enough rays for the walk to take two threads
  for (Eigen::Index i = 0; i < p.rows(); ++i) p.row(i) << c(rng), c(rng), 0.5 * c(rng);
  Eigen::VectorXd in(p.rows());
  for (Eigen::Index i = 0; i < p.rows(); ++i) in[i] = i % 5 == 0 ? 10.0 : 200.0;  // a fifth below the threshold
  const Eigen::Vector3d origin(0.01, -0.02, 0.03);
  const double threshold = ProbabilityUpdater(kRes).get_params().intensity_threshold;

  // The reference: each ray cast on its own, in order; its end a hit or a visit.
  struct Ref {
    std::uint32_t hits = 0, visits = 0;
    Eigen::Vector3d offsets = Eigen::Vector3d::Zero();
  };
  std::map<std::tuple<int, int, int>, Ref> ref;
  for (Eigen::Index i = 0; i < p.rows(); ++i) {
    const Eigen::Vector3d q = p.row(i).transpose();
    cast_ray(origin, q, kRes, [&](const VoxelKey& k) { ++ref[{k.x, k.y, k.z}].visits; });
    const VoxelKey k = world_to_key(q, kRes);
    Ref& r = ref[{k.x, k.y, k.z}];
    ++r.visits;
    if (in[i] > threshold) {
      ++r.hits;
      r.offsets += q - key_to_center(k, kRes);
    }
  }

  test_support::TempDir dir;
  ProbabilityUpdater one(kRes), two(kRes);
  OutofcoreTileMapper disk(dir.sub("map"), kRes, 0.8, 4);  // 16-voxel tiles, 4 resident
  two.set_num_threads(2);
  disk.set_num_threads(2);
  for (IMapperBackend* m : {static_cast<IMapperBackend*>(&one), static_cast<IMapperBackend*>(&two),
                            static_cast<IMapperBackend*>(&disk)}) {
    m->set_hit_accumulation(true);
    m->insert_scan(origin, p, in);
  }
  std::size_t checked = 0;
  for (const auto& [xyz, r] : ref) {
    const Eigen::Vector3d at = key_to_center({std::get<0>(xyz), std::get<1>(xyz), std::get<2>(xyz)}, kRes);
    const auto s1 = one.hit_statistics(at);
    ASSERT_TRUE(s1.has_value());
    ASSERT_EQ(s1->visits, r.visits);
    ASSERT_EQ(s1->hits, r.hits);
    if (r.hits > 0) {
      const Eigen::Vector3d mean = at + r.offsets / static_cast<double>(r.hits);
      ASSERT_NEAR((s1->mean_hit_position - mean).norm(), 0.0, 1e-12);
    }
    for (const IMapperBackend* m : {static_cast<const IMapperBackend*>(&two), static_cast<const IMapperBackend*>(&disk)}) {
      const auto s = m->hit_statistics(at);
      ASSERT_TRUE(s.has_value());
      ASSERT_EQ(s->visits, s1->visits);
      ASSERT_EQ(s->hits, s1->hits);
      ASSERT_EQ(s->mean_hit_position, s1->mean_hit_position);  // bit for bit
    }
    ++checked;
  }
  EXPECT_GT(checked, 100000u);
  EXPECT_GT(disk.get_num_tiles(), 4u);  // several tile groups
}

TEST(HitAccumulation, BatchCountsOccupiedObservationsAsHitsAndAllAsVisits) {
  ProbabilityUpdater map(0.1);
  map.set_hit_accumulation(true);
  Eigen::MatrixXd points(7, 3);
  points << 0.01, 0.02, 0.03,  // occupied: hit
      0.05, 0.05, 0.05,        // flag off: visit
      0.09, 0.08, 0.07,        // intensity 10 <= 35: visit
      kNaN, 0.0, 0.0,          // skipped
      0.03, 0.04, 0.05,        // intensity NaN: skipped
      0.07, 0.06, 0.01,        // occupied: hit
      0.15, 0.05, 0.05;        // voxel (1, 0, 0), weight 0: still a hit and a visit
  Eigen::VectorXd intensities(7);
  intensities << 200, 200, 10, 200, kNaN, 100, 200;
  Eigen::VectorXd weights = Eigen::VectorXd::Ones(7);
  weights[6] = 0.0;
  map.batch_update_iwlo(points, intensities, {true, false, true, true, true, true, true}, weights);
  const auto s = map.hit_statistics({0.05, 0.05, 0.05});
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->hits, 2u);
  EXPECT_EQ(s->visits, 4u);
  EXPECT_NEAR(s->mean_hit_position.x(), 0.04, 1e-12);
  EXPECT_NEAR(s->mean_hit_position.y(), 0.04, 1e-12);
  EXPECT_NEAR(s->mean_hit_position.z(), 0.02, 1e-12);
  EXPECT_DOUBLE_EQ(s->entropy, std::log(2.0));
  EXPECT_EQ(map.hit_statistics({0.15, 0.05, 0.05})->hits, 1u);

  // Three free observations more: 1 hit in 4 visits.
  Eigen::MatrixXd q(4, 3);
  q << 0.15, 0.05, 0.05, 0.15, 0.05, 0.05, 0.15, 0.05, 0.05, 0.15, 0.05, 0.05;
  map.batch_update_iwlo(q.topRows(3), Eigen::VectorXd::Constant(3, 200.0), {false, false, false});
  EXPECT_DOUBLE_EQ(map.hit_statistics({0.15, 0.05, 0.05})->entropy, kEntropyOneQuarter);
}

TEST(HitAccumulation, OnAgainKeepsClearEmptiesAndImportsAddNothing) {
  ProbabilityUpdater map(0.1);
  map.set_hit_accumulation(true);
  insert_test_scan(map);
  map.set_hit_accumulation(true);
  EXPECT_EQ(map.hit_statistics(centre(5, 0, 0))->hits, 2u);
  map.clear();
  EXPECT_TRUE(map.get_hit_accumulation());
  EXPECT_FALSE(map.hit_statistics(centre(5, 0, 0)).has_value());
  Eigen::MatrixXd p(1, 3);
  p << 0.25, 0.05, 0.05;
  map.set_log_odds(p, Eigen::VectorXd::Constant(1, 5.0));
  EXPECT_FALSE(map.hit_statistics(p.row(0).transpose()).has_value());
  // An occupied voxel without hits is output at its centre.
  const Eigen::MatrixXd means = map.get_occupied_mean_positions(0.5);
  ASSERT_EQ(means.rows(), 1);
  EXPECT_TRUE(means.row(0).head<3>().transpose().isApprox(centre(2, 0, 0)));
  EXPECT_THROW((void)map.hit_statistics({kNaN, 0, 0}), std::invalid_argument);
}

// The check: a plane at z = 0.013 m mapped at 0.05 m. Voxel centres sit at z = 0.025
// (0.012 m off); mean hit positions recover the plane to well within 0.005 m.
struct PlaneError {
  double centre_max = 0.0;
  double mean_max = 0.0;
  Eigen::Index occupied = 0;
};

PlaneError map_plane(double plane_z, double noise, bool ray_casting) {
  ProbabilityUpdater map(0.05);
  map.set_hit_accumulation(true);
  std::mt19937 rng(42);
  std::uniform_real_distribution<double> xy(-0.5, 0.5);
  std::normal_distribution<double> dz(0.0, noise);
  const Eigen::Index n = 40000;
  Eigen::MatrixXd points(n, 3);
  for (Eigen::Index i = 0; i < n; ++i) points.row(i) << xy(rng), xy(rng), plane_z + (noise > 0 ? dz(rng) : 0.0);
  const Eigen::VectorXd intensities = Eigen::VectorXd::Constant(n, 200.0);
  if (ray_casting)
    map.insert_scan({0.1, -0.2, 1.0}, points, intensities);
  else
    map.batch_update_iwlo(points, intensities, std::vector<bool>(static_cast<std::size_t>(n), true));
  const Eigen::MatrixXd centres = map.get_occupied_voxels(0.5);
  const Eigen::MatrixXd means = map.get_occupied_mean_positions(0.5);
  EXPECT_EQ(centres.rows(), means.rows());
  PlaneError e;
  e.occupied = centres.rows();
  for (Eigen::Index i = 0; i < centres.rows(); ++i) {
    EXPECT_EQ(centres(i, 3), means(i, 3));  // same rows, same order
    EXPECT_LE((means.row(i).head<2>() - centres.row(i).head<2>()).cwiseAbs().maxCoeff(), 0.025 + 1e-12);
    e.centre_max = std::max(e.centre_max, std::abs(centres(i, 2) - plane_z));
    e.mean_max = std::max(e.mean_max, std::abs(means(i, 2) - plane_z));
  }
  return e;
}

TEST(HitAccumulation, MeanPositionsRecoverAPlaneAt13MillimetresWithin5) {
  for (const bool rays : {true, false}) {
    const PlaneError e = map_plane(0.013, 0.002, rays);
    EXPECT_GE(e.occupied, 350);  // the 20 x 20 voxels of the plane
    EXPECT_LT(e.mean_max, 0.005) << (rays ? "insert_scan" : "batch_update_iwlo");
    EXPECT_NEAR(e.centre_max, 0.012, 1e-9);
    EXPECT_LE(e.centre_max, 0.025);
    std::printf("[ plane z = 0.013, %s ] max |z - 0.013|: voxel centres %.4f m, mean hit positions %.5f m\n",
                rays ? "insert_scan" : "batch", e.centre_max, e.mean_max);
  }
  // Noise-free planes across the voxel: centres are off by up to half a voxel, means are exact.
  for (const double z : {0.001, 0.024, 0.026, 0.049}) {
    const PlaneError e = map_plane(z, 0.0, true);
    const double centre_error = std::abs((std::floor(z / 0.05) + 0.5) * 0.05 - z);
    EXPECT_NEAR(e.centre_max, centre_error, 1e-9) << "z = " << z;
    EXPECT_LE(e.centre_max, 0.025);
    EXPECT_LT(e.mean_max, 1e-9) << "z = " << z;
  }
}

TEST(MapEntropy, MatchesHandComputedValuesInBits) {
  EXPECT_DOUBLE_EQ(occupancy_entropy_bits(0.5), 1.0);
  EXPECT_DOUBLE_EQ(occupancy_entropy_bits(0.0), 0.0);
  EXPECT_DOUBLE_EQ(occupancy_entropy_bits(1.0), 0.0);
  EXPECT_DOUBLE_EQ(occupancy_entropy_bits(0.75), kBitsThreeQuarters);
  EXPECT_DOUBLE_EQ(occupancy_entropy_bits(0.25), kBitsThreeQuarters);
  EXPECT_THROW((void)occupancy_entropy_bits(kNaN), std::invalid_argument);
  EXPECT_THROW((void)occupancy_entropy_bits(1.5), std::invalid_argument);

  ProbabilityUpdater map(0.1);
  EXPECT_DOUBLE_EQ(map_entropy_bits(map), 0.0);
  Eigen::MatrixXd points(4, 3);
  points << 0.05, 0.05, 0.05,  // key (0, 0, 0): p = 0.5
      0.15, 0.05, 0.05,        // key (1, 0, 0): p = 0.75
      0.05, 0.15, 0.05,        // key (0, 1, 0): p = 0.25
      5.05, 0.05, 0.05;        // key (50, 0, 0): p = 0.5, outside the box below
  Eigen::VectorXd log_odds(4);
  log_odds << 0.0, std::log(3.0), -std::log(3.0), 0.0;
  map.set_log_odds(points, log_odds);
  // Log-odds are stored as float, hence the tolerance.
  EXPECT_NEAR(map_entropy_bits(map), 2.0 + 2.0 * kBitsThreeQuarters, 1e-6);

  const VoxelBox box{{0, 0, 0}, {3, 3, 3}};  // 64 voxels
  const BoxEntropy e = box_entropy(map, box);
  EXPECT_EQ(e.known_voxels, 3u);
  EXPECT_EQ(e.unknown_voxels, 61u);
  EXPECT_NEAR(e.known_bits, 1.0 + 2.0 * kBitsThreeQuarters, 1e-6);
  EXPECT_NEAR(e.total_bits(), 62.0 + 2.0 * kBitsThreeQuarters, 1e-6);
  EXPECT_EQ(count_unknown_voxels(map, box), 61u);
  EXPECT_EQ(count_unknown_voxels(map, VoxelBox{{100, 0, 0}, {101, 1, 0}}), 4u);
  EXPECT_THROW((void)box_entropy(map, VoxelBox{{1, 0, 0}, {0, 0, 0}}), std::invalid_argument);
}

}  // namespace
}  // namespace iwlomap
