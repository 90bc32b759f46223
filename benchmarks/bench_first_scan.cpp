// SPDX-License-Identifier: BSD-3-Clause
//
// bench_first_scan: what a user's single run pays for fresh memory. One scan into a new RAM map
// (lidar preset, single thread), timed three ways, rounds interleaved:
//
//   fresh process  a child process that does nothing else (`iwlomap map` on one file): every
//                  page of the map, the scan's scratch and the heap is touched for the first time
//   new map        in this process, a new map after the last one was destroyed, with the
//                  library's defaults (no memory kept once no map is alive)
//   warm           a new map built from memory kept from the map before it
//                  (set_retained_map_memory(256 MiB) for this row only): no first touch at all
//
// and prints fresh / warm and new map / warm. Also the page faults of each (getrusage).
//
// Usage: bench_first_scan [--pcd FILE] [--resolution R] [--rounds N]

#include "bench_pcd.h"
#include "bench_util.h"
#include "iwlomap/map_memory.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/sensor_preset.h"
#include "iwlomap/synthetic_scan.h"

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <stdexcept>
#include <string>
#include <vector>

namespace {

using iwlomap::bench::median;

struct Options {
  std::string pcd;
  double resolution = 0.1;
  int rounds = 7;
};

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const auto value = [&]() -> std::string { return iwlomap::bench::option_value(argc, argv, i); };
    if (a == "--pcd") o.pcd = value();
    else if (a == "--resolution") o.resolution = std::stod(value());
    else if (a == "--rounds") o.rounds = std::stoi(value());
    else throw std::invalid_argument("unknown option " + a + " (see the comment at the top of bench_first_scan.cpp)");
  }
  if (!(o.resolution > 0.0) || o.rounds < 1) throw std::invalid_argument("--resolution > 0 and --rounds >= 1");
  return o;
}

struct Scan {
  Eigen::Vector3d origin;
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
};

Scan load(const Options& o) {
  if (o.pcd.empty()) {
    iwlomap::SyntheticScan s = iwlomap::make_synthetic_scan();
    return {s.origin, std::move(s.points), std::move(s.intensities)};
  }
  iwlomap::bench::PcdCloud c = iwlomap::bench::read_pcd(o.pcd);
  return {c.origin, std::move(c.points), std::move(c.intensities)};
}

long minor_faults() {
  rusage u{};
  getrusage(RUSAGE_SELF, &u);
  return u.ru_minflt;
}

struct Run {
  double ms = 0;
  long faults = 0;
  std::size_t voxels = 0;
};

// One scan into a new map; the map is destroyed after the timed call.
Run one_scan(const Scan& s, double resolution) {
  iwlomap::ProbabilityUpdater map(resolution);
  map.set_params(iwlomap::sensor_preset_params(iwlomap::SensorPreset::kLidar));
  const long f0 = minor_faults();
  const auto t0 = iwlomap::bench::now();
  map.insert_scan(s.origin, s.points, s.intensities);
  const double ms = iwlomap::bench::elapsed(t0, iwlomap::bench::now()).wall_ms;
  return {ms, minor_faults() - f0, map.get_num_known_voxels()};
}

// The fresh-process row: a child loads the scan, then times its one scan and reports it on a pipe.
Run in_child(const Options& o) {
  int fd[2];
  if (pipe(fd) != 0) throw std::runtime_error(std::string("pipe: ") + std::strerror(errno));
  const pid_t pid = fork();
  if (pid < 0) throw std::runtime_error(std::string("fork: ") + std::strerror(errno));
  if (pid == 0) {
    close(fd[0]);
    // The child re-executes this program so that nothing the parent touched is inherited.
    const std::string out = std::to_string(fd[1]);
    std::vector<std::string> args = {"/proc/self/exe", "--child", out, "--resolution", std::to_string(o.resolution)};
    if (!o.pcd.empty()) args.insert(args.end(), {"--pcd", o.pcd});
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    execv("/proc/self/exe", argv.data());
    _exit(127);
  }
  close(fd[1]);
  Run r;
  const ssize_t n = read(fd[0], &r, sizeof(r));
  close(fd[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  if (n != static_cast<ssize_t>(sizeof(r)) || !WIFEXITED(status) || WEXITSTATUS(status) != 0)
    throw std::runtime_error("the fresh-process child failed");
  return r;
}

int child_main(int argc, char** argv) {
  const int fd = std::atoi(argv[2]);
  std::vector<char*> rest = {argv[0]};
  for (int i = 3; i < argc; ++i) rest.push_back(argv[i]);
  const Options o = parse(static_cast<int>(rest.size()), rest.data());
  const Scan s = load(o);
  const Run r = one_scan(s, o.resolution);
  return write(fd, &r, sizeof(r)) == static_cast<ssize_t>(sizeof(r)) ? 0 : 1;
}

}  // namespace

int main(int argc, char** argv) try {
  if (argc > 2 && std::string(argv[1]) == "--child") return child_main(argc, argv);
  const Options o = parse(argc, argv);
  const Scan s = load(o);
  std::printf("bench_first_scan: %s, %lld points, %.3g m, %d rounds, single thread, lidar preset\n",
              o.pcd.empty() ? "synthetic scan (iwlomap generate)" : o.pcd.c_str(),
              static_cast<long long>(s.points.rows()), o.resolution, o.rounds);
  iwlomap::bench::print_build();
  std::vector<double> fresh, fresh_faults, renewed, renewed_faults, warm, warm_faults;
  std::size_t voxels = 0;
  (void)one_scan(s, o.resolution);  // the heap and the scan's scratch of this process are touched once
  for (int round = 0; round < o.rounds; ++round) {
    const Run f = in_child(o);
    fresh.push_back(f.ms);
    fresh_faults.push_back(static_cast<double>(f.faults));
    const Run n = one_scan(s, o.resolution);
    renewed.push_back(n.ms);
    renewed_faults.push_back(static_cast<double>(n.faults));
    iwlomap::set_retained_map_memory(std::size_t{256} << 20);
    (void)one_scan(s, o.resolution);  // leaves its slabs for the next map
    const Run w = one_scan(s, o.resolution);
    iwlomap::set_retained_map_memory(0);
    warm.push_back(w.ms);
    warm_faults.push_back(static_cast<double>(w.faults));
    voxels = w.voxels;
  }
  const double w = median(warm);
  std::printf("  map: %zu known voxels\n", voxels);
  std::printf("  %-44s %9.1f ms  %8.0f page faults\n", "warm (memory kept from the map before)", w, median(warm_faults));
  std::printf("  %-44s %9.1f ms  %8.0f page faults  %5.2fx warm\n", "new map in this process (library defaults)",
              median(renewed), median(renewed_faults), median(renewed) / w);
  std::printf("  %-44s %9.1f ms  %8.0f page faults  %5.2fx warm\n", "fresh process (library defaults)", median(fresh),
              median(fresh_faults), median(fresh) / w);
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_first_scan: %s\n", e.what());
  return 1;
}
