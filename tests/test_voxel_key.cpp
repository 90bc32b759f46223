// SPDX-License-Identifier: BSD-3-Clause
// Voxel keys: floor semantics around 0, centres, far coordinates and the checked conversion.

#include "iwlomap/voxel_key.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <unordered_set>

namespace iwlomap {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

TEST(VoxelKey, FloorKeyWhenCoordinateJustBelowAndAboveZero) {
  const double r = 0.05;
  EXPECT_EQ(coordinate_to_key(-1e-9, r), -1);  // a cast toward zero would give 0
  EXPECT_EQ(coordinate_to_key(-1e-300, r), -1);
  EXPECT_EQ(coordinate_to_key(0.0, r), 0);
  EXPECT_EQ(coordinate_to_key(-0.0, r), 0);
  EXPECT_EQ(coordinate_to_key(1e-9, r), 0);
  EXPECT_EQ(coordinate_to_key(0.0499, r), 0);  // rounding would give 1
  EXPECT_EQ(coordinate_to_key(0.0251, r), 0);
  EXPECT_EQ(coordinate_to_key(-0.05, r), -1);
  EXPECT_EQ(coordinate_to_key(-0.0499, r), -1);
  EXPECT_EQ(coordinate_to_key(-0.0501, r), -2);
  EXPECT_EQ(coordinate_to_key(0.0501, r), 1);
  EXPECT_EQ(coordinate_to_key(-0.1249, r), -3);
}

TEST(VoxelKey, WorldToKeyFloorsEachAxisWhenMixedSigns) {
  const VoxelKey k = world_to_key(Eigen::Vector3d(-1e-9, 0.0499, -0.05), 0.05);
  EXPECT_EQ(k, (VoxelKey{-1, 0, -1}));
  // Resolution 0.25 (exact in binary): 1.0 / 0.25 = 4 exactly, -0.25 -> -1, -0.26 -> -2.
  EXPECT_EQ(world_to_key(Eigen::Vector3d(1.0, -0.25, -0.26), 0.25), (VoxelKey{4, -1, -2}));
}

TEST(VoxelKey, CentreIsMiddleOfVoxelWhenConvertedBack) {
  const double r = 0.05;
  const Eigen::Vector3d c = key_to_center(VoxelKey{-1, 0, 2}, r);
  // (-1 + 0.5) * 0.05 = -0.025, (0 + 0.5) * 0.05 = 0.025, (2 + 0.5) * 0.05 = 0.125.
  EXPECT_NEAR(c.x(), -0.025, 1e-15);
  EXPECT_NEAR(c.y(), 0.025, 1e-15);
  EXPECT_NEAR(c.z(), 0.125, 1e-15);
  // The centre maps back to its own key.
  for (int x = -20; x <= 20; x += 3) {
    const VoxelKey k{x, -x, 7 * x};
    EXPECT_EQ(world_to_key(key_to_center(k, r), r), k);
  }
}

TEST(VoxelKey, RoundTripInsideVoxelWhenHundredKilometresAway) {
  const double r = 0.05;
  // 100 km / 0.05 m = 2,000,000 voxels, far beyond OctoMap's 16-bit keys.
  EXPECT_EQ(coordinate_to_key(100000.0, r), 2000000);
  EXPECT_EQ(coordinate_to_key(-100000.0, r), -2000000);
  EXPECT_EQ(coordinate_to_key(100000.03, r), 2000000);
  EXPECT_EQ(coordinate_to_key(-100000.03, r), -2000001);
  const Eigen::Vector3d points[] = {{100000.0123, -100000.0123, 99999.9987},
                                    {-100000.0, 100000.0, -99999.951},
                                    {100000.049, -100000.001, 0.0}};
  for (const Eigen::Vector3d& p : points) {
    SCOPED_TRACE(p.transpose());
    const VoxelKey k = world_to_key_checked(p, r);
    const Eigen::Vector3d c = key_to_center(k, r);
    for (int i = 0; i < 3; ++i) {
      const std::int32_t ki = i == 0 ? k.x : (i == 1 ? k.y : k.z);
      // The point lies inside [k r, (k + 1) r] (a few ulps of slack at 1e5 m) ...
      EXPECT_GE(p[i], ki * r - 1e-9);
      EXPECT_LE(p[i], (ki + 1) * r + 1e-9);
      // ... and within half a voxel of the centre.
      EXPECT_LE(std::abs(p[i] - c[i]), 0.5 * r + 1e-9);
    }
    EXPECT_EQ(world_to_key(c, r), k);
  }
}

TEST(VoxelKey, CheckedThrowsInvalidArgumentWhenNotFinite) {
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(kNaN, 0, 0), 0.05), std::invalid_argument);
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(0, kInf, 0), 0.05), std::invalid_argument);
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(0, 0, -kInf), 0.05), std::invalid_argument);
  // A bad resolution is an invalid argument too.
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(1, 2, 3), 0.0), std::invalid_argument);
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(1, 2, 3), -0.05), std::invalid_argument);
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(1, 2, 3), kNaN), std::invalid_argument);
}

TEST(VoxelKey, CheckedThrowsOutOfRangeWhenKeyBeyondInt32) {
  // 1e9 m / 0.05 m = 2e10 > 2^31 - 1.
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(1e9, 0, 0), 0.05), std::out_of_range);
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(0, -1e9, 0), 0.05), std::out_of_range);
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(0, 0, 1e300), 0.05), std::out_of_range);
  // At resolution 1 the limits are exactly the int32 limits.
  const double max_key = static_cast<double>(std::numeric_limits<std::int32_t>::max());  // 2^31 - 1
  const double min_key = static_cast<double>(std::numeric_limits<std::int32_t>::min());  // -2^31
  EXPECT_EQ(world_to_key_checked(Eigen::Vector3d(max_key + 0.5, 0, 0), 1.0).x,
            std::numeric_limits<std::int32_t>::max());
  EXPECT_EQ(world_to_key_checked(Eigen::Vector3d(0, min_key, 0), 1.0).y, std::numeric_limits<std::int32_t>::min());
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(max_key + 1.0, 0, 0), 1.0), std::out_of_range);
  EXPECT_THROW((void)world_to_key_checked(Eigen::Vector3d(0, min_key - 0.5, 0), 1.0), std::out_of_range);
}

TEST(VoxelKey, IsRepresentableWhenFiniteAndWithinInt32) {
  const double max_key = static_cast<double>(std::numeric_limits<std::int32_t>::max());
  const double min_key = static_cast<double>(std::numeric_limits<std::int32_t>::min());
  EXPECT_TRUE(is_representable(Eigen::Vector3d(0, 0, 0), 0.05));
  EXPECT_TRUE(is_representable(Eigen::Vector3d(1e5, -1e5, 1e5), 0.05));
  EXPECT_TRUE(is_representable(Eigen::Vector3d(max_key + 0.5, min_key, 0), 1.0));
  EXPECT_FALSE(is_representable(Eigen::Vector3d(max_key + 1.0, 0, 0), 1.0));
  EXPECT_FALSE(is_representable(Eigen::Vector3d(0, min_key - 0.5, 0), 1.0));
  EXPECT_FALSE(is_representable(Eigen::Vector3d(0, 0, 1e9), 0.05));
  EXPECT_FALSE(is_representable(Eigen::Vector3d(kNaN, 0, 0), 0.05));
  EXPECT_FALSE(is_representable(Eigen::Vector3d(0, -kInf, 0), 0.05));
}

TEST(VoxelKey, ComparisonAndHashWhenKeysDiffer) {
  const VoxelKey a{1, 2, 3};
  const VoxelKey b{1, 2, 4};
  const VoxelKey c{-1, 5, 0};
  EXPECT_TRUE(a == (VoxelKey{1, 2, 3}));
  EXPECT_TRUE(a != b);
  EXPECT_TRUE(a < b);
  EXPECT_TRUE(c < a);
  EXPECT_FALSE(a < a);
  EXPECT_EQ(VoxelKeyHash{}(a), std::hash<VoxelKey>{}(a));
  // Small neighbourhoods hash to distinct values (a collision here would point at a weak mix).
  std::unordered_set<std::size_t> hashes;
  for (int x = -4; x < 4; ++x)
    for (int y = -4; y < 4; ++y)
      for (int z = -4; z < 4; ++z) hashes.insert(VoxelKeyHash{}(VoxelKey{x, y, z}));
  EXPECT_EQ(hashes.size(), 512u);
}

}  // namespace
}  // namespace iwlomap
