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
  EXPECT_EQ(detail::encode_tile(grid, nullptr, 0, kResolution, kTileVoxels, kTile, bytes), ref.size());
  EXPECT_EQ(decode_all(bytes), ref);
  // Encoding is canonical: the same voxels give the same bytes.
  std::vector<std::uint8_t> again;
  (void)detail::encode_tile(grid, nullptr, 0, kResolution, kTileVoxels, kTile, again);
  EXPECT_EQ(bytes, again);
}

// Version 2: the hit statistics come back bit for bit, with their epoch; a file without them is
// version 1 and holds no hit record.
TEST(TileFile, DecodesHitStatisticsWhenEncodedWithThem) {
  VoxelMap ref;
  const detail::BlockGrid grid = random_tile(ref);
  detail::HitAccumulator hits(kResolution);
  std::mt19937 rng(8u);
  const auto edge = static_cast<std::int32_t>(kTileVoxels);
  for (int i = 0; i < 3000; ++i) {
    const VoxelKey k{kTile.x * edge + static_cast<std::int32_t>(rng() % kTileVoxels),
                     kTile.y * edge + static_cast<std::int32_t>(rng() % kTileVoxels),
                     kTile.z * edge + static_cast<std::int32_t>(rng() % 16)};
    if (rng() % 3 == 0)
      hits.add_visit(k);
    else
      hits.add_hit(k, key_to_center(k, kResolution) + Eigen::Vector3d(0.01, -0.02, 0.03) * static_cast<double>(rng() % 5));
  }
  std::vector<std::uint8_t> bytes;
  (void)detail::encode_tile(grid, &hits, 7, kResolution, kTileVoxels, kTile, bytes);
  const detail::TileHeader h =
      detail::parse_tile_header(bytes.data(), bytes.size(), bytes.size(), kResolution, kTileVoxels, kTile, "t.iwt");
  EXPECT_EQ(h.version, 2u);
  EXPECT_EQ(h.hit_epoch, 7u);
  EXPECT_GT(h.hit_record_count, 0u);
  detail::HitAccumulator back(kResolution);
  detail::DenseBlock scratch;
  std::size_t voxels = 0;
  detail::decode_tile(
      bytes, h, kTileVoxels, "t.iwt", scratch, [&](const detail::DenseBlock& b) { voxels += b.known; },
      [&](const VoxelKey& k, const detail::HitAccumulator::Block& cells) { back.merge(k, cells); });
  EXPECT_EQ(voxels, ref.size());
  std::size_t compared = 0;
  hits.for_each_block([&](const VoxelKey& b, const detail::HitAccumulator::Block& cells) {
    for (int i = 0; i < detail::kBlockVoxels; ++i) {
      const detail::HitCell& want = cells.cells[static_cast<std::size_t>(i)];
      const detail::HitCell* got = back.find(detail::voxel_of(b, i));
      if (want.visits == 0) continue;
      ASSERT_NE(got, nullptr);
      EXPECT_EQ(got->hits, want.hits);
      EXPECT_EQ(got->visits, want.visits);
      EXPECT_EQ(got->offset_sum, want.offset_sum);
      ++compared;
    }
  });
  EXPECT_GT(compared, 1000u);
  std::vector<std::uint8_t> plain;
  (void)detail::encode_tile(grid, nullptr, 7, kResolution, kTileVoxels, kTile, plain);
  const detail::TileHeader p =
      detail::parse_tile_header(plain.data(), plain.size(), plain.size(), kResolution, kTileVoxels, kTile, "t.iwt");
  EXPECT_EQ(p.version, 1u);
  EXPECT_EQ(p.hit_record_count, 0u);
}

TEST(TileFile, ReportsCorruptionWhenAnyByteChangesOrTheFileIsCut) {
  VoxelMap ref;
  const detail::BlockGrid grid = random_tile(ref);
  std::vector<std::uint8_t> good;
  (void)detail::encode_tile(grid, nullptr, 0, kResolution, kTileVoxels, kTile, good);
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
