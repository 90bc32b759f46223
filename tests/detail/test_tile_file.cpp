// SPDX-License-Identifier: BSD-3-Clause
// The Disk backend's tile format on its own: encode and decode give back every voxel, and every
// damaged or cut header and payload is reported as corrupt, never read as a map.

#include "backends/disk/tile_file.h"
#include "storage/block_grid.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <map>
#include <random>
#include <tuple>
#include <vector>

namespace iwlomap {
namespace {

constexpr double kResolution = 0.1;
constexpr std::uint32_t kTileVoxels = 64;  // 8 blocks a side
const VoxelKey kTile{-2, 1, 0};

using VoxelMap = std::map<std::tuple<int, int, int>, std::uint32_t>;  // voxel words

// A tile's grid with random voxels (some blocks full, most sparse), words of \p format, and the
// same as a map.
detail::BlockGrid random_tile(VoxelMap& ref, const iwlo::VoxelFormat& format = {}) {
  std::mt19937 rng(13u);
  detail::BlockGrid grid;
  std::uniform_real_distribution<double> lo(-10.0, 10.0);
  const auto edge = static_cast<std::int32_t>(kTileVoxels);
  for (int i = 0; i < 6000; ++i) {
    const VoxelKey k{kTile.x * edge + static_cast<std::int32_t>(rng() % kTileVoxels),
                     kTile.y * edge + static_cast<std::int32_t>(rng() % kTileVoxels),
                     kTile.z * edge + static_cast<std::int32_t>(rng() % 16)};
    detail::VoxelBlock& b = grid.get_or_create(detail::block_of(k));
    detail::Voxel& v = grid.voxel(b, detail::index_in_block(k));
    if (!v.known()) ++b.known;
    v.word = format.encode(lo(rng), 1 + rng() % format.max_count());
    ref[{k.x, k.y, k.z}] = v.word;
  }
  return grid;
}

VoxelMap decode_all(const std::vector<std::uint8_t>& bytes, const iwlo::VoxelFormat& to = {}) {
  const detail::TileHeader h =
      detail::parse_tile_header(bytes.data(), bytes.size(), bytes.size(), kResolution, kTileVoxels, kTile, "t.iwt");
  VoxelMap out;
  detail::DenseBlock scratch;
  detail::decode_tile(bytes, h, kTileVoxels, "t.iwt", to, scratch, [&](const detail::DenseBlock& b) {
    for (int i = 0; i < detail::kBlockVoxels; ++i) {
      const detail::Voxel& v = b.voxels[static_cast<std::size_t>(i)];
      if (!v.known()) continue;
      const VoxelKey k = detail::voxel_of(b.key, i);
      out[{k.x, k.y, k.z}] = v.word;
    }
  });
  return out;
}

// A tile file of version 1 (no statistics) or 2 as earlier builds wrote them: the same header,
// no format block, each voxel as f32 log-odds and u16 count.
std::vector<std::uint8_t> old_tile(const std::map<std::tuple<int, int, int>, std::pair<float, std::uint16_t>>& voxels,
                                   std::uint32_t version) {
  std::map<VoxelKey, std::map<int, std::pair<float, std::uint16_t>>> blocks;  // by block, file position
  for (const auto& [t, v] : voxels) {
    const VoxelKey k{std::get<0>(t), std::get<1>(t), std::get<2>(t)};
    const VoxelKey in{k.x & 7, k.y & 7, k.z & 7};
    blocks[detail::block_of(k)][in.x + 8 * in.y + 64 * in.z] = v;
  }
  std::vector<std::uint8_t> out(detail::kTileHeaderBytes, 0);
  for (const auto& [key, cells] : blocks) {
    std::uint8_t head[detail::kRecordFixedBytes] = {};
    detail::store_key(head, key);
    detail::store_u32(head + 12, static_cast<std::uint32_t>(cells.size()));
    std::uint64_t mask[8] = {};
    for (const auto& [f, v] : cells) mask[f / 64] |= std::uint64_t{1} << (f % 64);
    for (int w = 0; w < 8; ++w) detail::store_u64(head + 16 + 8 * w, mask[w]);
    out.insert(out.end(), head, head + sizeof head);
    for (const auto& [f, v] : cells) {
      std::uint8_t cell[6];
      std::uint32_t raw;
      std::memcpy(&raw, &v.first, sizeof raw);
      detail::store_u32(cell, raw);
      detail::store_u16(cell + 4, v.second);
      out.insert(out.end(), cell, cell + sizeof cell);
    }
  }
  const std::size_t payload = out.size() - detail::kTileHeaderBytes;
  std::uint8_t* h = out.data();
  std::memcpy(h, "IWLOTILE", 8);
  detail::store_u32(h + 8, version);
  detail::store_u32(h + 12, 0x01020304u);
  detail::store_u32(h + 16, static_cast<std::uint32_t>(detail::kTileHeaderBytes));
  detail::store_u32(h + 20, kTileVoxels);
  detail::store_f64(h + 24, kResolution);
  detail::store_key(h + 32, kTile);
  detail::store_u32(h + 44, static_cast<std::uint32_t>(blocks.size()));
  detail::store_u64(h + 48, voxels.size());
  detail::store_u64(h + 56, payload);
  detail::store_u32(h + 64, detail::crc32(out.data() + detail::kTileHeaderBytes, payload));
  detail::store_u32(h + 76, detail::crc32(h, detail::kTileHeaderBytes - 4));
  return out;
}

TEST(TileFile, DecodesEveryVoxelWhenEncoded) {
  VoxelMap ref;
  const detail::BlockGrid grid = random_tile(ref);
  std::vector<std::uint8_t> bytes;
  const iwlo::VoxelFormat format;
  EXPECT_EQ(detail::encode_tile(grid, format, nullptr, 0, kResolution, kTileVoxels, kTile, bytes), ref.size());
  EXPECT_EQ(decode_all(bytes), ref);
  // Encoding is canonical: the same voxels give the same bytes.
  std::vector<std::uint8_t> again;
  (void)detail::encode_tile(grid, format, nullptr, 0, kResolution, kTileVoxels, kTile, again);
  EXPECT_EQ(bytes, again);
  // 4 bytes a voxel after the header, the format block and the records' fixed parts.
  EXPECT_EQ(bytes.size(), detail::kTileHeaderBytes + detail::kFormatBlockBytes +
                              detail::kRecordFixedBytes * grid.num_blocks() + 4 * ref.size());
}

// A tile read into a map of another layout is converted voxel by voxel, as a change of the map's
// parameters converts its grid: log-odds rounded to the new step, counts saturated. Another
// clamp range alone keeps the layout and every word.
TEST(TileFile, ConvertsVoxelsWhenTheMapHasAnotherLayout) {
  IwloParams wide;
  wide.decay_rate = 0.001;  // the learning rate reaches its floor after 2,334 observations: 12-bit counts
  const iwlo::VoxelFormat twelve = iwlo::voxel_format(wide);
  const iwlo::VoxelFormat eight;  // the defaults
  ASSERT_EQ(twelve.count_bits(), 12);
  ASSERT_EQ(eight.count_bits(), 8);
  ASSERT_EQ(twelve.fraction_bits(), 15);
  ASSERT_EQ(eight.fraction_bits(), 19);
  std::vector<std::uint8_t> bytes;
  {  // 12-bit counts into 8: the finer step holds every value, counts saturate at 255.
    VoxelMap ref;
    const detail::BlockGrid grid = random_tile(ref, twelve);
    (void)detail::encode_tile(grid, twelve, nullptr, 0, kResolution, kTileVoxels, kTile, bytes);
    const VoxelMap got = decode_all(bytes, eight);
    ASSERT_EQ(got.size(), ref.size());
    std::size_t saturated = 0;
    for (const auto& [k, word] : ref) {
      EXPECT_EQ(eight.log_odds(got.at(k)), twelve.log_odds(word));
      EXPECT_EQ(eight.count(got.at(k)), std::min<std::uint32_t>(twelve.count(word), 255));
      saturated += twelve.count(word) > 255 ? 1 : 0;
    }
    EXPECT_GT(saturated, 1000u);
  }
  {  // 8-bit counts into 12: rounded to the nearest 2^-15 (ties to even), counts kept.
    VoxelMap ref;
    const detail::BlockGrid grid = random_tile(ref, eight);
    (void)detail::encode_tile(grid, eight, nullptr, 0, kResolution, kTileVoxels, kTile, bytes);
    const VoxelMap got = decode_all(bytes, twelve);
    ASSERT_EQ(got.size(), ref.size());
    for (const auto& [k, word] : ref) {
      const double L = eight.log_odds(word);
      EXPECT_EQ(twelve.log_odds(got.at(k)), static_cast<float>(std::nearbyint(L * 32768.0) / 32768.0)) << L;
      EXPECT_EQ(twelve.count(got.at(k)), eight.count(word));
    }
  }
  {  // Another clamp range, the same layout: the words as they were, also outside [L_min, L_max].
    IwloParams narrow;
    narrow.L_min = -2.0;
    narrow.L_max = 3.5;
    const iwlo::VoxelFormat to = iwlo::voxel_format(narrow);
    ASSERT_TRUE(to.same_layout(eight));
    VoxelMap ref;
    const detail::BlockGrid grid = random_tile(ref, eight);
    (void)detail::encode_tile(grid, eight, nullptr, 0, kResolution, kTileVoxels, kTile, bytes);
    EXPECT_EQ(decode_all(bytes, to), ref);
  }
}

// Versions 1 and 2 (float log-odds, 16-bit counts) are still read: each voxel is rounded to the
// map's format and its count saturated.
TEST(TileFile, ReadsOlderVersionsWhenConverting) {
  std::mt19937 rng(5u);
  std::uniform_real_distribution<float> lo(-12.0f, 12.0f);
  std::map<std::tuple<int, int, int>, std::pair<float, std::uint16_t>> voxels;
  const auto edge = static_cast<std::int32_t>(kTileVoxels);
  for (int i = 0; i < 4000; ++i)
    voxels[{kTile.x * edge + static_cast<std::int32_t>(rng() % kTileVoxels),
            kTile.y * edge + static_cast<std::int32_t>(rng() % kTileVoxels), kTile.z * edge + static_cast<std::int32_t>(rng() % 8)}] =
        {lo(rng), static_cast<std::uint16_t>(1 + rng() % 65535)};
  const iwlo::VoxelFormat to;
  for (const std::uint32_t version : {1u, 2u}) {
    const VoxelMap got = decode_all(old_tile(voxels, version), to);
    ASSERT_EQ(got.size(), voxels.size());
    for (const auto& [k, v] : voxels) {
      const std::uint32_t word = got.at(k);
      // Kept as they were (no clamp: an update clamps), to the nearest 2^-19, ties to even.
      EXPECT_EQ(to.log_odds(word), static_cast<float>(std::nearbyint(static_cast<double>(v.first) * 524288.0) / 524288.0));
      EXPECT_NEAR(to.log_odds(word), v.first, to.step() / 2);
      EXPECT_EQ(to.count(word), std::min<std::uint32_t>(v.second, 255));
    }
  }
}

// The hit statistics come back bit for bit, with their epoch; a file without them holds no hit
// record and epoch 0.
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
  (void)detail::encode_tile(grid, iwlo::VoxelFormat{}, &hits, 7, kResolution, kTileVoxels, kTile, bytes);
  const detail::TileHeader h =
      detail::parse_tile_header(bytes.data(), bytes.size(), bytes.size(), kResolution, kTileVoxels, kTile, "t.iwt");
  EXPECT_EQ(h.version, 3u);
  EXPECT_EQ(h.hit_epoch, 7u);
  EXPECT_GT(h.hit_record_count, 0u);
  detail::HitAccumulator back(kResolution);
  detail::DenseBlock scratch;
  std::size_t voxels = 0;
  detail::decode_tile(
      bytes, h, kTileVoxels, "t.iwt", iwlo::VoxelFormat{}, scratch, [&](const detail::DenseBlock& b) { voxels += b.known; },
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
  (void)detail::encode_tile(grid, iwlo::VoxelFormat{}, nullptr, 7, kResolution, kTileVoxels, kTile, plain);
  const detail::TileHeader p =
      detail::parse_tile_header(plain.data(), plain.size(), plain.size(), kResolution, kTileVoxels, kTile, "t.iwt");
  EXPECT_EQ(p.version, 3u);
  EXPECT_EQ(p.hit_record_count, 0u);
  EXPECT_EQ(p.hit_epoch, 0u);
}

TEST(TileFile, ReportsCorruptionWhenAnyByteChangesOrTheFileIsCut) {
  VoxelMap ref;
  const detail::BlockGrid grid = random_tile(ref);
  std::vector<std::uint8_t> good;
  (void)detail::encode_tile(grid, iwlo::VoxelFormat{}, nullptr, 0, kResolution, kTileVoxels, kTile, good);
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
