// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// IWLO (Intensity-Weighted Log-Odds): the parameters and the per-observation update math.
///
/// Every backend applies exactly these functions, so that RAM, Disk and OctoMap maps built from
/// the same input agree voxel by voxel. The math is done in double precision; backends store the
/// resulting log-odds as float (see iwlo::apply_observation()).

#include <array>
#include <cstdint>
#include <limits>
#include <vector>

namespace iwlomap {

namespace detail {
struct UpdaterKernel;
}

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
[[nodiscard]] double delta(double log_odds, std::uint32_t count, double intensity, bool occupied_flag,
                           double weight, const IwloParams& p);

/// One complete IWLO step: returns clamp(L + delta, L_min, L_max).
[[nodiscard]] double step(double log_odds, std::uint32_t count, double intensity, bool occupied_flag,
                          double weight, const IwloParams& p);

/// Saturating increment of an observation count (never exceeds kMaxCount).
[[nodiscard]] constexpr std::uint32_t increment_count(std::uint32_t count) noexcept {
  return count >= kMaxCount ? kMaxCount : count + 1;
}

/// step() with the per-parameter constants precomputed, for the hot loops of the backends.
/// It returns exactly what step() returns (bit for bit): learning rates and the weights of integer
/// intensities 0..255 come from tables filled by learning_rate() and intensity_weight()
/// themselves, and the voxel's probability is skipped only when the log-odds lie clearly on the
/// side of an adaptive threshold where the scale is 1; everything else takes step()'s path.
class Updater {
 public:
  /// Validates \p params (throws std::invalid_argument).
  explicit Updater(const IwloParams& params = {});
  [[nodiscard]] const IwloParams& params() const noexcept { return p_; }
  [[nodiscard]] double step(double log_odds, std::uint32_t count, double intensity, bool occupied_flag,
                            double weight) const;

 private:
  friend struct detail::UpdaterKernel;  // the backends' inlined copy of step()
  IwloParams p_;
  std::vector<double> alpha_;                  // alpha_[n - 1] for counts below the floor
  std::array<double, 256> integer_weight_{};   // intensity_weight(I) for I = 0..255
  double occupied_fast_from_;  // L at or above this: P >= P_th for certain, occupied scale is 1
  double free_fast_to_;        // L at or below this: P <= 1 - P_th for certain, free scale is 1
  std::array<double, 2> scale_at_zero_{};  // adaptive_scale(0.5, occupied) for occupied = false, true
  // The stored log-odds (float, as voxels keep them) after an unknown voxel's first observation
  // with weight 1: with the occupied flag and integer intensity I = 0..255, and without the flag.
  std::array<float, 256> first_flagged_{};
  float first_free_ = 0.0f;
};

/// Applies one observation to a stored voxel state in place: increments the count (saturating),
/// runs step() in double precision and stores the result as float. This is the single place where
/// the stored state changes, shared by every backend.
inline void apply_observation(float& log_odds_value, std::uint16_t& count, double intensity,
                              bool occupied_flag, double weight, const IwloParams& p) {
  const std::uint32_t n = increment_count(count);
  log_odds_value =
      static_cast<float>(step(static_cast<double>(log_odds_value), n, intensity, occupied_flag, weight, p));
  count = static_cast<std::uint16_t>(n);
}

/// The same with a precomputed Updater (identical results, faster).
inline void apply_observation(float& log_odds_value, std::uint16_t& count, double intensity,
                              bool occupied_flag, double weight, const Updater& u) {
  const std::uint32_t n = increment_count(count);
  log_odds_value = static_cast<float>(u.step(static_cast<double>(log_odds_value), n, intensity, occupied_flag, weight));
  count = static_cast<std::uint16_t>(n);
}

}  // namespace iwlo
}  // namespace iwlomap
