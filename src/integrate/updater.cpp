// SPDX-License-Identifier: BSD-3-Clause
#include "integrate/updater.h"

#include <limits>

namespace iwlomap::detail {

// The margin keeps the shortcut away from the thresholds by far more than the rounding error of
// iwlo::probability(), so the shortcut is taken only where iwlo::adaptive_scale() returns exactly 1.
Updater::Updater(const IwloParams& params) : p_(params) {
  p_.validate();
  format_ = iwlo::voxel_format(p_);
  constexpr double kMargin = 1e-6;
  const double inf = std::numeric_limits<double>::infinity();
  occupied_fast_from_ = p_.adaptive_enabled ? iwlo::log_odds(p_.adaptive_threshold) + kMargin : -inf;
  free_fast_to_ = p_.adaptive_enabled ? iwlo::log_odds(1.0 - p_.adaptive_threshold) - kMargin : inf;
  // The scale at L = 0, where probability() is exactly 0.5 (exp(-0) = 1): every new voxel's.
  scale_at_zero_ = {iwlo::adaptive_scale(0.5, false, p_), iwlo::adaptive_scale(0.5, true, p_)};
  // Learning rates until they reach the floor (at most 4096 entries; beyond, computed).
  constexpr std::uint32_t kMaxTable = 4096;
  for (std::uint32_t n = 1; n <= kMaxTable; ++n) {
    const double a = iwlo::learning_rate(n, p_);
    alpha_.push_back(a);
    if (a == p_.min_alpha) break;
  }
  for (std::size_t i = 0; i < integer_weight_.size(); ++i)
    integer_weight_[i] = iwlo::intensity_weight(static_cast<double>(i), p_);
  for (std::size_t i = 0; i < first_flagged_.size(); ++i)
    first_flagged_[i] = format_.encode(step(0.0, 1, static_cast<double>(i), true, 1.0), 1);
  first_free_ = format_.encode(step(0.0, 1, 0.0, false, 1.0), 1);
}

}  // namespace iwlomap::detail
