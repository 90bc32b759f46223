// SPDX-License-Identifier: BSD-3-Clause
// The Disk backend's tile format on its own: encode and decode give back every voxel, and every
// damaged or cut header and payload is reported as corrupt, never read as a map.

#include "backends/disk/tile_file.h"
#include "storage/block_grid.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <map>
#include <random>
#include <tuple>
#include <vector>

namespace iwlomap {
namespace {

constexpr double kResolution = 0.1;
constexpr std::uint32_t kTileVoxels = 64;  // 8 blocks a side
const VoxelKey kTile{-2, 1, 0};

using VoxelMap = std::map<std::tuple<int, int, int>, std::pair<float, std::uint16_t>>;

// A tile's grid with random voxels (some blocks full, most sparse) and the same as a map.
detail::BlockGrid random_tile(VoxelMap& ref) {
  std::mt19937 rng(13u);
  detail::BlockGrid grid;
  std::uniform_real_distribution<float> lo(-10.0f, 10.0f);
  const auto edge = static_cast<std::int32_t>(kTileVoxels);
  for (int i = 0; i < 6000; ++i) {
    const VoxelKey k{kTile.x * edge + static_cast<std::int32_t>(rng() % kTileVoxels),
                     kTile.y * edge + static_cast<std::int32_t>(rng() % kTileVoxels),
                     kTile.z * edge + static_cast<std::int32_t>(rng() % 16)};
    detail::VoxelBlock& b = grid.get_or_create(detail::block_of(k));
    detail::Voxel& v = grid.voxel(b, detail::index_in_block(k));
    if (v.count == 0) ++b.known;
    v.count = static_cast<std::uint16_t>(1 + rng() % 65535);
    v.log_odds = lo(rng);
    ref[{k.x, k.y, k.z}] = {v.log_odds, v.count};
  }
  return grid;
}

VoxelMap decode_all(const std::vector<std::uint8_t>& bytes) {
  const detail::TileHeader h =
      detail::parse_tile_header(bytes.data(), bytes.size(), bytes.size(), kResolution, kTileVoxels, kTile, "t.iwt");
  VoxelMap out;
  detail::DenseBlock scratch;
  detail::decode_tile(bytes, h, kTileVoxels, "t.iwt", scratch, [&](const detail::DenseBlock& b) {
    for (int i = 0; i < detail::kBlockVoxels; ++i) {
      const detail::Voxel& v = b.voxels[static_cast<std::size_t>(i)];
      if (v.count == 0) continue;
      const VoxelKey k = detail::voxel_of(b.key, i);
      out[{k.x, k.y, k.z}] = {v.log_odds, v.count};
    }
  });
  return out;
}

TEST(TileFile, DecodesEveryVoxelWhenEncoded) {
  VoxelMap ref;
  const detail::BlockGrid grid = random_tile(ref);
  std::vector<std::uint8_t> bytes;
  EXPECT_EQ(detail::encode_tile(grid, kResolution, kTileVoxels, kTile, bytes), ref.size());
  EXPECT_EQ(decode_all(bytes), ref);
  // Encoding is canonical: the same voxels give the same bytes.
  std::vector<std::uint8_t> again;
  (void)detail::encode_tile(grid, kResolution, kTileVoxels, kTile, again);
  EXPECT_EQ(bytes, again);
}

TEST(TileFile, ReportsCorruptionWhenAnyByteChangesOrTheFileIsCut) {
  VoxelMap ref;
  const detail::BlockGrid grid = random_tile(ref);
  std::vector<std::uint8_t> good;
  (void)detail::encode_tile(grid, kResolution, kTileVoxels, kTile, good);
  std::mt19937 rng(2u);
  // Every header byte, and a sample of payload bytes, each flipped in turn.
  std::vector<std::size_t> positions;
  for (std::size_t i = 0; i < detail::kTileHeaderBytes; ++i) positions.push_back(i);
  for (int i = 0; i < 300; ++i) positions.push_back(detail::kTileHeaderBytes + rng() % (good.size() - detail::kTileHeaderBytes));
  for (const std::size_t at : positions) {
    std::vector<std::uint8_t> bad = good;
    bad[at] ^= static_cast<std::uint8_t>(1u << (rng() % 8));
    try {
      (void)decode_all(bad);
      ADD_FAILURE() << "byte " << at << " changed and the tile still decoded";
    } catch (const StorageError& e) {
      // The version field read as a higher version is reported as newer, not as corrupt.
      const bool version = at >= 8 && at < 12;
      EXPECT_TRUE(e.kind() == StorageError::Kind::kCorrupt || (version && e.kind() == StorageError::Kind::kNewerVersion))
          << "byte " << at << ": " << e.what();
      EXPECT_EQ(e.path(), "t.iwt");
    }
  }
  for (const std::size_t size : {std::size_t{0}, std::size_t{7}, std::size_t{40}, detail::kTileHeaderBytes,
                                 good.size() / 2, good.size() - 1}) {
    const std::vector<std::uint8_t> cut(good.begin(), good.begin() + static_cast<std::ptrdiff_t>(size));
    EXPECT_THROW((void)decode_all(cut), StorageError) << "cut at " << size;
  }
}

}  // namespace
}  // namespace iwlomap
