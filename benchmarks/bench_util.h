// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Small timing helpers shared by the benchmark programs.

#include <algorithm>
#include <chrono>
#include <cstdlib>
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

/// Call between timed regions (untimed). An octree freed node by node leaves glibc's fast bins
/// full of small chunks, and the next allocation of a kilobyte or more, whoever makes it, first
/// merges them all (malloc_consolidate: tens of milliseconds after a map of millions of nodes).
/// One such allocation here does the merge outside the timed regions. It returns nothing to the
/// system (malloc_trim() would, and the next octree would then pay page faults instead).
inline void settle_heap() {
  void* volatile p = std::malloc(4096);  // volatile: the pair must not be optimised away
  std::free(p);
}

}  // namespace iwlomap::bench
