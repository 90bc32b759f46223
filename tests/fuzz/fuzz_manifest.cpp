// SPDX-License-Identifier: BSD-3-Clause
// Fuzz target: the Disk backend's manifest reader. The checksum is recomputed over the input
// first (a random change would otherwise only ever exercise the checksum test). A manifest the
// reader accepts must encode back to the same bytes: the format has one way to say each thing,
// so an accepted input that differs is a reader that let something through.

#include "backends/disk/map_manifest.h"
#include "backends/disk/tile_file.h"
#include "iwlomap/outofcore_tile_mapper.h"

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <vector>

namespace d = iwlomap::detail;

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  if (size < 4) return 0;
  std::vector<std::uint8_t> bytes(data, data + size);
  d::store_u32(bytes.data() + size - 4, d::crc32(bytes.data(), size - 4));
  d::MapManifest m;
  try {
    m = d::decode_manifest(bytes, "fuzz.manifest");
  } catch (const iwlomap::StorageError&) {
    return 0;  // the reader's answer to a damaged manifest
  }
  if (d::encode_manifest(m) != bytes) std::abort();
  return 0;
}
