// SPDX-License-Identifier: BSD-3-Clause
// Fuzz target: the Disk backend's tile reader. The checksums are recomputed over the input first
// (a random change would otherwise only ever exercise the checksum test), and the header's own
// resolution, tile edge and coordinate are the expected ones, so the input reaches the record
// decoder; every block it accepts is stored in a block grid as the backend does. The map's voxel
// layout is the defaults' or that of 12-bit counts (by the input's last byte), so both the copy
// of words in the map's own layout and the conversion of another run.

#include "backends/disk/tile_file.h"
#include "integrate/hit_accumulator.h"
#include "storage/block_grid.h"
#include "iwlomap/outofcore_tile_mapper.h"

#include <cstddef>
#include <cstdint>
#include <cstring>
#include <vector>

namespace d = iwlomap::detail;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < d::kTileHeaderBytes) return 0;
  std::vector<std::uint8_t> bytes(data, data + size);
  std::uint8_t* h = bytes.data();
  d::store_u32(h + 64, d::crc32(h + d::kTileHeaderBytes, size - d::kTileHeaderBytes));
  d::store_u32(h + 76, d::crc32(h, d::kTileHeaderBytes - 4));
  double resolution = 0.0;
  const std::uint64_t res_bits = d::load_u64(h + 24);
  std::memcpy(&resolution, &res_bits, sizeof resolution);
  const std::uint32_t tile_voxels = d::load_u32(h + 20);
  const iwlomap::VoxelKey tile{static_cast<std::int32_t>(d::load_u32(h + 32)), static_cast<std::int32_t>(d::load_u32(h + 36)),
                               static_cast<std::int32_t>(d::load_u32(h + 40))};
  try {
    const d::TileHeader header = d::parse_tile_header(h, size, size, resolution, tile_voxels, tile, "fuzz.tile");
    d::BlockGrid grid;
    d::HitAccumulator hits(header.resolution);
    d::DenseBlock scratch;
    static const iwlomap::iwlo::VoxelFormat formats[2] = {
        iwlomap::iwlo::VoxelFormat{}, iwlomap::iwlo::voxel_format([] {
          iwlomap::IwloParams p;
          p.decay_rate = 0.001;
          return p;
        }())};
    d::decode_tile(
        bytes, header, tile_voxels, "fuzz.tile", formats[data[size - 1] & 1], scratch,
        [&](const d::DenseBlock& block) {
          if (grid.find(block.key) == nullptr) grid.add_dense(block);
        },
        [&](const iwlomap::VoxelKey& key, const d::HitAccumulator::Block& block) { hits.merge(key, block); });
  } catch (const iwlomap::StorageError&) {
    return 0;  // the reader's answer to a corrupt tile
  }
  return 0;
}
