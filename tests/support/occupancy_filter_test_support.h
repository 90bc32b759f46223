// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Helpers of the OccupancyFilter tests (test_occupancy_filter.cpp, test_occupancy_filter_points.cpp,
// test_occupancy_filter_data.cpp): the XYZI cloud and filter types, a small scan of a wall, and
// the voxel keys of a cloud.

#include <Eigen/Geometry>
#include <iwlomap/filters/occupancy_filter.h>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <cmath>
#include <cstdint>
#include <random>
#include <set>
#include <tuple>

namespace iwlomap::filter_test {

using Cloud = pcl::PointCloud<pcl::PointXYZI>;
using Filter = iwlomap::OccupancyFilter<pcl::PointXYZI>;

// A small scene seen from (0.05, 0.05, 0.05): a wall at x = 2 m, hit by a fan of rays.
inline Cloud::Ptr make_wall_scan(float intensity = 200.0f, int n = 200, std::uint32_t seed = 7) {
  Cloud::Ptr c(new Cloud);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-0.5f, 0.5f);
  for (int i = 0; i < n; ++i) {
    pcl::PointXYZI p;
    p.x = 2.0f;
    p.y = u(rng);
    p.z = u(rng);
    p.intensity = intensity;
    c->push_back(p);
  }
  c->sensor_origin_ = Eigen::Vector4f(0.05f, 0.05f, 0.05f, 0.0f);
  c->sensor_orientation_ = Eigen::Quaternionf(Eigen::AngleAxisf(0.3f, Eigen::Vector3f::UnitZ()));
  c->header.frame_id = "map";
  c->header.stamp = 123456;
  c->header.seq = 42;
  return c;
}

using KeySet = std::set<std::tuple<long, long, long>>;
inline KeySet keys_of(const Cloud& c, double resolution) {
  KeySet s;
  for (const auto& p : c)
    s.emplace(std::lround(std::floor(p.x / resolution)), std::lround(std::floor(p.y / resolution)),
              std::lround(std::floor(p.z / resolution)));
  return s;
}

}  // namespace iwlomap::filter_test
