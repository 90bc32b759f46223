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
}

namespace iwlo {

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
