// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/sonar_preset.h"

#include <cmath>
#include <stdexcept>
#include <string>

namespace iwlomap {

SonarPreset sonar_preset(double intensity_threshold) {
  if (!std::isfinite(intensity_threshold))
    throw std::invalid_argument("iwlomap: invalid sonar preset intensity_threshold " +
                                std::to_string(intensity_threshold) + " (must be finite)");
  SonarPreset p;
  p.map.intensity_threshold = intensity_threshold;
  p.map.sharpness = 0.0;  // w = 0.5: the SNR weight takes the intensity sigmoid's place
  p.map.log_odds_occupied = 3.0;  // a full-weight echo adds 1.5
  p.map.log_odds_free = -0.8;
  p.map.decay_rate = 0.0;  // every ping counts the same
  p.map.min_alpha = 1.0;
  p.map.L_min = -2.0;  // OctoMap's clamping thresholds 0.12 and 0.97
  p.map.L_max = 3.5;
  p.map.occupied_threshold = 0.8;
  p.projector.intensity_threshold = intensity_threshold;
  p.projector.detector = SonarDetector::kOrderedStatisticCfar;
  p.projector.snr_weight.enabled = true;
  p.map.validate();
  p.projector.validate();
  return p;
}

}  // namespace iwlomap
