// SPDX-License-Identifier: BSD-3-Clause
// VoxelColorMeans: per-voxel mean colours against hand-computed values, and the hits it counts
// against the map's own hit statistics.

#include "iwlomap/probability_updater.h"
#include "iwlomap/voxel_colors.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

namespace iwlomap {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

ColorMatrix colors_of(std::initializer_list<Rgb8> list) {
  ColorMatrix m(static_cast<Eigen::Index>(list.size()), 3);
  Eigen::Index i = 0;
  for (const Rgb8& c : list) {
    m(i, 0) = c.r;
    m(i, 1) = c.g;
    m(i, 2) = c.b;
    ++i;
  }
  return m;
}

TEST(VoxelColorMeans, MeansAreRoundedHandComputedAverages) {
  VoxelColorMeans colors(0.1);
  // Voxel (0, 0, 0): r (10 + 11 + 12) / 3 = 11, g (20 + 20 + 21) / 3 = 20.33 -> 20,
  // b (30 + 31 + 31) / 3 = 30.67 -> 31.
  EXPECT_TRUE(colors.add({0.01, 0.02, 0.03}, {10, 20, 30}));
  EXPECT_TRUE(colors.add({0.05, 0.05, 0.05}, {11, 20, 31}));
  EXPECT_TRUE(colors.add({0.09, 0.09, 0.01}, {12, 21, 31}));
  // Voxel (1, 0, 0): halves round up: (1 + 2) / 2 = 1.5 -> 2, (254 + 255) / 2 -> 255, (0 + 1) / 2 -> 1.
  EXPECT_TRUE(colors.add({0.15, 0.05, 0.05}, {1, 254, 0}));
  EXPECT_TRUE(colors.add({0.19, 0.01, 0.09}, {2, 255, 1}));
  EXPECT_FALSE(colors.add({kNaN, 0.0, 0.0}, {255, 255, 255}));

  EXPECT_EQ(colors.size(), 2u);
  EXPECT_EQ(colors.mean({0.05, 0.05, 0.05}), (Rgb8{11, 20, 31}));
  EXPECT_EQ(colors.mean({0.15, 0.05, 0.05}), (Rgb8{2, 255, 1}));
  EXPECT_EQ(colors.hits({0.0, 0.0, 0.0}), 3u);
  EXPECT_EQ(colors.hits({0.1, 0.0, 0.0}), 2u);
  EXPECT_FALSE(colors.mean({-0.05, 0.05, 0.05}).has_value());
  EXPECT_FALSE(colors.mean({kNaN, 0.0, 0.0}).has_value());
  EXPECT_EQ(colors.hits({-0.05, 0.0, 0.0}), 0u);

  Eigen::MatrixXd rows(3, 4);
  rows << 0.05, 0.05, 0.05, 0.9,  //
      0.15, 0.05, 0.05, 0.8,      //
      0.55, 0.05, 0.05, 0.7;
  const ColorMatrix at = colors.colors_at(rows, {7, 8, 9});
  EXPECT_EQ(at, colors_of({{11, 20, 31}, {2, 255, 1}, {7, 8, 9}}));
  EXPECT_GT(colors.memory_bytes(), 0u);
  colors.clear();
  EXPECT_EQ(colors.size(), 0u);
  EXPECT_FALSE(colors.mean({0.05, 0.05, 0.05}).has_value());
}

TEST(VoxelColorMeans, ScansCountTheHitsTheMapCounts) {
  IwloParams params;  // threshold 35
  VoxelColorMeans colors(0.1);
  Eigen::MatrixXd points(6, 3);
  points << 2.05, 0.05, 0.05,  // hit
      2.06, 0.06, 0.06,        // hit in the same voxel: counted too
      2.05, 0.05, 0.05,        // intensity at the threshold: free evidence, no colour
      5.05, 0.05, 0.05,        // beyond max_range 3: clipped, no colour
      kNaN, 0.0, 0.0,          // skipped
      2.05, 1.05, 0.05;        // NaN intensity: skipped
  Eigen::VectorXd intensities(6);
  intensities << 200, 100, 35, 200, 200, kNaN;
  const ColorMatrix rgb = colors_of({{100, 0, 0}, {200, 0, 0}, {0, 255, 0}, {0, 0, 255}, {9, 9, 9}, {9, 9, 9}});
  colors.add_scan(Eigen::Vector3d(0.05, 0.05, 0.05), points, intensities, rgb, params, 3.0);
  EXPECT_EQ(colors.size(), 1u);
  EXPECT_EQ(colors.hits({2.05, 0.05, 0.05}), 2u);
  EXPECT_EQ(colors.mean({2.05, 0.05, 0.05}), (Rgb8{150, 0, 0}));

  VoxelColorMeans batch(0.1);
  batch.add_observations(points, intensities, {true, false, true, true, true, true}, rgb, params);
  // Without rays nothing is clipped: rows 0 and 3 are hits, row 1 is not flagged occupied.
  EXPECT_EQ(batch.size(), 2u);
  EXPECT_EQ(batch.mean({2.05, 0.05, 0.05}), (Rgb8{100, 0, 0}));
  EXPECT_EQ(batch.mean({5.05, 0.05, 0.05}), (Rgb8{0, 0, 255}));
}

// The colour hit counts equal the hits of the RAM backend's statistics, voxel by voxel, on a scan
// with points below the threshold, beyond the range and several hits per voxel.
TEST(VoxelColorMeans, HitCountsEqualTheMapsHitStatistics) {
  ProbabilityUpdater map(0.1);
  map.set_hit_accumulation(true);
  VoxelColorMeans colors(0.1);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::uniform_real_distribution<double> level(0.0, 255.0);
  const int n = 3000;
  Eigen::MatrixXd points(n, 3);
  Eigen::VectorXd intensities(n);
  ColorMatrix rgb(n, 3);
  for (int i = 0; i < n; ++i) {
    const double range = 2.0 + 1.5 * (u(rng) + 1.0);  // 2..5 m, max_range 4
    points.row(i) = Eigen::RowVector3d(range, u(rng), 0.3 * u(rng));
    intensities[i] = level(rng);
    rgb.row(i) << static_cast<std::uint8_t>(i % 256), static_cast<std::uint8_t>(i % 7), 3;
  }
  const Eigen::Vector3d origin(0.05, 0.05, 0.05);
  map.insert_scan(origin, points, intensities, 4.0);
  colors.add_scan(origin, points, intensities, rgb, map.get_params(), 4.0);
  std::size_t voxels_with_hits = 0;
  for (int i = 0; i < n; ++i) {
    const Eigen::Vector3d p = points.row(i).transpose();
    const auto stats = map.hit_statistics(p);
    const std::uint64_t map_hits = stats ? stats->hits : 0;
    EXPECT_EQ(colors.hits(p), map_hits) << "row " << i;
    if (map_hits > 0) ++voxels_with_hits;
  }
  EXPECT_GT(voxels_with_hits, 500u);
  EXPECT_GT(colors.size(), 100u);
}

TEST(VoxelColorMeans, BadInputThrowsAndAddsNothing) {
  EXPECT_THROW(VoxelColorMeans{0.0}, std::invalid_argument);
  EXPECT_THROW(VoxelColorMeans{kNaN}, std::invalid_argument);
  VoxelColorMeans colors(0.1);
  IwloParams params;
  Eigen::MatrixXd points(2, 3);
  points << 1.0, 0.0, 0.0, 1e12, 0.0, 0.0;
  const Eigen::VectorXd intensities = Eigen::VectorXd::Constant(2, 200.0);
  EXPECT_THROW(colors.add_scan(Eigen::Vector3d::Zero(), points, intensities, colors_of({{1, 2, 3}}), params),
               std::invalid_argument);
  EXPECT_THROW(colors.add_scan(Eigen::Vector3d(kNaN, 0, 0), points, intensities, colors_of({{1, 2, 3}, {1, 2, 3}}), params),
               std::invalid_argument);
  EXPECT_THROW(colors.add_observations(points, intensities, {true}, colors_of({{1, 2, 3}, {1, 2, 3}}), params),
               std::invalid_argument);
  // 1e12 m has no key at 0.1 m: the whole call fails before the first point is added.
  EXPECT_THROW(colors.add_observations(points, intensities, {true, true}, colors_of({{1, 2, 3}, {1, 2, 3}}), params),
               std::out_of_range);
  EXPECT_THROW(colors.add(Eigen::Vector3d(1e12, 0, 0), {1, 2, 3}), std::out_of_range);
  EXPECT_EQ(colors.size(), 0u);
  EXPECT_THROW((void)colors.colors_at(Eigen::MatrixXd::Zero(1, 2)), std::invalid_argument);
}

}  // namespace
}  // namespace iwlomap
