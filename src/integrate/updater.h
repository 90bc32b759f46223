// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The IWLO step of iwlo.h with its per-parameter constants precomputed, inlined into the backends'
// per-voxel loops (a call per observation cost a tenth of a batch update). It lives here, compiled
// only into the library with its floating-point flags (no contraction into fused multiply-adds),
// not in a public header, where a consumer's flags could change the rounding of an inlined copy.
//
// Invariant: Updater::step() returns exactly what iwlo::step() returns, bit for bit, for every
// input. Learning rates and the weights of integer intensities 0..255 come from tables filled by
// iwlo::learning_rate() and iwlo::intensity_weight() themselves; the voxel's probability is
// skipped only where the log-odds lie clearly on the side of an adaptive threshold where the scale
// is exactly 1; everything else takes iwlo::step()'s own path.

#include "iwlomap/iwlo.h"

#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace iwlomap::detail {

class Updater {
 public:
  /// Validates \p params (throws std::invalid_argument).
  explicit Updater(const IwloParams& params = {});
  [[nodiscard]] const IwloParams& params() const noexcept { return p_; }
  /// How the map's voxels store their state: iwlo::voxel_format(params()).
  [[nodiscard]] const iwlo::VoxelFormat& format() const noexcept { return format_; }

  /// iwlo::step(log_odds, count, intensity, occupied_flag, weight, params()).
  [[nodiscard]] double step(double log_odds_value, std::uint32_t count, double intensity, bool occupied_flag,
                            double weight) const {
    return std::clamp(log_odds_value + weighted_delta(log_odds_value, count, intensity, occupied_flag, weight),
                      p_.L_min, p_.L_max);
  }

  /// iwlo::delta(log_odds, count, intensity, occupied_flag, weight, params()): the increment,
  /// already multiplied by the weight.
  [[nodiscard]] double weighted_delta(double log_odds_value, std::uint32_t count, double intensity,
                                      bool occupied_flag, double weight) const {
    const IwloParams& p = p_;
    const bool occupied = occupied_flag && intensity > p.intensity_threshold;  // is_occupied_observation()
    const bool unit_scale = occupied ? log_odds_value >= occupied_fast_from_ : log_odds_value <= free_fast_to_;
    // A voxel's first observation finds L = 0, whose scale is precomputed.
    const double s = unit_scale                ? 1.0
                     : log_odds_value == 0.0 ? scale_at_zero_[occupied ? 1 : 0]
                                             : iwlo::adaptive_scale(iwlo::probability(log_odds_value), occupied, p);
    const std::size_t n = count == 0 ? 1 : count;
    const double alpha = n <= alpha_.size() ? alpha_[n - 1]
                         : (alpha_.back() == p.min_alpha ? p.min_alpha : iwlo::learning_rate(count, p));
    double d;
    if (occupied) {
      // An integer in 0..255 (the conversion only runs in range; cheaper than std::floor here).
      const bool tabled = intensity >= 0.0 && intensity < 256.0 &&
                          static_cast<double>(static_cast<int>(intensity)) == intensity;
      const double w =
          tabled ? integer_weight_[static_cast<std::size_t>(intensity)] : iwlo::intensity_weight(intensity, p);
      d = p.log_odds_occupied * w * alpha * s;
    } else {
      d = p.log_odds_free * alpha * s;
    }
    return d * weight;
  }

  /// The stored word after an unknown voxel's first observation with weight 1, into \p out;
  /// false (out untouched) when the intensity of a flagged observation is not an integer 0..255.
  /// The table holds step()'s own results, encoded, so this is step() for those inputs.
  [[nodiscard]] bool first_observation(double intensity, bool occupied_flag, std::uint32_t& out) const {
    if (!occupied_flag) {
      out = first_free_;
      return true;
    }
    if (!(intensity >= 0.0 && intensity < 256.0)) return false;
    const int k = static_cast<int>(intensity);
    if (static_cast<double>(k) != intensity) return false;
    out = first_flagged_[static_cast<std::size_t>(k)];
    return true;
  }

 private:
  IwloParams p_;
  iwlo::VoxelFormat format_;
  std::vector<double> alpha_;                 // alpha_[n - 1] for counts below the floor
  std::array<double, 256> integer_weight_{};  // intensity_weight(I) for I = 0..255
  double occupied_fast_from_;  // L at or above this: P >= P_th for certain, occupied scale is 1
  double free_fast_to_;        // L at or below this: P <= 1 - P_th for certain, free scale is 1
  std::array<double, 2> scale_at_zero_{};  // adaptive_scale(0.5, occupied) for occupied = false, true
  // The stored word after an unknown voxel's first observation with weight 1: with the occupied
  // flag and integer intensity I = 0..255, and without the flag.
  std::array<std::uint32_t, 256> first_flagged_{};
  std::uint32_t first_free_ = 0;
};

}  // namespace iwlomap::detail
