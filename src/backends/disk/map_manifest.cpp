// SPDX-License-Identifier: BSD-3-Clause
#include "backends/disk/map_manifest.h"

#include "backends/disk/map_directory.h"
#include "backends/disk/tile_file.h"

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <iterator>
#include <stdexcept>

namespace iwlomap::detail {

namespace {

constexpr char kMagic[8] = {'I', 'W', 'L', 'O', 'M', 'A', 'N', 'F'};
constexpr std::uint32_t kVersion = 1;
constexpr std::uint32_t kByteOrderMark = 0x01020304u;
constexpr std::size_t kHeadBytes = 144;
constexpr std::size_t kTileBytes = 40;
constexpr std::size_t kRetiredBytes = 24;
constexpr int kParams = 13;

[[noreturn]] void bad(const std::string& path, const std::string& what) {
  throw StorageError(StorageError::Kind::kCorrupt, path,
                     "iwlomap: map manifest " + path + " is corrupt: " + what +
                         " (the map's tiles cannot be told apart without it; restore it from a copy)");
}

}  // namespace

bool same_state(const MapState& a, const MapState& b) noexcept {
  double va[kParams], vb[kParams];
  params_to_array(a.params, va);
  params_to_array(b.params, vb);
  return std::equal(std::begin(va), std::end(va), std::begin(vb)) && a.hit_statistics == b.hit_statistics &&
         a.hit_epoch == b.hit_epoch;
}

std::vector<std::uint8_t> encode_manifest(const MapManifest& m) {
  std::vector<std::uint8_t> out(kHeadBytes + m.tiles.size() * kTileBytes + m.retired.size() * kRetiredBytes + 4, 0);
  std::uint8_t* p = out.data();
  std::memcpy(p, kMagic, sizeof kMagic);
  store_u32(p + 8, kVersion);
  store_u32(p + 12, kByteOrderMark);
  store_u64(p + 16, m.commit);
  store_u32(p + 24, static_cast<std::uint32_t>(m.tiles.size()));
  store_u32(p + 28, static_cast<std::uint32_t>(m.retired.size()));
  double v[kParams];
  params_to_array(m.state.params, v);
  for (int i = 0; i < kParams; ++i) store_f64(p + 32 + 8 * i, v[i]);
  store_u32(p + 136, m.state.hit_statistics ? 1u : 0u);
  store_u32(p + 140, m.state.hit_epoch);
  p += kHeadBytes;
  for (const ManifestTile& t : m.tiles) {
    store_key(p, t.key);
    store_u32(p + 12, t.header_crc);
    store_u64(p + 16, t.generation);
    store_u64(p + 24, t.bytes);
    store_u64(p + 32, t.known);
    p += kTileBytes;
  }
  for (const RetiredFile& r : m.retired) {
    store_key(p, r.key);
    store_u64(p + 16, r.generation);
    p += kRetiredBytes;
  }
  store_u32(p, crc32(out.data(), out.size() - 4));
  return out;
}

MapManifest decode_manifest(const std::vector<std::uint8_t>& bytes, const std::string& path) {
  const std::uint8_t* p = bytes.data();
  if (bytes.size() < sizeof kMagic || std::memcmp(p, kMagic, sizeof kMagic) != 0) bad(path, "wrong magic");
  if (bytes.size() < kHeadBytes + 4) bad(path, "truncated: " + std::to_string(bytes.size()) + " bytes");
  const std::uint32_t version = load_u32(p + 8);
  if (version > kVersion)
    throw StorageError(StorageError::Kind::kNewerVersion, path,
                       "iwlomap: map manifest " + path + " has format version " + std::to_string(version) +
                           ", newer than the version " + std::to_string(kVersion) +
                           " this build reads; open the map with a newer iwlomap");
  if (version == 0) bad(path, "format version 0");
  if (load_u32(p + 12) != kByteOrderMark) bad(path, "unknown byte-order mark " + hex32(load_u32(p + 12)));
  const std::uint64_t n = load_u32(p + 24), r = load_u32(p + 28);
  if (bytes.size() != kHeadBytes + n * kTileBytes + r * kRetiredBytes + 4)
    bad(path, std::to_string(bytes.size()) + " bytes for " + std::to_string(n) + " tiles and " + std::to_string(r) +
                  " retired files (cut short or extended?)");
  const std::uint32_t stored = load_u32(p + bytes.size() - 4);
  const std::uint32_t crc = crc32(p, bytes.size() - 4);
  if (stored != crc) bad(path, "checksum mismatch (stored CRC-32 " + hex32(stored) + ", computed " + hex32(crc) + ")");
  MapManifest m;
  m.commit = load_u64(p + 16);
  double v[kParams];
  for (int i = 0; i < kParams; ++i) v[i] = load_f64(p + 32 + 8 * i);
  // The flag's own bytes, not its value: -0.0 equals 0.0 but would be written back as 0.0.
  const std::uint64_t flag = load_u64(p + 32 + 8 * 9);
  if (flag != 0 && flag != 0x3ff0000000000000ull) bad(path, "adaptive_enabled is neither 0.0 nor 1.0");
  m.state.params = params_from_array(v);
  try {
    m.state.params.validate();
  } catch (const std::invalid_argument& e) {
    bad(path, e.what());
  }
  const std::uint32_t hits = load_u32(p + 136);
  if (hits > 1) bad(path, "hit statistics flag " + std::to_string(hits));
  m.state.hit_statistics = hits == 1;
  m.state.hit_epoch = load_u32(p + 140);
  const std::uint8_t* q = p + kHeadBytes;
  m.tiles.resize(static_cast<std::size_t>(n));
  for (std::size_t i = 0; i < n; ++i, q += kTileBytes) {
    ManifestTile& t = m.tiles[i];
    t.key = load_key(q);
    t.header_crc = load_u32(q + 12);
    t.generation = load_u64(q + 16);
    t.bytes = load_u64(q + 24);
    t.known = load_u64(q + 32);
    if (i > 0 && !(m.tiles[i - 1].key < t.key)) bad(path, "tile entry " + std::to_string(i) + " is out of order or repeated");
    if (t.generation > m.commit)
      bad(path, "tile entry " + std::to_string(i) + " has generation " + std::to_string(t.generation) +
                    ", after the commit " + std::to_string(m.commit));
    if (t.bytes < kTileHeaderBytes) bad(path, "tile entry " + std::to_string(i) + " is shorter than a tile header");
  }
  m.retired.resize(static_cast<std::size_t>(r));
  for (std::size_t i = 0; i < r; ++i, q += kRetiredBytes) {
    if (load_u32(q + 12) != 0) bad(path, "retired entry " + std::to_string(i) + " has non-zero reserved bytes");
    m.retired[i] = {load_key(q), load_u64(q + 16)};
  }
  return m;
}

void write_manifest_file(const std::string& directory, const MapManifest& m) {
  const std::string path = (std::filesystem::path(directory) / kManifestName).string();
  write_file_durably(path + kTempSuffix, path, encode_manifest(m));
  sync_directory(directory);
}

void sort_by_tile(std::vector<ManifestTile>& tiles) {
  std::sort(tiles.begin(), tiles.end(), [](const ManifestTile& a, const ManifestTile& b) { return a.key < b.key; });
}

MapState state_of(const MapMeta& meta) { return {meta.params, meta.hit_statistics, meta.hit_epoch}; }

MapManifest read_committed_manifest(const std::string& directory) {
  namespace fs = std::filesystem;
  const std::string path = (fs::path(directory) / kManifestName).string();
  std::error_code ec;
  if (fs::exists(path, ec)) {
    MapManifest m = decode_manifest(read_file(path), path);
    m.retired.clear();
    return m;
  }
  const MapMeta meta = MapDirectory::read_meta(directory);
  MapManifest m;
  m.state = state_of(meta);
  for (fs::directory_iterator it(directory, ec), end; !ec && it != end; it.increment(ec)) {
    VoxelKey t;
    std::uint64_t generation = 0;
    std::error_code type_ec;
    if (!it->is_regular_file(type_ec) || !parse_tile_file_name(it->path().filename().string(), t, generation) ||
        generation != 0)
      continue;
    std::uint64_t size = 0;
    const TileHeader h = read_tile_header(it->path().string(), meta.resolution, meta.tile_voxels, t, size);
    m.tiles.push_back({t, 0, size, h.known_voxels, h.header_crc});
  }
  if (ec) throw StorageError(StorageError::Kind::kIo, directory, "iwlomap: cannot list " + directory + ": " + ec.message());
  sort_by_tile(m.tiles);
  return m;
}

}  // namespace iwlomap::detail
