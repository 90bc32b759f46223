// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Argument checks and error messages shared by every part of the library, so that all of them
// reject the same inputs with the same words. The ground floor: includes public headers only.

#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <string>

namespace iwlomap::detail {

/// The shortest decimal form of \p value that reads back as the same double ("0.2", not
/// "0.20000000000000001"), for messages.
[[nodiscard]] std::string shortest(double value);

/// "name = value" with shortest(value), for exception messages.
[[nodiscard]] std::string describe(const char* name, double value);

/// Throws std::invalid_argument unless \p resolution is finite and > 0.
void check_resolution(double resolution);

/// Throws std::invalid_argument unless \p points is N x 3 (any width when N = 0) and
/// \p n_values (the length of the per-point array called \p values_name) is N.
void check_points_shape(const Eigen::MatrixXd& points, Eigen::Index n_values, const char* values_name);

/// Throws std::out_of_range for a point whose key does not fit in int32. \p index names it: a
/// row >= 0, -1 for the scan origin, < -1 for a single point.
[[noreturn]] void throw_out_of_range(Eigen::Index index, const Eigen::Vector3d& point, double resolution);

/// Resolves get_occupied_voxels()'s argument: negative -> 0.5; NaN or > 1 throws.
[[nodiscard]] double resolve_min_probability(double min_probability);

}  // namespace iwlomap::detail
