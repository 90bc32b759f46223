// SPDX-License-Identifier: BSD-3-Clause
// Threads in the core, measured side by side in one run:
//  (a) insert_scan with 1 and 2 threads (set_num_threads) on the same scans, and the ratio;
//  (b) how long a sensor loop is blocked per scan when it hands scans to an AsyncMapper in
//      sequential mode (integration in the caller's thread) and in parallel mode (a worker).
// usage: bench_threads [--reps N] [--resolution R] [--scans K]

#include "bench_util.h"

#include <iwlomap/async_mapper.h>
#include <iwlomap/probability_updater.h>
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

}  // namespace

int main(int argc, char** argv) {
  int reps = 5;
  int scan_count = 6;
  double resolution = 0.1;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--reps" && i + 1 < argc) reps = std::atoi(argv[++i]);
    else if (a == "--scans" && i + 1 < argc) scan_count = std::atoi(argv[++i]);
    else if (a == "--resolution" && i + 1 < argc) resolution = std::atof(argv[++i]);
    else {
      std::fprintf(stderr, "usage: %s [--reps N] [--scans K] [--resolution R]\n", argv[0]);
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
