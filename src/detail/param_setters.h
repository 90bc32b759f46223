// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The reference API's grouped setters, as validated copies of IwloParams: each backend assigns the
// result, so a rejected value leaves its parameters unchanged.

#include "iwlomap/iwlo.h"

namespace iwlomap::detail {

[[nodiscard]] inline IwloParams validated(IwloParams p) {
  p.validate();
  return p;
}
[[nodiscard]] inline IwloParams with_iwlo(IwloParams p, double sharpness, double decay_rate, double min_alpha,
                                          double L_min, double L_max) {
  p.sharpness = sharpness;
  p.decay_rate = decay_rate;
  p.min_alpha = min_alpha;
  p.L_min = L_min;
  p.L_max = L_max;
  return validated(p);
}
[[nodiscard]] inline IwloParams with_log_odds(IwloParams p, double occupied, double free) {
  p.log_odds_occupied = occupied;
  p.log_odds_free = free;
  return validated(p);
}
[[nodiscard]] inline IwloParams with_intensity(IwloParams p, double threshold, double max) {
  p.intensity_threshold = threshold;
  p.intensity_max = max;
  return validated(p);
}
[[nodiscard]] inline IwloParams with_adaptive(IwloParams p, bool enabled, double threshold, double max_ratio) {
  p.adaptive_enabled = enabled;
  p.adaptive_threshold = threshold;
  p.adaptive_max_ratio = max_ratio;
  return validated(p);
}
[[nodiscard]] inline IwloParams with_occupied_threshold(IwloParams p, double threshold) {
  p.occupied_threshold = threshold;
  return validated(p);
}

}  // namespace iwlomap::detail
