// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The on-disk format of the Disk backend's tiles.
//
// A tile file is a fixed 80-byte header followed by a payload of block records; every integer is
// little-endian whatever the host, so a map directory can move between machines.
//
//   header  offset  field
//           0       magic "IWLOTILE" (8 bytes)
//           8       u32 format version: 3 (1 and 2 are read, see below)
//           12      u32 byte-order mark 0x01020304 (bytes 04 03 02 01 on disk)
//           16      u32 header size (80)
//           20      u32 tile edge in voxels
//           24      f64 resolution (IEEE-754 bits as u64)
//           32      i32 x, y, z tile coordinate
//           44      u32 record count (blocks)
//           48      u64 known voxels
//           56      u64 payload bytes
//           64      u32 CRC-32 of the payload
//           68      u32 hit record count (0 in version 1)
//           72      u32 hit statistics epoch (0 when the file holds no statistics)
//           76      u32 CRC-32 of header bytes 0..75
//   format  (version 3, the first 8 bytes of the payload) the layout of the records' voxel words
//           (iwlo::VoxelFormat): u32 count bits, i32 fraction bits
//   record  i32 x, y, z block coordinate (absolute, voxel key >> 3), u32 known voxels n (1..512),
//           8 x u64 mask of the known voxels (bit i = the voxel at x + 8 y + 64 z inside the
//           block, whatever the in-memory layout), then n x u32 voxel words in that order.
//   hit record (after the voxel records): i32 x, y, z block coordinate, u32 visited
//           voxels n (1..512), 8 x u64 mask of the visited voxels (as above), then n x (3 x f64
//           sum of hit offsets from the voxel centre, u32 hits, u32 visits).
// Records of each kind are sorted by block coordinate, which makes a file a canonical image of its
// tile and lets the reader detect duplicates. The epoch ties a tile's statistics to the map's
// (the metadata's hit_epoch): statistics of another epoch were gathered before accumulation was
// last turned off, and are read as empty.
//
// The header has its own checksum so that a map can be opened by reading headers only; the
// version is checked before that checksum, so a newer file is reported as newer, not as corrupt.
//
// Older versions are read and converted: version 1 (no statistics) and 2 (with statistics) have
// no format block and store each voxel as (f32 log-odds bits as u32, u16 count), 6 bytes. A
// reader converts every voxel to the map's own format (iwlo::VoxelFormat::encode_kept(), counts
// saturated), as it converts the words of a version-3 file of another layout; a tile is written
// in version 3 and the map's format the next time it is written.

#include "backends/disk/file_io.h"
#include "integrate/hit_accumulator.h"
#include "storage/block_grid.h"
#include "iwlomap/iwlo.h"
#include "iwlomap/voxel_key.h"

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap::detail {

inline constexpr std::uint32_t kTileFormatVersion = 3;  // the newest this build reads, and the one it writes
inline constexpr std::size_t kTileHeaderBytes = 80;
inline constexpr std::size_t kFormatBlockBytes = 8;            // version 3: the records' voxel layout
inline constexpr std::size_t kRecordFixedBytes = 12 + 4 + 64;  // key, count, mask
inline constexpr std::size_t kVoxelBytes = 4;                  // a voxel word
inline constexpr std::size_t kOldVoxelBytes = 6;               // versions 1 and 2: f32 log-odds, u16 count
inline constexpr std::size_t kHitCellBytes = 32;               // 3 x f64 offset sum, u32 hits, u32 visits

/// index_in_block() of the voxel at file position \p f = x + 8 y + 64 z of a block record.
[[nodiscard]] inline std::size_t file_to_block_index(int f) noexcept {
  return static_cast<std::size_t>(index_in_block(VoxelKey{f & 7, (f >> 3) & 7, f >> 6}));
}

/// CRC-32 (IEEE 802.3 polynomial, reflected, as zlib's crc32()): \p crc is the value of the data
/// before (0 to start).
[[nodiscard]] std::uint32_t crc32(const std::uint8_t* data, std::size_t size, std::uint32_t crc = 0) noexcept;

struct TileHeader {
  std::uint32_t version = kTileFormatVersion;
  std::uint32_t tile_voxels = 0;
  double resolution = 0.0;
  VoxelKey tile{};
  std::uint32_t record_count = 0;
  std::uint64_t known_voxels = 0;
  std::uint64_t payload_bytes = 0;
  std::uint32_t payload_crc = 0;
  std::uint32_t hit_record_count = 0;
  std::uint32_t hit_epoch = 0;
  std::uint32_t header_crc = 0;  // bytes 76..79: names this exact file in the map's manifest
};

/// Serialises the known voxels of \p grid (words of format \p format), the blocks of tile
/// \p tile, and the statistics in \p hits (null: none) of epoch \p hit_epoch, into \p out
/// (replaced). Returns the number of known voxels written.
std::uint64_t encode_tile(const BlockGrid& grid, const iwlo::VoxelFormat& format, const HitAccumulator* hits,
                          std::uint32_t hit_epoch, double resolution, std::uint32_t tile_voxels, const VoxelKey& tile,
                          std::vector<std::uint8_t>& out);

/// Parses and checks the header in \p data (the first \p available bytes of a file of
/// \p file_size bytes): magic, version, byte order, header checksum, the expected resolution,
/// tile edge and tile coordinate, and a file size that matches the payload size. Throws
/// StorageError naming \p path.
[[nodiscard]] TileHeader parse_tile_header(const std::uint8_t* data, std::size_t available, std::uint64_t file_size,
                                           double resolution, std::uint32_t tile_voxels, const VoxelKey& tile,
                                           const std::string& path);

/// Reads the header of the tile file \p path (its first kTileHeaderBytes bytes) and checks it as
/// parse_tile_header() does; \p file_size receives the file's size.
[[nodiscard]] TileHeader read_tile_header(const std::string& path, double resolution, std::uint32_t tile_voxels,
                                         const VoxelKey& tile, std::uint64_t& file_size);

/// Checks the payload checksum of a whole tile file \p bytes (whose header \p h was parsed) and
/// calls fn(const DenseBlock&) once per voxel record, in file order, then
/// hit_fn(block key, const HitAccumulator::Block&) once per hit record. \p scratch is reused for
/// every record: its voxels hold the record's known voxels, as words of format \p to (converted
/// when the file holds another), and zeros elsewhere; its known field the record's count. Throws
/// StorageError (kCorrupt) naming \p path for any inconsistency.
template <class Fn, class HitFn>
void decode_tile(const std::vector<std::uint8_t>& bytes, const TileHeader& h, std::uint32_t tile_voxels,
                 const std::string& path, const iwlo::VoxelFormat& to, DenseBlock& scratch, Fn&& fn, HitFn&& hit_fn);

/// decode_tile() of the voxel records only (the hit records are checked all the same).
template <class Fn>
void decode_tile(const std::vector<std::uint8_t>& bytes, const TileHeader& h, std::uint32_t tile_voxels,
                 const std::string& path, const iwlo::VoxelFormat& to, DenseBlock& scratch, Fn&& fn) {
  decode_tile(bytes, h, tile_voxels, path, to, scratch, std::forward<Fn>(fn),
              [](const VoxelKey&, const HitAccumulator::Block&) {});
}

/// The voxel layout of a version-3 format block at \p p (a format whose update bounds are the
/// bits' limits); throws StorageError (kCorrupt) naming \p path when it describes no valid layout.
[[nodiscard]] iwlo::VoxelFormat load_voxel_format(const std::uint8_t* p, const std::string& path);

/// "0x1234abcd", for messages.
[[nodiscard]] std::string hex32(std::uint32_t v);

// ---- little-endian access ----

inline std::uint32_t load_u32(const std::uint8_t* p) noexcept {
  return static_cast<std::uint32_t>(p[0]) | (static_cast<std::uint32_t>(p[1]) << 8) |
         (static_cast<std::uint32_t>(p[2]) << 16) | (static_cast<std::uint32_t>(p[3]) << 24);
}
inline std::uint64_t load_u64(const std::uint8_t* p) noexcept {
  return static_cast<std::uint64_t>(load_u32(p)) | (static_cast<std::uint64_t>(load_u32(p + 4)) << 32);
}
inline std::uint16_t load_u16(const std::uint8_t* p) noexcept {
  return static_cast<std::uint16_t>(p[0] | (p[1] << 8));
}
inline void store_u16(std::uint8_t* p, std::uint16_t v) noexcept {
  p[0] = static_cast<std::uint8_t>(v);
  p[1] = static_cast<std::uint8_t>(v >> 8);
}
inline void store_u32(std::uint8_t* p, std::uint32_t v) noexcept {
  p[0] = static_cast<std::uint8_t>(v);
  p[1] = static_cast<std::uint8_t>(v >> 8);
  p[2] = static_cast<std::uint8_t>(v >> 16);
  p[3] = static_cast<std::uint8_t>(v >> 24);
}
inline void store_u64(std::uint8_t* p, std::uint64_t v) noexcept {
  store_u32(p, static_cast<std::uint32_t>(v));
  store_u32(p + 4, static_cast<std::uint32_t>(v >> 32));
}

inline void store_f64(std::uint8_t* p, double v) noexcept {
  std::uint64_t bits;
  std::memcpy(&bits, &v, sizeof bits);
  store_u64(p, bits);
}
inline double load_f64(const std::uint8_t* p) noexcept {
  const std::uint64_t bits = load_u64(p);
  double v;
  std::memcpy(&v, &bits, sizeof v);
  return v;
}
/// A key as three i32, x first.
inline void store_key(std::uint8_t* p, const VoxelKey& k) noexcept {
  store_u32(p, static_cast<std::uint32_t>(k.x));
  store_u32(p + 4, static_cast<std::uint32_t>(k.y));
  store_u32(p + 8, static_cast<std::uint32_t>(k.z));
}
inline VoxelKey load_key(const std::uint8_t* p) noexcept {
  return {static_cast<std::int32_t>(load_u32(p)), static_cast<std::int32_t>(load_u32(p + 4)),
          static_cast<std::int32_t>(load_u32(p + 8))};
}

/// Floor division of a key by a positive divisor (tile coordinate of a voxel or block key).
[[nodiscard]] inline std::int32_t floor_div(std::int32_t a, std::int32_t b) noexcept {
  const std::int32_t q = a / b;
  return (a % b != 0 && a < 0) ? q - 1 : q;
}

// ---- template body ----

template <class Fn, class HitFn>
void decode_tile(const std::vector<std::uint8_t>& bytes, const TileHeader& h, std::uint32_t tile_voxels,
                 const std::string& path, const iwlo::VoxelFormat& to, DenseBlock& scratch, Fn&& fn, HitFn&& hit_fn) {
  if (bytes.size() != kTileHeaderBytes + h.payload_bytes)
    throw_corrupt(path, "the file has " + std::to_string(bytes.size()) + " bytes, its header announces " +
                            std::to_string(kTileHeaderBytes + h.payload_bytes) + " (changed while read?)");
  const std::uint8_t* p = bytes.data() + kTileHeaderBytes;
  const std::uint8_t* const end = p + h.payload_bytes;
  const std::uint32_t crc = crc32(p, static_cast<std::size_t>(h.payload_bytes));
  if (crc != h.payload_crc)
    throw_corrupt(path, "payload checksum mismatch (stored CRC-32 " + hex32(h.payload_crc) + ", computed " +
                            hex32(crc) + ")");
  // Block coordinates in 64 bits: a tile coordinate times the edge may exceed int32.
  const std::int64_t edge = static_cast<std::int64_t>(tile_voxels / kBlockEdge);
  const std::int64_t lo[3] = {h.tile.x * edge, h.tile.y * edge, h.tile.z * edge};
  const auto block_in_tile = [&](const VoxelKey& k) {
    return k.x >= lo[0] && k.x < lo[0] + edge && k.y >= lo[1] && k.y < lo[1] + edge && k.z >= lo[2] &&
           k.z < lo[2] + edge;
  };
  // A record: block key, voxel count, 512-bit mask of the voxels that follow, then the voxels.
  // Checks that the block lies in the tile, keys increase, the count matches the mask and the
  // record's \p cell_bytes per voxel fit; advances p past the fixed part.
  VoxelKey previous{};
  std::uint64_t mask[kBlockVoxels / 64];
  const auto read_record_head = [&](const std::string& where, bool first, std::size_t cell_bytes) {
    if (static_cast<std::size_t>(end - p) < kRecordFixedBytes) throw_corrupt(path, where + " is cut short");
    const VoxelKey key = load_key(p);
    const std::uint32_t n = load_u32(p + 12);
    if (!block_in_tile(key))
      throw_corrupt(path, where + " holds block (" + std::to_string(key.x) + ", " + std::to_string(key.y) + ", " +
                              std::to_string(key.z) + ") outside the tile");
    if (!first && !(previous < key)) throw_corrupt(path, where + " is out of order or repeated");
    previous = key;
    std::uint32_t bits = 0;
    for (int w = 0; w < kBlockVoxels / 64; ++w) {
      mask[w] = load_u64(p + 16 + 8 * w);
      bits += static_cast<std::uint32_t>(__builtin_popcountll(mask[w]));
    }
    if (n == 0 || n != bits)
      throw_corrupt(path, where + " announces " + std::to_string(n) + " voxels, its mask holds " + std::to_string(bits));
    p += kRecordFixedBytes;
    if (static_cast<std::size_t>(end - p) < static_cast<std::size_t>(n) * cell_bytes)
      throw_corrupt(path, where + " is cut short");
    return std::pair<VoxelKey, std::uint32_t>(key, n);
  };
  // Version 3 names its voxel format; older versions hold floats and 16-bit counts.
  const bool words = h.version >= 3;
  iwlo::VoxelFormat from = to;
  if (words) {
    if (static_cast<std::size_t>(end - p) < kFormatBlockBytes) throw_corrupt(path, "the voxel format is cut short");
    from = load_voxel_format(p, path);
    p += kFormatBlockBytes;
  }
  std::uint64_t known_total = 0;
  for (std::uint32_t r = 0; r < h.record_count; ++r) {
    const std::string where = "record " + std::to_string(r);
    const auto [key, n] = read_record_head(where, r == 0, words ? kVoxelBytes : kOldVoxelBytes);
    scratch.key = key;
    scratch.known = n;
    scratch.voxels.fill(Voxel{});
    for (int w = 0; w < kBlockVoxels / 64; ++w) {
      std::uint64_t m = mask[w];
      while (m != 0) {
        const int i = w * 64 + __builtin_ctzll(m);
        m &= m - 1;
        Voxel& v = scratch.voxels[file_to_block_index(i)];
        const std::uint32_t raw = load_u32(p);
        if (words) {
          if (from.count(raw) == 0) throw_corrupt(path, where + " holds voxel " + std::to_string(i) + " with count 0");
          v.word = to.convert(raw, from);
          p += kVoxelBytes;
        } else {
          static_assert(sizeof(float) == sizeof(std::uint32_t), "IEEE-754 binary32 floats expected");
          float f;
          std::memcpy(&f, &raw, sizeof raw);
          const std::uint32_t count = load_u16(p + 4);
          if (count == 0 || !std::isfinite(f))
            throw_corrupt(path, where + " holds voxel " + std::to_string(i) + " with count 0 or a non-finite log-odds");
          v.word = to.encode_kept(static_cast<double>(f), count);
          p += kOldVoxelBytes;
        }
      }
    }
    known_total += n;
    fn(static_cast<const DenseBlock&>(scratch));
  }
  std::unique_ptr<HitAccumulator::Block> cells;
  for (std::uint32_t r = 0; r < h.hit_record_count; ++r) {
    const std::string where = "hit record " + std::to_string(r);
    const VoxelKey key = read_record_head(where, r == 0, kHitCellBytes).first;
    if (!cells) cells = std::make_unique<HitAccumulator::Block>();
    cells->cells.fill(HitCell{});
    for (int w = 0; w < kBlockVoxels / 64; ++w) {
      std::uint64_t m = mask[w];
      while (m != 0) {
        const int i = w * 64 + __builtin_ctzll(m);
        m &= m - 1;
        HitCell& c = cells->cells[file_to_block_index(i)];
        for (std::size_t a = 0; a < 3; ++a) {
          const std::uint64_t raw = load_u64(p + 8 * a);
          std::memcpy(&c.offset_sum[a], &raw, sizeof raw);
        }
        c.hits = load_u32(p + 24);
        c.visits = load_u32(p + 28);
        if (c.visits == 0 || c.hits > c.visits || !std::isfinite(c.offset_sum[0]) || !std::isfinite(c.offset_sum[1]) ||
            !std::isfinite(c.offset_sum[2]))
          throw_corrupt(path, where + " holds voxel " + std::to_string(i) +
                                  " with no visit, more hits than visits or a non-finite sum");
        p += kHitCellBytes;
      }
    }
    hit_fn(static_cast<const VoxelKey&>(key), static_cast<const HitAccumulator::Block&>(*cells));
  }
  if (p != end) throw_corrupt(path, "the payload has bytes after its last record");
  if (known_total != h.known_voxels)
    throw_corrupt(path, "the records hold " + std::to_string(known_total) + " voxels, the header announces " +
                            std::to_string(h.known_voxels));
}

}  // namespace iwlomap::detail
