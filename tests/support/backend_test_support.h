// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Helpers shared by the backend test suites: a private temporary directory, exact snapshots of a
// map for comparisons, and seeded random batches.

#include "iwlomap/mapper_backend.h"

#include <Eigen/Core>

#include <gtest/gtest.h>
#include <stdlib.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <limits>
#include <map>
#include <random>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap::test_support {

/// A fresh directory under the system's temporary directory, removed with everything in it.
class TempDir {
 public:
  TempDir() {
    std::string tmpl = (std::filesystem::temp_directory_path() / "iwlomap_test_XXXXXX").string();
    if (::mkdtemp(tmpl.data()) == nullptr) throw std::runtime_error("mkdtemp failed for " + tmpl);
    path_ = tmpl;
  }
  ~TempDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  TempDir(const TempDir&) = delete;
  TempDir& operator=(const TempDir&) = delete;
  /// Path of \p name inside the directory.
  [[nodiscard]] std::string sub(const std::string& name) const { return (std::filesystem::path(path_) / name).string(); }

 private:
  std::string path_;
};

/// Every known voxel with its exact log-odds and count.
using Snapshot = std::map<VoxelKey, std::pair<double, std::uint32_t>>;

/// The map's voxels through for_each_voxel(), checking on the way that each reported probability
/// matches its log-odds and that no voxel is visited twice.
inline Snapshot snapshot(const IMapperBackend& map) {
  Snapshot s;
  map.for_each_voxel([&s](const VoxelKey& k, const VoxelState& v) {
    EXPECT_EQ(v.probability, 1.0 / (1.0 + std::exp(-v.log_odds)));
    const bool inserted = s.emplace(k, std::make_pair(v.log_odds, v.count)).second;
    EXPECT_TRUE(inserted) << "voxel (" << k.x << ", " << k.y << ", " << k.z << ") visited twice";
  });
  return s;
}

/// Rows (x, y, z, p) of get_occupied_voxels() sorted, so backends may list them in any order.
inline std::vector<std::array<double, 4>> sorted_rows(const Eigen::MatrixXd& m) {
  std::vector<std::array<double, 4>> rows;
  for (Eigen::Index i = 0; i < m.rows(); ++i) rows.push_back({m(i, 0), m(i, 1), m(i, 2), m(i, 3)});
  std::sort(rows.begin(), rows.end());
  return rows;
}

/// A batch with per-point weights.
struct Batch {
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
  std::vector<bool> flags;
  Eigen::VectorXd weights;
};

/// How many kinds of bad rows random_batch() puts in.
enum class BadRows {
  kNaNPoints,          ///< about 1% of the points get a NaN coordinate
  kNaNInfAndIntensity  ///< also infinite coordinates, and about 0.5% NaN intensities
};

/// n points in a box of half edge \p half_extent around \p centre (voxels repeat within and across
/// batches), integer and fractional intensities around the threshold, about 60% flagged occupied,
/// weights in [0, 2) including 0, and a few bad rows that must be skipped.
inline Batch random_batch(std::mt19937& rng, int n, double half_extent, const Eigen::Vector3d& centre,
                          BadRows bad) {
  constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
  constexpr double kInf = std::numeric_limits<double>::infinity();
  std::uniform_real_distribution<double> coord(-half_extent, half_extent);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_int_distribution<int> int_intensity(0, 255);
  Batch b{Eigen::MatrixXd(n, 3), Eigen::VectorXd(n), std::vector<bool>(static_cast<std::size_t>(n)),
          Eigen::VectorXd(n)};
  for (int i = 0; i < n; ++i) {
    b.points.row(i) << centre.x() + coord(rng), centre.y() + coord(rng), centre.z() + coord(rng);
    b.intensities[i] = unit(rng) < 0.5 ? static_cast<double>(int_intensity(rng)) : 255.0 * unit(rng);
    b.flags[static_cast<std::size_t>(i)] = unit(rng) < 0.6;
    b.weights[i] = unit(rng) < 0.1 ? 0.0 : 2.0 * unit(rng);
    const bool harsh = bad == BadRows::kNaNInfAndIntensity;
    if (unit(rng) < 0.01) b.points(i, static_cast<Eigen::Index>(i % 3)) = harsh && i % 2 != 0 ? kInf : kNaN;
    if (harsh && unit(rng) < 0.005) b.intensities[i] = kNaN;
  }
  return b;
}

}  // namespace iwlomap::test_support
