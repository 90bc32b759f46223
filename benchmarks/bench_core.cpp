// SPDX-License-Identifier: BSD-3-Clause
//
// bench_core: the core engine (RAM backend, iwlomap::ProbabilityUpdater) against OctoMap's
// OcTree, measured side by side in one run, single thread, on the same input.
//
//   (a) batch_update_iwlo  vs  OcTree::updateNode(point, 0.85f, lazy_eval=false) per point, into an
//                              empty map and again into the map that now holds those voxels; and
//                              into new space of a growing map (16 batches moved 60 m apart)
//   (b) insert_scan        vs  OcTree::insertPointCloud(cloud, origin, maxrange, lazy_eval=false,
//                              discretize=false), synthetic 64 x 1024 scan, into an empty map
//                              (first scan) and into a map that already holds the scan (steady state)
//   (c) the same as (b) on a recorded Ouster OS-1-128 frame, max range 25 m, when the data exists
//
// Repetitions alternate iwlomap and OctoMap (and swap which goes first every repetition) so both
// share the machine's noise; the tables report medians of wall-clock and of thread CPU time, after
// one untimed warm-up round. Each repetition starts from freshly built maps; building and
// destroying maps and converting the input to each library's own types are not timed. The
// program ends with a voxel-by-voxel comparison of the two maps, so a speedup never comes from
// doing less work. See docs/benchmarks.md for the figures and how to read them.
//
// Usage: bench_core [--reps N] [--batch-reps N] [--resolution R] [--data DIR] [--quick]

#include "bench_pcd.h"
#include "bench_util.h"
#include "iwlomap/iwlo.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"
#include "iwlomap/voxel_key.h"

#include <octomap/OcTree.h>
#include <octomap/octomap.h>

#include <Eigen/Core>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <ctime>
#include <fstream>
#include <functional>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#ifndef IWLOMAP_BENCH_DATA_DIR
#define IWLOMAP_BENCH_DATA_DIR "../shared/data"
#endif
#ifndef IWLOMAP_BENCH_OCTOMAP_VERSION
#define IWLOMAP_BENCH_OCTOMAP_VERSION "unknown"
#endif

namespace {

using iwlomap::bench::median;

// OctoMap's default hit probability is 0.7, i.e. log-odds ln(0.7 / 0.3) = 0.847; 0.85 is that
// increment, so updateNode() does the work of one occupied observation per point, as
// batch_update_iwlo() does.
constexpr float kOctomapHitLogOdds = 0.85f;
constexpr double kOusterMaxRange = 25.0;
constexpr double kTargetBatchSpeedup = 20.0;
constexpr double kTargetScanSpeedup = 25.0;
const char* const kOusterFrame = "ouster_os1_128_3frames/frame_000_world.pcd";

struct Options {
  int reps = 5;  // of each scan measurement, and rounds of the growing map
  // A batch takes 1-20 ms a side against seconds for a scan, so (a) affords more repetitions:
  // its median then moves less with the machine's noise, which for a 1 ms call is large.
  int batch_reps = 25;
  double resolution = 0.1;
  std::string data_dir = IWLOMAP_BENCH_DATA_DIR;
  bool quick = false;
};

void print_usage(const char* argv0) {
  std::printf(
      "Usage: %s [--reps N] [--batch-reps N] [--resolution R] [--data DIR] [--quick]\n"
      "  --reps N        timed repetitions per scan measurement, (b) and (c), and rounds of the\n"
      "                  growing-map batches of (a) (default 5; the median is reported)\n"
      "  --batch-reps N  timed repetitions of the batch into an empty map and again, (a) (default 25)\n"
      "  --resolution R  voxel edge in metres for both libraries (default 0.1)\n"
      "  --data DIR      folder holding %s (default %s)\n"
      "  --quick         2 repetitions, 5 of the batch (a smoke run; figures are noisier)\n",
      argv0, kOusterFrame, IWLOMAP_BENCH_DATA_DIR);
}

Options parse_options(int argc, char** argv) {
  Options o;
  bool reps_given = false;
  bool batch_reps_given = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    auto value = [&](const char* name) -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(std::string(name) + " needs a value");
      return argv[++i];
    };
    const auto count = [&](const char* name) {
      const std::string v = value(name);
      char* end = nullptr;
      const long n = std::strtol(v.c_str(), &end, 10);
      if (end == v.c_str() || *end != '\0' || n < 1 || n > 1000)
        throw std::invalid_argument(std::string(name) + " must be an integer in [1, 1000], got '" + v + "'");
      return static_cast<int>(n);
    };
    if (a == "--reps") {
      o.reps = count("--reps");
      reps_given = true;
    } else if (a == "--batch-reps") {
      o.batch_reps = count("--batch-reps");
      batch_reps_given = true;
    } else if (a == "--resolution") {
      const std::string v = value("--resolution");
      char* end = nullptr;
      const double r = std::strtod(v.c_str(), &end);
      if (end == v.c_str() || *end != '\0' || !std::isfinite(r) || r <= 0.0)
        throw std::invalid_argument("--resolution must be a positive number of metres, got '" + v + "'");
      o.resolution = r;
    } else if (a == "--data") {
      o.data_dir = value("--data");
    } else if (a == "--quick") {
      o.quick = true;
    } else if (a == "--help" || a == "-h") {
      print_usage(argv[0]);
      std::exit(0);
    } else {
      throw std::invalid_argument("unknown argument '" + a + "' (see --help)");
    }
  }
  if (o.quick && !reps_given) o.reps = 2;
  if (o.quick && !batch_reps_given) o.batch_reps = 5;
  return o;
}

using iwlomap::bench::elapsed;
using iwlomap::bench::now;
using iwlomap::bench::Sample;
using iwlomap::bench::Stamp;

// (into an empty map, again into the map that now holds the same input)
using TimePair = std::pair<Sample, Sample>;

struct Row {
  std::string name;
  std::size_t points = 0;
  std::vector<double> iw_ms, om_ms;          // wall clock
  std::vector<double> iw_cpu_ms, om_cpu_ms;  // thread CPU time
  std::vector<bool> iw_after_om;             // iwlomap's call came right after an OctoMap call
  [[nodiscard]] double iw() const { return median(iw_ms); }
  [[nodiscard]] double om() const { return median(om_ms); }
  [[nodiscard]] double speedup() const { return om() / iw(); }
  [[nodiscard]] double iw_cpu() const { return median(iw_cpu_ms); }
  [[nodiscard]] double om_cpu() const { return median(om_cpu_ms); }
  [[nodiscard]] double cpu_speedup() const { return om_cpu() / iw_cpu(); }
};

// ---- input -------------------------------------------------------------------------------------

// One scan in both libraries' native types, converted once, outside the timed regions.
struct ScanInput {
  std::string name;
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::MatrixXd points;  // N x 3
  Eigen::VectorXd intensities;
  double max_range = -1.0;
  octomap::Pointcloud cloud;
  octomap::point3d om_origin;
  std::vector<octomap::point3d> om_points;
  std::vector<bool> occupied_flags;  // all true: every point is a hit
};

ScanInput make_input(std::string name, const Eigen::Vector3d& origin, Eigen::MatrixXd points,
                     Eigen::VectorXd intensities, double max_range) {
  ScanInput in;
  in.name = std::move(name);
  in.origin = origin;
  in.points = std::move(points);
  in.intensities = std::move(intensities);
  in.max_range = max_range;
  const Eigen::Index n = in.points.rows();
  in.cloud.reserve(static_cast<std::size_t>(n));
  in.om_points.reserve(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) {
    const octomap::point3d p(static_cast<float>(in.points(i, 0)), static_cast<float>(in.points(i, 1)),
                             static_cast<float>(in.points(i, 2)));
    in.cloud.push_back(p);
    in.om_points.push_back(p);
  }
  in.om_origin = octomap::point3d(static_cast<float>(origin.x()), static_cast<float>(origin.y()),
                                  static_cast<float>(origin.z()));
  in.occupied_flags.assign(static_cast<std::size_t>(n), true);
  return in;
}

// ---- the two engines ---------------------------------------------------------------------------

// Lidar semantics (iwlo.h, IwloParams::intensity_threshold): threshold 0, so every return is a hit whose
// intensity only weights it, as every point is a hit in OctoMap. Everything else is the default.
// One thread, explicitly: the comparison is single thread against single thread (OctoMap as Debian
// ships it is built without OpenMP).
iwlomap::ProbabilityUpdater make_iwlomap(double resolution) {
  iwlomap::ProbabilityUpdater m(resolution);
  iwlomap::IwloParams p;
  p.intensity_threshold = 0.0;
  m.set_params(p);
  m.set_num_threads(1);
  return m;
}

// OctoMap with its own defaults (hit 0.7, miss 0.4, clamping 0.1192 / 0.971).
struct OctoMapTree {
  octomap::OcTree tree;
  explicit OctoMapTree(double resolution) : tree(resolution) {}
};

// Times the batch into an empty map and the same batch again into the map that now holds its
// voxels (no allocation left to do: the update itself).
TimePair time_iw_batch(double res, const ScanInput& in) {
  auto m = make_iwlomap(res);
  const Stamp t0 = now();
  m.batch_update_iwlo(in.points, in.intensities, in.occupied_flags);
  const Stamp t1 = now();
  m.batch_update_iwlo(in.points, in.intensities, in.occupied_flags);
  const Stamp t2 = now();
  return {elapsed(t0, t1), elapsed(t1, t2)};
}

TimePair time_om_batch(double res, const ScanInput& in) {
  OctoMapTree m(res);
  const Stamp t0 = now();
  for (const auto& p : in.om_points) m.tree.updateNode(p, kOctomapHitLogOdds, false);
  const Stamp t1 = now();
  for (const auto& p : in.om_points) m.tree.updateNode(p, kOctomapHitLogOdds, false);
  const Stamp t2 = now();
  return {elapsed(t0, t1), elapsed(t1, t2)};
}

// Times the first scan into an empty map and the same scan again into the map that now holds it.
TimePair time_iw_scan(double res, const ScanInput& in) {
  auto m = make_iwlomap(res);
  const Stamp t0 = now();
  m.insert_scan(in.origin, in.points, in.intensities, in.max_range);
  const Stamp t1 = now();
  m.insert_scan(in.origin, in.points, in.intensities, in.max_range);
  const Stamp t2 = now();
  return {elapsed(t0, t1), elapsed(t1, t2)};
}

TimePair time_om_scan(double res, const ScanInput& in) {
  OctoMapTree m(res);
  const Stamp t0 = now();
  m.tree.insertPointCloud(in.cloud, in.om_origin, in.max_range, false, false);
  const Stamp t1 = now();
  m.tree.insertPointCloud(in.cloud, in.om_origin, in.max_range, false, false);
  const Stamp t2 = now();
  return {elapsed(t0, t1), elapsed(t1, t2)};
}

// ---- sanity: compare the two maps voxel by voxel -------------------------------------------------

struct Agreement {
  std::size_t iw_known = 0, iw_occupied = 0;
  std::size_t om_known = 0, om_occupied = 0;  // finest-resolution voxels (pruned leaves expanded)
  std::size_t om_leaves = 0, om_nodes = 0;
  std::size_t both_known = 0, both_occupied = 0;
  double iw_mb = 0.0, om_mb = 0.0;
};

Agreement compare_maps(const iwlomap::ProbabilityUpdater& iw, const octomap::OcTree& om) {
  Agreement a;
  const unsigned max_depth = om.getTreeDepth();
  for (auto it = om.begin_leafs(), end = om.end_leafs(); it != end; ++it) {
    const unsigned shift = max_depth - it.getDepth();
    const std::size_t voxels = std::size_t{1} << (3 * shift);
    ++a.om_leaves;
    a.om_known += voxels;
    if (om.isNodeOccupied(*it)) a.om_occupied += voxels;
  }
  a.om_nodes = om.size();
  a.om_mb = static_cast<double>(om.memoryUsage()) / (1024.0 * 1024.0);
  a.iw_mb = iw.get_memory_usage().memory_mb;

  // OctoMap keys are floor(coordinate / resolution) + 32768, the same grid as iwlomap's keys, so
  // voxels are matched by key, with no coordinate round trip.
  // The key of the voxel [0, r) is the offset (tree_max_val is not public).
  const int offset = static_cast<int>(om.coordToKey(0.5 * om.getResolution()));
  iw.for_each_voxel([&](const iwlomap::VoxelKey& k, const iwlomap::VoxelState& s) {
    ++a.iw_known;
    const bool iw_occ = s.probability > 0.5;
    if (iw_occ) ++a.iw_occupied;
    const int x = k.x + offset, y = k.y + offset, z = k.z + offset;
    if (x < 0 || y < 0 || z < 0 || x > 0xFFFF || y > 0xFFFF || z > 0xFFFF) return;
    const octomap::OcTreeKey key(static_cast<octomap::key_type>(x), static_cast<octomap::key_type>(y),
                                 static_cast<octomap::key_type>(z));
    const octomap::OcTreeNode* node = om.search(key);
    if (node == nullptr) return;
    ++a.both_known;
    if (iw_occ && om.isNodeOccupied(node)) ++a.both_occupied;
  });
  return a;
}

double jaccard(std::size_t a, std::size_t b, std::size_t both) {
  const double uni = static_cast<double>(a) + static_cast<double>(b) - static_cast<double>(both);
  return uni > 0.0 ? static_cast<double>(both) / uni : 1.0;
}

void print_agreement(const std::string& title, const Agreement& a) {
  std::printf("  %s\n", title.c_str());
  std::printf("    %-26s %14s %14s %10s %12s\n", "", "iwlomap", "OctoMap", "ratio", "same voxels");
  std::printf("    %-26s %14zu %14zu %10.4f %11.3f%%\n", "known voxels", a.iw_known, a.om_known,
              static_cast<double>(a.iw_known) / static_cast<double>(std::max<std::size_t>(a.om_known, 1)),
              100.0 * jaccard(a.iw_known, a.om_known, a.both_known));
  std::printf("    %-26s %14zu %14zu %10.4f %11.3f%%\n", "occupied voxels (p > 0.5)", a.iw_occupied,
              a.om_occupied,
              static_cast<double>(a.iw_occupied) / static_cast<double>(std::max<std::size_t>(a.om_occupied, 1)),
              100.0 * jaccard(a.iw_occupied, a.om_occupied, a.both_occupied));
  std::printf("    %-26s %14.1f %14.1f %10.4f\n", "memory (MiB)", a.iw_mb, a.om_mb, a.iw_mb / a.om_mb);
  std::printf("    (OctoMap: %zu octree nodes, %zu leaves; 'same voxels' = |both| / |either|)\n", a.om_nodes,
              a.om_leaves);
}

// ---- the measurements ---------------------------------------------------------------------------

void progress(const Row& r, std::size_t i) {
  std::printf("    %-40s rep %zu: iwlomap %9.2f ms (cpu %9.2f)   OctoMap %9.2f ms (cpu %9.2f)\n", r.name.c_str(),
              i + 1, r.iw_ms[i], r.iw_cpu_ms[i], r.om_ms[i], r.om_cpu_ms[i]);
  std::fflush(stdout);
}

// Runs one untimed warm-up round (first-touch page faults, caches), then \p reps timed rounds that
// alternate which library goes first.
std::pair<Row, Row> measure(const Options& o, int reps, const ScanInput& in, const std::string& first_name,
                            const std::string& steady_name,
                            const std::function<TimePair(double, const ScanInput&)>& iw_fn,
                            const std::function<TimePair(double, const ScanInput&)>& om_fn) {
  Row first, steady;
  first.name = first_name;
  steady.name = steady_name;
  first.points = steady.points = static_cast<std::size_t>(in.points.rows());
  // Each call starts from a settled heap: the octree freed by the previous call must not make
  // the next call's first large allocation pay for merging its chunks (see settle_heap()).
  const auto iw_call = [&] {
    iwlomap::bench::settle_heap();
    return iw_fn(o.resolution, in);
  };
  const auto om_call = [&] {
    iwlomap::bench::settle_heap();
    return om_fn(o.resolution, in);
  };
  (void)iw_call();
  (void)om_call();
  for (int i = 0; i < reps; ++i) {
    TimePair iw, om;
    if (i % 2 == 0) {
      iw = iw_call();
      om = om_call();
    } else {
      om = om_call();
      iw = iw_call();
    }
    for (auto [row, iw_s, om_s] : {std::tuple<Row*, Sample, Sample>{&first, iw.first, om.first},
                                   std::tuple<Row*, Sample, Sample>{&steady, iw.second, om.second}}) {
      row->iw_ms.push_back(iw_s.wall_ms);
      row->om_ms.push_back(om_s.wall_ms);
      row->iw_cpu_ms.push_back(iw_s.cpu_ms);
      row->om_cpu_ms.push_back(om_s.cpu_ms);
      row->iw_after_om.push_back(i % 2 == 1 || i == 0);  // round 0 follows the warm-up's OctoMap call
    }
    progress(first, static_cast<std::size_t>(i));
    progress(steady, static_cast<std::size_t>(i));
  }
  return {first, steady};
}

// A long-lived map growing into new space, as a survey's map does: each library fills one map with
// kGrowingBatches batches, batch k being the input moved 60 m * (k + 1) along x (the synthetic
// scene spans about +-26 m), so every batch lands in space the map has not seen. Unlike the empty
// map of measure_batch(), whose memory is the recycled memory of the map before, the map grows here:
// new blocks go into an ever larger block index, and once the slabs cached from destroyed maps are
// used up, new cells come from memory the kernel hands out page by page. Every batch is one
// sample; rounds alternate which library goes first.
constexpr int kGrowingBatches = 16;

Row measure_growing(const Options& o, int rounds, const ScanInput& in) {
  Row row;
  row.name = "growing map, batch into new space";
  row.points = static_cast<std::size_t>(in.points.rows());
  std::vector<ScanInput> shifted;  // both libraries' copies of each batch, converted once
  for (int k = 0; k < kGrowingBatches; ++k) {
    const Eigen::Vector3d shift(60.0 * (k + 1), 0.0, 0.0);
    shifted.push_back(make_input(in.name, in.origin + shift, in.points.rowwise() + shift.transpose(), in.intensities,
                                 in.max_range));
  }
  const auto iw_round = [&] {
    iwlomap::bench::settle_heap();
    auto m = make_iwlomap(o.resolution);
    for (const ScanInput& q : shifted) {
      const Stamp t0 = now();
      m.batch_update_iwlo(q.points, q.intensities, q.occupied_flags);
      const Sample t = elapsed(t0, now());
      row.iw_ms.push_back(t.wall_ms);
      row.iw_cpu_ms.push_back(t.cpu_ms);
    }
  };
  const auto om_round = [&] {
    iwlomap::bench::settle_heap();
    OctoMapTree m(o.resolution);
    for (const ScanInput& q : shifted) {
      const Stamp t0 = now();
      for (const auto& p : q.om_points) m.tree.updateNode(p, kOctomapHitLogOdds, false);
      const Sample t = elapsed(t0, now());
      row.om_ms.push_back(t.wall_ms);
      row.om_cpu_ms.push_back(t.cpu_ms);
    }
  };
  for (int r = 0; r < rounds; ++r) {
    if (r % 2 == 0) {
      iw_round();
      om_round();
    } else {
      om_round();
      iw_round();
    }
    std::printf("    %-40s round %d: iwlomap %9.2f ms (median of the round's %d batches)   OctoMap %9.2f ms\n",
                row.name.c_str(), r + 1,
                median({row.iw_ms.end() - kGrowingBatches, row.iw_ms.end()}), kGrowingBatches,
                median({row.om_ms.end() - kGrowingBatches, row.om_ms.end()}));
    std::fflush(stdout);
  }
  return row;  // iw_after_om stays empty: within a round nearly every call follows the library's own
}

std::pair<Row, Row> measure_batch(const Options& o, const ScanInput& in) {
  return measure(o, o.batch_reps, in, "batch_update_iwlo / updateNode, empty", "batch_update_iwlo / updateNode, again",
                 time_iw_batch, time_om_batch);
}

std::pair<Row, Row> measure_scan(const Options& o, const ScanInput& in) {
  return measure(o, o.reps, in, in.name + ", first scan", in.name + ", steady state", time_iw_scan, time_om_scan);
}

Agreement scan_agreement(const Options& o, const ScanInput& in) {
  auto iw = make_iwlomap(o.resolution);
  iw.insert_scan(in.origin, in.points, in.intensities, in.max_range);
  OctoMapTree om(o.resolution);
  om.tree.insertPointCloud(in.cloud, in.om_origin, in.max_range, false, false);
  return compare_maps(iw, om.tree);
}

Agreement batch_agreement(const Options& o, const ScanInput& in) {
  auto iw = make_iwlomap(o.resolution);
  iw.batch_update_iwlo(in.points, in.intensities, in.occupied_flags);
  OctoMapTree om(o.resolution);
  for (const auto& p : in.om_points) om.tree.updateNode(p, kOctomapHitLogOdds, false);
  return compare_maps(iw, om.tree);
}

std::string spread(const std::vector<double>& v) {
  const auto [lo, hi] = std::minmax_element(v.begin(), v.end());
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.1f-%.1f", *lo, *hi);
  return buf;
}

void print_table(const std::vector<Row>& rows) {
  const std::string rule(117, '-');
  std::printf("\nwall clock, median of the repetitions\n");
  std::printf("%-40s %8s %11s %11s %14s %14s %9s\n", "comparison", "points", "iwlomap ms", "OctoMap ms",
              "iwlomap Mpt/s", "OctoMap Mpt/s", "speedup");
  std::printf("%s\n", rule.c_str());
  for (const Row& r : rows) {
    const double pts = static_cast<double>(r.points);
    std::printf("%-40s %8zu %11.2f %11.2f %14.3f %14.3f %8.1fx\n", r.name.c_str(), r.points, r.iw(), r.om(),
                pts / (r.iw() * 1e3), pts / (r.om() * 1e3), r.speedup());
  }
  std::printf("%s\n", rule.c_str());
  std::printf("\nthread CPU time, median of the repetitions (less sensitive to other load on the machine)\n");
  std::printf("%-40s %8s %11s %11s %14s %14s %9s\n", "comparison", "points", "iwlomap ms", "OctoMap ms",
              "iwlomap Mpt/s", "OctoMap Mpt/s", "speedup");
  std::printf("%s\n", rule.c_str());
  for (const Row& r : rows) {
    const double pts = static_cast<double>(r.points);
    std::printf("%-40s %8zu %11.2f %11.2f %14.3f %14.3f %8.1fx\n", r.name.c_str(), r.points, r.iw_cpu(),
                r.om_cpu(), pts / (r.iw_cpu() * 1e3), pts / (r.om_cpu() * 1e3), r.cpu_speedup());
  }
  std::printf("%s\n", rule.c_str());
  std::printf("spread of the repetitions, wall clock (min-max ms):\n");
  for (const Row& r : rows)
    std::printf("  %-40s iwlomap %-18s OctoMap %s\n", r.name.c_str(), spread(r.iw_ms).c_str(),
                spread(r.om_ms).c_str());
  // The rounds alternate which library goes first, so half of iwlomap's calls follow an OctoMap
  // call (whose octree churned the caches) and half follow iwlomap's own previous call; for the
  // short batch calls the two halves differ, and their medians are shown apart.
  std::printf("by what ran just before iwlomap's call, wall clock (median ms, speedup over OctoMap's median):\n");
  for (const Row& r : rows) {
    std::vector<double> after_om, after_iw;
    if (r.iw_after_om.size() != r.iw_ms.size()) continue;  // not recorded for this row
    for (std::size_t i = 0; i < r.iw_ms.size(); ++i) (r.iw_after_om[i] ? after_om : after_iw).push_back(r.iw_ms[i]);
    if (after_om.empty() || after_iw.empty()) continue;
    std::printf("  %-40s after OctoMap %8.2f ms %5.1fx (%zu)   after iwlomap %8.2f ms %5.1fx (%zu)\n", r.name.c_str(),
                median(after_om), r.om() / median(after_om), after_om.size(), median(after_iw),
                r.om() / median(after_iw), after_iw.size());
  }
}

// The machine is shared; the load average says how much else ran during the measurements.
std::string load_average() {
  std::ifstream f("/proc/loadavg");
  std::string a, b, c;
  if (!(f >> a >> b >> c)) return "n/a";
  return a + " " + b + " " + c;
}

const char* verdict(double speedup, double target) { return speedup >= target ? "met" : "NOT met"; }

}  // namespace

int main(int argc, char** argv) {
  Options o;
  try {
    o = parse_options(argc, argv);
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_core: %s\n", e.what());
    return 2;
  }

  std::printf("bench_core: iwlomap core engine (RAM backend) vs OctoMap %s\n", IWLOMAP_BENCH_OCTOMAP_VERSION);
  iwlomap::bench::retain_map_memory();
  std::printf("  resolution %.3f m, %d repetition(s) of the batch, %d of each scan measurement (median reported), "
              "single thread\n", o.resolution, o.batch_reps, o.reps);
  iwlomap::bench::print_build();
  std::printf("  iwlomap: default IwloParams with intensity_threshold 0 (lidar: every return is a hit), 1 thread\n");
  std::printf("  OctoMap: OcTree defaults (hit 0.7, miss 0.4); updateNode log-odds %+.2f per point; "
              "insertPointCloud(lazy_eval=false, discretize=false)\n",
              static_cast<double>(kOctomapHitLogOdds));
  std::printf("  one untimed warm-up round per measurement; load average at start: %s\n\n", load_average().c_str());

  std::vector<Row> rows;
  try {
    const iwlomap::SyntheticScan scan = iwlomap::make_synthetic_scan();
    const ScanInput synthetic =
        make_input("synthetic 64x1024", scan.origin, scan.points, scan.intensities, -1.0);
    std::printf("synthetic scan: %lld points, origin (%.2f, %.2f, %.2f), no max range\n",
                static_cast<long long>(synthetic.points.rows()), scan.origin.x(), scan.origin.y(), scan.origin.z());

    std::printf("\n(a) batch_update_iwlo vs OcTree::updateNode, synthetic scan points\n");
    const auto [batch, batch_again] = measure_batch(o, synthetic);
    rows.push_back(batch);
    rows.push_back(batch_again);
    const Row growing = measure_growing(o, o.reps, synthetic);
    rows.push_back(growing);

    std::printf("\n(b) insert_scan vs OcTree::insertPointCloud, synthetic scan\n");
    const auto [syn_first, syn_steady] = measure_scan(o, synthetic);
    rows.push_back(syn_first);
    rows.push_back(syn_steady);

    std::printf("\n(c) insert_scan vs OcTree::insertPointCloud, recorded Ouster OS-1-128 frame\n");
    std::optional<ScanInput> ouster;
    const std::string pcd = o.data_dir + "/" + kOusterFrame;
    if (!std::ifstream(pcd).good()) {
      std::printf("    SKIPPED: %s not found (pass --data DIR to point at the data folder)\n", pcd.c_str());
    } else {
      iwlomap::bench::PcdCloud c = iwlomap::bench::read_pcd(pcd);
      std::printf("    %s: %lld points (%zu non-finite dropped), origin (%.2f, %.2f, %.2f), max range %.0f m\n",
                  pcd.c_str(), static_cast<long long>(c.points.rows()), c.non_finite, c.origin.x(), c.origin.y(),
                  c.origin.z(), kOusterMaxRange);
      ouster = make_input("Ouster frame 0, 25 m", c.origin, std::move(c.points), std::move(c.intensities),
                          kOusterMaxRange);
      const auto [ou_first, ou_steady] = measure_scan(o, *ouster);
      rows.push_back(ou_first);
      rows.push_back(ou_steady);
    }

    print_table(rows);
    std::printf("load average at end: %s\n", load_average().c_str());

    std::printf("\nsanity: both maps after one update from empty (voxels matched by key)\n");
    print_agreement("(a) synthetic scan, batch_update_iwlo / updateNode per point", batch_agreement(o, synthetic));
    print_agreement("(b) synthetic scan, insert_scan / insertPointCloud", scan_agreement(o, synthetic));
    if (ouster) print_agreement("(c) Ouster frame 0, insert_scan / insertPointCloud, 25 m", scan_agreement(o, *ouster));

    std::printf("\nsummary (resolution %.3f m, median of %d repetitions for (a), %d for (b) and (c), single thread; "
                "speedup = OctoMap time / iwlomap time):\n", o.resolution, o.batch_reps, o.reps);
    auto line = [](const char* what, const char* vs, const Row& r, const char* label, double target) {
      std::printf("%s speedup vs OctoMap %s: %.1fx wall, %.1fx CPU time (%s; target >= %.0fx: %s wall, %s CPU)\n",
                  what, vs, r.speedup(), r.cpu_speedup(), label, target, verdict(r.speedup(), target),
                  verdict(r.cpu_speedup(), target));
    };
    line("batch_update_iwlo", "updateNode", batch, "empty map", kTargetBatchSpeedup);
    line("batch_update_iwlo", "updateNode", batch_again, "same batch again", kTargetBatchSpeedup);
    std::printf("batch_update_iwlo speedup vs OctoMap updateNode: %.1fx wall, %.1fx CPU time (growing map, batches "
                "into new space; no target of its own)\n", growing.speedup(), growing.cpu_speedup());
    line("insert_scan", "insertPointCloud", syn_first, "synthetic, first scan", kTargetScanSpeedup);
    line("insert_scan", "insertPointCloud", syn_steady, "synthetic, steady state", kTargetScanSpeedup);
    if (ouster) {
      line("insert_scan", "insertPointCloud", rows[rows.size() - 2], "Ouster, first scan", kTargetScanSpeedup);
      line("insert_scan", "insertPointCloud", rows[rows.size() - 1], "Ouster, steady state", kTargetScanSpeedup);
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "bench_core: %s\n", e.what());
    return 1;
  }
  return 0;
}
