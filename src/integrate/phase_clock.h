// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Adds the wall-clock seconds of a scope to one field of ScanPhaseTimes (scan_phases.h), or does
// nothing when given no field: the kernels time their phases with it for
// IMapperBackend::get_last_scan_phases().

#include "iwlomap/scan_phases.h"

#include <chrono>

namespace iwlomap::detail {

class PhaseClock {
 public:
  explicit PhaseClock(double* into) noexcept : into_(into), start_(into ? Clock::now() : Clock::time_point{}) {}
  PhaseClock(const PhaseClock&) = delete;
  PhaseClock& operator=(const PhaseClock&) = delete;
  ~PhaseClock() { stop(); }
  /// Adds the time so far and stops (a later stop() or the destructor adds nothing).
  void stop() noexcept {
    if (into_ == nullptr) return;
    *into_ += std::chrono::duration<double>(Clock::now() - start_).count();
    into_ = nullptr;
  }

 private:
  using Clock = std::chrono::steady_clock;
  double* into_;
  Clock::time_point start_;
};

/// Starts the record of one insert_scan(): \p phases emptied, its thread count set, and the clock
/// of its total returned (it adds to phases.total when it stops or goes out of scope).
[[nodiscard]] inline PhaseClock start_scan_phases(ScanPhaseTimes& phases, int threads) noexcept {
  phases = ScanPhaseTimes{};
  phases.threads = threads;
  return PhaseClock(&phases.total);
}

}  // namespace iwlomap::detail
