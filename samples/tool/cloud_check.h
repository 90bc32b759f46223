// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Cloud files checked before PCL parses them, and their fields converted by type. PCL's readers
// trust a file's header: a negative or huge COUNT or SIZE, a vertex count beyond the file or a
// compressed block of the wrong size makes them crash, hang or allocate gigabytes, and a double
// field is read as zeros by pcl::fromPCLPointCloud2. The tool therefore reads only files whose
// header is consistent with itself and with the file's size, and converts the fields itself.

#include <iwlomap/voxel_colors.h>

#include <pcl/PCLPointCloud2.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <cstdint>

#include <optional>
#include <string>
#include <vector>

namespace iwlomap::tool {

/// What a checked header promises (PCD; PLY fills `points` only).
struct CloudHeader {
  std::uint64_t points = 0;  ///< WIDTH * HEIGHT (PCD) or the vertex count (PLY)
  std::uint64_t fields = 0;      ///< entries of FIELDS (PCD)
  std::uint64_t point_size = 0;  ///< bytes per point (PCD)
  bool has_viewpoint = false;
  /// The header's comment lines without their marker ('#' in PCD, "comment " in PLY), in order.
  std::vector<std::string> comments;
};

/// Checks the header of the .pcd or .ply file \p path against the formats and against the size
/// of the file: field names, sizes (1, 2, 4 or 8 bytes), types, counts, WIDTH * HEIGHT = POINTS,
/// a finite VIEWPOINT, the data kind, and that the data the header promises fits in the file (the
/// compressed block's sizes for binary_compressed; at least one line per point for ASCII; the
/// vertex count against the body for PLY). Throws std::runtime_error "'path': ..." naming the
/// first field that is wrong.
CloudHeader check_cloud_file(const std::string& path);

/// Copies the x, y, z and (when present) intensity fields of \p blob into \p out, converting from
/// any type PCL stores (float32/64, signed and unsigned integers of 1 to 8 bytes); a missing
/// intensity field gives every point \p missing_intensity. \p colors gets the points' colours when
/// the cloud has an rgb or rgba field (pointcloud2_colors()), nullopt otherwise. Throws
/// std::runtime_error naming \p path when x, y or z is missing or a field lies outside the point.
void blob_to_xyzi(const pcl::PCLPointCloud2& blob, float missing_intensity, const std::string& path,
                  pcl::PointCloud<pcl::PointXYZI>& out, std::optional<ColorMatrix>& colors);

}  // namespace iwlomap::tool
