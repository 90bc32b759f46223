// SPDX-License-Identifier: BSD-3-Clause
// Precomputation grids against brute force: every cell of the grown grid of random 2D and 3D
// grids for widths 1..64, the stack's box maxima, the 8-bit discretization, and grids taken from
// a map (frames, slices, columns).

#include "iwlomap/precomputation_grid.h"
#include "iwlomap/precomputation_stack.h"
#include "iwlomap/probability_updater.h"
#include "repetitions.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap {
namespace {

// Random values; a small alphabet makes ties frequent, which is where a monotonic deque that pops
// equal values wrongly would fail.
std::vector<std::uint8_t> random_values(std::size_t n, std::mt19937& rng, bool few_levels) {
  std::uniform_int_distribution<int> any(0, 255), pick(0, 3);
  const std::uint8_t levels[4] = {0, 0, 128, 255};
  std::vector<std::uint8_t> v(n);
  for (auto& x : v) x = few_levels ? levels[pick(rng)] : static_cast<std::uint8_t>(any(rng));
  return v;
}

// Brute force: the maximum of base cells s - w + 1 .. s (per axis) that lie in the base grid.
std::uint8_t brute_2d(const DiscreteGrid2D& g, int w, int si, int sj) {
  std::uint8_t m = 0;
  for (int j = std::max(0, sj - w + 1); j <= std::min(g.size().y() - 1, sj); ++j)
    for (int i = std::max(0, si - w + 1); i <= std::min(g.size().x() - 1, si); ++i)
      m = std::max(m, g.values()[g.offset({i, j})]);
  return m;
}

std::uint8_t brute_3d(const DiscreteGrid3D& g, int w, int si, int sj, int sk) {
  std::uint8_t m = 0;
  for (int k = std::max(0, sk - w + 1); k <= std::min(g.size().z() - 1, sk); ++k)
    for (int j = std::max(0, sj - w + 1); j <= std::min(g.size().y() - 1, sj); ++j)
      for (int i = std::max(0, si - w + 1); i <= std::min(g.size().x() - 1, si); ++i)
        m = std::max(m, g.values()[g.offset({i, j, k})]);
  return m;
}

void expect_all_cells_2d(const DiscreteGrid2D& base, int w) {
  const PrecomputationGrid2D grid(base, w);
  ASSERT_EQ(grid.size(), Eigen::Vector2i(base.size().x() + w - 1, base.size().y() + w - 1));
  int mismatches = 0;
  for (int j = 0; j < grid.size().y(); ++j)
    for (int i = 0; i < grid.size().x(); ++i)
      if (grid.value(i, j) != brute_2d(base, w, i, j) && ++mismatches <= 3)
        ADD_FAILURE() << "w = " << w << ", base " << base.size().transpose() << ", cell (" << i << ", " << j
                      << "): " << int(grid.value(i, j)) << " != " << int(brute_2d(base, w, i, j));
  EXPECT_EQ(mismatches, 0) << "w = " << w;
}

TEST(PrecomputationGrid2D, EveryCellMatchesBruteForceForWidths1To64) {
  std::mt19937 rng(7);
  const Eigen::Vector2i sizes[] = {{1, 1}, {1, 50}, {50, 1}, {37, 23}, {64, 65}};
  for (const auto& size : sizes)
    for (const bool few : {false, true}) {
      const DiscreteGrid2D base(size, random_values(static_cast<std::size_t>(size.prod()), rng, few));
      for (int w = 1; w <= 64; ++w) expect_all_cells_2d(base, w);
    }
}

TEST(PrecomputationGrid3D, EveryCellMatchesBruteForceForWidths1To64) {
  std::mt19937 rng(11);
  for (const bool few : {false, true}) {
    const Eigen::Vector3i size(5, 4, 3);
    const DiscreteGrid3D base(size, random_values(static_cast<std::size_t>(size.prod()), rng, few));
    for (int w = 1; w <= 64; ++w) {
      const PrecomputationGrid3D grid(base, w);
      ASSERT_EQ(grid.size(), Eigen::Vector3i(5 + w - 1, 4 + w - 1, 3 + w - 1));
      int mismatches = 0;
      for (int k = 0; k < grid.size().z(); ++k)
        for (int j = 0; j < grid.size().y(); ++j)
          for (int i = 0; i < grid.size().x(); ++i)
            if (grid.value(i, j, k) != brute_3d(base, w, i, j, k)) ++mismatches;
      EXPECT_EQ(mismatches, 0) << "w = " << w;
    }
  }
}

// A larger 3D grid: every cell for the narrow widths; for the wide ones (where brute force over
// ~10^6 grown cells times the window is too slow for a unit test) the 8 corners of the grown grid,
// every cell of three planes through the border and the interior, and 20,000 random cells.
TEST(PrecomputationGrid3D, LargerGridMatchesBruteForceForWidths1To64) {
  std::mt19937 rng(13);
  const Eigen::Vector3i size(23, 19, 17);
  const DiscreteGrid3D base(size, random_values(static_cast<std::size_t>(size.prod()), rng, false));
  for (int w = 1; w <= 64; ++w) {
    const PrecomputationGrid3D grid(base, w);
    const Eigen::Vector3i n = grid.size();
    int mismatches = 0;
    const auto check = [&](int i, int j, int k) {
      if (grid.value(i, j, k) != brute_3d(base, w, i, j, k) && ++mismatches <= 3)
        ADD_FAILURE() << "w = " << w << ", cell (" << i << ", " << j << ", " << k << ")";
    };
    if (w <= 12) {
      for (int k = 0; k < n.z(); ++k)
        for (int j = 0; j < n.y(); ++j)
          for (int i = 0; i < n.x(); ++i) check(i, j, k);
    } else {
      for (int c = 0; c < 8; ++c) check(c & 1 ? n.x() - 1 : 0, c & 2 ? n.y() - 1 : 0, c & 4 ? n.z() - 1 : 0);
      for (const int k : {0, w / 2, n.z() - 1})
        for (int j = 0; j < n.y(); ++j)
          for (int i = 0; i < n.x(); ++i) check(i, j, k);
      std::uniform_int_distribution<int> di(0, n.x() - 1), dj(0, n.y() - 1), dk(0, n.z() - 1);
      for (int s = 0; s < test_support::repetitions(20000, 2000); ++s) check(di(rng), dj(rng), dk(rng));
    }
    EXPECT_EQ(mismatches, 0) << "w = " << w;
  }
}

TEST(PrecomputationGrid2D, WindowMaxIsTheValueAtTheWindowsHighestCellAndZeroOutside) {
  std::mt19937 rng(3);
  const DiscreteGrid2D base({9, 6}, random_values(54, rng, false));
  for (const int w : {1, 2, 4, 5, 16}) {
    const PrecomputationGrid2D grid(base, w);
    for (int j = -w - 2; j < 6 + 2; ++j)
      for (int i = -w - 2; i < 9 + 2; ++i) {
        const bool inside = i + w - 1 >= 0 && i + w - 1 < grid.size().x() && j + w - 1 >= 0 && j + w - 1 < grid.size().y();
        const std::uint8_t expected = inside ? grid.value(i + w - 1, j + w - 1) : 0;
        EXPECT_EQ(grid.window_max({i, j}), expected) << "w = " << w << " corner (" << i << ", " << j << ")";
        if (inside) {
          EXPECT_EQ(grid.window_max({i, j}), brute_2d(base, w, i + w - 1, j + w - 1));
        }
      }
  }
  const PrecomputationGrid2D grid(base, 4);
  EXPECT_EQ(grid.window_max({std::numeric_limits<int>::max(), 0}), 0);
  EXPECT_EQ(grid.window_max({std::numeric_limits<int>::min(), 0}), 0);
}

TEST(PrecomputationGrid2D, WidthOneIsTheBaseGrid) {
  std::mt19937 rng(5);
  const DiscreteGrid2D base({13, 7}, random_values(91, rng, false));
  EXPECT_EQ(PrecomputationGrid2D(base, 1).values(), base.values());
}

TEST(PrecomputationGrid2D, RejectsBadWidthsSizesAndCells) {
  const DiscreteGrid2D base({4, 3});
  EXPECT_THROW(PrecomputationGrid2D(base, 0), std::invalid_argument);
  EXPECT_THROW(PrecomputationGrid2D(base, -3), std::invalid_argument);
  EXPECT_THROW(DiscreteGrid2D(Eigen::Vector2i(0, 3)), std::invalid_argument);
  EXPECT_THROW(DiscreteGrid2D(Eigen::Vector2i(4, 3), std::vector<std::uint8_t>(11)), std::invalid_argument);
  EXPECT_THROW(DiscreteGrid3D(Eigen::Vector3i(2048, 2048, 2048)), std::length_error);
  EXPECT_THROW(PrecomputationGrid2D(DiscreteGrid2D({1, 1}), std::numeric_limits<int>::max()), std::length_error);
  const PrecomputationGrid2D grid(base, 2);
  EXPECT_THROW((void)grid.value(5, 0), std::out_of_range);
  EXPECT_THROW((void)grid.value(0, -1), std::out_of_range);
  try {
    (void)grid.value(5, 0);
  } catch (const std::out_of_range& e) {
    EXPECT_NE(std::string(e.what()).find("(5, 0)"), std::string::npos) << e.what();
  }
}

TEST(ProbabilityToValue, IsCartographersDiscretization) {
  EXPECT_EQ(probability_to_value(0.0), 0);
  EXPECT_EQ(probability_to_value(0.1), 0);
  EXPECT_EQ(probability_to_value(0.5), 128);  // 127.5, rounded half away from zero
  EXPECT_EQ(probability_to_value(0.9), 255);
  EXPECT_EQ(probability_to_value(1.0), 255);
  EXPECT_EQ(probability_to_value(0.3), 64);   // 63.75
  EXPECT_EQ(probability_to_value(0.7), 191);  // 191.25
  EXPECT_EQ(probability_to_value(-1.0), 0);   // clamped like any other value
  EXPECT_EQ(probability_to_value(2.0), 255);
  EXPECT_EQ(kUnknownValue, 0);
  EXPECT_THROW((void)probability_to_value(std::numeric_limits<double>::quiet_NaN()), std::invalid_argument);
  for (int v = 0; v <= 255; ++v)
    EXPECT_EQ(probability_to_value(value_to_probability(static_cast<std::uint8_t>(v))), v) << "value " << v;
}

TEST(ProbabilityToValue, UnknownVoxelsOfAMapAreZero) {
  ProbabilityUpdater map(0.5);
  Eigen::MatrixXd points(2, 3);
  points << 0.25, 0.25, 0.25, 1.25, 0.25, 0.25;
  Eigen::VectorXd log_odds(2);
  log_odds << 0.0, -5.0;  // p = 0.5 and p ~ 0.0067
  map.set_log_odds(points, log_odds);
  const DiscreteGrid3D grid = discretize_volume(map, VoxelBox{{0, 0, 0}, {3, 0, 0}});
  EXPECT_EQ(grid.at({0, 0, 0}), 128);
  EXPECT_EQ(grid.at({1, 0, 0}), 0);  // free
  EXPECT_EQ(grid.at({2, 0, 0}), 0);  // unknown
  EXPECT_EQ(grid.at({3, 0, 0}), 0);
}

// A small map with voxels at negative and positive keys, some outside the box.
ProbabilityUpdater make_map() {
  ProbabilityUpdater map(0.1);
  const std::vector<std::pair<Eigen::Vector3d, double>> voxels = {
      {{-0.25, -0.15, 0.05}, 10.0},   // key (-3, -2, 0): p ~ 1 -> 255
      {{-0.25, -0.15, 0.25}, 0.0},    // key (-3, -2, 2): p = 0.5 -> 128
      {{0.15, 0.05, 0.15}, 10.0},     // key (1, 0, 1)
      {{0.15, 0.05, -0.35}, 10.0},    // key (1, 0, -4): below the box
      {{5.0, 0.05, 0.05}, 10.0},      // key (50, 0, 0): outside the box
  };
  Eigen::MatrixXd points(static_cast<Eigen::Index>(voxels.size()), 3);
  Eigen::VectorXd log_odds(static_cast<Eigen::Index>(voxels.size()));
  for (std::size_t i = 0; i < voxels.size(); ++i) {
    points.row(static_cast<Eigen::Index>(i)) = voxels[i].first.transpose();
    log_odds[static_cast<Eigen::Index>(i)] = voxels[i].second;
  }
  map.set_log_odds(points, log_odds);
  return map;
}

TEST(DiscretizeMap, VolumeColumnAndSliceUseTheBoxFrame) {
  const ProbabilityUpdater map = make_map();
  const VoxelBox box{{-4, -3, -1}, {2, 1, 3}};
  const DiscreteGrid3D volume = discretize_volume(map, box);
  EXPECT_EQ(volume.size(), Eigen::Vector3i(7, 5, 5));
  EXPECT_EQ(volume.frame().origin, box.min);
  EXPECT_DOUBLE_EQ(volume.frame().resolution, 0.1);
  EXPECT_EQ(volume.at({1, 1, 1}), 255);  // key (-3, -2, 0) = origin + (1, 1, 1)
  EXPECT_EQ(volume.at({1, 1, 3}), 128);
  EXPECT_EQ(volume.at({5, 3, 2}), 255);  // key (1, 0, 1)
  EXPECT_EQ(volume.key_of({5, 3, 2}), (VoxelKey{1, 0, 1}));
  int nonzero = 0;
  for (const auto v : volume.values()) nonzero += v != 0;
  EXPECT_EQ(nonzero, 3);  // the voxels below and beside the box are left out

  const DiscreteGrid2D column = discretize_column_max(map, box);
  EXPECT_EQ(column.size(), Eigen::Vector2i(7, 5));
  EXPECT_EQ(column.at({1, 1}), 255);  // max of 255 and 128
  EXPECT_EQ(column.at({5, 3}), 255);
  EXPECT_EQ(column.frame().origin, box.min);

  const DiscreteGrid2D slice = discretize_slice(map, box, 0.25);  // z key 2
  EXPECT_EQ(slice.at({1, 1}), 128);
  EXPECT_EQ(slice.at({5, 3}), 0);
  EXPECT_EQ(slice.frame().origin, (VoxelKey{-4, -3, 2}));
  const DiscreteGrid2D below = discretize_slice(map, box, -0.35);  // outside the box's z range: its own z
  EXPECT_EQ(below.at({5, 3}), 255);
  EXPECT_THROW((void)discretize_slice(map, box, std::numeric_limits<double>::infinity()), std::invalid_argument);
  EXPECT_THROW((void)discretize_volume(map, VoxelBox{{0, 0, 0}, {-1, 0, 0}}), std::invalid_argument);
}

TEST(DiscretizeMap, PrecomputationCellZeroEndsAtTheBoxOrigin) {
  const ProbabilityUpdater map = make_map();
  const VoxelBox box{{-3, -2, 0}, {2, 1, 0}};
  const PrecomputationGrid2D grid(discretize_slice(map, box, 0.05), 4);
  // Cell 0's window is keys origin - 3 .. origin; the occupied voxel at the origin is in it.
  EXPECT_EQ(grid.window_min_key({0, 0}), (VoxelKey{-6, -5, 0}));
  EXPECT_EQ(grid.value(0, 0), 255);
  EXPECT_EQ(grid.value(3, 3), 255);
  EXPECT_EQ(grid.value(4, 3), 0);  // its window, keys -2 .. 1 along x, starts past the voxel
  EXPECT_EQ(grid.window_max({0, 0}), 255);   // base window 0..3 holds the origin voxel
  EXPECT_EQ(grid.window_max({-3, -3}), 255);
  EXPECT_EQ(grid.window_max({1, 0}), 0);
}

TEST(PrecomputationStack, LevelsHaveWidthsPowersOfTwo) {
  const DiscreteGrid2D base({10, 10});
  const PrecomputationStack2D stack(base);
  ASSERT_EQ(stack.num_levels(), 7);
  for (int k = 0; k < 7; ++k) {
    EXPECT_EQ(stack.width(k), 1 << k);
    EXPECT_EQ(stack.level(k).size(), Eigen::Vector2i(10 + (1 << k) - 1, 10 + (1 << k) - 1));
  }
  EXPECT_THROW((void)stack.level(7), std::out_of_range);
  EXPECT_THROW((void)stack.level(-1), std::out_of_range);
  EXPECT_THROW(PrecomputationStack2D(base, 0), std::invalid_argument);
  EXPECT_THROW(PrecomputationStack2D(base, 17), std::invalid_argument);
}

TEST(PrecomputationStack, BoxMaximaAreExactAndLevelAnswersAreUpperBounds2D) {
  std::mt19937 rng(17);
  const Eigen::Vector2i size(61, 47);
  const DiscreteGrid2D base(size, random_values(static_cast<std::size_t>(size.prod()), rng, false));
  const PrecomputationStack2D stack(base);
  std::uniform_int_distribution<int> dx(-5, 65), dy(-5, 50);
  for (int t = 0; t < 400; ++t) {
    Eigen::Vector2i lo(dx(rng), dy(rng)), hi(dx(rng), dy(rng));
    for (int a = 0; a < 2; ++a)
      if (lo[a] > hi[a]) std::swap(lo[a], hi[a]);
    std::uint8_t truth = 0;
    for (int j = std::max(lo.y(), 0); j <= std::min(hi.y(), size.y() - 1); ++j)
      for (int i = std::max(lo.x(), 0); i <= std::min(hi.x(), size.x() - 1); ++i)
        truth = std::max(truth, base.values()[base.offset({i, j})]);
    EXPECT_EQ(stack.max_in_box(lo, hi), truth) << lo.transpose() << " .. " << hi.transpose();
    for (int k = 0; k < stack.num_levels(); ++k) {
      const std::uint8_t bound = stack.max_in_box(k, lo, hi);
      EXPECT_GE(bound, truth);
      const Eigen::Vector2i extent = hi - lo + Eigen::Vector2i::Ones();
      if ((extent.array() >= (1 << k)).all()) {
        EXPECT_EQ(bound, truth) << "level " << k;
      }
    }
  }
  EXPECT_THROW((void)stack.max_in_box({3, 0}, {2, 0}), std::invalid_argument);
  EXPECT_EQ(stack.max_in_box({100, 100}, {200, 200}), 0);
}

TEST(PrecomputationStack, BoxMaximaAreExact3D) {
  std::mt19937 rng(19);
  const Eigen::Vector3i size(21, 18, 15);
  const DiscreteGrid3D base(size, random_values(static_cast<std::size_t>(size.prod()), rng, true));
  // Sparse: mostly zeros with a few peaks, so that box maxima differ from box to box.
  DiscreteGrid3D sparse(size);
  std::uniform_int_distribution<int> cell(0, size.prod() - 1);
  for (int s = 0; s < 30; ++s) sparse.values()[static_cast<std::size_t>(cell(rng))] = static_cast<std::uint8_t>(1 + s * 8);
  for (const DiscreteGrid3D* g : {static_cast<const DiscreteGrid3D*>(&base), static_cast<const DiscreteGrid3D*>(&sparse)}) {
    const PrecomputationStack3D stack(*g, 5);
    std::uniform_int_distribution<int> d(-3, 23);
    for (int t = 0; t < 200; ++t) {
      Eigen::Vector3i lo(d(rng), d(rng), d(rng)), hi(d(rng), d(rng), d(rng));
      for (int a = 0; a < 3; ++a)
        if (lo[a] > hi[a]) std::swap(lo[a], hi[a]);
      std::uint8_t truth = 0;
      for (int k = std::max(lo.z(), 0); k <= std::min(hi.z(), size.z() - 1); ++k)
        for (int j = std::max(lo.y(), 0); j <= std::min(hi.y(), size.y() - 1); ++j)
          for (int i = std::max(lo.x(), 0); i <= std::min(hi.x(), size.x() - 1); ++i)
            truth = std::max(truth, g->values()[g->offset({i, j, k})]);
      EXPECT_EQ(stack.max_in_box(lo, hi), truth);
    }
  }
}

TEST(VoxelBox, FromWorldCountsAndKnownBox) {
  const VoxelBox box = VoxelBox::from_world({-0.05, 0.0, 0.0}, {0.25, 0.1, 0.0}, 0.1);
  EXPECT_EQ(box.min, (VoxelKey{-1, 0, 0}));
  EXPECT_EQ(box.max, (VoxelKey{2, 1, 0}));
  EXPECT_EQ(box.num_voxels(), 8u);
  EXPECT_THROW((void)VoxelBox::from_world({1, 0, 0}, {0, 0, 0}, 0.1), std::invalid_argument);
  const VoxelBox huge{{std::numeric_limits<std::int32_t>::min(), std::numeric_limits<std::int32_t>::min(),
                       std::numeric_limits<std::int32_t>::min()},
                      {std::numeric_limits<std::int32_t>::max(), std::numeric_limits<std::int32_t>::max(),
                       std::numeric_limits<std::int32_t>::max()}};
  EXPECT_EQ(huge.num_voxels(), std::numeric_limits<std::uint64_t>::max());
  const ProbabilityUpdater map = make_map();
  const auto known = known_voxel_box(map);
  ASSERT_TRUE(known.has_value());
  EXPECT_EQ(known->min, (VoxelKey{-3, -2, -4}));
  EXPECT_EQ(known->max, (VoxelKey{50, 0, 2}));
  EXPECT_FALSE(known_voxel_box(ProbabilityUpdater(0.1)).has_value());
}

}  // namespace
}  // namespace iwlomap
