// SPDX-License-Identifier: BSD-3-Clause
//
// bench_peers: iwlomap's scan insertion against Bonxai's ProbabilisticMap::insertPointCloud, and
// per-point updates of scattered points against Bonxai and OctoMap, measured side by side in one
// run, single thread, on the same input.
//
// Scan workloads (iwlomap insert_scan, lidar semantics, exact face-connected rays or, with
// --rays fast, RayModel::kFast's 26-connected line; Bonxai insertPointCloud with its defaults,
// 26-connected rays):
//   fresh       one scan into an empty map
//   again       the same scan into the map that holds it (only the second call is timed)
//   sequence    the three Ouster frames in order into one map, per scan; iwlomap also runs them
//               a second time over (its own row). Bonxai runs no second pass: its 2-bit per-cell
//               update id wraps every three scans, so on a second pass it skips updates it should
//               make, and its time there would flatter it.
//   growing     16 Ouster frames into one map, frame k being frame k % 3 moved 10 m * k along x
//               (25 m range: each frame overlaps the last and reaches into unseen space), per frame
// Scattered: N points uniform in a 20 x 20 x 5 m box at 0.05 m, one occupied update each: iwlomap
// batch_update_iwlo, OctoMap OcTree::updateNode per point, Bonxai a cell accessor per point (the
// hit update of its addHitPoint, without the ray bookkeeping); into an empty map and again.
//
// Rounds alternate which library goes first, so both share the machine's noise; tables show the
// medians of wall clock and thread CPU time after one untimed warm-up round. Memory after each
// workload: iwlomap's get_memory_usage() beside Bonxai's memUsage(), and the resident-set growth
// of building each map in a fresh child process. The voxel counts of both maps are printed: the
// two ray models visit different voxels, so neither map is a reference for the other.
//
// Bonxai is not part of iwlomap: configure with -DIWLOMAP_BONXAI_DIR=<Bonxai source folder> to
// build its rows; without it this program measures iwlomap alone and says so.
//
// Each library runs with its defaults: iwlomap keeps no memory of destroyed maps (with
// --retain-memory it keeps 64 MiB, as a long-running process may ask). The fresh workloads are
// also timed in child processes forked before any map is built, each library alone: a user's
// single run.
//
// Usage: bench_peers [--reps N] [--data DIR] [--scattered N] [--only TEXT] [--rays exact|fast]
//                    [--retain-memory] [--quick]

#include "bench_pcd.h"
#include "bench_util.h"
#include "iwlomap/iwlo.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/sensor_preset.h"
#include "iwlomap/synthetic_scan.h"

#include <octomap/OcTree.h>

#ifdef IWLOMAP_BENCH_WITH_BONXAI
#include "bonxai_map/probabilistic_map.hpp"
#endif

#include <Eigen/Core>

#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <functional>
#include <memory>
#include <optional>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#ifndef IWLOMAP_BENCH_DATA_DIR
#define IWLOMAP_BENCH_DATA_DIR "../shared/data"
#endif

namespace {

using iwlomap::bench::elapsed;
using iwlomap::bench::median;
using iwlomap::bench::now;
using iwlomap::bench::Sample;
using iwlomap::bench::Stamp;

constexpr double kResolution = 0.1;
constexpr double kOusterMaxRange = 25.0;
constexpr double kScatteredResolution = 0.05;
constexpr int kGrowingFrames = 16;
constexpr double kGrowingStep = 10.0;  // metres along x between growing frames
constexpr double kTarget = 1.3;        // Bonxai time / iwlomap time on every scan workload, exact rays
constexpr double kFastTarget = 1.6;    // the same with --rays fast
constexpr float kOctomapHitLogOdds = 0.85f;  // OctoMap's default hit, log(0.7 / 0.3)

#ifdef IWLOMAP_BENCH_WITH_BONXAI
constexpr bool kWithBonxai = true;
#else
constexpr bool kWithBonxai = false;
#endif

struct Options {
  int reps = 5;
  std::string data_dir = IWLOMAP_BENCH_DATA_DIR;
  long scattered = 1000000;
  std::string only;  // run only the scan workloads whose name contains this ("scattered": only that row)
  iwlomap::RayModel rays = iwlomap::RayModel::kExact;
  bool retain_memory = false;  // set_retained_map_memory(64 MiB) before the timed rounds
};

void print_usage(const char* argv0) {
  std::printf(
      "Usage: %s [--reps N] [--data DIR] [--scattered N] [--only TEXT] [--rays exact|fast] [--retain-memory]\n"
      "          [--quick]\n"
      "  --reps N       timed rounds per workload (default 5; medians are reported)\n"
      "  --data DIR     folder holding ouster_os1_128_3frames/ and octomap_scan/ (default %s)\n"
      "  --scattered N  points of the scattered-points row (default 1000000; 0 skips the row)\n"
      "  --only TEXT    only the scan workloads whose name contains TEXT (e.g. 'Ouster', 'again');\n"
      "                 'scattered': only the scattered-points row\n"
      "  --rays MODEL   iwlomap's ray model: exact (default, every voxel a ray crosses) or fast\n"
      "                 (RayModel::kFast, a 26-connected line as Bonxai's)\n"
      "  --retain-memory  iwlomap maps reuse the memory of destroyed ones (set_retained_map_memory(64 MiB));\n"
      "                 the default is the library's: none kept\n"
      "  --quick        2 rounds and 100000 scattered points (a smoke run; figures are noisier)\n",
      argv0, IWLOMAP_BENCH_DATA_DIR);
}

Options parse_options(int argc, char** argv) {
  Options o;
  bool reps_given = false, scattered_given = false, quick = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](const char* name) -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(std::string(name) + " needs a value");
      return argv[++i];
    };
    auto integer = [&](const char* name, long lo, long hi) {
      const std::string v = value(name);
      char* end = nullptr;
      const long n = std::strtol(v.c_str(), &end, 10);
      if (end == v.c_str() || *end != '\0' || n < lo || n > hi)
        throw std::invalid_argument(std::string(name) + " must be an integer in [" + std::to_string(lo) + ", " +
                                    std::to_string(hi) + "], got '" + v + "'");
      return n;
    };
    if (a == "--reps") {
      o.reps = static_cast<int>(integer("--reps", 1, 1000));
      reps_given = true;
    } else if (a == "--data") {
      o.data_dir = value("--data");
    } else if (a == "--scattered") {
      o.scattered = integer("--scattered", 0, 100000000);
      scattered_given = true;
    } else if (a == "--only") {
      o.only = value("--only");
    } else if (a == "--rays") {
      const std::string v = value("--rays");
      const std::optional<iwlomap::RayModel> model = iwlomap::parse_ray_model(v);
      if (!model) throw std::invalid_argument("--rays must be exact or fast, got '" + v + "'");
      o.rays = *model;
    } else if (a == "--retain-memory") {
      o.retain_memory = true;
    } else if (a == "--quick") {
      quick = true;
    } else if (a == "--help" || a == "-h") {
      print_usage(argv[0]);
      std::exit(0);
    } else {
      throw std::invalid_argument("unknown argument '" + a + "' (see --help)");
    }
  }
  if (quick && !reps_given) o.reps = 2;
  if (quick && !scattered_given) o.scattered = 100000;
  return o;
}

// ---- input -------------------------------------------------------------------------------------

// One scan in both libraries' types, converted once, outside the timed regions.
struct Scan {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::MatrixXd points;  // N x 3, map frame
  Eigen::VectorXd intensities;
  double max_range = -1.0;            // iwlomap: <= 0 means none
  std::vector<Eigen::Vector3d> list;  // the same points for Bonxai
};

Scan make_scan(const Eigen::Vector3d& origin, Eigen::MatrixXd points, Eigen::VectorXd intensities, double max_range) {
  Scan s;
  s.origin = origin;
  s.points = std::move(points);
  s.intensities = std::move(intensities);
  s.max_range = max_range;
  s.list.reserve(static_cast<std::size_t>(s.points.rows()));
  for (Eigen::Index i = 0; i < s.points.rows(); ++i) s.list.emplace_back(s.points.row(i).transpose());
  return s;
}

Scan shifted(const Scan& s, const Eigen::Vector3d& d) {
  return make_scan(s.origin + d, s.points.rowwise() + d.transpose(), s.intensities, s.max_range);
}

Scan load_frame(const std::string& path, double max_range) {
  iwlomap::bench::PcdCloud c = iwlomap::bench::read_pcd(path);
  return make_scan(c.origin, std::move(c.points), std::move(c.intensities), max_range);
}

// ---- the libraries -----------------------------------------------------------------------------

// The lidar preset (every return is a hit, a zero intensity too: octomap_scan has none), one thread.
std::unique_ptr<iwlomap::ProbabilityUpdater> make_iwlomap(double resolution,
                                                          iwlomap::RayModel rays = iwlomap::RayModel::kExact) {
  auto m = std::make_unique<iwlomap::ProbabilityUpdater>(resolution);
  m->set_params(iwlomap::sensor_preset_params(iwlomap::SensorPreset::kLidar));
  m->set_num_threads(1);
  m->set_ray_model(rays);
  return m;
}

void iw_insert(iwlomap::ProbabilityUpdater& m, const Scan& s) {
  m.insert_scan(s.origin, s.points, s.intensities, s.max_range);
}

#ifdef IWLOMAP_BENCH_WITH_BONXAI
// Bonxai turns every point farther than max_range into a free ray; with no range limit (the
// synthetic scan) a range longer than any ray keeps every point a hit, as in iwlomap.
void bx_insert(Bonxai::ProbabilisticMap& m, const Scan& s) {
  m.insertPointCloud(s.list, s.origin, s.max_range > 0.0 ? s.max_range : 1e9);
}
#endif

// The calling process's resident set, KiB (-1 when unknown).
long rss_kib() {
  std::ifstream f("/proc/self/status");
  long v = -1;
  for (std::string line; std::getline(f, line);)
    if (line.rfind("VmRSS:", 0) == 0) v = std::strtol(line.c_str() + 6, nullptr, 10);
  return v;
}

struct MapSize {
  double api_mib = 0.0;  // the library's own figure
  long rss_kib = -1;     // the process's resident set with the map built, before it is destroyed
  std::size_t known = 0, occupied = 0;
};

MapSize iw_size(const iwlomap::ProbabilityUpdater& m) {
  MapSize z;
  z.api_mib = m.get_memory_usage().memory_mb;
  m.for_each_voxel([&](const iwlomap::VoxelKey&, const iwlomap::VoxelState& v) {
    ++z.known;
    if (v.probability > 0.5) ++z.occupied;
  });
  return z;
}

#ifdef IWLOMAP_BENCH_WITH_BONXAI
MapSize bx_size(Bonxai::ProbabilisticMap& m) {
  MapSize z;
  z.api_mib = static_cast<double>(m.grid().memUsage()) / (1024.0 * 1024.0);
  const std::int32_t threshold = m.options().occupancy_threshold_log;
  m.grid().forEachCell([&](Bonxai::ProbabilisticMap::CellT& c, const Bonxai::CoordT&) {
    ++z.known;
    if (c.probability_log > threshold) ++z.occupied;
  });
  return z;
}
#endif

// ---- workloads ---------------------------------------------------------------------------------

// A workload builds its own map, times its scans and returns the time per timed scan; with
// \p size it also reports the map it built.
struct Workload {
  std::string name;
  std::size_t points = 0;  // per timed scan
  std::function<Sample(MapSize*)> iw;
  std::function<Sample(MapSize*)> bx;  // empty: not run for Bonxai
};

Sample per_scan(const Sample& total, std::size_t scans) {
  return {total.wall_ms / static_cast<double>(scans), total.cpu_ms / static_cast<double>(scans)};
}

// Times \p timed after \p untimed, each scan into one map of the library.
template <class MakeMap, class Insert, class Size>
Sample run_scans(MakeMap make_map, Insert insert, Size size, const std::vector<const Scan*>& untimed,
                 const std::vector<const Scan*>& timed, MapSize* out) {
  iwlomap::bench::settle_heap();
  auto m = make_map();
  for (const Scan* s : untimed) insert(*m, *s);
  const Stamp t0 = now();
  for (const Scan* s : timed) insert(*m, *s);
  const Sample t = per_scan(elapsed(t0, now()), timed.size());
  if (out != nullptr) {
    *out = size(*m);
    out->rss_kib = rss_kib();
  }
  return t;
}

Workload scan_workload(std::string name, std::vector<const Scan*> untimed, std::vector<const Scan*> timed,
                       bool bonxai, iwlomap::RayModel rays) {
  Workload w;
  w.name = std::move(name);
  w.points = static_cast<std::size_t>(timed.front()->points.rows());
  w.iw = [=](MapSize* out) {
    return run_scans([rays] { return make_iwlomap(kResolution, rays); }, iw_insert,
                                                  [](const iwlomap::ProbabilityUpdater& m) { return iw_size(m); },
                                                  untimed, timed, out);
  };
#ifdef IWLOMAP_BENCH_WITH_BONXAI
  if (bonxai)
    w.bx = [=](MapSize* out) {
      return run_scans(
          [] { return std::make_unique<Bonxai::ProbabilisticMap>(kResolution); }, bx_insert,
          [](Bonxai::ProbabilisticMap& m) { return bx_size(m); }, untimed, timed, out);
    };
#else
  (void)bonxai;
#endif
  return w;
}

// ---- measuring ---------------------------------------------------------------------------------

struct Result {
  std::string name;
  std::size_t points = 0;
  std::vector<double> iw_ms, bx_ms, iw_cpu, bx_cpu;
  MapSize iw_map, bx_map;
  bool has_bx = false;
  [[nodiscard]] double ratio() const { return median(bx_ms) / median(iw_ms); }
  [[nodiscard]] double cpu_ratio() const { return median(bx_cpu) / median(iw_cpu); }
};

Result measure(const Workload& w, int reps) {
  Result r;
  r.name = w.name;
  r.points = w.points;
  r.has_bx = static_cast<bool>(w.bx);
  (void)w.iw(&r.iw_map);  // warm-up, and the map's size
  if (r.has_bx) (void)w.bx(&r.bx_map);
  for (int i = 0; i < reps; ++i) {
    Sample a, b;
    if (i % 2 == 0 || !r.has_bx) {
      a = w.iw(nullptr);
      if (r.has_bx) b = w.bx(nullptr);
    } else {
      b = w.bx(nullptr);
      a = w.iw(nullptr);
    }
    r.iw_ms.push_back(a.wall_ms);
    r.iw_cpu.push_back(a.cpu_ms);
    if (r.has_bx) {
      r.bx_ms.push_back(b.wall_ms);
      r.bx_cpu.push_back(b.cpu_ms);
      std::printf("    %-34s round %d: iwlomap %8.2f ms (cpu %8.2f)   Bonxai %8.2f ms (cpu %8.2f)\n", w.name.c_str(),
                  i + 1, a.wall_ms, a.cpu_ms, b.wall_ms, b.cpu_ms);
    } else {
      std::printf("    %-34s round %d: iwlomap %8.2f ms (cpu %8.2f)\n", w.name.c_str(), i + 1, a.wall_ms, a.cpu_ms);
    }
    std::fflush(stdout);
  }
  return r;
}

// One run of \p run in a child process forked for it: the time of its timed scans and the
// resident-set growth (MiB) from its start to the moment its map is built. The child has built
// no map before, so the parent's heap and memory cached from maps destroyed earlier neither
// flatter nor burden either library: a user's single run.
struct ChildRun {
  Sample time{-1.0, -1.0};
  double rss_mib = -1.0;
};

ChildRun run_in_child(const std::function<Sample(MapSize*)>& run) {
  ChildRun r;
  int fds[2];
  if (pipe(fds) != 0) return r;
  const pid_t pid = fork();
  if (pid < 0) {
    close(fds[0]);
    close(fds[1]);
    return r;
  }
  if (pid == 0) {
    close(fds[0]);
    const long before = rss_kib();
    MapSize z;
    ChildRun c;
    c.time = run(&z);
    c.rss_mib = static_cast<double>(z.rss_kib - before) / 1024.0;
    const ssize_t n = write(fds[1], &c, sizeof c);
    _exit(n == static_cast<ssize_t>(sizeof c) ? 0 : 1);
  }
  close(fds[1]);
  if (read(fds[0], &r, sizeof r) != static_cast<ssize_t>(sizeof r)) r = ChildRun{};
  close(fds[0]);
  int status = 0;
  waitpid(pid, &status, 0);
  return r;
}

// ---- scattered points --------------------------------------------------------------------------

struct Scattered {
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
  std::vector<bool> occupied;
  std::vector<octomap::point3d> om;
};

Scattered make_scattered(long n) {
  Scattered s;
  std::mt19937_64 rng(27);
  std::uniform_real_distribution<double> xy(-10.0, 10.0), z(-2.5, 2.5);
  s.points.resize(n, 3);
  for (long i = 0; i < n; ++i) s.points.row(i) << xy(rng), xy(rng), z(rng);
  s.intensities = Eigen::VectorXd::Constant(n, 200.0);
  s.occupied.assign(static_cast<std::size_t>(n), true);
  for (long i = 0; i < n; ++i)
    s.om.emplace_back(static_cast<float>(s.points(i, 0)), static_cast<float>(s.points(i, 1)),
                      static_cast<float>(s.points(i, 2)));
  return s;
}

// (empty map, again) for one library.
using Pair = std::pair<Sample, Sample>;

Pair scattered_iw(const Scattered& s) {
  iwlomap::bench::settle_heap();
  auto m = make_iwlomap(kScatteredResolution);
  const Stamp t0 = now();
  m->batch_update_iwlo(s.points, s.intensities, s.occupied);
  const Stamp t1 = now();
  m->batch_update_iwlo(s.points, s.intensities, s.occupied);
  return {elapsed(t0, t1), elapsed(t1, now())};
}

Pair scattered_om(const Scattered& s) {
  iwlomap::bench::settle_heap();
  octomap::OcTree m(kScatteredResolution);
  const Stamp t0 = now();
  for (const auto& p : s.om) m.updateNode(p, kOctomapHitLogOdds, false);
  const Stamp t1 = now();
  for (const auto& p : s.om) m.updateNode(p, kOctomapHitLogOdds, false);
  return {elapsed(t0, t1), elapsed(t1, now())};
}

#ifdef IWLOMAP_BENCH_WITH_BONXAI
Pair scattered_bx(const Scattered& s) {
  iwlomap::bench::settle_heap();
  Bonxai::ProbabilisticMap m(kScatteredResolution);
  const auto opt = m.options();
  auto pass = [&] {
    auto acc = m.grid().createAccessor();
    for (Eigen::Index i = 0; i < s.points.rows(); ++i) {
      const Eigen::Vector3d p = s.points.row(i).transpose();
      auto* cell = acc.value(m.grid().posToCoord(p), true);
      cell->probability_log = std::min(cell->probability_log + opt.prob_hit_log, opt.clamp_max_log);
    }
  };
  const Stamp t0 = now();
  pass();
  const Stamp t1 = now();
  pass();
  return {elapsed(t0, t1), elapsed(t1, now())};
}
#endif

void measure_scattered(const Options& o) {
  const Scattered s = make_scattered(o.scattered);
  std::printf("\nscattered points: %ld uniform in a 20 x 20 x 5 m box, %.2f m, one occupied update each\n", o.scattered,
              kScatteredResolution);
  std::vector<double> iw[2], om[2], bx[2];
  auto add = [](std::vector<double>* v, const Pair& p) {
    v[0].push_back(p.first.cpu_ms);
    v[1].push_back(p.second.cpu_ms);
  };
  // A peer's call: OctoMap or, when built, Bonxai.
  const auto peer = [&](bool octomap) {
    if (octomap) {
      add(om, scattered_om(s));
      return;
    }
#ifdef IWLOMAP_BENCH_WITH_BONXAI
    add(bx, scattered_bx(s));
#endif
  };
  // One untimed warm-up call of each library.
  (void)scattered_iw(s);
  (void)scattered_om(s);
#ifdef IWLOMAP_BENCH_WITH_BONXAI
  (void)scattered_bx(s);
#endif
  for (int i = 0; i < o.reps; ++i) {
    // iwlomap between the two peers, and which peer goes first alternates.
    peer(i % 2 == 0);
    add(iw, scattered_iw(s));
    peer(i % 2 != 0);
    std::printf("    round %d: iwlomap %8.2f / %8.2f ms   OctoMap %8.2f / %8.2f ms", i + 1, iw[0].back(), iw[1].back(),
                om[0].back(), om[1].back());
    if (kWithBonxai) std::printf("   Bonxai %8.2f / %8.2f ms", bx[0].back(), bx[1].back());
    std::printf("  (empty / again, cpu)\n");
    std::fflush(stdout);
  }
  std::printf("  %-10s %12s %12s %12s %14s %14s\n", "", "iwlomap ms", "OctoMap ms", "Bonxai ms", "OctoMap / iw",
              "Bonxai / iw");
  const char* names[2] = {"empty map", "again"};
  for (int k = 0; k < 2; ++k) {
    const double a = median(iw[k]), b = median(om[k]);
    std::printf("  %-10s %12.2f %12.2f", names[k], a, b);
    if (kWithBonxai)
      std::printf(" %12.2f %13.1fx %13.1fx\n", median(bx[k]), b / a, median(bx[k]) / a);
    else
      std::printf(" %12s %13.1fx %14s\n", "-", b / a, "-");
  }
  std::printf("  scattered points vs OctoMap updateNode, empty map: %.1fx (target >= 20x: %s)\n",
              median(om[0]) / median(iw[0]), median(om[0]) / median(iw[0]) >= 20.0 ? "met" : "NOT met");
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  try {
    o = parse_options(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_peers: %s\n", e.what());
    return 2;
  }
  const bool fast = o.rays == iwlomap::RayModel::kFast;
  const double target = fast ? kFastTarget : kTarget;
  std::printf("bench_peers: iwlomap scan insertion against Bonxai, single thread, %.2f m, %s rays\n", kResolution,
              fast ? "fast (26-connected)" : "exact");
  iwlomap::bench::print_build();
  if (!kWithBonxai)
    std::printf("  Bonxai rows SKIPPED: configure with -DIWLOMAP_BONXAI_DIR=<Bonxai source folder> to build them\n");
  std::printf("  %d timed round(s) per workload after one warm-up, medians; ratio = Bonxai time / iwlomap time\n",
              o.reps);
  // Children forked later have built no map, so the cache this may keep is empty for them: they
  // run with the library's defaults either way.
  if (o.retain_memory)
    iwlomap::bench::retain_map_memory();
  else
    std::printf("  library defaults: no memory kept from destroyed maps (--retain-memory keeps 64 MiB)\n");
  try {
    if (o.only == "scattered") {
      if (o.scattered == 0) throw std::invalid_argument("--only scattered with --scattered 0 runs nothing");
      measure_scattered(o);
      return 0;
    }
    const std::string dir = o.data_dir + "/ouster_os1_128_3frames/";
    std::vector<Scan> frames;
    for (int k = 0; k < 3; ++k)
      frames.push_back(load_frame(dir + "frame_00" + std::to_string(k) + "_world.pcd", kOusterMaxRange));
    const Scan other = load_frame(o.data_dir + "/octomap_scan/octomap_scan_sensor.pcd", -1.0);
    const iwlomap::SyntheticScan syn = iwlomap::make_synthetic_scan();
    const Scan synthetic = make_scan(syn.origin, syn.points, syn.intensities, -1.0);
    std::vector<Scan> growing;
    for (int k = 0; k < kGrowingFrames; ++k)
      growing.push_back(shifted(frames[static_cast<std::size_t>(k % 3)], Eigen::Vector3d(kGrowingStep * k, 0, 0)));
    std::printf("  input: synthetic scan %lld points (no range limit); Ouster frames %lld/%lld/%lld points, %.0f m "
                "range; octomap_scan %lld points (no range limit)\n\n",
                static_cast<long long>(synthetic.points.rows()), static_cast<long long>(frames[0].points.rows()),
                static_cast<long long>(frames[1].points.rows()), static_cast<long long>(frames[2].points.rows()),
                kOusterMaxRange, static_cast<long long>(other.points.rows()));

    const std::vector<const Scan*> seq = {&frames[0], &frames[1], &frames[2]};
    std::vector<const Scan*> grow;
    for (const Scan& s : growing) grow.push_back(&s);
    std::vector<Workload> workloads = {
        scan_workload("synthetic, fresh", {}, {&synthetic}, true, o.rays),
        scan_workload("synthetic, again", {&synthetic}, {&synthetic}, true, o.rays),
        scan_workload("Ouster frame 0, fresh", {}, {&frames[0]}, true, o.rays),
        scan_workload("Ouster frame 0, again", {&frames[0]}, {&frames[0]}, true, o.rays),
        scan_workload("octomap_scan, fresh", {}, {&other}, true, o.rays),
        scan_workload("octomap_scan, again", {&other}, {&other}, true, o.rays),
        scan_workload("Ouster sequence, per scan", {}, seq, true, o.rays),
        scan_workload("Ouster sequence, second pass", seq, seq, false, o.rays),
        scan_workload("growing, 16 frames, per frame", {}, grow, true, o.rays),
    };

    if (!o.only.empty()) {
      workloads.erase(std::remove_if(workloads.begin(), workloads.end(),
                                     [&](const Workload& w) { return w.name.find(o.only) == std::string::npos; }),
                      workloads.end());
      if (workloads.empty()) throw std::invalid_argument("--only '" + o.only + "' matches no workload");
    }
    // Child processes first, before this process has built and freed any map: the resident
    // memory of each workload, and the fresh workloads' times, each library alone.
    std::vector<std::pair<double, double>> rss(workloads.size(), {-1.0, -1.0});
    std::vector<std::pair<std::vector<double>, std::vector<double>>> alone(workloads.size());
    for (std::size_t i = 0; i < workloads.size(); ++i) {
      const bool fresh = workloads[i].name.find("fresh") != std::string::npos;
      for (int k = 0; k < (fresh ? o.reps : 1); ++k) {
        const bool bx_first = k % 2 == 1 && workloads[i].bx;
        ChildRun b;
        if (bx_first) b = run_in_child(workloads[i].bx);
        const ChildRun a = run_in_child(workloads[i].iw);
        if (workloads[i].bx && !bx_first) b = run_in_child(workloads[i].bx);
        if (k == 0) rss[i] = {a.rss_mib, b.rss_mib};
        if (fresh) {  // a child that failed (no time) is left out
          if (a.time.wall_ms >= 0.0) alone[i].first.push_back(a.time.wall_ms);
          if (workloads[i].bx && b.time.wall_ms >= 0.0) alone[i].second.push_back(b.time.wall_ms);
        }
      }
    }

    std::vector<Result> results;
    for (const Workload& w : workloads) results.push_back(measure(w, o.reps));

    const std::string rule(118, '-');
    std::printf("\nscan workloads, median per scan (wall clock; thread CPU time in brackets)\n");
    std::printf("%-32s %7s %19s %19s %14s\n", "workload", "points", "iwlomap ms", "Bonxai ms", "Bonxai / iw");
    std::printf("%s\n", rule.c_str());
    bool all_met = kWithBonxai;
    for (const Result& r : results) {
      char iw[40], bx[40] = "-", ratio[40] = "-";
      std::snprintf(iw, sizeof iw, "%8.2f (%8.2f)", median(r.iw_ms), median(r.iw_cpu));
      if (r.has_bx) {
        std::snprintf(bx, sizeof bx, "%8.2f (%8.2f)", median(r.bx_ms), median(r.bx_cpu));
        std::snprintf(ratio, sizeof ratio, "%5.2fx (%5.2fx)", r.ratio(), r.cpu_ratio());
        all_met = all_met && r.ratio() >= target;
      }
      std::printf("%-32s %7zu %19s %19s %14s\n", r.name.c_str(), r.points, iw, bx, ratio);
    }
    std::printf("%s\n", rule.c_str());
    std::printf("\nfresh workloads, each library alone in a fresh process (a child forked before any map is built), "
                "median of %d\n", o.reps);
    std::printf("%-32s %19s %19s %14s\n", "workload", "iwlomap ms", "Bonxai ms", "Bonxai / iw");
    for (std::size_t i = 0; i < results.size(); ++i) {
      if (alone[i].first.empty()) continue;
      char bx[40] = "-", ratio[40] = "-";
      if (!alone[i].second.empty()) {
        std::snprintf(bx, sizeof bx, "%8.2f", median(alone[i].second));
        const double r = median(alone[i].second) / median(alone[i].first);
        std::snprintf(ratio, sizeof ratio, "%5.2fx", r);
        all_met = all_met && r >= target;
      }
      std::printf("%-32s %19.2f %19s %14s\n", results[i].name.c_str(), median(alone[i].first), bx, ratio);
    }
    std::printf("%s\n", rule.c_str());
    std::printf("\nmaps after each workload: the library's own figure (MiB), resident growth of a child process "
                "building it (MiB), voxels known / occupied\n");
    std::printf("%-32s %10s %10s %10s %10s %21s %21s\n", "workload", "iw MiB", "Bx MiB", "iw RSS", "Bx RSS",
                "iwlomap voxels", "Bonxai voxels");
    for (std::size_t i = 0; i < results.size(); ++i) {
      const Result& r = results[i];
      char bx[24] = "-", bxr[24] = "-", bxv[40] = "-";
      if (r.has_bx) {
        std::snprintf(bx, sizeof bx, "%.1f", r.bx_map.api_mib);
        std::snprintf(bxr, sizeof bxr, "%.1f", rss[i].second);
        std::snprintf(bxv, sizeof bxv, "%zu / %zu", r.bx_map.known, r.bx_map.occupied);
      }
      char iwv[40];
      std::snprintf(iwv, sizeof iwv, "%zu / %zu", r.iw_map.known, r.iw_map.occupied);
      std::printf("%-32s %10.1f %10s %10.1f %10s %21s %21s\n", r.name.c_str(), r.iw_map.api_mib, bx, rss[i].first, bxr,
                  iwv, bxv);
    }
    if (kWithBonxai)
      std::printf("\ntarget: Bonxai / iwlomap >= %.1fx on every scan workload, in one process and in fresh processes "
                  "(wall clock): %s\n", target,
                  all_met ? "met" : "NOT met");
    if (o.scattered > 0) measure_scattered(o);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_peers: %s\n", e.what());
    return 1;
  }
  return 0;
}
