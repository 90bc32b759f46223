// SPDX-License-Identifier: BSD-3-Clause
// Keys of batch points: FloorDivider and ChunkKeys against the exact floor(x / r) of
// coordinate_to_key(), swept over resolutions and over values on and near voxel faces.

#include "integrate/batch_input.h"
#include "iwlomap/voxel_key.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

namespace iwlomap {
namespace {

// Values a batch meets: voxel faces k * r and their neighbours a few ulps away, tiny and zero
// coordinates, uniform ones, and the ends of the int32 key range.
std::vector<double> sweep_values(double r, std::mt19937_64& rng) {
  std::vector<double> v = {0.0, -0.0, 1e-300, -1e-300, 1e-16, -1e-16, r, -r, 0.5 * r, -0.5 * r};
  std::uniform_int_distribution<std::int64_t> key(-5000000, 5000000);
  std::uniform_real_distribution<double> uniform(-1e4, 1e4);
  for (int i = 0; i < 3000; ++i) {
    const double face = static_cast<double>(key(rng)) * r;
    double x = face;
    for (int u = 0; u < 4; ++u) {
      v.push_back(x);
      x = std::nextafter(x, std::numeric_limits<double>::infinity());
    }
    x = face;
    for (int u = 0; u < 4; ++u) {
      x = std::nextafter(x, -std::numeric_limits<double>::infinity());
      v.push_back(x);
    }
    v.push_back(uniform(rng));
  }
  for (double k : {2147483647.0, -2147483648.0, 2147483000.0, -2147483000.0}) v.push_back(k * r);
  return v;
}

TEST(FloorDivider, EqualsExactDivisionWhenSweepingResolutions) {
  std::mt19937_64 rng(17u);
  std::size_t compared = 0;
  for (double r : {0.1, 0.05, 0.02, 0.2, 0.3, 1.0 / 3.0, 0.01, 1e-3, 0.25, 7.3, 1e-300, 1e300}) {
    const detail::FloorDivider divide(r);
    for (const double x : sweep_values(r, rng)) {
      const double want = std::floor(x / r);
      ASSERT_EQ(divide(x), want) << "x = " << x << " r = " << r;
      ++compared;
    }
  }
  EXPECT_GT(compared, 100000u);
}

TEST(ChunkKeys, EqualsCoordinateToKeyWhenSweepingResolutions) {
  std::mt19937_64 rng(23u);
  for (double r : {0.1, 0.05, 0.3, 1.0 / 3.0, 0.01}) {
    const std::vector<double> v = sweep_values(r, rng);
    // Rows mix values on and off voxel faces within one chunk, so both passes run.
    const auto n = static_cast<Eigen::Index>(v.size());
    Eigen::MatrixXd points(n, 3);
    for (Eigen::Index i = 0; i < n; ++i)
      points.row(i) << v[static_cast<std::size_t>(i)], v[static_cast<std::size_t>((i * 7) % n)],
          v[static_cast<std::size_t>((i * 13) % n)];
    const detail::FloorDivider divide(r);
    detail::ChunkKeys keys;
    for (Eigen::Index begin = 0; begin < n; begin += detail::ChunkKeys::kRows) {
      const auto rows = static_cast<std::size_t>(std::min<Eigen::Index>(n - begin, detail::ChunkKeys::kRows));
      keys.compute(points, begin, rows, divide);
      for (std::size_t j = 0; j < rows; ++j) {
        const Eigen::Index i = begin + static_cast<Eigen::Index>(j);
        const Eigen::Vector3d p = points.row(i).transpose();
        if (!is_representable(p, r)) continue;
        ASSERT_EQ(keys[j], world_to_key(p, r)) << "row " << i << " r = " << r;
      }
    }
  }
}

}  // namespace
}  // namespace iwlomap
