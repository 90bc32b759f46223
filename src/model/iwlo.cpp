// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/iwlo.h"

#include "model/checks.h"

#include <algorithm>
#include <cmath>
#include <stdexcept>
#include <string>

namespace iwlomap {

namespace {

[[noreturn]] void fail(const char* name, double value, const char* rule) {
  throw std::invalid_argument(std::string("iwlomap: invalid IWLO parameter ") + detail::describe(name, value) +
                              " (" + rule + ")");
}

void require_finite(const char* name, double value) {
  if (!std::isfinite(value)) fail(name, value, "must be finite");
}

}  // namespace

void IwloParams::validate() const {
  require_finite("sharpness", sharpness);
  require_finite("decay_rate", decay_rate);
  if (decay_rate < 0.0) fail("decay_rate", decay_rate, "must be >= 0");
  if (!(min_alpha > 0.0 && min_alpha <= 1.0)) fail("min_alpha", min_alpha, "must be in (0, 1]");
  require_finite("L_min", L_min);
  require_finite("L_max", L_max);
  if (!(L_min < L_max)) fail("L_min", L_min, ("must be < L_max = " + std::to_string(L_max)).c_str());
  require_finite("log_odds_occupied", log_odds_occupied);
  require_finite("log_odds_free", log_odds_free);
  require_finite("intensity_threshold", intensity_threshold);
  require_finite("intensity_max", intensity_max);
  if (!(adaptive_threshold > 0.0 && adaptive_threshold < 1.0))
    fail("adaptive_threshold", adaptive_threshold, "must be in (0, 1)");
  if (!(adaptive_max_ratio >= 0.0 && adaptive_max_ratio <= 1.0))
    fail("adaptive_max_ratio", adaptive_max_ratio, "must be in [0, 1]");
  if (!(occupied_threshold > 0.0 && occupied_threshold < 1.0))
    fail("occupied_threshold", occupied_threshold, "must be in (0, 1)");
  (void)iwlo::voxel_format(*this);  // throws when no stored log-odds lies in [L_min, L_max]
}

namespace iwlo {

static_assert((-8 >> 1) == -4, "VoxelFormat::log_odds() needs an arithmetic shift of negative integers");

namespace {

constexpr int kMinFractionBits = -104;  // 2^23 * 2^104 = 2^127 still fits a float
constexpr int kMaxFractionBits = 100;

// The count bits a learning rate needs: enough to hold the first count whose rate is the floor,
// so that every rate above the floor comes from the exact count and a saturated count has the
// floor's rate.
int count_bits_for(const IwloParams& p) {
  if (!(p.decay_rate > 0.0) || p.min_alpha >= 1.0) return 8;  // the rate never decays: the count is not used
  // alpha(n) = 1 / (1 + decay_rate (n - 1)) <= min_alpha from n - 1 >= (1/min_alpha - 1) / decay_rate.
  const double x = (1.0 / p.min_alpha - 1.0) / p.decay_rate;
  if (x >= 65535.0) return 16;
  // The estimate, then learning_rate() itself decides (a step or two), so rounding cannot move
  // the floor by one.
  auto n = static_cast<std::uint32_t>(std::max(1.0, std::floor(x) - 1.0));
  while (learning_rate(n, p) > p.min_alpha) ++n;
  int bits = 8;
  while (bits < 16 && n > (1u << bits) - 1) ++bits;
  return bits;
}

}  // namespace

VoxelFormat::VoxelFormat() : VoxelFormat(voxel_format(IwloParams{})) {}

VoxelFormat::VoxelFormat(int count_bits, int fraction_bits, std::int32_t q_min, std::int32_t q_max)
    : fraction_bits_(fraction_bits) {
  if (count_bits < 8 || count_bits > 16)
    throw std::invalid_argument("iwlomap: voxel format: count bits must be in 8..16, got " + std::to_string(count_bits));
  if (fraction_bits < kMinFractionBits || fraction_bits > kMaxFractionBits)
    throw std::invalid_argument("iwlomap: voxel format: fraction bits must be in " + std::to_string(kMinFractionBits) +
                                ".." + std::to_string(kMaxFractionBits) + ", got " + std::to_string(fraction_bits));
  const std::int64_t limit = (std::int64_t{1} << (31 - count_bits)) - 1;
  if (!(q_min <= q_max && q_min >= -limit && q_max <= limit))
    throw std::invalid_argument("iwlomap: voxel format: stored values " + std::to_string(q_min) + ".." +
                                std::to_string(q_max) + " do not fit " + std::to_string(32 - count_bits) + " bits");
  count_bits_ = static_cast<std::uint64_t>(count_bits);
  count_mask_ = (std::uint64_t{1} << count_bits) - 1;
  step_ = std::ldexp(1.0, -fraction_bits);
  scale_ = std::ldexp(1.0, fraction_bits);
  update_lo_ = q_min;
  update_hi_ = q_max;
  limit_ = static_cast<double>(limit);
}

VoxelFormat voxel_format(const IwloParams& p) {
  const int count_bits = count_bits_for(p);
  const double largest = static_cast<double>((std::int64_t{1} << (31 - count_bits)) - 1);
  // At least +-15, so that the layout of the defaults serves every clamp range within it.
  constexpr double kLeastReach = 15.0;
  const double reach = std::max({std::abs(p.L_min), std::abs(p.L_max), kLeastReach});
  // The largest f with largest * 2^-f >= reach.
  int f = std::clamp(std::ilogb(largest) - std::ilogb(reach), kMinFractionBits, kMaxFractionBits);
  while (f > kMinFractionBits && std::ldexp(largest, -f) < reach) --f;
  while (f < kMaxFractionBits && std::ldexp(largest, -(f + 1)) >= reach) ++f;
  // L_min and L_max rounded inwards to a step, and within the stored bits.
  const double q_min = std::max(-largest, std::ceil(std::ldexp(p.L_min, f)));
  const double q_max = std::min(largest, std::floor(std::ldexp(p.L_max, f)));
  if (!(q_min <= q_max))
    throw std::invalid_argument("iwlomap: invalid IWLO parameter L_min = " + std::to_string(p.L_min) +
                                " (no stored log-odds lies between it and L_max = " + std::to_string(p.L_max) + ")");
  return VoxelFormat(count_bits, f, static_cast<std::int32_t>(q_min), static_cast<std::int32_t>(q_max));
}

void apply_observation(float& log_odds_value, std::uint16_t& count, double intensity, bool occupied_flag,
                       double weight, const IwloParams& p) {
  const VoxelFormat format = voxel_format(p);
  const std::uint32_t n = format.next_count(count);
  log_odds_value = format.log_odds(
      format.encode(step(static_cast<double>(log_odds_value), n, intensity, occupied_flag, weight, p), n));
  count = static_cast<std::uint16_t>(n);
}

double probability(double log_odds) { return 1.0 / (1.0 + std::exp(-log_odds)); }

double log_odds(double p) { return std::log(p / (1.0 - p)); }

bool is_occupied_observation(bool occupied_flag, double intensity, const IwloParams& p) {
  return occupied_flag && intensity > p.intensity_threshold;
}

double intensity_weight(double intensity, const IwloParams& p) {
  if (intensity <= p.intensity_threshold) return 0.0;
  const double span = p.intensity_max - p.intensity_threshold;
  const double u = span <= 1e-9 ? 1.0 : std::clamp((intensity - p.intensity_threshold) / span, 0.0, 1.0);
  return 1.0 / (1.0 + std::exp(-p.sharpness * (u - 0.5)));
}

double learning_rate(std::uint32_t count, const IwloParams& p) {
  const double n = static_cast<double>(count == 0 ? 1 : count);
  return std::max(p.min_alpha, 1.0 / (1.0 + p.decay_rate * (n - 1.0)));
}

double adaptive_scale(double prob, bool occupied, const IwloParams& p) {
  if (!p.adaptive_enabled) return 1.0;
  const double pth = p.adaptive_threshold;
  const double rmax = p.adaptive_max_ratio;
  if (occupied) return prob < pth ? (prob / pth) * rmax : 1.0;
  if (prob > 1.0 - pth) {
    const double f = (prob - (1.0 - pth)) / pth;
    return rmax + (1.0 - rmax) * (1.0 - f);
  }
  return 1.0;
}

double delta(double log_odds_value, std::uint32_t count, double intensity, bool occupied_flag, double weight,
             const IwloParams& p) {
  const bool occupied = is_occupied_observation(occupied_flag, intensity, p);
  const double s = adaptive_scale(probability(log_odds_value), occupied, p);
  const double alpha = learning_rate(count, p);
  const double d = occupied ? p.log_odds_occupied * intensity_weight(intensity, p) * alpha * s
                            : p.log_odds_free * alpha * s;
  return d * weight;
}

double step(double log_odds_value, std::uint32_t count, double intensity, bool occupied_flag, double weight,
            const IwloParams& p) {
  return std::clamp(log_odds_value + delta(log_odds_value, count, intensity, occupied_flag, weight, p), p.L_min,
                    p.L_max);
}

}  // namespace iwlo
}  // namespace iwlomap
