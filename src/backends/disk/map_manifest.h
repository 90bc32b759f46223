// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The commit record of a Disk map, `iwlomap_map.manifest`: which tile file holds each tile, and
// the map's parameters and hit-statistics setting, as of the last flush(). A flush writes the
// tiles it changed to new files (tile_<x>_<y>_<z>.g<commit>.iwt) and then replaces the manifest
// (temporary file, fsync, rename): that rename is the one moment the map changes, so a crash or a
// failure leaves the map of the previous commit or of the new one, never a mix. Files the new
// manifest no longer names are listed as retired and removed once no reader holds the map.
//
// Little-endian, like the tiles:
//   0    magic "IWLOMANF" (8 bytes)
//   8    u32 manifest format version (1)
//   12   u32 byte-order mark 0x01020304
//   16   u64 commit number (files written by commit c carry generation c)
//   24   u32 tile count n, u32 retired count r
//   32   13 x f64 IWLO parameters (map_directory.cpp's order), u32 hit statistics on (0 or 1),
//        u32 hit epoch
//   144  n x tile: i32 x, y, z, u32 header CRC-32 of the file (its bytes 76..79), u64 generation,
//        u64 file bytes, u64 known voxels; sorted by tile, each tile once
//   then r x retired file: i32 x, y, z, u32 0, u64 generation
//   last u32 CRC-32 of every byte before it
// Generation 0 is the name of a map written before manifests, tile_<x>_<y>_<z>.iwt.

#include "iwlomap/iwlo.h"
#include "iwlomap/voxel_key.h"

#include <cstdint>
#include <string>
#include <vector>

namespace iwlomap::detail {

inline constexpr const char* kManifestName = "iwlomap_map.manifest";

struct ManifestTile {
  VoxelKey key{};
  std::uint64_t generation = 0;
  std::uint64_t bytes = 0;
  std::uint64_t known = 0;
  std::uint32_t header_crc = 0;
};

struct RetiredFile {
  VoxelKey key{};
  std::uint64_t generation = 0;
};

/// What a map's last commit says beyond its tiles.
struct MapState {
  IwloParams params;
  bool hit_statistics = false;
  std::uint32_t hit_epoch = 0;
};

struct MapMeta;  // map_directory.h
/// The state a map's metadata records (a map without a manifest).
[[nodiscard]] MapState state_of(const MapMeta& meta);

/// Equal parameters (all 13, exactly) and hit-statistics setting.
[[nodiscard]] bool same_state(const MapState& a, const MapState& b) noexcept;

struct MapManifest {
  std::uint64_t commit = 0;
  MapState state;
  std::vector<ManifestTile> tiles;    // sorted by key
  std::vector<RetiredFile> retired;   // may name files already removed
};

/// Sorts \p tiles by tile key, the manifest's order.
void sort_by_tile(std::vector<ManifestTile>& tiles);

[[nodiscard]] std::vector<std::uint8_t> encode_manifest(const MapManifest& m);
/// Writes \p m as the manifest of \p directory durably (temporary file, fsync, rename, directory
/// fsync). Throws StorageError (kIo) naming the file.
void write_manifest_file(const std::string& directory, const MapManifest& m);
/// The last commit of the map in \p directory, which no writer may be changing: its manifest
/// (without retired files) or, for a map written before manifests, its tile files (headers read
/// and checked) and its metadata's parameters. Throws StorageError naming the file.
[[nodiscard]] MapManifest read_committed_manifest(const std::string& directory);

/// Parses and checks \p bytes (checksum, counts, sorted distinct tiles, valid parameters). Throws
/// StorageError (kCorrupt, or kNewerVersion) naming \p path.
[[nodiscard]] MapManifest decode_manifest(const std::vector<std::uint8_t>& bytes, const std::string& path);

}  // namespace iwlomap::detail
