// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Trajectories as text files that evaluation tools (evo) read:
/// - TUM: one line per pose, `t x y z qx qy qz qw` (seconds; metres; unit quaternion);
/// - KITTI: one line per pose, the first three rows of the 4 x 4 matrix, row by row (12 numbers).
/// Poses are sensor to world. The format follows the file's extension: `.kitti` (or `.txt` with
/// `TrajectoryFormat::kKitti` given), anything else TUM.

#include <Eigen/Geometry>

#include <string>
#include <vector>

namespace iwlomap {

enum class TrajectoryFormat { kTum, kKitti };

/// kKitti for a name ending in ".kitti", else kTum.
[[nodiscard]] TrajectoryFormat trajectory_format_of(const std::string& path);

/// Writes \p poses with \p stamps (seconds; empty: 0, 1, 2, ...) to \p path through a temporary
/// file renamed into place. Throws std::invalid_argument when stamps and poses differ in number and
/// std::runtime_error naming the path when it cannot be written.
void write_trajectory(const std::string& path, const std::vector<Eigen::Isometry3d>& poses,
                      const std::vector<double>& stamps, TrajectoryFormat format);

/// Reads a TUM or KITTI file (as written above). Throws std::runtime_error naming the file and line.
[[nodiscard]] std::vector<Eigen::Isometry3d> read_trajectory(const std::string& path, TrajectoryFormat format,
                                                             std::vector<double>* stamps = nullptr);

}  // namespace iwlomap
