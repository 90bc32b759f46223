// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// iwlo::probability(l) > threshold decided from l alone except near the threshold: readers that
// keep the voxels above a probability (occupied voxels, .bt occupancy) skip the exp() of every
// voxel that is plainly below or above it, and give exactly the answer the probability gives.

#include "iwlomap/iwlo.h"

#include <cmath>
#include <limits>

namespace iwlomap::detail {

class ProbabilityAbove {
 public:
  /// \p threshold in (0, 1).
  explicit ProbabilityAbove(double threshold) : threshold_(threshold) {
    // Why it is exact: the computed probability is within a few ulps (far less than `margin`) of
    // the true one, which increases with l. So every l below lo_, where the computed probability
    // is already below threshold - margin, computes to at most threshold, and every l above hi_
    // to more than it; between them the probability is computed.
    const double margin = 64.0 * std::numeric_limits<double>::epsilon();
    const double boundary = iwlo::log_odds(threshold);
    double d = margin / (threshold * (1.0 - threshold)) + 1e-9 * (1.0 + std::abs(boundary));
    for (int i = 0; i < 64 && std::isfinite(boundary); ++i, d *= 2.0) {
      if (iwlo::probability(boundary - d) < threshold - margin && iwlo::probability(boundary + d) > threshold + margin) {
        lo_ = boundary - d;
        hi_ = boundary + d;
        return;
      }
    }
    // A threshold within margin of 0 or 1: every voxel computes its probability.
  }

  /// iwlo::probability(log_odds) > threshold.
  [[nodiscard]] bool operator()(double log_odds) const {
    if (log_odds < lo_) return false;
    if (log_odds > hi_) return true;
    return iwlo::probability(log_odds) > threshold_;
  }

 private:
  double threshold_;
  double lo_ = -std::numeric_limits<double>::infinity();
  double hi_ = std::numeric_limits<double>::infinity();
};

}  // namespace iwlomap::detail
