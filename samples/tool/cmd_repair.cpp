// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap repair`: a usable map of the sound tiles of a damaged disk map.

#include "args.h"
#include "commands.h"

#include <iwlomap/outofcore_tile_mapper.h>

#include <iostream>

namespace iwlomap::tool {

namespace {
const char* kHelp = R"(usage: iwlomap repair DIR

Checks every tile of the disk map in DIR completely: its header, its checksums and records, and
that it is the file the map's last commit wrote. Damaged tiles, and tile files that are not part
of the map, are moved into DIR/damaged/ (a missing tile is forgotten); the map is then the other
tiles, in one commit. The voxels of the tiles set aside are lost from the map: if you have a copy
of those files, put them back instead. Prints one line per tile set aside. Exit code 0 when the
map is usable, 1 when it cannot be repaired (damaged metadata or manifest: restore them from a
copy) or another mapper has it open.
)";
}  // namespace

int run_repair(const std::vector<std::string>& argv) {
  const Args args(argv, {}, {"-h", "--help"});
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp;
    return 0;
  }
  if (args.positional().size() != 1) throw UsageError("give one map directory");
  const std::string& dir = args.positional()[0];
  const DiskMapRepair r = OutofcoreTileMapper::repair(dir);
  for (const std::string& line : r.set_aside) std::cout << line << "\n";
  if (r.set_aside.empty())
    std::cout << dir << ": every tile is sound (" << r.tiles_kept << " tiles); nothing changed\n";
  else
    std::cout << dir << ": " << r.set_aside.size() << " tile file(s) set aside, " << r.tiles_kept
              << " tiles kept; the map is usable\n";
  return 0;
}

}  // namespace iwlomap::tool
