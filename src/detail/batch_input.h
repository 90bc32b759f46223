// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Input checking shared by every backend, so that all of them reject the same inputs with the
// same messages and skip the same points.

#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <cstddef>
#include <string>
#include <vector>

namespace iwlomap::detail {

/// One observation of a batch, ready to apply.
struct Observation {
  VoxelKey key;
  double intensity;
  double weight;
  bool occupied_flag;
};

/// Throws std::invalid_argument unless resolution is finite and > 0.
void check_resolution(double resolution);

/// Validates a batch (sizes, weights, keys that fit int32) and converts it to observations in
/// \p out (cleared first). Non-finite points or intensities are skipped; returns how many.
/// Throws before producing anything when the batch is invalid: std::invalid_argument for sizes
/// and weights, std::out_of_range for a point whose key does not fit in int32.
std::size_t prepare_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                          const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights,
                          double resolution, std::vector<Observation>& out);

/// Throws std::invalid_argument unless points is N x 3 and intensities has N entries.
void check_scan_input(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                      const Eigen::VectorXd& intensities, double max_range, double resolution);

/// Resolves get_occupied_voxels()'s argument: negative -> 0.5; NaN or > 1 throws.
[[nodiscard]] double resolve_min_probability(double min_probability);

/// Builds the N x 4 (x, y, z, p) matrix of occupied voxels from \p rows (flattened quadruples).
[[nodiscard]] Eigen::MatrixXd rows_to_matrix(const std::vector<double>& rows);

/// Throws std::out_of_range for point \p index (-1: the scan origin, < -1: a single point) whose key does not fit in int32.
[[noreturn]] void throw_out_of_range(Eigen::Index index, const Eigen::Vector3d& point, double resolution);

/// "name = value" with full precision, for exception messages.
[[nodiscard]] std::string describe(const char* name, double value);

}  // namespace iwlomap::detail
