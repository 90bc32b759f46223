// SPDX-License-Identifier: BSD-3-Clause
// Disk maps written before the 4-byte voxel (tile format versions 1 and 2, float log-odds and
// 16-bit counts; tests/data/tile_format_1_2) still open: every voxel reads as the earlier build
// stored it, to the nearest step of the map's voxel format, its count saturated; a flush writes
// the tiles it changed in version 3 beside the older ones, and the map reads the same after
// reopening.

#include "backend_test_support.h"
#include "iwlomap/iwlo.h"
#include "iwlomap/outofcore_tile_mapper.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <utility>

namespace iwlomap {
namespace {

namespace fs = std::filesystem;
using test_support::TempDir;

const fs::path kData = fs::path(IWLOMAP_TEST_SOURCE_DIR) / "data" / "tile_format_1_2";

using Voxels = std::map<VoxelKey, std::pair<float, std::uint32_t>>;

Voxels read_expected(const fs::path& file) {
  std::ifstream in(file);
  Voxels out;
  std::string line;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream row(line);
    VoxelKey k;
    std::string hex;
    std::uint32_t count = 0;
    row >> k.x >> k.y >> k.z >> hex >> count;
    const auto bits = static_cast<std::uint32_t>(std::stoul(hex, nullptr, 16));
    float L;
    std::memcpy(&L, &bits, sizeof L);
    out[k] = {L, count};
  }
  return out;
}

Voxels read_map(const OutofcoreTileMapper& map) {
  Voxels out;
  map.for_each_voxel([&](const VoxelKey& k, const VoxelState& s) {
    out[k] = {static_cast<float>(s.log_odds), s.count};
  });
  return out;
}

std::uint32_t tile_version(const fs::path& file) {
  std::ifstream in(file, std::ios::binary);
  unsigned char h[12] = {};
  in.read(reinterpret_cast<char*>(h), sizeof h);
  return h[8] | (h[9] << 8) | (h[10] << 16) | (static_cast<std::uint32_t>(h[11]) << 24);
}

class TileFormatMigration : public ::testing::TestWithParam<int> {};

TEST_P(TileFormatMigration, ReadsEveryVoxelWhenTheMapIsOfAnEarlierVersion) {
  const int version = GetParam();
  const std::string name = "disk_map_v" + std::to_string(version);
  const TempDir tmp;
  const std::string dir = tmp.sub(name);
  fs::copy(kData / name, dir);
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() == ".iwt") {
      EXPECT_EQ(tile_version(e.path()), static_cast<std::uint32_t>(version));
    }
  }
  const Voxels before = read_expected(kData / (name + ".voxels"));
  ASSERT_GT(before.size(), 1000u);

  const iwlo::VoxelFormat format;  // the stored parameters are the defaults
  Voxels want;
  std::size_t saturated = 0, rounded = 0;
  for (const auto& [k, v] : before) {
    const std::uint32_t word = format.encode_kept(v.first, v.second);
    want[k] = {format.log_odds(word), format.count(word)};
    EXPECT_LE(std::abs(static_cast<double>(want[k].first) - v.first), format.step() / 2);
    saturated += v.second > 255 ? 1 : 0;
    rounded += want[k].first != v.first ? 1 : 0;
  }
  EXPECT_EQ(saturated, 1u);  // voxel (0, 0, 0): 300 observations
  EXPECT_GT(rounded, 100u);  // floats that are not a multiple of 2^-19
  {
    OutofcoreTileMapper map(dir);  // the stored resolution, tile size and parameters
    EXPECT_EQ(map.get_params().L_max, 10.0);
    EXPECT_EQ(read_map(map), want);
    if (version == 2) {
      EXPECT_TRUE(map.get_hit_accumulation());
      EXPECT_TRUE(map.hit_statistics(Eigen::Vector3d(0.05, 0.05, 0.05)).has_value());
    }
    // An update of a converted voxel continues from its converted state, as in a RAM map.
    map.batch_update_iwlo((Eigen::MatrixXd(1, 3) << 0.05, 0.05, 0.05).finished(), Eigen::VectorXd::Constant(1, 200.0),
                          {true});
    float L = want.at({0, 0, 0}).first;
    std::uint16_t n = static_cast<std::uint16_t>(want.at({0, 0, 0}).second);
    iwlo::apply_observation(L, n, 200.0, true, 1.0, map.get_params());
    want[{0, 0, 0}] = {L, n};
    EXPECT_EQ(read_map(map), want);
    map.flush();
  }
  // The changed tile is written in version 3; the others stay as they were.
  std::map<std::uint32_t, int> versions;
  for (const auto& e : fs::directory_iterator(dir)) {
    if (e.path().extension() == ".iwt") ++versions[tile_version(e.path())];
  }
  EXPECT_EQ(versions[3], 1);
  EXPECT_EQ(versions[static_cast<std::uint32_t>(version)], 9);
  const OutofcoreTileMapper again(dir);
  EXPECT_EQ(read_map(again), want);
}

INSTANTIATE_TEST_SUITE_P(Versions, TileFormatMigration, ::testing::Values(1, 2));

}  // namespace
}  // namespace iwlomap
