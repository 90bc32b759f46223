// SPDX-License-Identifier: BSD-3-Clause
// Threads in the core, measured side by side in one run:
//  (a) insert_scan with 1 and 2 threads (set_num_threads) on the same scans, and the ratio;
//  (b) how long a sensor loop is blocked per scan when it hands scans to an AsyncMapper in
//      sequential mode (integration in the caller's thread) and in parallel mode (a worker);
//  (c) the three Ouster frames into a fresh map with the library's defaults (no retained memory,
//      so new memory is first touched as a user's map touches it), 1 and 2 threads alternating,
//      phase by phase (get_last_scan_phases()): the serial share of the one-thread insert and
//      Amdahl's projection of it to 2, 16 and 64 threads, beside the measured 2-thread speed-up.
//      It runs first, before (a) and (b) make maps reuse memory.
// usage: bench_threads [--reps N] [--resolution R] [--scans K] [--data DIR]

#include "bench_pcd.h"
#include "bench_util.h"

#include <iwlomap/async_mapper.h>
#include <iwlomap/probability_updater.h>
#include <iwlomap/scan_phases.h>
#include <iwlomap/sensor_preset.h>
#include <iwlomap/synthetic_scan.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#ifndef IWLOMAP_BENCH_DATA_DIR
#define IWLOMAP_BENCH_DATA_DIR "../shared/data"
#endif

namespace {

using iwlomap::bench::Clock;
using iwlomap::bench::median;
using iwlomap::bench::ms_since;

std::vector<iwlomap::SyntheticScan> make_scans(int count) {
  std::vector<iwlomap::SyntheticScan> scans;
  for (int k = 0; k < count; ++k) {
    iwlomap::SyntheticScanOptions o;  // 64 x 1024 = 65,536 rays per scan, ranges up to ~26 m
    o.sensor_xy = Eigen::Vector2d(-8.0 + 2.0 * k, -3.0 + 0.5 * k);
    o.seed = static_cast<std::uint32_t>(100 + k);
    scans.push_back(iwlomap::make_synthetic_scan(o));
  }
  return scans;
}

struct InsertFigures {
  double fresh_ms;   // ms per scan into a fresh map (block allocation included)
  double steady_ms;  // ms per scan for the same scans again, into the map that holds them
};

// Integrates all scans into a fresh map with `threads` threads, then once more.
InsertFigures insert_ms_per_scan(const std::vector<iwlomap::SyntheticScan>& scans, double resolution, int threads) {
  iwlomap::ProbabilityUpdater map(resolution);
  map.set_num_threads(threads);
  auto t0 = Clock::now();
  for (const auto& s : scans) map.insert_scan(s.origin, s.points, s.intensities);
  const double fresh = ms_since(t0) / static_cast<double>(scans.size());
  t0 = Clock::now();
  for (const auto& s : scans) map.insert_scan(s.origin, s.points, s.intensities);
  return {fresh, ms_since(t0) / static_cast<double>(scans.size())};
}

struct LoopFigures {
  double blocked_ms_per_scan;
  double total_ms;
};

// A sensor loop: a sensor delivers one scan every `period_ms` (the loop waits for the frame time,
// as a driver waits for the next packet), copies it and hands it over. Measures the time spent
// inside integrate() and the whole loop including the final sync().
LoopFigures sensor_loop(const std::vector<iwlomap::SyntheticScan>& scans, double resolution,
                        iwlomap::ExecutionMode mode, double period_ms) {
  auto map = std::make_shared<iwlomap::ProbabilityUpdater>(resolution);
  iwlomap::AsyncMapper mapper(map, mode, 2);
  double blocked = 0.0;
  const auto start = Clock::now();
  for (std::size_t k = 0; k < scans.size(); ++k) {
    const auto& s = scans[k];
    std::this_thread::sleep_until(start + std::chrono::duration<double, std::milli>(period_ms * static_cast<double>(k)));
    Eigen::MatrixXd points = s.points;
    Eigen::VectorXd intensities = s.intensities;
    const auto t0 = Clock::now();
    mapper.integrate(s.origin, std::move(points), std::move(intensities));
    blocked += ms_since(t0);
  }
  mapper.sync();
  return {blocked / static_cast<double>(scans.size()), ms_since(start)};
}

// The phases of one pass of \p frames into a fresh map (lidar preset, 25 m range), summed over the
// frames; total is the sum of the calls' own totals.
iwlomap::ScanPhaseTimes sequence_phases(const std::vector<iwlomap::bench::PcdCloud>& frames, double resolution,
                                        int threads) {
  iwlomap::ProbabilityUpdater map(resolution);
  map.set_params(iwlomap::sensor_preset_params(iwlomap::SensorPreset::kLidar));
  map.set_num_threads(threads);
  iwlomap::ScanPhaseTimes sum;
  sum.threads = threads;
  for (const auto& f : frames) {
    map.insert_scan(f.origin, f.points, f.intensities, 25.0);
    const iwlomap::ScanPhaseTimes& p = map.get_last_scan_phases();
    sum.casting_rays += p.casting_rays;
    sum.merging += p.merging;
    sum.allocating += p.allocating;
    sum.preparing += p.preparing;
    sum.updating += p.updating;
    sum.total += p.total;
  }
  return sum;
}

// The median of each phase over \p runs (each phase on its own; total too).
iwlomap::ScanPhaseTimes median_phases(const std::vector<iwlomap::ScanPhaseTimes>& runs) {
  const auto med = [&](double iwlomap::ScanPhaseTimes::*field) {
    std::vector<double> v;
    for (const auto& r : runs) v.push_back(r.*field);
    return median(v);
  };
  iwlomap::ScanPhaseTimes m;
  m.casting_rays = med(&iwlomap::ScanPhaseTimes::casting_rays);
  m.merging = med(&iwlomap::ScanPhaseTimes::merging);
  m.allocating = med(&iwlomap::ScanPhaseTimes::allocating);
  m.preparing = med(&iwlomap::ScanPhaseTimes::preparing);
  m.updating = med(&iwlomap::ScanPhaseTimes::updating);
  m.total = med(&iwlomap::ScanPhaseTimes::total);
  m.threads = runs.front().threads;
  return m;
}

void print_phase_table(const std::vector<iwlomap::bench::PcdCloud>& frames, double resolution, int reps) {
  std::vector<iwlomap::ScanPhaseTimes> one, two;
  std::vector<double> ratios;  // per round, so both share the machine's state
  for (int r = 0; r < reps; ++r) {
    one.push_back(sequence_phases(frames, resolution, 1));
    two.push_back(sequence_phases(frames, resolution, 2));
    ratios.push_back(one.back().total / two.back().total);
  }
  const iwlomap::ScanPhaseTimes a = median_phases(one), b = median_phases(two);
  std::printf("\n(c) the %zu Ouster frames into a fresh map, library defaults (no retained memory), lidar preset,\n"
              "    25 m range; ms per pass, median of %d rounds alternating 1 and 2 threads\n",
              frames.size(), reps);
  std::printf("    phase                         runs on        1 thread   2 threads   speed-up\n");
  const auto row = [](const char* name, const char* where, double x, double y) {
    std::printf("    %-29s %-12s %10.1f %11.1f %9.2fx\n", name, where, 1e3 * x, 1e3 * y, y > 0.0 ? x / y : 0.0);
  };
  row("casting rays", "threads", a.casting_rays, b.casting_rays);
  row("merging the threads' rays", "one thread", a.merging, b.merging);
  row("allocating blocks", "one thread", a.allocating, b.allocating);
  row("preparing cells", "threads", a.preparing, b.preparing);
  row("updating voxels", "threads", a.updating, b.updating);
  row("serial, all (total - parallel)", "one thread", a.serial(), b.serial());
  row("total", "", a.total, b.total);
  const double measured = median(ratios);
  std::printf("    serial share of the 1-thread insert: %.1f %% (target <= 5 %%: %s)\n", 100.0 * a.serial_share(),
              a.serial_share() <= 0.05 ? "met" : "NOT met");
  std::printf("    Amdahl's projection from it: 2 threads %.2fx, 16 threads %.2fx, 64 threads %.2fx\n",
              a.amdahl_speedup(2), a.amdahl_speedup(16), a.amdahl_speedup(64));
  std::printf("    measured, 2 threads vs 1 (median of the rounds' ratios): %.2fx (target >= 1.85x: %s)\n", measured,
              measured >= 1.85 ? "met" : "NOT met");
}

}  // namespace

int main(int argc, char** argv) {
  int reps = 5;
  int scan_count = 6;
  double resolution = 0.1;
  std::string data_dir = IWLOMAP_BENCH_DATA_DIR;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--reps" && i + 1 < argc) reps = std::atoi(argv[++i]);
    else if (a == "--scans" && i + 1 < argc) scan_count = std::atoi(argv[++i]);
    else if (a == "--resolution" && i + 1 < argc) resolution = std::atof(argv[++i]);
    else if (a == "--data" && i + 1 < argc) data_dir = argv[++i];
    else {
      std::fprintf(stderr, "usage: %s [--reps N] [--scans K] [--resolution R] [--data DIR]\n", argv[0]);
      return 2;
    }
  }
  if (reps < 1 || scan_count < 1 || !(resolution > 0.0)) {
    std::fprintf(stderr, "bench_threads: --reps and --scans must be >= 1, --resolution > 0\n");
    return 2;
  }
  const auto scans = make_scans(scan_count);
  std::printf("bench_threads: %d synthetic scans of %lld rays, resolution %.3f m, median of %d, %u hardware threads\n",
              scan_count, static_cast<long long>(scans.front().points.rows()), resolution, reps,
              std::thread::hardware_concurrency());
  iwlomap::bench::print_build();
  std::vector<iwlomap::bench::PcdCloud> frames;
  try {
    for (int k = 0; k < 3; ++k)
      frames.push_back(
          iwlomap::bench::read_pcd(data_dir + "/ouster_os1_128_3frames/frame_00" + std::to_string(k) + "_world.pcd"));
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_threads: %s (pass --data DIR, the folder holding ouster_os1_128_3frames/)\n", e.what());
    return 2;
  }
  print_phase_table(frames, resolution, reps);

  std::printf("\n(a) and (b):\n");
  iwlomap::bench::retain_map_memory();

  std::vector<double> one, two, one_steady, two_steady;
  for (int r = 0; r < reps; ++r) {  // alternate so both see the same machine load
    const InsertFigures a = insert_ms_per_scan(scans, resolution, 1);
    const InsertFigures b = insert_ms_per_scan(scans, resolution, 2);
    one.push_back(a.fresh_ms);
    one_steady.push_back(a.steady_ms);
    two.push_back(b.fresh_ms);
    two_steady.push_back(b.steady_ms);
  }
  const double m1 = median(one), m2 = median(two), s1 = median(one_steady), s2 = median(two_steady);
  std::printf("\n(a) insert_scan, ms per scan      into a fresh map   the same scans again\n");
  std::printf("    1 thread                  %10.1f %20.1f\n", m1, s1);
  std::printf("    2 threads                 %10.1f %20.1f\n", m2, s2);
  std::printf("    speedup                   %9.2fx %19.2fx\n", m1 / m2, s1 / s2);

  // The sensor runs at 1.5 x the single-thread insertion time per scan, so a worker can keep up.
  const double period = 1.5 * m1;
  std::vector<double> seq_blocked, par_blocked, seq_total, par_total;
  for (int r = 0; r < reps; ++r) {
    const LoopFigures s = sensor_loop(scans, resolution, iwlomap::ExecutionMode::kSequential, period);
    const LoopFigures p = sensor_loop(scans, resolution, iwlomap::ExecutionMode::kParallel, period);
    seq_blocked.push_back(s.blocked_ms_per_scan);
    par_blocked.push_back(p.blocked_ms_per_scan);
    seq_total.push_back(s.total_ms);
    par_total.push_back(p.total_ms);
  }
  std::printf("\n(b) sensor loop, one scan every %.1f ms, handing scans to AsyncMapper (queue of 2)\n", period);
  std::printf("                          sequential   parallel\n");
  std::printf("    blocked ms per scan   %10.2f %10.2f\n", median(seq_blocked), median(par_blocked));
  std::printf("    whole loop ms         %10.1f %10.1f\n", median(seq_total), median(par_total));
  std::printf("\nsummary: insert_scan 2 threads vs 1: %.2fx into a fresh map, %.2fx again (target >= 1.6x: %s / %s); "
              "caller blocked per scan: %.2f ms sequential, %.2f ms parallel\n",
              m1 / m2, s1 / s2, m1 / m2 >= 1.6 ? "met" : "NOT met", s1 / s2 >= 1.6 ? "met" : "NOT met",
              median(seq_blocked), median(par_blocked));
  return 0;
}
