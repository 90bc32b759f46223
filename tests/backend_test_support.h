// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Helpers shared by the backend test suites: a private temporary directory and exact snapshots
// of a map for comparisons.

#include "iwlomap/mapper_backend.h"

#include <gtest/gtest.h>
#include <stdlib.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <map>
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

}  // namespace iwlomap::test_support
