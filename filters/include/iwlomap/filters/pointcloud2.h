// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// pcl::PCLPointCloud2 input: a cloud whose fields are known only at run time (a ROS
/// sensor_msgs/PointCloud2 converted with pcl_conversions, a file read without a point type)
/// becomes a PointXYZI cloud that OccupancyFilter<pcl::PointXYZI> and the cloud helpers take.
/// PCL's own pcl::fromPCLPointCloud2() copies a field only when its type matches the point
/// type's (a double `x` or a 16-bit `intensity` is left at 0); this conversion reads every numeric
/// type.

#include <pcl/PCLPointCloud2.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <iwlomap/voxel_colors.h>

#include <optional>
#include <string>

namespace iwlomap {

/// The names read as the intensity field, first match wins: PCL's `intensity`, `Intensity`, and
/// CloudCompare's scalar fields `scalar_intensity` and `scalar_Intensity` (its PLY export).
inline constexpr const char* kIntensityFieldNames[] = {"intensity", "Intensity", "scalar_intensity",
                                                       "scalar_Intensity"};

/// Fills \p out with the `x`, `y`, `z` (metres) and intensity (kIntensityFieldNames) fields of
/// \p blob, each converted from whatever type it is stored as (float32/64, signed or unsigned
/// integers of 1 to 8 bytes) to float. Without an intensity field every point gets
/// \p missing_intensity (the map's
/// intensity_max makes every point a full-weight hit). Width, height (organisation) and the point
/// order are kept; `is_dense` is false, since points are not checked; the sensor origin and
/// orientation are left as \p out had them (PCLPointCloud2 does not carry them).
/// Throws std::invalid_argument naming the field when x, y or z is missing, a field lies outside
/// the point or has an unknown type, and when the data is shorter than width x height points.
void pointcloud2_to_xyzi(const pcl::PCLPointCloud2& blob, pcl::PointCloud<pcl::PointXYZI>& out,
                         float missing_intensity = 255.0f);

/// The colours of \p blob's `rgb` field (or else its `rgba` field) in PCL's packed 32-bit form
/// (0x00RRGGBB or 0xAARRGGBB; the bits are the same whether the field is stored as float32 or as a
/// 4-byte integer, and PCL's PLY reader makes one from `red`, `green`, `blue` properties), one row
/// per point in the order of pointcloud2_to_xyzi(); nullopt when the cloud has neither field.
/// Throws std::invalid_argument when the field is not 4 bytes or lies outside the point, or the
/// data is shorter than width x height points.
[[nodiscard]] std::optional<ColorMatrix> pointcloud2_colors(const pcl::PCLPointCloud2& blob);

/// Whether \p blob has an intensity field (one of kIntensityFieldNames).
[[nodiscard]] bool has_intensity(const pcl::PCLPointCloud2& blob);

/// Whether \p blob has a field named \p name.
[[nodiscard]] bool has_field(const pcl::PCLPointCloud2& blob, const std::string& name);

}  // namespace iwlomap
