// SPDX-License-Identifier: BSD-3-Clause
#include "backends/disk/tile_file.h"

#include <algorithm>
#include <array>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <utility>

namespace iwlomap::detail {

namespace {

constexpr char kMagic[8] = {'I', 'W', 'L', 'O', 'T', 'I', 'L', 'E'};
constexpr std::uint32_t kByteOrderMark = 0x01020304u;

// Slicing-by-8 tables: eight bytes per step instead of one, so that checksums run at several GB/s
// and never dominate a flush.
using CrcTables = std::array<std::array<std::uint32_t, 256>, 8>;
constexpr CrcTables make_crc_tables() {
  CrcTables t{};
  for (std::uint32_t i = 0; i < 256; ++i) {
    std::uint32_t c = i;
    for (int k = 0; k < 8; ++k) c = (c & 1u) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
    t[0][i] = c;
  }
  for (std::size_t s = 1; s < 8; ++s)
    for (std::size_t i = 0; i < 256; ++i) t[s][i] = (t[s - 1][i] >> 8) ^ t[0][t[s - 1][i] & 0xFFu];
  return t;
}
constexpr CrcTables kCrc = make_crc_tables();

}  // namespace

std::uint32_t crc32(const std::uint8_t* data, std::size_t size, std::uint32_t crc) noexcept {
  std::uint32_t c = ~crc;
  while (size >= 8) {
    const std::uint32_t lo = load_u32(data) ^ c;
    const std::uint32_t hi = load_u32(data + 4);
    c = kCrc[7][lo & 0xFFu] ^ kCrc[6][(lo >> 8) & 0xFFu] ^ kCrc[5][(lo >> 16) & 0xFFu] ^ kCrc[4][lo >> 24] ^
        kCrc[3][hi & 0xFFu] ^ kCrc[2][(hi >> 8) & 0xFFu] ^ kCrc[1][(hi >> 16) & 0xFFu] ^ kCrc[0][hi >> 24];
    data += 8;
    size -= 8;
  }
  while (size-- > 0) c = kCrc[0][(c ^ *data++) & 0xFFu] ^ (c >> 8);
  return ~c;
}

std::string hex32(std::uint32_t v) {
  char buf[16];
  std::snprintf(buf, sizeof buf, "0x%08x", v);
  return buf;
}

iwlo::VoxelFormat load_voxel_format(const std::uint8_t* p, const std::string& path) {
  const auto count_bits = static_cast<std::int32_t>(load_u32(p));
  const auto fraction_bits = static_cast<std::int32_t>(load_u32(p + 4));
  try {
    if (count_bits < 8 || count_bits > 16) throw std::invalid_argument("count bits " + std::to_string(count_bits));
    const std::int32_t limit = (std::int32_t{1} << (31 - count_bits)) - 1;
    return iwlo::VoxelFormat(count_bits, fraction_bits, -limit, limit);
  } catch (const std::invalid_argument& e) {
    throw_corrupt(path, std::string("its voxel format is not valid: ") + e.what());
  }
}

std::uint64_t encode_tile(const BlockGrid& grid, const iwlo::VoxelFormat& format, const HitAccumulator* hits,
                          std::uint32_t hit_epoch, double resolution, std::uint32_t tile_voxels, const VoxelKey& tile,
                          std::vector<std::uint8_t>& out) {
  std::vector<const VoxelBlock*> blocks;
  blocks.reserve(grid.num_blocks());
  std::size_t payload = kFormatBlockBytes;
  for (const auto& b : grid.blocks()) {
    if (b->known == 0) continue;
    blocks.push_back(b);
    payload += kRecordFixedBytes + kVoxelBytes * b->known;
  }
  std::sort(blocks.begin(), blocks.end(), [](const VoxelBlock* a, const VoxelBlock* b) { return a->key < b->key; });
  // The hit records: blocks with a visited voxel, sorted, with their visited voxels' count.
  std::vector<std::pair<VoxelKey, const HitAccumulator::Block*>> hit_blocks;
  std::vector<std::uint32_t> visited;
  if (hits != nullptr) {
    hits->for_each_block([&](const VoxelKey& k, const HitAccumulator::Block& b) { hit_blocks.emplace_back(k, &b); });
    std::sort(hit_blocks.begin(), hit_blocks.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
    for (const auto& [k, b] : hit_blocks) {
      std::uint32_t n = 0;
      for (const HitCell& c : b->cells) n += c.visits != 0 ? 1 : 0;
      visited.push_back(n);
      if (n != 0) payload += kRecordFixedBytes + kHitCellBytes * n;
    }
  }

  out.assign(kTileHeaderBytes + payload, 0);
  std::uint8_t* p = out.data() + kTileHeaderBytes;
  store_u32(p, static_cast<std::uint32_t>(format.count_bits()));
  store_u32(p + 4, static_cast<std::uint32_t>(format.fraction_bits()));
  p += kFormatBlockBytes;
  std::uint64_t known = 0;
  DenseBlock dense;  // one block with every voxel in place, read in file order
  for (const VoxelBlock* b : blocks) {
    dense.voxels.fill(Voxel{});
    b->for_each_slot([&](int i, const Voxel& v) { dense.voxels[static_cast<std::size_t>(i)] = v; });
    store_key(p, b->key);
    std::uint8_t* const mask = p + 16;
    std::uint8_t* v = p + kRecordFixedBytes;
    std::uint32_t n = 0;
    for (int w = 0; w < kBlockVoxels / 64; ++w) {
      std::uint64_t bits = 0;
      for (int i = 0; i < 64; ++i) {
        const Voxel& voxel = dense.voxels[file_to_block_index(w * 64 + i)];
        if (!voxel.known()) continue;
        bits |= std::uint64_t{1} << i;
        store_u32(v, voxel.word);
        v += kVoxelBytes;
        ++n;
      }
      store_u64(mask + 8 * w, bits);
    }
    // b->known is maintained by every update; a mismatch would be a bug that must not reach disk.
    if (n != b->known) throw std::logic_error("iwlomap: block voxel count out of sync while writing a tile");
    store_u32(p + 12, n);
    known += n;
    p = v;
  }
  std::uint32_t hit_records = 0;
  for (std::size_t r = 0; r < hit_blocks.size(); ++r) {
    if (visited[r] == 0) continue;
    const auto& [k, b] = hit_blocks[r];
    store_key(p, k);
    store_u32(p + 12, visited[r]);
    std::uint8_t* const mask = p + 16;
    std::uint8_t* c = p + kRecordFixedBytes;
    for (int w = 0; w < kBlockVoxels / 64; ++w) {
      std::uint64_t bits = 0;
      for (int i = 0; i < 64; ++i) {
        const HitCell& cell = b->cells[file_to_block_index(w * 64 + i)];
        if (cell.visits == 0) continue;
        bits |= std::uint64_t{1} << i;
        for (std::size_t a = 0; a < 3; ++a) {
          std::uint64_t raw;
          std::memcpy(&raw, &cell.offset_sum[a], sizeof raw);
          store_u64(c + 8 * a, raw);
        }
        store_u32(c + 24, cell.hits);
        store_u32(c + 28, cell.visits);
        c += kHitCellBytes;
      }
      store_u64(mask + 8 * w, bits);
    }
    ++hit_records;
    p = c;
  }

  std::uint8_t* h = out.data();
  std::memcpy(h, kMagic, sizeof kMagic);
  store_u32(h + 8, kTileFormatVersion);
  store_u32(h + 12, kByteOrderMark);
  store_u32(h + 16, static_cast<std::uint32_t>(kTileHeaderBytes));
  store_u32(h + 20, tile_voxels);
  store_f64(h + 24, resolution);
  store_key(h + 32, tile);
  store_u32(h + 44, static_cast<std::uint32_t>(blocks.size()));
  store_u64(h + 48, known);
  store_u64(h + 56, payload);
  store_u32(h + 64, crc32(out.data() + kTileHeaderBytes, payload));
  store_u32(h + 68, hit_records);
  store_u32(h + 72, hits != nullptr ? hit_epoch : 0u);
  store_u32(h + 76, crc32(h, kTileHeaderBytes - 4));
  return known;
}

TileHeader parse_tile_header(const std::uint8_t* data, std::size_t available, std::uint64_t file_size,
                             double resolution, std::uint32_t tile_voxels, const VoxelKey& tile,
                             const std::string& path) {
  if (available >= sizeof kMagic && std::memcmp(data, kMagic, sizeof kMagic) != 0)
    throw_corrupt(path, "wrong magic (not an iwlomap tile)");
  if (available < 16)
    throw_corrupt(path, "truncated: " + std::to_string(file_size) + " bytes, shorter than a tile header");
  TileHeader h;
  h.version = load_u32(data + 8);
  if (h.version > kTileFormatVersion)
    throw StorageError(StorageError::Kind::kNewerVersion, path,
                       "iwlomap: tile file " + path + " has format version " + std::to_string(h.version) +
                           ", newer than the version " + std::to_string(kTileFormatVersion) +
                           " this build reads; open the map with a newer iwlomap");
  if (h.version == 0) throw_corrupt(path, "format version 0");
  if (load_u32(data + 12) != kByteOrderMark) throw_corrupt(path, "unknown byte-order mark " + hex32(load_u32(data + 12)));
  if (available < kTileHeaderBytes)
    throw_corrupt(path, "truncated: " + std::to_string(file_size) + " bytes, shorter than the " +
                            std::to_string(kTileHeaderBytes) + "-byte header");
  const std::uint32_t stored_crc = load_u32(data + 76);
  const std::uint32_t crc = crc32(data, kTileHeaderBytes - 4);
  if (stored_crc != crc)
    throw_corrupt(path, "header checksum mismatch (stored CRC-32 " + hex32(stored_crc) + ", computed " + hex32(crc) + ")");
  if (load_u32(data + 16) != kTileHeaderBytes)
    throw_corrupt(path, "header size " + std::to_string(load_u32(data + 16)) + ", expected " +
                            std::to_string(kTileHeaderBytes));
  h.tile_voxels = load_u32(data + 20);
  h.resolution = load_f64(data + 24);
  h.tile = load_key(data + 32);
  h.record_count = load_u32(data + 44);
  h.known_voxels = load_u64(data + 48);
  h.payload_bytes = load_u64(data + 56);
  h.payload_crc = load_u32(data + 64);
  h.hit_record_count = load_u32(data + 68);
  h.hit_epoch = load_u32(data + 72);
  h.header_crc = stored_crc;
  if (h.version == 1 && (h.hit_record_count != 0 || h.hit_epoch != 0))
    throw_corrupt(path, "the reserved header bytes 68..75 of a version-1 tile are not 0");
  if (h.resolution != resolution || h.tile_voxels != tile_voxels)
    throw_corrupt(path, "written for resolution " + std::to_string(h.resolution) + " and " +
                            std::to_string(h.tile_voxels) + "-voxel tiles, the map has " + std::to_string(resolution) +
                            " and " + std::to_string(tile_voxels));
  if (h.tile != tile)
    throw_corrupt(path, "holds tile (" + std::to_string(h.tile.x) + ", " + std::to_string(h.tile.y) + ", " +
                            std::to_string(h.tile.z) + "), not the tile its name says");
  if (file_size < kTileHeaderBytes + h.payload_bytes)
    throw_corrupt(path, "truncated: " + std::to_string(file_size) + " bytes, the header announces " +
                            std::to_string(kTileHeaderBytes + h.payload_bytes));
  if (file_size > kTileHeaderBytes + h.payload_bytes)
    throw_corrupt(path, std::to_string(file_size) + " bytes, longer than the " +
                            std::to_string(kTileHeaderBytes + h.payload_bytes) + " its header announces");
  if (h.payload_bytes < (static_cast<std::uint64_t>(h.record_count) + h.hit_record_count) * kRecordFixedBytes ||
      h.known_voxels > static_cast<std::uint64_t>(h.record_count) * kBlockVoxels)
    throw_corrupt(path, "inconsistent record count " + std::to_string(h.record_count));
  return h;
}

TileHeader read_tile_header(const std::string& path, double resolution, std::uint32_t tile_voxels,
                            const VoxelKey& tile, std::uint64_t& file_size) {
  const std::vector<std::uint8_t> head = read_file_prefix(path, kTileHeaderBytes, file_size);
  return parse_tile_header(head.data(), head.size(), file_size, resolution, tile_voxels, tile, path);
}

}  // namespace iwlomap::detail
