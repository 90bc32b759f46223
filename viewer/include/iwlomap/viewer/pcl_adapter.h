// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Renders PCL clouds with SnapshotRenderer. Header-only on purpose: iwlomap::viewer itself does
/// not depend on PCL; a program that includes this header links PCL anyway.

#include "iwlomap/viewer/snapshot_renderer.h"

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <Eigen/Core>

#include <string>

namespace iwlomap::viewer {

/// The N x 4 (x, y, z, p) matrix SnapshotRenderer takes, from a cloud of voxel centres such as
/// OccupancyFilter's output: p is the point's `intensity` (the filter stores the occupancy
/// probability there) or \p probability for point types without one.
template <typename PointT>
[[nodiscard]] Eigen::MatrixXd cloud_to_voxels(const pcl::PointCloud<PointT>& cloud, double probability = 1.0) {
  Eigen::MatrixXd v(static_cast<Eigen::Index>(cloud.size()), 4);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const PointT& p = cloud[i];
    const auto row = static_cast<Eigen::Index>(i);
    v(row, 0) = p.x;
    v(row, 1) = p.y;
    v(row, 2) = p.z;
    if constexpr (pcl::traits::has_intensity_v<PointT>) {
      (void)probability;
      v(row, 3) = p.intensity;
    } else {
      v(row, 3) = probability;
    }
  }
  return v;
}

/// \p options, with voxel_rgb filled from the points' r, g, b when it asks for ColorBy::kRgb, has
/// no colours of its own and the point type has colour (e.g. OccupancyFilter<PointXYZRGB>'s output).
template <typename PointT>
[[nodiscard]] SnapshotOptions with_cloud_colors(const pcl::PointCloud<PointT>& cloud, SnapshotOptions options) {
  if constexpr (pcl::traits::has_color_v<PointT>) {
    if (options.color_by == ColorBy::kRgb && options.voxel_rgb.rows() == 0) {
      options.voxel_rgb.resize(static_cast<Eigen::Index>(cloud.size()), 3);
      for (std::size_t i = 0; i < cloud.size(); ++i)
        options.voxel_rgb.row(static_cast<Eigen::Index>(i)) << cloud[i].r, cloud[i].g, cloud[i].b;
    }
  }
  return options;
}

/// SnapshotRenderer::render() of a cloud of voxel centres (see cloud_to_voxels()); ColorBy::kRgb
/// takes the points' own colours (with_cloud_colors()).
template <typename PointT>
[[nodiscard]] RgbImage render_cloud(const pcl::PointCloud<PointT>& cloud, double resolution,
                                    const SnapshotOptions& options) {
  return SnapshotRenderer::render(cloud_to_voxels(cloud), resolution, with_cloud_colors(cloud, options));
}

/// SnapshotRenderer::render_png() of a cloud of voxel centres (see render_cloud()).
template <typename PointT>
void render_cloud_png(const pcl::PointCloud<PointT>& cloud, double resolution, const SnapshotOptions& options,
                      const std::string& path) {
  SnapshotRenderer::render_png(cloud_to_voxels(cloud), resolution, with_cloud_colors(cloud, options), path);
}

}  // namespace iwlomap::viewer
