// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap export`: a stored map (disk-backend tile directory, or .bt/.ot) to a cloud or OctoMap file.

#include "args.h"
#include "cloud_io.h"
#include "commands.h"
#include "map_open.h"
#include "output_files.h"
#include "progress.h"

#include <iwlomap/filters/cloud_conversions.h>

#ifdef IWLOMAP_HAVE_OCTOMAP
#include <iwlomap/octomap/octree_mapper.h>
#endif

#include <filesystem>
#include <iostream>
#include <stdexcept>

namespace iwlomap::tool {

namespace {
const char* kHelp = R"(usage: iwlomap export MAP -o OUT.pcd|OUT.ply|OUT.bt|OUT.ot [--threshold P]

Writes a stored map in another format. MAP is a disk-backend tile directory (as written by
'iwlomap map --backend disk --tiles DIR') or an OctoMap .bt/.ot file; it is opened with its stored
resolution and read tile by tile, so a map larger than RAM exports with bounded memory.

  -o, --output FILE   .pcd / .ply: the occupied voxels (centres, intensity = probability);
                      .bt / .ot: the whole map as an OctoMap file (needs the OctoMap layer)
  --threshold P       voxels with probability > P are occupied (default 0.7)
  --cache-tiles N     tiles a tile directory may hold in RAM while exporting (default 4)
  -q, --quiet         no progress bar, no summary line
)";
}  // namespace

int run_export(const std::vector<std::string>& argv) {
  const Args args(argv, {"-o", "--output", "--threshold", "--cache-tiles"}, {"-h", "--help", "-q", "--quiet"});
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp;
    return 0;
  }
  if (args.positional().size() != 1) throw UsageError("give exactly one map (a tile directory, .bt or .ot)");
  const std::string input = args.positional().front();
  if (!is_map_path(input)) throw UsageError("'" + input + "' is not a tile directory, .bt or .ot file");
  const auto output = args.value("-o") ? args.value("-o") : args.value("--output");
  if (!output) throw UsageError("no output file (-o OUT.pcd|.ply|.bt|.ot)");
  OutputFiles files(args);
  files.add("-o", *output, {".pcd", ".ply", ".bt", ".ot"});
  const std::string ext = extension(*output);
  const bool quiet = args.flag("-q") || args.flag("--quiet");
  const double threshold = args.number("--threshold", 0.7);
  if (!(threshold > 0.0 && threshold < 1.0)) throw UsageError("--threshold must be in (0, 1)");
  const long cache = args.integer("--cache-tiles", 4);
  if (cache < 1) throw UsageError("--cache-tiles must be >= 1");

  const auto map = open_map(input, static_cast<std::size_t>(cache));
  if (ext == ".bt" || ext == ".ot") {
#ifdef IWLOMAP_HAVE_OCTOMAP
    // .bt stores occupied / free by this threshold; the bar follows the blocks written.
    Progress bar("writing", 1, !quiet);
    files.write(*output, [&](const std::string& file) {
      export_octomap(*map, file, threshold, progress_within(bar, 0, std::filesystem::path(*output).filename().string()));
    });
#else
    throw std::runtime_error("writing OctoMap files needs the OctoMap layer (build with -DIWLOMAP_WITH_OCTOMAP=ON)");
#endif
  } else {
    show_status(!quiet, "reading the occupied voxels of " + input);
    pcl::PointCloud<pcl::PointXYZI> occupied;
    occupied_to_cloud(*map, threshold, occupied);
    show_status(!quiet, "writing " + *output);
    save_cloud(files.temporary(*output), occupied, *output, MapCloudInfo{map->get_resolution(), false});
  }
  files.commit();
  show_status(!quiet, "");
  if (quiet) return 0;
  std::cout << "wrote " << *output << " from " << input << " (" << map->get_backend_type() << " map, "
            << map->get_num_known_voxels() << " known voxels at " << map->get_resolution() << " m)\n";
  return 0;
}

}  // namespace iwlomap::tool
