// SPDX-License-Identifier: BSD-3-Clause
// The PCL filter in a pipeline: PassThrough -> OccupancyFilter -> VoxelGrid.
#include <iwlomap/filters/occupancy_filter.h>

#include <pcl/filters/passthrough.h>
#include <pcl/filters/voxel_grid.h>

#include <iostream>

int main() {
  auto cloud = pcl::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  for (int i = 0; i < 400; ++i) {
    pcl::PointXYZI p;
    p.x = 3.0f;
    p.y = -1.0f + 0.005f * static_cast<float>(i);
    p.z = 0.5f;
    p.intensity = 200.0f;
    cloud->push_back(p);
  }
  cloud->sensor_origin_ = Eigen::Vector4f(0.0f, 0.0f, 0.5f, 0.0f);
  pcl::PassThrough<pcl::PointXYZI> pass;
  pass.setInputCloud(cloud);
  pass.setFilterFieldName("x");
  pass.setFilterLimits(0.0f, 10.0f);
  auto passed = pcl::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  pass.filter(*passed);
  iwlomap::OccupancyFilter<pcl::PointXYZI> occupancy;
  occupancy.setResolution(0.1);
  occupancy.setInputCloud(passed);
  auto occupied = pcl::make_shared<pcl::PointCloud<pcl::PointXYZI>>();
  occupancy.filter(*occupied);
  pcl::VoxelGrid<pcl::PointXYZI> grid;
  grid.setInputCloud(occupied);
  grid.setLeafSize(0.2f, 0.2f, 0.2f);
  pcl::PointCloud<pcl::PointXYZI> out;
  grid.filter(out);
  std::cout << "consumer: " << occupied->size() << " occupied voxels, " << out.size() << " after the voxel grid\n";
#ifdef PCL_NO_PRECOMPILE
  // A point type the library does not precompile: the header brings the implementation along.
  pcl::PointCloud<pcl::PointWithViewpoint> with_viewpoint;
  for (const auto& p : *cloud) {
    pcl::PointWithViewpoint q;
    q.x = p.x;
    q.y = p.y;
    q.z = p.z;
    with_viewpoint.push_back(q);
  }
  with_viewpoint.sensor_origin_ = cloud->sensor_origin_;
  iwlomap::OccupancyFilter<pcl::PointWithViewpoint> any_type;
  any_type.setResolution(0.1);
  any_type.setInputCloud(pcl::make_shared<pcl::PointCloud<pcl::PointWithViewpoint>>(with_viewpoint));
  pcl::PointCloud<pcl::PointWithViewpoint> any_out;
  any_type.filter(any_out);
  std::cout << "consumer: PointWithViewpoint (PCL_NO_PRECOMPILE): " << any_out.size() << " occupied voxels\n";
  if (any_out.size() != occupied->size()) return 1;
#endif
  return occupied->size() >= 15 && !out.empty() ? 0 : 1;
}
