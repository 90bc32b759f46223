// SPDX-License-Identifier: BSD-3-Clause
// The iwlomap command-line tool: maps .pcd/.ply clouds into an IWLO occupancy map and writes the
// occupied voxels. Exit codes: 0 success, 1 failure, 2 bad usage; one line on stderr on error.

#include "args.h"
#include "cloud_io.h"
#include "commands.h"
#include "progress.h"

#include <iwlomap/map_memory.h>
#include <iwlomap/version.h>
#include <pcl/console/print.h>

#include <iostream>
#include <new>
#include <string>
#include <vector>

namespace {

const char* kUsage = R"(usage: iwlomap <command> [options]

Probabilistic 3D occupancy mapping of intensity point clouds (IWLO).

commands:
  map        integrate .pcd/.ply clouds into one map, write the occupied voxels
  info       describe a .pcd/.ply cloud or a stored map (tile directory, .bt, .ot)
  export     write a stored map as .pcd, .ply, .bt or .ot
  generate   write a synthetic lidar scan (.pcd) to try the tool on
  render     draw a voxel map (.pcd/.ply, tile directory, .bt/.ot) into a PNG image, off screen
  sonar      map imaging-sonar pings (Oculus .raw) into one map, write the occupied voxels
  pyramid    write a map's multi-resolution max grids (Cartographer's precomputation grids) as PNGs
  register   find where a scan (sensor frame) fits a map; prints its pose
  repair     set the damaged tiles of a disk map aside so that the rest can be used

Run 'iwlomap <command> --help' for the options of a command, 'iwlomap --version' for the version
and the layers of this build.
)";

}  // namespace

int main(int argc, char** argv) {
  using namespace iwlomap::tool;
  // The tool reports every failure in one line of its own that names the file; PCL's console
  // messages (warnings and errors alike) would only add lines that repeat it without the path.
  pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);
  const std::vector<std::string> args(argv + 1, argv + argc);
  if (args.empty()) {
    std::cerr << kUsage;
    return 2;
  }
  const std::string& command = args[0];
  const std::vector<std::string> rest(args.begin() + 1, args.end());
  try {
    if (command == "-h" || command == "--help" || command == "help") {
      std::cout << kUsage;
      return 0;
    }
    if (command == "--version" || command == "version") {
      std::cout << "iwlomap " << iwlomap::version() << " (layers: core, filters"
#ifdef IWLOMAP_HAVE_OCTOMAP
                << ", octomap"
#endif
#ifdef IWLOMAP_HAVE_VIEWER
                << ", viewer"
#endif
#ifdef IWLOMAP_HAVE_REGISTRATION
                << ", registration"
#endif
#ifdef IWLOMAP_HAVE_SLAM
                << ", slam"
#endif
#ifdef IWLOMAP_HAVE_MPI
                << ", mpi"
#endif
                << ")\n";
      return 0;
    }
    if (command == "map") return run_map(rest);
    if (command == "info") return run_info(rest);
    if (command == "generate") return run_generate(rest);
    if (command == "export") return run_export(rest);
    if (command == "render") return run_render(rest);
    if (command == "sonar") return run_sonar(rest);
    if (command == "pyramid") return run_pyramid(rest);
    if (command == "register") return run_register(rest);
    if (command == "repair") return run_repair(rest);
    throw UsageError("unknown command '" + command + "'");
  } catch (const UsageError& e) {
    std::cerr << "iwlomap " << (command.rfind('-', 0) == 0 ? std::string() : command + " ") << "usage error: " << e.what()
              << " (see 'iwlomap " << (command.rfind('-', 0) == 0 ? std::string() : command + " ") << "--help')\n";
    return 2;
  } catch (const std::bad_alloc&) {
    show_status(true, "");
    std::cerr << "iwlomap " << command << ": error: out of memory (a finer --resolution, a longer --max-range or "
                 "larger inputs than this machine holds; --max-memory sets the budget the map keeps to)\n";
    return 1;
  } catch (const iwlomap::MemoryLimitError& e) {
    show_status(true, "");
    std::cerr << "iwlomap " << command << ": error: " << e.what() << " (--resolution, --max-range, --max-memory)\n";
    return 1;
  } catch (const std::exception& e) {
    show_status(true, "");  // a status line in progress gives way to the error
    std::cerr << "iwlomap " << command << ": error: " << e.what() << "\n";
    return 1;
  }
}
