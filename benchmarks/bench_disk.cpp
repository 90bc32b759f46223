// SPDX-License-Identifier: BSD-3-Clause
//
// bench_disk: the Disk backend (iwlomap::OutofcoreTileMapper) against the RAM backend
// (iwlomap::ProbabilityUpdater) on a spatially coherent stream, single thread, same input.
//
// The stream is a synthetic multibeam survey: a sensor flies a straight line at constant altitude
// over rolling terrain and pings every `step` metres; a ping is a fan of `beams` rays across the
// track (+-60 degrees) in `slices` parallel planes, each ray ending on the terrain with an
// intensity that falls with the incidence angle. The map grows along the track, so old tiles
// leave the working set for good: the case out-of-core maps are made for.
//
//   (a) insertion throughput, insert_scan (rays/s) and batch_update_iwlo of the endpoints
//       (points/s): RAM; Disk with a cache that holds the whole map (no eviction: the cost of the
//       tiles alone); Disk with a cache that holds the working set (tiles left behind are evicted,
//       each written once to a file of its own); Disk with a cache smaller than the working set
//   (b) flush throughput (MB/s) and number of files: the whole map resident then flushed, and the
//       final flush of a streaming run (staged evictions made durable, dirty tiles written)
//   (c) peak resident memory (VmHWM) of a map many times larger than the cache, against the RAM
//       backend holding the same map
//
// Every measurement runs in a child process of its own (fork), so that its VmHWM is its own; each
// child reports its map's voxel count and the parent checks that every backend built the same
// number of voxels. Only the backend calls are timed (generating pings is not), in wall-clock time
// and in thread CPU time (which a loaded machine disturbs less; it leaves out waiting for the
// disk). The insertion runs are repeated --reps times, RAM and Disk alternating, and the tables
// give medians. Map directories live under --dir (default: the system's temporary directory) and
// are deleted at the end.
//
// Usage: bench_disk [--pings N] [--reps N] [--dir DIR] [--quick]

#include "iwlomap/mapper_backend.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"

#include "bench_util.h"

#include <sys/wait.h>
#include <time.h>
#include <unistd.h>

#include <Eigen/Core>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

using iwlomap::bench::median;

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

constexpr double kResolution = 0.1;
constexpr double kTileSize = 6.4;  // 64 voxels, 8 blocks per edge
constexpr double kAltitude = 8.0;  // sensor height above the mean terrain (m)
constexpr double kStep = 0.4;      // along-track distance between pings (m)
constexpr int kBeams = 256;
constexpr int kSlices = 4;  // parallel fan planes per ping, 0.1 m apart along the track
constexpr double kPi = 3.14159265358979323846;

struct Options {
  int pings = 700;  // 280 m of track
  int reps = 3;
  std::string dir;
  bool quick = false;
  bool hits = false;
};

double terrain(double x, double y) { return 1.2 * std::sin(0.15 * x) * std::cos(0.11 * y) + 0.5 * std::sin(0.37 * x + 0.2 * y); }

struct Ping {
  Eigen::Vector3d origin;
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
  std::vector<bool> flags;
};

// Ping k of the survey line; the same k gives the same ping in every process.
Ping make_ping(int k) {
  std::mt19937 rng(77u + static_cast<std::uint32_t>(k));
  std::normal_distribution<double> noise(0.0, 8.0);
  const double x = kStep * k;
  Ping p;
  p.origin = Eigen::Vector3d(x, 0.5 * std::sin(0.02 * k), kAltitude);  // a little sway across the track
  const int n = kBeams * kSlices;
  p.points.resize(n, 3);
  p.intensities.resize(n);
  p.flags.assign(static_cast<std::size_t>(n), true);
  for (int s = 0; s < kSlices; ++s) {
    for (int b = 0; b < kBeams; ++b) {
      const int i = s * kBeams + b;
      const double angle = (-60.0 + 120.0 * (b + 0.5) / kBeams) * kPi / 180.0;
      const double gx = x + 0.1 * s, gy = p.origin.y() + kAltitude * std::tan(angle);
      p.points.row(i) << gx, gy, terrain(gx, gy);
      const double c = std::cos(angle);
      p.intensities[i] = std::clamp(30.0 + 200.0 * c * c + noise(rng), 0.0, 255.0);
    }
  }
  return p;
}

long vm_hwm_kib() {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line))
    if (line.rfind("VmHWM:", 0) == 0) return std::strtol(line.c_str() + 6, nullptr, 10);
  return -1;
}

std::size_t count_files(const std::string& dir) {
  std::size_t n = 0;
  for (const auto& e : fs::directory_iterator(dir)) n += e.is_regular_file() ? 1 : 0;
  return n;
}

// What a child reports to the parent (plain data through a pipe).
double thread_cpu_s() {
  timespec t{};
  ::clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
  return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
}

struct Result {
  double insert_s = 0.0;      // wall-clock time in insert_scan / batch_update_iwlo
  double insert_cpu_s = 0.0;  // thread CPU time in them
  double items = 0.0;         // rays or points
  double flush_s = 0.0;       // the final flush (Disk)
  double flushed_mb = 0.0;    // bytes on disk after it
  double files = 0.0;         // files in the map directory
  double nodes = 0.0;         // known voxels
  double tiles = 0.0;         // tiles of the map (Disk)
  double peak_tiles = 0.0;    // most tiles resident at once (Disk)
  double vm_hwm_mb = 0.0;     // peak resident memory of the process
  double memory_mb = 0.0;     // the backend's own memory_mb
  double ping_tiles = 0.0;    // tiles one ping touches (Disk, first ping)
  bool ok = false;
  char error[256] = {};
};

struct Job {
  bool disk = false;
  bool scans = true;          // insert_scan, else batch_update_iwlo of the endpoints
  std::size_t cache = 0;
  int pings = 0;
  std::string dir;
  bool hits = false;  // hit statistics accumulated
};

Result run_job(const Job& job) {
  Result r;
  std::unique_ptr<iwlomap::IMapperBackend> map;
  if (job.disk)
    map = std::make_unique<iwlomap::OutofcoreTileMapper>(job.dir, kResolution, kTileSize, job.cache);
  else
    map = std::make_unique<iwlomap::ProbabilityUpdater>(kResolution);
  map->set_hit_accumulation(job.hits);
  for (int k = 0; k < job.pings; ++k) {
    const Ping p = make_ping(k);
    const double c0 = thread_cpu_s();
    const auto t0 = Clock::now();
    if (job.scans)
      map->insert_scan(p.origin, p.points, p.intensities);
    else
      map->batch_update_iwlo(p.points, p.intensities, p.flags);
    r.insert_s += std::chrono::duration<double>(Clock::now() - t0).count();
    r.insert_cpu_s += thread_cpu_s() - c0;
    r.items += static_cast<double>(p.points.rows());
    if (k == 0 && job.disk)
      r.ping_tiles = static_cast<double>(dynamic_cast<iwlomap::OutofcoreTileMapper&>(*map).get_num_tiles());
  }
  r.nodes = static_cast<double>(map->get_num_known_voxels());
  r.memory_mb = map->get_memory_usage().memory_mb;
  if (job.disk) {
    auto& disk = dynamic_cast<iwlomap::OutofcoreTileMapper&>(*map);
    const auto t0 = Clock::now();
    disk.flush();
    r.flush_s = std::chrono::duration<double>(Clock::now() - t0).count();
    r.flushed_mb = static_cast<double>(disk.get_disk_usage()) / (1024.0 * 1024.0);
    r.files = static_cast<double>(count_files(job.dir));
    r.tiles = static_cast<double>(disk.get_num_tiles());
    r.peak_tiles = static_cast<double>(disk.get_peak_resident_tiles());
  }
  r.vm_hwm_mb = static_cast<double>(vm_hwm_kib()) / 1024.0;
  r.ok = true;
  return r;
}

// Runs a job in a child process and returns what it reports.
Result in_child(const Job& job) {
  int fds[2];
  if (::pipe(fds) != 0) throw std::runtime_error("pipe failed");
  const pid_t pid = ::fork();
  if (pid < 0) throw std::runtime_error("fork failed");
  if (pid == 0) {
    ::close(fds[0]);
    Result r;
    try {
      r = run_job(job);
    } catch (const std::exception& e) {
      std::snprintf(r.error, sizeof r.error, "%s", e.what());
    }
    const ssize_t w = ::write(fds[1], &r, sizeof r);
    ::_exit(w == static_cast<ssize_t>(sizeof r) ? 0 : 1);
  }
  ::close(fds[1]);
  Result r;
  std::size_t got = 0;
  while (got < sizeof r) {
    const ssize_t n = ::read(fds[0], reinterpret_cast<char*>(&r) + got, sizeof r - got);
    if (n <= 0) break;
    got += static_cast<std::size_t>(n);
  }
  ::close(fds[0]);
  int status = 0;
  ::waitpid(pid, &status, 0);
  if (got != sizeof r || !r.ok) throw std::runtime_error(std::string("benchmark child failed: ") + r.error);
  return r;
}

void print_usage(const char* argv0) {
  std::printf(
      "Usage: %s [--pings N] [--reps N] [--dir DIR] [--hit-statistics] [--quick]\n"
      "  --pings N  pings of the survey line (default 700: 280 m of track, %d rays per ping)\n"
      "  --reps N   repetitions of each insertion run; medians are reported (default 3)\n"
      "  --dir DIR  where the map directories are made (default: the system's temporary directory)\n"
      "  --hit-statistics  every backend accumulates hit statistics (off by default)\n"
      "  --quick    200 pings, 1 repetition\n",
      argv0, kBeams * kSlices);
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--pings" && i + 1 < argc) {
      o.pings = std::atoi(argv[++i]);
    } else if (a == "--reps" && i + 1 < argc) {
      o.reps = std::max(1, std::atoi(argv[++i]));
    } else if (a == "--dir" && i + 1 < argc) {
      o.dir = argv[++i];
    } else if (a == "--hit-statistics") {
      o.hits = true;
    } else if (a == "--quick") {
      o.quick = true;
      o.pings = 200;
      o.reps = 1;
    } else {
      print_usage(argv[0]);
      return a == "--help" || a == "-h" ? 0 : 2;
    }
  }
  const fs::path base = fs::path(o.dir.empty() ? fs::temp_directory_path().string() : o.dir) /
                        ("iwlomap_bench_disk_" + std::to_string(::getpid()));
  fs::create_directories(base);
  int counter = 0;
  const auto fresh_dir = [&] { return (base / ("map" + std::to_string(counter++))).string(); };

  try {
    std::printf("bench_disk: survey line of %d pings x %d rays (%.0f m of track), resolution %.2f m, tiles of %.1f m "
                "(%d voxels), hit statistics %s\n\n",
                o.pings, kBeams * kSlices, o.pings * kStep, kResolution, kTileSize,
                static_cast<int>(std::lround(kTileSize / kResolution)), o.hits ? "on" : "off");
    iwlomap::bench::retain_map_memory();

    // A probe: how many tiles one ping touches, i.e. the working set of the stream.
    Job probe{true, true, 4096, 1, fresh_dir()};
    const Result pr = in_child(probe);
    const auto ping_tiles = static_cast<std::size_t>(pr.ping_tiles);
    const std::size_t fits = 2 * ping_tiles + 8;              // a ping and its neighbours, with room
    const std::size_t tight = std::max<std::size_t>(2, ping_tiles / 3);  // a third of one ping
    std::printf("one ping touches %zu tiles; cache that fits the working set: %zu tiles, one that does not: %zu\n\n",
                ping_tiles, fits, tight);

    for (const bool scans : {true, false}) {
      // Repetitions alternate the backends so that they share the machine's noise.
      constexpr int kConfigs = 4;
      std::vector<Result> runs[kConfigs];
      const std::size_t caches[kConfigs] = {0, std::size_t{1} << 20, fits, tight};
      for (int r = 0; r < o.reps; ++r)
        for (int b = 0; b < kConfigs; ++b) {
          const int which = (b + r) % kConfigs;
          runs[which].push_back(
              in_child({which != 0, scans, caches[which], o.pings, which != 0 ? fresh_dir() : "", o.hits}));
        }
      const auto rate = [](const std::vector<Result>& v, bool cpu) {
        std::vector<double> x;
        for (const Result& r : v) x.push_back(r.items / (cpu ? r.insert_cpu_s : r.insert_s));
        return median(x);
      };
      const auto med = [](const std::vector<Result>& v, double Result::*field) {
        std::vector<double> x;
        for (const Result& r : v) x.push_back(r.*field);
        return median(x);
      };
      const double ram_wall = rate(runs[0], false), ram_cpu = rate(runs[0], true);
      std::printf("(a) %s, median of %d\n", scans ? "insert_scan (rays/s)" : "batch_update_iwlo of the endpoints (points/s)",
                  o.reps);
      std::printf("| backend | cache tiles | map tiles | M%s/s wall | vs RAM | M%s/s CPU | vs RAM | voxels | VmHWM (MB) | "
                  "final flush (s) | on disk (MB) | files |\n",
                  scans ? "rays" : "points", scans ? "rays" : "points");
      std::printf("|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n");
      const char* names[kConfigs] = {"RAM", "Disk, whole map resident", "Disk, working set fits",
                                     "Disk, working set does not fit"};
      for (int b = 0; b < kConfigs; ++b) {
        const std::vector<Result>& v = runs[b];
        const double wall = rate(v, false), cpu = rate(v, true);
        std::printf("| %s | ", names[b]);
        if (b == 0)
          std::printf("- | - | ");
        else if (b == 1)
          std::printf("all | %.0f | ", v.front().tiles);
        else
          std::printf("%zu | %.0f | ", caches[b], v.front().tiles);
        std::printf("%.2f | %.2f | %.2f | %.2f | %.0f | %.0f | ", wall / 1e6, wall / ram_wall, cpu / 1e6, cpu / ram_cpu,
                    v.front().nodes, med(v, &Result::vm_hwm_mb));
        if (b == 0)
          std::printf("- | - | - |\n");
        else
          std::printf("%.2f | %.1f | %.0f |\n", med(v, &Result::flush_s), v.front().flushed_mb, v.front().files);
        for (const Result& r : v) {
          if (r.nodes != runs[0].front().nodes)
            std::printf("  MISMATCH: %s built %.0f voxels, RAM %.0f\n", names[b], r.nodes, runs[0].front().nodes);
          if (b > 0 && r.peak_tiles > static_cast<double>(caches[b]))
            std::printf("  BOUND EXCEEDED: %.0f tiles resident at once, cache %zu\n", r.peak_tiles, caches[b]);
        }
      }
      std::printf("\n");
    }

    // (b) Flush of a whole resident map: every tile written, fsync'ed and renamed.
    {
      const int pings = std::max(50, o.pings / 4);
      const Result all = in_child({true, true, 100000, pings, fresh_dir()});
      std::printf("(b) flush of a fully resident map (%d pings): %.1f MB in %.0f files in %.3f s = %.1f MB/s "
                  "(%.1f ms per file)\n\n",
                  pings, all.flushed_mb, all.files, all.flush_s, all.flushed_mb / all.flush_s,
                  1e3 * all.flush_s / all.files);
    }

    // (c) Peak memory of a map much larger than the cache, against RAM holding it all.
    {
      const std::size_t cache = 8;
      const Result ram = in_child({false, true, 0, o.pings, ""});
      const Result disk = in_child({true, true, cache, o.pings, fresh_dir()});
      std::printf("(c) peak memory, %d pings: the map has %.0f tiles = %.0fx the cache of %zu tiles\n", o.pings, disk.tiles,
                  disk.tiles / cache, cache);
      std::printf("| backend | VmHWM (MB) | memory_mb at the end | voxels | on disk (MB) |\n|---|---:|---:|---:|---:|\n");
      std::printf("| RAM | %.0f | %.0f | %.0f | - |\n", ram.vm_hwm_mb, ram.memory_mb, ram.nodes);
      std::printf("| Disk, %zu tiles | %.0f | %.0f | %.0f | %.0f |\n", cache, disk.vm_hwm_mb, disk.memory_mb, disk.nodes,
                  disk.flushed_mb);
      std::printf("peak resident tiles: %.0f (bound %zu)\n", disk.peak_tiles, cache);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_disk: %s\n", e.what());
    std::error_code ec;
    fs::remove_all(base, ec);
    return 1;
  }
  std::error_code ec;
  fs::remove_all(base, ec);
  return 0;
}
