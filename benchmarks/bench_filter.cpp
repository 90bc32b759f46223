// SPDX-License-Identifier: BSD-3-Clause
// The PCL filter end to end, per recorded Ouster frame, against the backend's insert_scan alone
// and against OctoMap's insertPointCloud on the same frame, measured side by side in one run.
//   filter       OccupancyFilter::filter(): cloud -> matrices, insert_scan, occupied voxels -> cloud
//   insert_scan  ProbabilityUpdater::insert_scan() on matrices prepared beforehand
//   OctoMap      octomap::OcTree::insertPointCloud() on an octomap::Pointcloud prepared beforehand
// Each frame goes into a fresh map, with the same resolution and maximum range for all three.
// usage: bench_filter [--data DIR] [--reps N] [--resolution R] [--max-range M]

#include "bench_util.h"

#include <iwlomap/filters/cloud_conversions.h>
#include <iwlomap/filters/occupancy_filter.h>
#include <iwlomap/probability_updater.h>

#include <octomap/octomap.h>
#include <pcl/console/print.h>
#include <pcl/io/pcd_io.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

namespace {

using iwlomap::bench::Clock;
using iwlomap::bench::median;
using iwlomap::bench::ms_since;

}  // namespace

int main(int argc, char** argv) {
  std::string data = IWLOMAP_BENCH_DATA_DIR;
  int reps = 3;
  double resolution = 0.1, max_range = 25.0;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--data" && i + 1 < argc) data = argv[++i];
    else if (a == "--reps" && i + 1 < argc) reps = std::atoi(argv[++i]);
    else if (a == "--resolution" && i + 1 < argc) resolution = std::atof(argv[++i]);
    else if (a == "--max-range" && i + 1 < argc) max_range = std::atof(argv[++i]);
    else {
      std::fprintf(stderr, "usage: %s [--data DIR] [--reps N] [--resolution R] [--max-range M]\n", argv[0]);
      return 2;
    }
  }
  if (reps < 1 || !(resolution > 0.0)) {
    std::fprintf(stderr, "bench_filter: --reps must be >= 1 and --resolution > 0\n");
    return 2;
  }
  pcl::console::setVerbosityLevel(pcl::console::L_ERROR);
  const std::filesystem::path dir = std::filesystem::path(data) / "ouster_os1_128_3frames";
  if (!std::filesystem::exists(dir)) {
    std::fprintf(stderr, "bench_filter: recorded data not found at %s (use --data DIR)\n", dir.c_str());
    return 1;
  }
  std::printf("bench_filter: Ouster OS-1-128 frames, resolution %.3f m, max range %.1f m, median of %d, one thread\n\n",
              resolution, max_range, reps);
  std::printf("  frame   points   filter ms  insert_scan ms  OctoMap ms   filter/insert  OctoMap/filter  occupied\n");
  for (int k = 0; k < 3; ++k) {
    const auto path = dir / ("frame_00" + std::to_string(k) + "_world.pcd");
    pcl::PointCloud<pcl::PointXYZI>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZI>);
    if (pcl::io::loadPCDFile(path.string(), *cloud) < 0) {
      std::fprintf(stderr, "bench_filter: cannot read %s\n", path.c_str());
      return 1;
    }
    iwlomap::IwloParams lidar;
    lidar.intensity_threshold = 0.0;  // every return with a positive intensity is a hit

    Eigen::MatrixXd points;
    Eigen::VectorXd intensities;
    iwlomap::cloud_to_matrices(*cloud, nullptr, lidar.intensity_max, points, intensities);
    const Eigen::Vector3d origin = cloud->sensor_origin_.head<3>().cast<double>();
    octomap::Pointcloud octo_points;
    for (const auto& p : *cloud) octo_points.push_back(p.x, p.y, p.z);
    const octomap::point3d octo_origin(static_cast<float>(origin.x()), static_cast<float>(origin.y()),
                                       static_cast<float>(origin.z()));

    std::vector<double> t_filter, t_insert, t_octo;
    std::size_t occupied = 0;
    for (int r = 0; r < reps; ++r) {
      {
        iwlomap::OccupancyFilter<pcl::PointXYZI> filter;
        filter.setResolution(resolution);
        filter.setMaxRange(max_range);
        filter.setIwloParams(lidar);
        filter.setInputCloud(cloud);
        pcl::PointCloud<pcl::PointXYZI> out;
        const auto t0 = Clock::now();
        filter.filter(out);
        t_filter.push_back(ms_since(t0));
        occupied = out.size();
      }
      {
        iwlomap::ProbabilityUpdater map(resolution);
        map.set_params(lidar);
        const auto t0 = Clock::now();
        map.insert_scan(origin, points, intensities, max_range);
        t_insert.push_back(ms_since(t0));
      }
      {
        octomap::OcTree tree(resolution);
        const auto t0 = Clock::now();
        tree.insertPointCloud(octo_points, octo_origin, max_range);
        t_octo.push_back(ms_since(t0));
      }
    }
    const double f = median(t_filter), i = median(t_insert), o = median(t_octo);
    std::printf("  %5d  %7zu  %10.1f  %14.1f  %10.1f  %14.2f  %14.1fx  %8zu\n", k, cloud->size(), f, i, o, f / i, o / f,
                occupied);
  }
  std::printf("\n(filter/insert: the cost of the PCL layer on top of the backend; OctoMap/filter: how much\n"
              " faster the whole filter is than OctoMap's insertPointCloud alone)\n");
  return 0;
}
