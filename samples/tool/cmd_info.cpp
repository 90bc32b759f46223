// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap info`: what a cloud file or a stored map holds.

#include "args.h"
#include "cloud_io.h"
#include "commands.h"
#include "map_open.h"

#include <iwlomap/map_entropy.h>
#include <iwlomap/outofcore_tile_mapper.h>

#include <cmath>
#include <iostream>
#include <limits>
#include <stdexcept>

namespace iwlomap::tool {

namespace {
const char* kHelp = R"(usage: iwlomap info FILE...

Describes each FILE: for a .pcd or .ply cloud, the number of points (and of non-finite ones),
the organisation, the bounding box in metres, the intensity range and the sensor origin; for a
stored map -- a disk-backend tile directory, or a .bt/.ot OctoMap file (with the OctoMap layer) --
the resolution, the known and occupied voxels, their bounding box and the map entropy: the
Shannon entropy of the occupancy probabilities summed over the known voxels, in bits, and the
unknown voxels of the bounding box (1 bit each for an explorer); for a tile directory also the
tiles and the bytes on disk.
)";

// A stored map: size, bounds and entropy (iwlomap/map_entropy.h).
void describe_map(const std::string& path) {
  const auto map = open_map(path);
  const double r = map->get_resolution();
  std::cout << path << ": " << map->get_backend_type() << " map, " << map->get_num_known_voxels() << " known voxels at " << r
            << " m, " << map->get_occupied_voxels(map->get_params().occupied_threshold).rows() << " occupied (p > "
            << map->get_params().occupied_threshold << ")\n";
  if (const auto* disk = dynamic_cast<const OutofcoreTileMapper*>(map.get()))
    std::cout << "  tiles: " << disk->get_num_tiles() << " of " << disk->get_tile_size() << " m, "
              << disk->get_disk_usage() << " bytes on disk\n";
  const auto box = known_voxel_box(*map);
  if (!box) return;
  std::cout << "  bounds (m): x [" << box->min.x * r << ", " << (box->max.x + 1) * r << "] y [" << box->min.y * r << ", "
            << (box->max.y + 1) * r << "] z [" << box->min.z * r << ", " << (box->max.z + 1) * r << "]\n";
  const BoxEntropy e = box_entropy(*map, *box);
  std::cout << "  entropy: " << e.known_bits << " bits over the known voxels (" << e.known_bits / static_cast<double>(e.known_voxels)
            << " per voxel); " << e.unknown_voxels << " unknown voxels in the bounds (" << e.total_bits()
            << " bits counting 1 bit each)\n";
}
}  // namespace

int run_info(const std::vector<std::string>& argv) {
  const Args args(argv, {}, {"-h", "--help"});
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp;
    return 0;
  }
  if (args.positional().empty()) throw UsageError("no file given");
  for (const std::string& path : args.positional()) {
    if (is_map_path(path)) {
      describe_map(path);
      continue;
    }
    const LoadedCloud in = load_cloud(path, std::numeric_limits<float>::quiet_NaN());
    const auto& c = *in.cloud;
    Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max()), hi = -lo;
    float imin = std::numeric_limits<float>::max(), imax = -imin;
    std::size_t finite = 0;
    for (const auto& p : c) {
      const Eigen::Vector3f v(p.x, p.y, p.z);
      if (!v.allFinite()) continue;
      ++finite;
      lo = lo.cwiseMin(v);
      hi = hi.cwiseMax(v);
      if (std::isfinite(p.intensity)) {
        imin = std::min(imin, p.intensity);
        imax = std::max(imax, p.intensity);
      }
    }
    std::cout << path << ": cloud, " << c.size() << " points (" << c.size() - finite << " non-finite), "
              << (c.height > 1 ? "organised " + std::to_string(c.width) + " x " + std::to_string(c.height)
                               : std::string("unorganised"))
              << "\n";
    if (finite > 0)
      std::cout << "  bounds (m): x [" << lo.x() << ", " << hi.x() << "] y [" << lo.y() << ", " << hi.y() << "] z ["
                << lo.z() << ", " << hi.z() << "]\n";
    if (!in.has_intensity)
      std::cout << "  intensity: none (the map tool uses --intensity-max for every point)\n";
    else if (imin <= imax)
      std::cout << "  intensity: [" << imin << ", " << imax << "]\n";
    const auto& o = c.sensor_origin_;
    const auto& q = c.sensor_orientation_;
    std::cout << "  sensor origin (m): (" << o.x() << ", " << o.y() << ", " << o.z() << "), orientation (w x y z): ("
              << q.w() << ", " << q.x() << ", " << q.y() << ", " << q.z() << ")\n";
  }
  return 0;
}

}  // namespace iwlomap::tool
