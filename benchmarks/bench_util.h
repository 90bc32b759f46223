// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Small timing helpers shared by the benchmark programs.

#include <algorithm>
#include <chrono>
#include <vector>

namespace iwlomap::bench {

using Clock = std::chrono::steady_clock;

/// Milliseconds of wall clock since \p t0.
[[nodiscard]] inline double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

/// The median of \p v (the upper one of an even count); \p v must not be empty.
[[nodiscard]] inline double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace iwlomap::bench
