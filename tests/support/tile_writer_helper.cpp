// SPDX-License-Identifier: BSD-3-Clause
// A second process for test_outofcore_tile_mapper: it writes a map directory with the Disk backend
// so that the test can open what another process wrote, and it integrates and flushes in a loop
// until it is killed, for the crash test.
//
//   tile_writer_helper write <directory> <steps> <cache_tiles>
//       applies steps 1..steps of tile_test_inputs.h, then exits (the destructor flushes); exit 0
//   tile_writer_helper loop <directory> <steps> <cache_tiles>
//       for k = 1..steps: applies step k, flushes, then writes k as a 4-byte integer to stdout, so
//       that the parent knows the last step whose flush completed when it kills this process

#include "iwlomap/outofcore_tile_mapper.h"

#include "tile_test_inputs.h"

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <string>

int main(int argc, char** argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: %s write|loop <directory> <steps> <cache_tiles>\n", argv[0]);
    return 2;
  }
  const std::string mode = argv[1];
  const std::string directory = argv[2];
  const int steps = std::atoi(argv[3]);
  const auto cache = static_cast<std::size_t>(std::atoi(argv[4]));
  try {
    iwlomap::OutofcoreTileMapper map(directory, iwlomap::tile_test::kResolution, iwlomap::tile_test::kTileSize, cache);
    for (int k = 1; k <= steps; ++k) {
      iwlomap::tile_test::apply_step(map, k);
      if (mode == "loop") {
        map.flush();
        const std::int32_t done = k;
        if (::write(STDOUT_FILENO, &done, sizeof done) != static_cast<ssize_t>(sizeof done)) return 3;
      } else if (mode != "write") {
        std::fprintf(stderr, "unknown mode '%s'\n", mode.c_str());
        return 2;
      }
    }
    map.flush();
  } catch (const std::exception& e) {
    std::fprintf(stderr, "tile_writer_helper: %s\n", e.what());
    return 1;
  }
  return 0;
}
