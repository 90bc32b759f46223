// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// IWLO (Intensity-Weighted Log-Odds): the parameters and the per-observation update math.
///
/// These functions are the reference of the update: every backend's result equals
/// iwlo::apply_observation() bit for bit (the backends run a precomputed, inlined form of step()
/// that is tested against it), so RAM, Disk and OctoMap maps built from the same input agree voxel
/// by voxel. The math is done in double precision; voxels store the result in 4 bytes as
/// VoxelFormat describes (fixed-point log-odds and a saturating count).

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

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

/// Largest observation count any voxel format stores (VoxelFormat::max_count() of a 16-bit count).
/// A map's own limit is VoxelFormat::max_count() of its parameters: 255 with the defaults.
inline constexpr std::uint32_t kMaxCount = std::numeric_limits<std::uint16_t>::max();

/// How a voxel stores its IWLO state in 4 bytes, in every backend, tile file and message.
///
/// The word's low `count_bits` bits hold the observation count, which saturates at
/// max_count() = 2^count_bits - 1 and never wraps; its other 32 - count_bits bits hold the
/// log-odds as a signed fixed-point number q, L = q * 2^-fraction_bits. The result of an update
/// is rounded to the nearest step (halfway cases to the even step) and kept within [L_min, L_max]
/// (rounded inwards to a step); 0, the state of a voxel seen for the first time, is exact, and
/// every stored value is exactly a float. A word of 0 is an unknown voxel: a known one has a count.
///
/// The count takes 8 bits when the learning rate reaches its floor min_alpha within 255
/// observations (n = 1 + (1/min_alpha - 1)/decay_rate <= 255: the defaults need 25, and any
/// decay_rate >= 0.0092 with min_alpha 0.3), or when it never decays (decay_rate 0 or
/// min_alpha 1). Otherwise the count takes as many bits as that n needs, at most 16, so the
/// learning rate stays exact, and the log-odds keep the rest. fraction_bits is the largest whose
/// range holds max(|L_min|, |L_max|, 15): with 8 count bits a step of 2^-19 = 1.9e-6 over
/// +-16 for every clamp range within +-15, so changing L_min or L_max does not change the layout.
///
/// When parameters change the layout (count_bits or fraction_bits) of a map that holds voxels,
/// every voxel is converted (convert()): its log-odds rounded to the new step, bounded only by
/// what the new bits hold, its count saturated. Values outside a new [L_min, L_max] are kept, as
/// they are when the layout stays, until an update clamps them, as the reference update does.
class VoxelFormat {
 public:
  /// The format of the default parameters (voxel_format(IwloParams{})).
  VoxelFormat();
  /// A count of \p count_bits (8..16) bits, a step of 2^-fraction_bits (-104..100) and stored
  /// fixed-point values q_min <= q <= q_max, both within the 32 - count_bits bits left. Throws
  /// std::invalid_argument otherwise.
  VoxelFormat(int count_bits, int fraction_bits, std::int32_t q_min, std::int32_t q_max);

  [[nodiscard]] int count_bits() const noexcept { return static_cast<int>(count_bits_); }
  [[nodiscard]] int fraction_bits() const noexcept { return fraction_bits_; }
  /// The smallest and largest fixed-point log-odds of an update: L_min and L_max rounded inwards.
  [[nodiscard]] std::int32_t q_min() const noexcept { return static_cast<std::int32_t>(update_lo_); }
  [[nodiscard]] std::int32_t q_max() const noexcept { return static_cast<std::int32_t>(update_hi_); }
  /// The largest |q| the bits hold: 2^(31 - count_bits) - 1.
  [[nodiscard]] std::int32_t q_limit() const noexcept { return static_cast<std::int32_t>(limit_); }
  /// True when words of \p other mean the same as words of this format (count bits and fraction
  /// bits agree; the update bounds may differ).
  [[nodiscard]] bool same_layout(const VoxelFormat& other) const noexcept {
    return count_bits_ == other.count_bits_ && fraction_bits_ == other.fraction_bits_;
  }
  /// The log-odds step 2^-fraction_bits.
  [[nodiscard]] double step() const noexcept { return step_; }
  /// 2^fraction_bits: a log-odds in steps.
  [[nodiscard]] double scale() const noexcept { return scale_; }
  /// The largest stored count: 2^count_bits - 1.
  [[nodiscard]] std::uint32_t max_count() const noexcept { return static_cast<std::uint32_t>(count_mask_); }
  /// Saturating increment of a count: never beyond max_count().
  [[nodiscard]] std::uint32_t next_count(std::uint32_t count) const noexcept {
    return count >= max_count() ? max_count() : count + 1;
  }
  /// The word of a voxel with log-odds \p log_odds (rounded and bounded as above; NaN stores q_min)
  /// and count \p count (1..max_count()).
  [[nodiscard]] std::uint32_t encode(double log_odds, std::uint32_t count) const noexcept {
    return encode_fixed(log_odds * scale_, count);  // exact: scale_ is a power of two
  }
  /// encode() of a log-odds given in steps (log_odds * scale()).
  [[nodiscard]] std::uint32_t encode_fixed(double steps, std::uint32_t count) const noexcept {
    return encode_within(steps, count, update_lo_, update_hi_);
  }
  /// A word of this format for \p word of format \p from: the same word when the layouts agree,
  /// else its log-odds rounded to this step and bounded by q_limit() only, its count saturated.
  [[nodiscard]] std::uint32_t convert(std::uint32_t word, const VoxelFormat& from) const noexcept {
    return same_layout(from) ? word : encode_kept(from.log_odds_exact(word), from.count(word));
  }
  /// A word for a log-odds kept from elsewhere (a file of an older version): rounded to this step,
  /// bounded by q_limit() only; \p count is saturated.
  [[nodiscard]] std::uint32_t encode_kept(double log_odds, std::uint32_t count) const noexcept {
    return encode_within(log_odds * scale_, count < max_count() ? count : max_count(), -limit_, limit_);
  }
  /// The log-odds of \p word, exactly (every stored value is a float).
  [[nodiscard]] float log_odds(std::uint32_t word) const noexcept { return static_cast<float>(log_odds_exact(word)); }
  /// log_odds() as a double, without the float conversion (the same value).
  [[nodiscard]] double log_odds_exact(std::uint32_t word) const noexcept {
    return static_cast<double>(fixed(word)) * step_;
  }
  /// The log-odds of \p word in steps: q.
  [[nodiscard]] std::int32_t fixed(std::uint32_t word) const noexcept {
    // An arithmetic shift of the signed word (what GCC and Clang do; checked in iwlo.cpp).
    return static_cast<std::int32_t>(word) >> count_bits_;
  }
  /// The count of \p word.
  [[nodiscard]] std::uint32_t count(std::uint32_t word) const noexcept {
    return static_cast<std::uint32_t>(word & count_mask_);
  }
  /// \p log_odds as a voxel stores it: log_odds(encode(log_odds, 1)).
  [[nodiscard]] float quantize(double log_odds) const noexcept { return this->log_odds(encode(log_odds, 1)); }

  friend bool operator==(const VoxelFormat& a, const VoxelFormat& b) noexcept {
    return a.same_layout(b) && a.update_lo_ == b.update_lo_ && a.update_hi_ == b.update_hi_;
  }
  friend bool operator!=(const VoxelFormat& a, const VoxelFormat& b) noexcept { return !(a == b); }

 private:
  // A log-odds in steps rounded to the nearest step, bounded to lo..hi (whole numbers of steps),
  // above \p count.
  [[nodiscard]] std::uint32_t encode_within(double steps, std::uint32_t count, double lo, double hi) const noexcept {
    // Bounded first (NaN takes lo), so the conversion is always in range.
    const double x = std::max(lo, std::min(steps, hi));
#if defined(__SSE2__)
    const std::int32_t q = _mm_cvtsd_si32(_mm_set_sd(x));  // one instruction: to nearest, ties to even
#else
    const auto q = static_cast<std::int32_t>(std::nearbyint(x));  // the same in the default rounding mode
#endif
    return (static_cast<std::uint32_t>(q) << count_bits_) | count;
  }

  // What an update reads is 64-bit or double: a store of a voxel's 32-bit word cannot alias it, so
  // a loop of updates keeps it in registers.
  std::uint64_t count_bits_ = 8;
  std::uint64_t count_mask_ = 255;
  double step_ = 0.0;       // 2^-fraction_bits
  double scale_ = 0.0;      // 2^fraction_bits
  double update_lo_ = 0.0;  // q_min, q_max and q_limit (whole numbers, exact as doubles)
  double update_hi_ = 0.0;
  double limit_ = 0.0;
  int fraction_bits_ = 19;
};

/// The voxel format of a map with parameters \p p (see VoxelFormat). Throws
/// std::invalid_argument when \p p is invalid.
[[nodiscard]] VoxelFormat voxel_format(const IwloParams& p);

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

/// Saturating increment of an observation count (never exceeds kMaxCount; a map's voxels saturate
/// at VoxelFormat::max_count(), see apply_observation()).
[[nodiscard]] constexpr std::uint32_t increment_count(std::uint32_t count) noexcept {
  return count >= kMaxCount ? kMaxCount : count + 1;
}

/// Applies one observation to a stored voxel state in place: increments the count (saturating at
/// voxel_format(p).max_count()), runs step() in double precision and stores the result as a voxel
/// does (VoxelFormat::quantize()): the stored state a voxel gets from one observation in every
/// backend.
void apply_observation(float& log_odds_value, std::uint16_t& count, double intensity, bool occupied_flag,
                       double weight, const IwloParams& p);

}  // namespace iwlo
}  // namespace iwlomap
