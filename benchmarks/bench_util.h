// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Small timing helpers shared by the benchmark programs.

#include "iwlomap/map_memory.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <stdexcept>
#include <string>
#include <ctime>
#include <vector>

namespace iwlomap::bench {

using Clock = std::chrono::steady_clock;

/// Milliseconds of wall clock since \p t0.
[[nodiscard]] inline double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

/// Wall-clock time and the calling thread's CPU time (user + system, so page faults count). For a
/// single-threaded measurement on an idle machine the two agree; on a shared machine the CPU time
/// leaves out the time the thread waited for a core, and is the steadier figure.
struct Stamp {
  Clock::time_point wall;
  double cpu_ns;
};

[[nodiscard]] inline Stamp now() {
  timespec ts{};
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return {Clock::now(), static_cast<double>(ts.tv_sec) * 1e9 + static_cast<double>(ts.tv_nsec)};
}

/// Milliseconds between two stamps, wall clock and thread CPU time.
struct Sample {
  double wall_ms = 0.0;
  double cpu_ms = 0.0;
};

[[nodiscard]] inline Sample elapsed(const Stamp& t0, const Stamp& t1) {
  return {std::chrono::duration<double, std::milli>(t1.wall - t0.wall).count(), (t1.cpu_ns - t0.cpu_ns) * 1e-6};
}

/// The median of \p v (the mean of the middle two of an even count; NaN when empty).
[[nodiscard]] inline double median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

/// The value of option argv[i] (which needs one): argv[i + 1], advancing i; std::invalid_argument
/// naming the option when it is the last argument.
[[nodiscard]] inline const char* option_value(int argc, char** argv, int& i) {
  if (i + 1 >= argc) throw std::invalid_argument(std::string(argv[i]) + " needs a value");
  return argv[++i];
}

/// Prints the compiler and whether assertions are off (figures of a build with assertions on are
/// not representative, and the line says so).
inline void print_build() {
#ifdef NDEBUG
  std::printf("  compiler %s, NDEBUG (optimised build)\n", __VERSION__);
#else
  std::printf("  compiler %s, WARNING: assertions enabled, not a Release build; figures are not representative\n",
              __VERSION__);
#endif
}

/// Lets maps reuse the memory of the maps destroyed before them (iwlomap/map_memory.h), as a
/// program that builds one map after another would, so that rounds measure the library rather
/// than the kernel's first touch of fresh pages; says so on standard output.
inline void retain_map_memory() {
  iwlomap::set_retained_map_memory(std::size_t{64} << 20);
  std::printf("  maps reuse the memory of destroyed maps (set_retained_map_memory(64 MiB))\n");
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
