// SPDX-License-Identifier: BSD-3-Clause
//
// bench_octomap_backend: the OctoMap backend (iwlomap::OctreeMapper) against the RAM backend
// (iwlomap::ProbabilityUpdater) on the same input, in one run, single thread; plain
// octomap::OcTree is measured beside them so the cost of keeping the exact IWLO state next to the
// octree can be read off.
//
//   (a) insert_scan of synthetic 64 x 1024 scans from three sensor positions, into an empty map
//       (plain OcTree: insertPointCloud(cloud, origin, max_range, lazy_eval=false, discretize=false))
//   (b) batch_update_iwlo of random points in the courtyard (plain OcTree: updateNode(point,
//       hit log-odds, lazy_eval=false) per point)
//   (c) get_occupied_voxels() of the map from (a)
//   (d) memory held by the map from (a), and exporting it to .bt and .ot
//
// The two iwlomap backends must end with identical maps (every voxel's log-odds and count); the
// program checks that and fails otherwise. Repetitions alternate the libraries; medians are
// reported after one untimed warm-up round; building and destroying maps is not timed.
//
// Usage: bench_octomap_backend [--reps N] [--resolution R] [--quick]

#include "bench_util.h"
#include "iwlomap/octomap/octree_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"

#include <octomap/OcTree.h>

#include <Eigen/Core>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <memory>
#include <random>
#include <stdexcept>
#include <string>
#include <tuple>
#include <unistd.h>
#include <vector>

namespace {

using iwlomap::bench::median;

using Clock = std::chrono::steady_clock;
constexpr double kMaxRange = 25.0;
constexpr float kHitLogOdds = 0.85f;  // OctoMap's default hit, ln(0.7 / 0.3)

struct Options {
  int reps = 3;
  double resolution = 0.1;
  bool quick = false;
};

Options parse_options(int argc, char** argv) {
  Options o;
  bool reps_given = false;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw std::invalid_argument(a + " needs a value");
      return argv[++i];
    };
    if (a == "--reps") {
      const std::string v = value();
      char* end = nullptr;
      const long n = std::strtol(v.c_str(), &end, 10);
      if (end == v.c_str() || *end != '\0' || n < 1 || n > 100)
        throw std::invalid_argument("--reps must be an integer in [1, 100], got '" + v + "'");
      o.reps = static_cast<int>(n);
      reps_given = true;
    } else if (a == "--resolution") {
      const std::string v = value();
      char* end = nullptr;
      const double r = std::strtod(v.c_str(), &end);
      if (end == v.c_str() || *end != '\0' || !std::isfinite(r) || r <= 0.0)
        throw std::invalid_argument("--resolution must be a positive number of metres, got '" + v + "'");
      o.resolution = r;
    } else if (a == "--quick") {
      o.quick = true;
    } else if (a == "--help" || a == "-h") {
      std::printf(
          "Usage: %s [--reps N] [--resolution R] [--quick]\n"
          "  --reps N        timed repetitions (default 3; medians are reported)\n"
          "  --resolution R  voxel edge in metres (default 0.1)\n"
          "  --quick         1 repetition of 16 x 256 scans (a smoke run)\n",
          argv[0]);
      std::exit(0);
    } else {
      throw std::invalid_argument("unknown argument '" + a + "' (see --help)");
    }
  }
  if (o.quick && !reps_given) o.reps = 1;
  return o;
}

// Every timed region starts from a settled heap (see settle_heap()).
double time_ms(const std::function<void()>& f) {
  iwlomap::bench::settle_heap();
  const auto t0 = Clock::now();
  f();
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

struct Scan {
  iwlomap::SyntheticScan scan;
  octomap::Pointcloud cloud;
  octomap::point3d origin;
};

std::vector<Scan> make_scans(bool quick) {
  std::vector<Scan> scans;
  const Eigen::Vector2d positions[] = {{0.0, 0.0}, {6.0, -4.0}, {-8.0, 5.0}};
  for (int s = 0; s < 3; ++s) {
    iwlomap::SyntheticScanOptions o;
    o.rings = quick ? 16 : 64;
    o.columns = quick ? 256 : 1024;
    o.sensor_xy = positions[s];
    o.seed = 11u + static_cast<std::uint32_t>(s);
    Scan sc{iwlomap::make_synthetic_scan(o), {}, {}};
    for (Eigen::Index i = 0; i < sc.scan.points.rows(); ++i)
      sc.cloud.push_back(static_cast<float>(sc.scan.points(i, 0)), static_cast<float>(sc.scan.points(i, 1)),
                         static_cast<float>(sc.scan.points(i, 2)));
    sc.origin = octomap::point3d(static_cast<float>(sc.scan.origin.x()), static_cast<float>(sc.scan.origin.y()),
                                 static_cast<float>(sc.scan.origin.z()));
    scans.push_back(std::move(sc));
  }
  return scans;
}

struct Batch {
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
  std::vector<bool> flags;
  std::vector<octomap::point3d> om_points;
};

Batch make_batch(int n) {
  std::mt19937 rng(2024u);
  std::uniform_real_distribution<double> x(-20.0, 20.0), y(-15.0, 15.0), z(0.0, 5.0), intensity(0.0, 255.0);
  Batch b{Eigen::MatrixXd(n, 3), Eigen::VectorXd(n), std::vector<bool>(static_cast<std::size_t>(n), true), {}};
  for (int i = 0; i < n; ++i) {
    b.points.row(i) << x(rng), y(rng), z(rng);
    b.intensities[i] = std::round(intensity(rng));
    b.om_points.emplace_back(static_cast<float>(b.points(i, 0)), static_cast<float>(b.points(i, 1)),
                             static_cast<float>(b.points(i, 2)));
  }
  return b;
}

using State = std::vector<std::tuple<std::int32_t, std::int32_t, std::int32_t, double, std::uint32_t>>;
State state_of(const iwlomap::IMapperBackend& map) {
  State s;
  map.for_each_voxel([&s](const iwlomap::VoxelKey& k, const iwlomap::VoxelState& v) {
    s.emplace_back(k.x, k.y, k.z, v.log_odds, v.count);
  });
  std::sort(s.begin(), s.end());
  return s;
}

struct Figures {
  std::vector<double> ram, octo, plain;
};

void print_row(const char* what, const Figures& f, const char* unit, double per) {
  const double ram = median(f.ram) / per, octo = median(f.octo) / per;
  char plain[32] = "-", ratio[32] = "-";
  if (!f.plain.empty()) {
    std::snprintf(plain, sizeof(plain), "%.1f %s", median(f.plain) / per, unit);
    std::snprintf(ratio, sizeof(ratio), "%.2fx", octo / (median(f.plain) / per));
  }
  std::printf("| %-44s | %9.1f %-2s | %12.1f %-2s | %10.2fx | %12s | %13s |\n", what, ram, unit, octo, unit,
              octo / ram, plain, ratio);
}

}  // namespace

int main(int argc, char** argv) try {
  const Options opt = parse_options(argc, argv);
  const double r = opt.resolution;
  const std::vector<Scan> scans = make_scans(opt.quick);
  const Batch batch = make_batch(opt.quick ? 50000 : 200000);
  std::size_t scan_points = 0;
  for (const Scan& s : scans) scan_points += static_cast<std::size_t>(s.scan.points.rows());

  Figures scan_ms, batch_ms, occupied_ms;
  double ram_mb = 0, octo_mb = 0, plain_mb = 0, bt_ms = 0, ot_ms = 0, ram_bt_ms = 0;
  std::size_t known = 0, occupied = 0, tree_nodes = 0, bt_bytes = 0, ot_bytes = 0;
  bool identical = true;
  const std::string tmp = (std::filesystem::temp_directory_path() /
                           ("iwlomap_bench_octomap_" + std::to_string(::getpid())))
                              .string();

  for (int rep = -1; rep < opt.reps; ++rep) {  // rep -1: warm-up, not recorded
    const bool record = rep >= 0;
    const bool octo_first = rep % 2 == 0;
    iwlomap::ProbabilityUpdater ram(r);
    iwlomap::OctreeMapper octo(r);
    octomap::OcTree plain(r);
    const auto run_ram = [&] { return time_ms([&] { for (const Scan& s : scans) ram.insert_scan(s.scan.origin, s.scan.points, s.scan.intensities, kMaxRange); }); };
    const auto run_octo = [&] { return time_ms([&] { for (const Scan& s : scans) octo.insert_scan(s.scan.origin, s.scan.points, s.scan.intensities, kMaxRange); }); };
    const auto run_plain = [&] { return time_ms([&] { for (const Scan& s : scans) plain.insertPointCloud(s.cloud, s.origin, kMaxRange, false, false); }); };
    double t_ram, t_octo, t_plain;
    if (octo_first) {
      t_octo = run_octo();
      t_ram = run_ram();
    } else {
      t_ram = run_ram();
      t_octo = run_octo();
    }
    t_plain = run_plain();
    if (record) {
      scan_ms.ram.push_back(t_ram);
      scan_ms.octo.push_back(t_octo);
      scan_ms.plain.push_back(t_plain);
    }

    Eigen::MatrixXd occ_ram, occ_octo;
    const double o_ram = time_ms([&] { occ_ram = ram.get_occupied_voxels(); });
    const double o_octo = time_ms([&] { occ_octo = octo.get_occupied_voxels(); });
    if (record) {
      occupied_ms.ram.push_back(o_ram);
      occupied_ms.octo.push_back(o_octo);
    }
    if (rep == opt.reps - 1) {
      identical = identical && state_of(ram) == state_of(octo) && occ_ram == occ_octo;
      known = ram.get_num_known_voxels();
      occupied = static_cast<std::size_t>(occ_ram.rows());
      ram_mb = ram.get_memory_usage().memory_mb;
      const iwlomap::MemoryStats m = octo.get_memory_usage();
      octo_mb = m.memory_mb;
      tree_nodes = m.num_nodes;
      plain_mb = static_cast<double>(plain.memoryUsage()) / (1024.0 * 1024.0);
      std::filesystem::create_directories(tmp);
      bt_ms = time_ms([&] { octo.save_to_file(tmp + "/map.bt"); });
      ot_ms = time_ms([&] { octo.save_to_file(tmp + "/map.ot"); });
      ram_bt_ms = time_ms([&] { iwlomap::export_octomap(ram, tmp + "/ram.bt"); });
      bt_bytes = std::filesystem::file_size(tmp + "/map.bt");
      ot_bytes = std::filesystem::file_size(tmp + "/map.ot");
      std::filesystem::remove_all(tmp);
    }

    iwlomap::ProbabilityUpdater bram(r);
    iwlomap::OctreeMapper bocto(r);
    octomap::OcTree bplain(r);
    const auto b_ram = [&] { return time_ms([&] { bram.batch_update_iwlo(batch.points, batch.intensities, batch.flags); }); };
    const auto b_octo = [&] { return time_ms([&] { bocto.batch_update_iwlo(batch.points, batch.intensities, batch.flags); }); };
    double tb_ram, tb_octo;
    if (octo_first) {
      tb_octo = b_octo();
      tb_ram = b_ram();
    } else {
      tb_ram = b_ram();
      tb_octo = b_octo();
    }
    const double tb_plain = time_ms([&] {
      for (const octomap::point3d& p : batch.om_points) bplain.updateNode(p, kHitLogOdds, false);
    });
    if (record) {
      batch_ms.ram.push_back(tb_ram);
      batch_ms.octo.push_back(tb_octo);
      batch_ms.plain.push_back(tb_plain);
    }
    identical = identical && state_of(bram) == state_of(bocto);
  }

  std::printf("bench_octomap_backend: resolution %.3g m, %d repetitions (medians), OctoMap %s\n", r, opt.reps,
              IWLOMAP_BENCH_OCTOMAP_VERSION);
  iwlomap::bench::retain_map_memory();
  std::printf("input: 3 synthetic scans, %zu points in all, max range %.0f m; batch of %ld random points\n\n",
              scan_points, kMaxRange, static_cast<long>(batch.points.rows()));
  std::printf("| %-44s | %12s | %15s | %11s | %12s | %13s |\n", "measurement", "RAM", "OctoMap backend",
              "OctoMap/RAM", "plain OcTree", "backend/plain");
  std::printf("|%s|%s|%s|%s|%s|%s|\n", std::string(46, '-').c_str(), std::string(14, '-').c_str(),
              std::string(17, '-').c_str(), std::string(13, '-').c_str(), std::string(14, '-').c_str(),
              std::string(15, '-').c_str());
  print_row("insert_scan, per scan (empty map, 3 scans)", scan_ms, "ms", 3.0);
  print_row("batch_update_iwlo, per 1,000,000 points", batch_ms, "ms", static_cast<double>(batch.points.rows()) / 1e6);
  print_row("get_occupied_voxels (map after the scans)", occupied_ms, "ms", 1.0);
  std::printf("\nmap after the scans: %zu known voxels, %zu occupied (p > 0.5), octree of %zu nodes\n", known,
              occupied, tree_nodes);
  std::printf("memory: RAM %.1f MiB, OctoMap backend %.1f MiB (octree + exact state), plain OcTree %.1f MiB\n",
              ram_mb, octo_mb, plain_mb);
  std::printf("files: OctoMap backend save .bt %.0f ms (%.1f MiB), .ot %.0f ms (%.1f MiB); export_octomap(RAM) .bt %.0f ms\n",
              bt_ms, static_cast<double>(bt_bytes) / (1024.0 * 1024.0), ot_ms,
              static_cast<double>(ot_bytes) / (1024.0 * 1024.0), ram_bt_ms);
  std::printf("identical maps (every voxel's log-odds and count, occupied rows): %s\n", identical ? "yes" : "NO");
  return identical ? 0 : 1;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_octomap_backend: %s\n", e.what());
  return 2;
}
