// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Input checking of IMapperBackend::set_log_odds(), shared by every backend so that all of them
// reject the same inputs with the same messages, skip the same rows and store the same values.

#include "integrate/batch_input.h"
#include "iwlomap/iwlo.h"
#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstddef>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap::detail {

/// One absolute value of a set_log_odds() call, ready to store.
struct AbsoluteLogOdds {
  VoxelKey key;
  float log_odds;  // already clamped to [L_min, L_max] and rounded to a stored value (iwlo::VoxelFormat)
};

/// Validates a set_log_odds() call and converts it to keyed values in \p out (cleared first).
/// Rows with a non-finite point or value are skipped; returns how many. Throws before producing
/// anything: std::invalid_argument for shapes, std::out_of_range for a point whose key does not
/// fit in int32.
inline std::size_t prepare_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds,
                                    const IwloParams& params, double resolution, std::vector<AbsoluteLogOdds>& out) {
  out.clear();
  if (points.rows() > 0 && points.cols() != 3)
    throw std::invalid_argument("iwlomap: points must be N x 3, got " + std::to_string(points.rows()) + " x " +
                                std::to_string(points.cols()));
  if (log_odds.size() != points.rows())
    throw std::invalid_argument("iwlomap: log_odds has " + std::to_string(log_odds.size()) +
                                " entries but points has " + std::to_string(points.rows()) + " rows");
  out.reserve(static_cast<std::size_t>(points.rows()));
  const iwlo::VoxelFormat format = iwlo::voxel_format(params);
  std::size_t skipped = 0;
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    const Eigen::Vector3d p = points.row(i).transpose();
    const double value = log_odds[i];
    if (!p.allFinite() || !std::isfinite(value)) {
      ++skipped;
      continue;
    }
    if (!is_representable(p, resolution)) {
      out.clear();
      throw_out_of_range(i, p, resolution);
    }
    // Clamped in double and rounded once, exactly as iwlo::apply_observation() stores a result.
    out.push_back({world_to_key(p, resolution), format.quantize(std::clamp(value, params.L_min, params.L_max))});
  }
  return skipped;
}

}  // namespace iwlomap::detail
