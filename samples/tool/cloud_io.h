// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Reading and writing .pcd / .ply clouds for the iwlomap tool, with errors that name the file.

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <iwlomap/voxel_colors.h>

#include <Eigen/Geometry>

#include <optional>
#include <string>

namespace iwlomap::tool {

/// What a map cloud written by the tool records about itself in a header comment
/// (`# iwlomap map resolution 0.1 positions centres` in a PCD, `comment iwlomap map ...` in a
/// PLY), so that a reader needs no --resolution.
struct MapCloudInfo {
  double resolution = 0.0;      ///< voxel edge in metres
  bool mean_positions = false;  ///< points at the mean hit positions (else at the voxel centres)
};

struct LoadedCloud {
  pcl::PointCloud<pcl::PointXYZI>::Ptr cloud;
  bool has_intensity = true;  ///< false: the file had no intensity field (filled with a default)
  std::optional<ColorMatrix> colors;  ///< one row per point when the file has an rgb/rgba field
  std::optional<MapCloudInfo> map_info;  ///< the file's map comment, when it has one
};

/// Loads a .pcd or .ply file as PointXYZI, keeping the sensor origin and orientation of a PCD's
/// VIEWPOINT, and the MapCloudInfo of its header comment. A file without an `intensity` field gets
/// \p missing_intensity for every point. Throws std::runtime_error naming the file when it is
/// missing, unreadable or has no x/y/z, or when its iwlomap map comment is malformed.
[[nodiscard]] LoadedCloud load_cloud(const std::string& path, float missing_intensity);

/// The cloud's sensor pose (sensor to map): its VIEWPOINT's origin and orientation.
[[nodiscard]] Eigen::Isometry3d viewpoint_pose(const pcl::PointCloud<pcl::PointXYZI>& cloud);

/// Writes a cloud as binary .pcd or .ply by the extension of \p file (an OutputFiles temporary),
/// with \p info as its header comment when given; throws std::runtime_error naming \p shown_as
/// on failure.
void save_cloud(const std::string& file, const pcl::PointCloud<pcl::PointXYZI>& cloud, const std::string& shown_as,
                const std::optional<MapCloudInfo>& info = std::nullopt);

/// As save_cloud(), with an `rgb` field (PCL's packed colour; a PLY gets red, green and blue
/// properties) from \p colors, one row per point of \p cloud.
void save_cloud(const std::string& file, const pcl::PointCloud<pcl::PointXYZI>& cloud, const ColorMatrix& colors,
                const std::string& shown_as, const std::optional<MapCloudInfo>& info = std::nullopt);

}  // namespace iwlomap::tool
