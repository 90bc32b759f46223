// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Moving PCL clouds into and out of an IMapperBackend. OccupancyFilter is built on these; they
/// are public for pipelines that drive a backend directly (e.g. integrate many frames and read the
/// occupied voxels once at the end).

#include <iwlomap/mapper_backend.h>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/types.h>

#include <cstdint>
#include <vector>

namespace iwlomap {

/// Intensity of a point for the map: its `intensity` field, or \p intensity_max for point types
/// without one (so every point is a full-weight hit).
template <typename PointT>
[[nodiscard]] double point_intensity(const PointT& p, double intensity_max) {
  if constexpr (pcl::traits::has_intensity_v<PointT>) {
    (void)intensity_max;
    return static_cast<double>(p.intensity);
  } else {
    (void)p;
    return intensity_max;
  }
}

/// The points of \p cloud (restricted to \p indices when not null) as an N x 3 matrix in metres
/// and their intensities (point_intensity()), as IMapperBackend takes them.
template <typename PointT>
void cloud_to_matrices(const pcl::PointCloud<PointT>& cloud, const pcl::Indices* indices, double intensity_max,
                       Eigen::MatrixXd& points, Eigen::VectorXd& intensities) {
  const std::size_t n = indices != nullptr ? indices->size() : cloud.size();
  points.resize(static_cast<Eigen::Index>(n), 3);
  intensities.resize(static_cast<Eigen::Index>(n));
  for (std::size_t i = 0; i < n; ++i) {
    const PointT& p = cloud[indices != nullptr ? static_cast<std::size_t>((*indices)[i]) : i];
    const auto row = static_cast<Eigen::Index>(i);
    points(row, 0) = p.x;
    points(row, 1) = p.y;
    points(row, 2) = p.z;
    intensities[row] = point_intensity(p, intensity_max);
  }
}

/// Integrates \p cloud (restricted to \p indices when not null) into \p map. With ray casting, one
/// scan from `cloud.sensor_origin_` (metres, map frame) via IMapperBackend::insert_scan(); without,
/// every point is one observation (occupied iff its intensity exceeds the map's threshold) via
/// batch_update_iwlo(). Points are taken as they are stored (map frame). Non-finite points are
/// skipped and counted by the map.
template <typename PointT>
void integrate_cloud(IMapperBackend& map, const pcl::PointCloud<PointT>& cloud, const pcl::Indices* indices,
                     bool ray_casting, double max_range) {
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
  cloud_to_matrices(cloud, indices, map.get_params().intensity_max, points, intensities);
  if (points.rows() == 0) return;
  if (ray_casting)
    map.insert_scan(cloud.sensor_origin_.template head<3>().template cast<double>(), points, intensities, max_range);
  else
    map.batch_update_iwlo(points, intensities, std::vector<bool>(static_cast<std::size_t>(points.rows()), true));
}

/// Writes the map's voxels with probability > \p min_probability into \p output as voxel centres
/// (metres, map frame), `intensity` = probability where the type has it; unorganised and dense.
/// With \p mean_positions, each voxel is at its mean hit position instead
/// (IMapperBackend::get_occupied_mean_positions(); the map must accumulate hits).
template <typename PointT>
void occupied_to_cloud(IMapperBackend& map, double min_probability, pcl::PointCloud<PointT>& output,
                       bool mean_positions = false) {
  const Eigen::MatrixXd occupied =
      mean_positions ? map.get_occupied_mean_positions(min_probability) : map.get_occupied_voxels(min_probability);
  output.resize(static_cast<std::size_t>(occupied.rows()));
  for (Eigen::Index i = 0; i < occupied.rows(); ++i) {
    PointT& q = output[static_cast<std::size_t>(i)];
    q = PointT{};
    q.x = static_cast<float>(occupied(i, 0));
    q.y = static_cast<float>(occupied(i, 1));
    q.z = static_cast<float>(occupied(i, 2));
    if constexpr (pcl::traits::has_intensity_v<PointT>) q.intensity = static_cast<float>(occupied(i, 3));
  }
  output.width = static_cast<std::uint32_t>(occupied.rows());
  output.height = 1;
  output.is_dense = true;
}

}  // namespace iwlomap
