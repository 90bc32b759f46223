// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Random numbers for the synthetic scenes that are the same on every platform: std::mt19937's
// output sequence is fixed by the standard, std::normal_distribution's and
// std::uniform_real_distribution's are not, so both are derived here from the raw outputs.

#include <cmath>
#include <cstdint>
#include <random>

namespace iwlomap::detail {

class PortableRandom {
 public:
  explicit PortableRandom(std::uint32_t seed) : rng_(seed) {}

  /// Standard normal deviate (Box-Muller; two engine outputs per call).
  double gaussian() {
    constexpr double kPi = 3.14159265358979323846;
    const double u1 = (static_cast<double>(rng_()) + 1.0) / 4294967297.0;  // in (0, 1]: log() stays finite
    const double u2 = static_cast<double>(rng_()) / 4294967296.0;
    return std::sqrt(-2.0 * std::log(u1)) * std::cos(2.0 * kPi * u2);
  }

  /// Uniform in [lo, hi).
  double uniform(double lo, double hi) { return lo + (hi - lo) * (static_cast<double>(rng_()) / 4294967296.0); }

 private:
  std::mt19937 rng_;
};

}  // namespace iwlomap::detail
