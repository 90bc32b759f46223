// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// The sonar preset: map and projection parameters chosen together for imaging-sonar surveys and
/// measured against the simulator's known scenes (docs/accuracy.md). The reference API's
/// defaults (IwloParams{}, SonarProjectorParams{}) do not change; this is the setting to start a
/// sonar map with.

#include <iwlomap/iwlo.h>
#include <iwlomap/sonar_image_projector.h>

namespace iwlomap {

/// Parameters for a sonar map and the projector that feeds it.
struct SonarPreset {
  IwloParams map;                  ///< for the map (set_params of any backend)
  SonarProjectorParams projector;  ///< for the SonarImageProjector of the map's resolution
};

/// The sonar preset.
/// - Detection: the first return of a beam is its first ordered-statistic CFAR detection
///   (near-side window, false-alarm rate 1e-3) that also exceeds the intensity threshold, so
///   gain, range and seabed type, which move the noise floor, neither flood the map with false
///   echoes nor hide weak ones.
/// - Weight: each echo weighs by its strength over the CFAR threshold (SonarSnrWeight with its
///   defaults: 0.5 at the threshold, 0.88 at 11 dB above it); the map's intensity sigmoid is flat
///   (sharpness 0, w = 0.5), the SNR weight takes its place.
/// - Evidence: every ping counts the same (decay_rate 0, min_alpha 1); a full-weight echo adds
///   +1.5 (log_odds_occupied 3.0 times w = 0.5), a free observation -0.8, clamped to
///   [-2, 3.5] (OctoMap's 0.12 and 0.97), adaptive scaling as in the reference; a voxel is
///   occupied above p = 0.8 (log-odds 1.39). So one echo makes a voxel occupied on its own only
///   when it is about 14 dB or more above the CFAR threshold and covers the voxel fully; a weaker
///   echo needs the voxel seen again. The arcs that a single ping's vertical aperture leaves at
///   the edges of the swath mostly stay below the threshold.
/// \p intensity_threshold (raw units, finite) is the echo threshold of both the map and the
/// projector. Throws std::invalid_argument for a non-finite value.
[[nodiscard]] SonarPreset sonar_preset(double intensity_threshold = 35.0);

}  // namespace iwlomap
