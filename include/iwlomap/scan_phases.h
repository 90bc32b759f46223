// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Where one insert_scan() spent its time, phase by phase (IMapperBackend::get_last_scan_phases()).
/// A map inserts a scan in phases, some on up to get_num_threads() threads, the rest on the calling
/// thread only. The share of the calling thread's phases in a one-thread insert bounds what more
/// threads can give (Amdahl's law): with a serial share s, N threads are at most 1 / (s + (1 - s) / N)
/// times faster. serial_share() and amdahl_speedup() give both.
///
/// Times are wall-clock seconds measured on the calling thread (steady clock). Reading the phases
/// costs nothing; measuring them costs a few clock reads per scan.

namespace iwlomap {

struct ScanPhaseTimes {
  /// Parallel: the scan's rays walked into per-thread scratch masks (ProgressStage::kCastingRays).
  double casting_rays = 0.0;
  /// Serial: the per-thread scratches merged into one (zero with one thread), and the ends of the
  /// rays added to the hit statistics when the map keeps them.
  double merging = 0.0;
  /// Serial: the map's blocks the scan adds created, and room taken for the cells it adds, before
  /// any voxel changes.
  double allocating = 0.0;
  /// Parallel: the cells each block needs gathered from the scratch, and the added cells
  /// zero-filled (a new map's memory is first touched here).
  double preparing = 0.0;
  /// Parallel: every observed voxel updated, free and hit (ProgressStage::kUpdatingVoxels). A
  /// backend whose updates are not threaded (the OctoMap backend's octree, the batches of the
  /// default insert_scan()) runs this phase on the calling thread.
  double updating = 0.0;
  /// The whole call, from its input check to its return.
  double total = 0.0;
  /// Threads the call could use (get_num_threads() at the time).
  int threads = 1;

  /// Time outside the parallel phases: merging, allocating, and the rest of the call (input
  /// checks, hit statistics); never below zero.
  [[nodiscard]] double serial() const noexcept {
    const double s = total - casting_rays - preparing - updating;
    return s > 0.0 ? s : 0.0;
  }
  /// serial() / total: measured with threads == 1, the serial share of Amdahl's law (0 for an
  /// empty measurement).
  [[nodiscard]] double serial_share() const noexcept { return total > 0.0 ? serial() / total : 0.0; }
  /// The speed-up Amdahl's law allows \p n threads (at least 1) for serial_share(): 1 / (s + (1 - s)
  /// / n); 1 for an empty measurement, which shows nothing.
  [[nodiscard]] double amdahl_speedup(int n) const noexcept {
    if (!(total > 0.0)) return 1.0;
    const double s = serial_share();
    return 1.0 / (s + (1.0 - s) / static_cast<double>(n < 1 ? 1 : n));
  }
};

}  // namespace iwlomap
