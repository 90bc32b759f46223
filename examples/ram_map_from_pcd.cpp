// SPDX-License-Identifier: BSD-3-Clause
// A RAM map from one or more .pcd files: read each cloud with PCL, cast its rays from the sensor
// origin stored in the file (the PCD VIEWPOINT), and print what the map holds.
//
//   ram_map_from_pcd SCAN.pcd [MORE.pcd...]
//
// Points are taken in the map frame as stored, in metres; the lidar preset (every return is a
// hit, however dark, weighted by its intensity) suits lidar scans.
#include <iwlomap/filters/cloud_conversions.h>
#include <iwlomap/probability_updater.h>
#include <iwlomap/sensor_preset.h>

#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include <iostream>

int main(int argc, char** argv) {
  if (argc < 2) {
    std::cerr << "usage: " << argv[0] << " SCAN.pcd [MORE.pcd...]\n";
    return 2;
  }
  iwlomap::ProbabilityUpdater map(0.1);  // 10 cm voxels
  const iwlomap::IwloParams params = iwlomap::sensor_preset_params(iwlomap::SensorPreset::kLidar);
  map.set_params(params);                // lidar: every return is a hit, however dark

  for (int i = 1; i < argc; ++i) {
    pcl::PointCloud<pcl::PointXYZI> cloud;
    if (pcl::io::loadPCDFile(argv[i], cloud) < 0) {
      std::cerr << "cannot read " << argv[i] << "\n";
      return 1;
    }
    // One scan: rays from cloud.sensor_origin_ to each point, 30 m at most.
    iwlomap::integrate_cloud(map, cloud, nullptr, /*ray_casting=*/true, /*max_range=*/30.0);
    std::cout << argv[i] << ": " << cloud.size() << " points\n";
  }

  // The occupied voxels: one row per voxel, x y z of its centre (metres) and its probability.
  const Eigen::MatrixXd occupied = map.get_occupied_voxels(params.occupied_threshold);
  std::cout << map.get_num_nodes() << " known voxels, " << occupied.rows() << " occupied (p > "
            << params.occupied_threshold << "), " << map.get_memory_usage().memory_mb << " MiB\n";
  // Any point can be asked about: unknown space has no state.
  if (const auto v = map.query(Eigen::Vector3d(0.0, 0.0, 0.0)))
    std::cout << "at the origin: p = " << v->probability << " after " << v->count << " observations\n";
  return occupied.rows() > 0 ? 0 : 1;
}
