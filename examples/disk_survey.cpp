// SPDX-License-Identifier: BSD-3-Clause
// A survey larger than the tile cache, mapped with the Disk backend: the map lives in tiles in a
// directory, only a few tiles stay in RAM, and the map is reopened afterwards as a later run (or
// another program) would.
//
//   disk_survey DIR [SCANS]
//
// Each scan is the synthetic lidar scan moved 12 m further along x, so the survey covers a strip
// of SCANS x 12 m; a cache of 4 tiles of ~6.4 m holds a fraction of it.
#include <iwlomap/outofcore_tile_mapper.h>
#include <iwlomap/sensor_preset.h>
#include <iwlomap/synthetic_scan.h>

#include <cstdlib>
#include <iostream>
#include <string>

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: " << argv[0] << " DIR [SCANS]\n";
    return 2;
  }
  const std::string dir = argv[1];
  const int scans = argc > 2 ? std::atoi(argv[2]) : 6;
  iwlomap::SyntheticScanOptions shape;
  shape.rings = 32;
  shape.columns = 512;
  const iwlomap::SyntheticScan scan = iwlomap::make_synthetic_scan(shape);
  {
    // 0.1 m voxels, tiles of 6.4 m (64 voxels), at most 4 tiles in RAM. An existing map in DIR
    // is continued (with the parameters stored in it).
    iwlomap::OutofcoreTileMapper map(dir, 0.1, 6.4, 4);
    // Lidar: every return is a hit (stored in the map directory).
    map.set_params(iwlomap::sensor_preset_params(iwlomap::SensorPreset::kLidar));
    for (int i = 0; i < scans; ++i) {
      const Eigen::Vector3d shift(12.0 * i, 0.0, 0.0);
      map.insert_scan(scan.origin + shift, scan.points.rowwise() + shift.transpose(), scan.intensities, 25.0);
    }
    map.flush();  // every tile on disk, durable; the destructor would flush too
    std::cout << "mapped " << scans << " scans: " << map.get_num_tiles() << " tiles on disk ("
              << map.get_disk_usage() / 1e6 << " MB), at most " << map.get_peak_resident_tiles()
              << " in RAM at once (cache " << map.get_cache_tiles() << ")\n";
  }
  // Reopened: resolution, tile size and parameters come from the directory.
  const iwlomap::DiskMapInfo info = iwlomap::OutofcoreTileMapper::read_map_info(dir);
  iwlomap::OutofcoreTileMapper map(dir, info.resolution, info.tile_size, 4);
  const Eigen::MatrixXd occupied = map.get_occupied_voxels(map.get_params().occupied_threshold);
  std::cout << "reopened: " << map.get_num_nodes() << " known voxels, " << occupied.rows() << " occupied\n";
  return occupied.rows() > 0 ? 0 : 1;
}
