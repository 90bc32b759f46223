// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Helpers of the RAM backend's tests (test_ram_batches.cpp, test_ram_scans.cpp,
// test_ram_bad_input.cpp, test_ram_lifecycle.cpp): a reference voxel, exact snapshots of a map,
// the log-odds of one observation, small hand-written batches and the state of one voxel.

#include "iwlomap/iwlo.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <gtest/gtest.h>

#include <array>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <map>
#include <utility>

namespace iwlomap::ram_test {

inline constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
inline constexpr double kInf = std::numeric_limits<double>::infinity();

struct RefVoxel {
  float L = 0.0f;
  std::uint16_t count = 0;
};

using Snapshot = std::map<VoxelKey, std::pair<double, std::uint32_t>>;

// Every known voxel of a map, through the visitor; fails the test on a voxel visited twice.
inline Snapshot snapshot(const IMapperBackend& map) {
  Snapshot s;
  map.for_each_voxel([&s](const VoxelKey& k, const VoxelState& v) {
    const bool inserted = s.emplace(k, std::make_pair(v.log_odds, v.count)).second;
    EXPECT_TRUE(inserted) << "voxel (" << k.x << ", " << k.y << ", " << k.z << ") visited twice";
  });
  return s;
}

// A single occupied observation with intensity I on an unknown voxel, through the shared update.
inline float single_observation(double intensity, bool occupied_flag, const IwloParams& p) {
  float L = 0.0f;
  std::uint16_t n = 0;
  iwlo::apply_observation(L, n, intensity, occupied_flag, 1.0, p);
  return L;
}

inline Eigen::MatrixXd rows(std::initializer_list<std::array<double, 3>> pts) {
  Eigen::MatrixXd m(static_cast<Eigen::Index>(pts.size()), 3);
  Eigen::Index i = 0;
  for (const auto& p : pts) {
    m.row(i++) << p[0], p[1], p[2];
  }
  return m;
}

inline Eigen::VectorXd values(std::initializer_list<double> v) {
  Eigen::VectorXd out(static_cast<Eigen::Index>(v.size()));
  Eigen::Index i = 0;
  for (double x : v) out[i++] = x;
  return out;
}

inline std::pair<double, std::uint32_t> state_at(const ProbabilityUpdater& map, int x, int y, int z) {
  const auto s = map.query(key_to_center(VoxelKey{x, y, z}, map.get_resolution()));
  return s ? std::make_pair(s->log_odds, s->count) : std::make_pair(kNaN, 0u);
}

}  // namespace iwlomap::ram_test
