// SPDX-License-Identifier: BSD-3-Clause
// The occupancy map as a step of a PCL pipeline: PassThrough (keep a height band) ->
// OccupancyFilter (integrate the frame, output the occupied voxels of the map so far) ->
// VoxelGrid (coarser output), frame after frame.
//
//   filter_pipeline [FRAME.pcd...]     (without files: three synthetic scans)
#include <iwlomap/filters/occupancy_filter.h>
#include <iwlomap/synthetic_scan.h>

#include <pcl/filters/passthrough.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/io/pcd_io.h>

#include <iostream>
#include <vector>

using Cloud = pcl::PointCloud<pcl::PointXYZI>;

// A synthetic lidar scan as a PCL cloud with its sensor origin, moved dx metres along x.
Cloud::Ptr synthetic_frame(double dx) {
  const iwlomap::SyntheticScan scan = iwlomap::make_synthetic_scan();
  auto cloud = pcl::make_shared<Cloud>();
  for (Eigen::Index i = 0; i < scan.points.rows(); ++i) {
    pcl::PointXYZI p;
    p.x = static_cast<float>(scan.points(i, 0) + dx);
    p.y = static_cast<float>(scan.points(i, 1));
    p.z = static_cast<float>(scan.points(i, 2));
    p.intensity = static_cast<float>(scan.intensities[i]);
    cloud->push_back(p);
  }
  cloud->sensor_origin_ = Eigen::Vector4f(static_cast<float>(scan.origin.x() + dx), static_cast<float>(scan.origin.y()),
                                          static_cast<float>(scan.origin.z()), 0.0f);
  return cloud;
}

int main(int argc, char** argv) {
  std::vector<Cloud::Ptr> frames;
  for (int i = 1; i < argc; ++i) {
    auto cloud = pcl::make_shared<Cloud>();
    if (pcl::io::loadPCDFile(argv[i], *cloud) < 0) return 1;
    frames.push_back(cloud);
  }
  if (frames.empty())
    for (double dx : {0.0, 0.5, 1.0}) frames.push_back(synthetic_frame(dx));

  pcl::PassThrough<pcl::PointXYZI> band;
  band.setFilterFieldName("z");
  band.setFilterLimits(-5.0f, 10.0f);

  iwlomap::OccupancyFilter<pcl::PointXYZI> occupancy;  // one map across all frames
  occupancy.setResolution(0.1);
  occupancy.setMaxRange(30.0);
  occupancy.setSensorPreset(iwlomap::SensorPreset::kLidar);  // every return is a hit

  pcl::VoxelGrid<pcl::PointXYZI> coarse;
  coarse.setLeafSize(0.5f, 0.5f, 0.5f);

  std::size_t last = 0;
  for (const auto& frame : frames) {
    auto in_band = pcl::make_shared<Cloud>();
    band.setInputCloud(frame);
    band.filter(*in_band);
    in_band->sensor_origin_ = frame->sensor_origin_;  // the ray origin travels with the cloud

    auto occupied = pcl::make_shared<Cloud>();  // voxel centres, intensity = probability
    occupancy.setInputCloud(in_band);
    occupancy.filter(*occupied);

    Cloud out;
    coarse.setInputCloud(occupied);
    coarse.filter(out);
    std::cout << frame->size() << " points -> " << in_band->size() << " in band -> " << occupied->size()
              << " occupied voxels -> " << out.size() << " at 0.5 m\n";
    last = out.size();
  }
  return last > 0 ? 0 : 1;
}
