// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// IWLO (Intensity-Weighted Log-Odds): the parameters and the per-observation update math.
///
/// These functions are the reference of the update: every backend's result equals
/// iwlo::apply_observation() bit for bit (the backends run a precomputed, inlined form of step()
/// that is tested against it), so RAM, Disk and OctoMap maps built from the same input agree voxel
/// by voxel. The math is done in double precision; voxels store the resulting log-odds as float.

#include <cstdint>
#include <limits>

namespace iwlomap {

/// All parameters of the IWLO update, with the defaults of the reference API.
/// Intensities are in the sensor's raw units (e.g. 0..255 echo amplitude); log-odds are natural
/// logarithms of p / (1 - p).
struct IwloParams {
  double sharpness = 0.1;            ///< slope of the intensity sigmoid (unitless)
  double decay_rate = 0.1;           ///< learning-rate decay per observation
  double min_alpha = 0.3;            ///< floor of the learning rate, in (0, 1]
  double L_min = -10.0;              ///< lower log-odds clamp
  double L_max = 10.0;               ///< upper log-odds clamp
  double log_odds_occupied = 3.5;    ///< L_occ: increment of a full-weight occupied observation
  double log_odds_free = -3.0;       ///< L_free: increment of a free observation
  double intensity_threshold = 35.0; ///< I_th: a return at or below this is free-space evidence
  double intensity_max = 255.0;      ///< I_max: intensity that maps to full weight
  bool adaptive_enabled = true;      ///< protect settled voxels against contradicting evidence
  double adaptive_threshold = 0.5;   ///< P_th of the adaptive scale, in (0, 1)
  double adaptive_max_ratio = 0.3;   ///< r_max of the adaptive scale, in [0, 1]
  double occupied_threshold = 0.7;   ///< probability above which a voxel is reported occupied, in (0, 1)

  /// Throws std::invalid_argument naming the first invalid parameter and its value.
  void validate() const;
};

namespace iwlo {

/// Largest observation count a voxel stores; counts saturate here and never wrap.
inline constexpr std::uint32_t kMaxCount = std::numeric_limits<std::uint16_t>::max();

/// p = 1 / (1 + exp(-L)).
[[nodiscard]] double probability(double log_odds);

/// L = ln(p / (1 - p)); p must be in (0, 1).
[[nodiscard]] double log_odds(double probability);

/// True when an observation with flag \p occupied_flag and intensity \p intensity counts as
/// occupied: `occupied_flag && intensity > I_th`. Everything else is a free observation.
[[nodiscard]] bool is_occupied_observation(bool occupied_flag, double intensity, const IwloParams& p);

/// Intensity weight w in (0, 1): 0 at or below I_th, else a sigmoid of the normalised intensity.
/// When I_max - I_th <= 1e-9 the normalised intensity is 1.
[[nodiscard]] double intensity_weight(double intensity, const IwloParams& p);

/// Learning rate for the observation that brings the count to \p count (count >= 1):
/// max(min_alpha, 1 / (1 + decay_rate * (count - 1))). The first observation gets 1.
[[nodiscard]] double learning_rate(std::uint32_t count, const IwloParams& p);

/// Adaptive scale s in [0, 1] given the voxel's current probability \p prob before the update.
/// Returns 1 when adaptive scaling is disabled.
[[nodiscard]] double adaptive_scale(double prob, bool occupied, const IwloParams& p);

/// The log-odds increment of one observation (already multiplied by \p weight).
/// \param log_odds current log-odds of the voxel (before this observation)
/// \param count    observation count including this observation (>= 1)
/// \param intensity the echo's intensity in the sensor's raw units
/// \param occupied_flag true for a hit (the voxel holds a surface), false for free space
/// \param weight   the observation's weight in [0, 1] (1 = a full observation)
/// \param p        the IWLO parameters
[[nodiscard]] double delta(double log_odds, std::uint32_t count, double intensity, bool occupied_flag,
                           double weight, const IwloParams& p);

/// One complete IWLO step: returns clamp(L + delta, L_min, L_max).
[[nodiscard]] double step(double log_odds, std::uint32_t count, double intensity, bool occupied_flag,
                          double weight, const IwloParams& p);

/// Saturating increment of an observation count (never exceeds kMaxCount).
[[nodiscard]] constexpr std::uint32_t increment_count(std::uint32_t count) noexcept {
  return count >= kMaxCount ? kMaxCount : count + 1;
}

/// Applies one observation to a stored voxel state in place: increments the count (saturating),
/// runs step() in double precision and stores the result as float: the stored state a voxel gets
/// from one observation in every backend.
inline void apply_observation(float& log_odds_value, std::uint16_t& count, double intensity,
                              bool occupied_flag, double weight, const IwloParams& p) {
  const std::uint32_t n = increment_count(count);
  log_odds_value =
      static_cast<float>(step(static_cast<double>(log_odds_value), n, intensity, occupied_flag, weight, p));
  count = static_cast<std::uint16_t>(n);
}

}  // namespace iwlo
}  // namespace iwlomap
