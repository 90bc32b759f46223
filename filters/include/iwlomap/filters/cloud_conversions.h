// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Moving PCL clouds into and out of an IMapperBackend. OccupancyFilter is built on these; they
/// are public for pipelines that drive a backend directly (e.g. integrate many frames and read the
/// occupied voxels once at the end).

#include <iwlomap/mapper_backend.h>
#include <iwlomap/voxel_colors.h>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/types.h>

#include <cstdint>
#include <stdexcept>
#include <string>
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

/// The 8-bit colours of the points of \p cloud (restricted to \p indices when not null), one row
/// (r, g, b) per point, in the order of cloud_to_matrices(). The point type must have colour
/// (pcl::traits::has_color_v, e.g. pcl::PointXYZRGB or PointXYZRGBA).
template <typename PointT>
[[nodiscard]] ColorMatrix cloud_colors(const pcl::PointCloud<PointT>& cloud, const pcl::Indices* indices) {
  static_assert(pcl::traits::has_color_v<PointT>, "cloud_colors: the point type has no rgb or rgba field");
  const std::size_t n = indices != nullptr ? indices->size() : cloud.size();
  ColorMatrix colors(static_cast<Eigen::Index>(n), 3);
  for (std::size_t i = 0; i < n; ++i) {
    const PointT& p = cloud[indices != nullptr ? static_cast<std::size_t>((*indices)[i]) : i];
    const auto row = static_cast<Eigen::Index>(i);
    colors(row, 0) = p.r;
    colors(row, 1) = p.g;
    colors(row, 2) = p.b;
  }
  return colors;
}

/// Integrates \p cloud (restricted to \p indices when not null) into \p map. With ray casting, one
/// scan from `cloud.sensor_origin_` (metres, map frame) via IMapperBackend::insert_scan(); without,
/// every point is one observation (occupied iff its intensity exceeds the map's threshold) via
/// batch_update_iwlo(). Points are taken as they are stored (map frame). Non-finite points are
/// skipped and counted by the map. When \p colors is not null (the point type must have colour),
/// the colours of the hits the map counted are added to it after the map took the cloud (a cloud
/// the map refuses adds no colour); its resolution must be the map's (std::invalid_argument).
template <typename PointT>
void integrate_cloud(IMapperBackend& map, const pcl::PointCloud<PointT>& cloud, const pcl::Indices* indices,
                     bool ray_casting, double max_range, VoxelColorMeans* colors = nullptr) {
  if (!pcl::traits::has_color_v<PointT> && colors != nullptr)
    throw std::invalid_argument("integrate_cloud: colour means need a point type with an rgb or rgba field");
  if (colors != nullptr && colors->resolution() != map.get_resolution())
    throw std::invalid_argument("integrate_cloud: the colour means are at " + std::to_string(colors->resolution()) +
                                " m, the map at " + std::to_string(map.get_resolution()) + " m");
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
  cloud_to_matrices(cloud, indices, map.get_params().intensity_max, points, intensities);
  if (points.rows() == 0) return;
  const Eigen::Vector3d origin = cloud.sensor_origin_.template head<3>().template cast<double>();
  const std::vector<bool> occupied(ray_casting ? 0 : static_cast<std::size_t>(points.rows()), true);
  if (ray_casting)
    map.insert_scan(origin, points, intensities, max_range);
  else
    map.batch_update_iwlo(points, intensities, occupied);
  if constexpr (pcl::traits::has_color_v<PointT>) {
    if (colors == nullptr) return;
    const ColorMatrix rgb = cloud_colors(cloud, indices);
    if (ray_casting)
      colors->add_scan(origin, points, intensities, rgb, map.get_params(), max_range);
    else
      colors->add_observations(points, intensities, occupied, rgb, map.get_params());
  }
}

/// Writes the rows (x, y, z, p) of \p voxels (get_occupied_voxels() or
/// get_occupied_mean_positions()) into \p output as points (metres, map frame), `intensity` = p
/// where the type has it; unorganised and dense. With \p colors and a point type with colour,
/// each point's r, g, b are its voxel's mean colour (0, 0, 0 for a voxel without coloured hits);
/// otherwise they stay as PointT{} has them.
template <typename PointT>
void voxels_to_cloud(const Eigen::MatrixXd& voxels, pcl::PointCloud<PointT>& output,
                     const VoxelColorMeans* colors = nullptr) {
  output.resize(static_cast<std::size_t>(voxels.rows()));
  for (Eigen::Index i = 0; i < voxels.rows(); ++i) {
    PointT& q = output[static_cast<std::size_t>(i)];
    q = PointT{};
    q.x = static_cast<float>(voxels(i, 0));
    q.y = static_cast<float>(voxels(i, 1));
    q.z = static_cast<float>(voxels(i, 2));
    if constexpr (pcl::traits::has_intensity_v<PointT>) q.intensity = static_cast<float>(voxels(i, 3));
  }
  if constexpr (pcl::traits::has_color_v<PointT>) {
    if (colors != nullptr) {
      // From the double positions: a mean hit position near a voxel face keeps its voxel.
      const ColorMatrix rgb = colors->colors_at(voxels);
      for (Eigen::Index i = 0; i < voxels.rows(); ++i) {
        PointT& q = output[static_cast<std::size_t>(i)];
        q.r = rgb(i, 0);
        q.g = rgb(i, 1);
        q.b = rgb(i, 2);
      }
    }
  }
  output.width = static_cast<std::uint32_t>(voxels.rows());
  output.height = 1;
  output.is_dense = true;
}

/// Writes the map's voxels with probability > \p min_probability into \p output as voxel centres
/// (see voxels_to_cloud()). With \p mean_positions, each voxel is at its mean hit position instead
/// (IMapperBackend::get_occupied_mean_positions(); the map must accumulate hits).
template <typename PointT>
void occupied_to_cloud(IMapperBackend& map, double min_probability, pcl::PointCloud<PointT>& output,
                       bool mean_positions = false, const VoxelColorMeans* colors = nullptr) {
  voxels_to_cloud(mean_positions ? map.get_occupied_mean_positions(min_probability)
                                 : map.get_occupied_voxels(min_probability),
                  output, colors);
}

}  // namespace iwlomap
