// SPDX-License-Identifier: BSD-3-Clause
// Integration throughput of DistributedMapper on 1 and N ranks against the one-process RAM map,
// side by side in one job, and the bytes each scan sends between ranks (docs/scale-out.md).
//
//   mpirun --allow-run-as-root -np 2 bench_mpi [--rounds R] [--data DIR] [--tile-size M]
//
// Each round, in turn: (a) rank 0 alone integrates the scans into a plain RAM map (insert_scan),
// (b) rank 0 alone through a one-rank DistributedMapper, (c) all ranks through one
// DistributedMapper (scan i on rank i mod N). Every configuration starts from an empty map and
// integrates the same scans; the medians over the rounds are printed with their ratios. (b) over
// (a) is what the distributed path costs on one rank; (a) over (c) the speedup of N ranks.
// Workloads: the Ouster OS-1 frames of ../shared/data cycled to 12 scans (0.1 m, max range 25 m),
// and 12 synthetic courtyard scans (64 x 1024 beams) from 12 places (0.1 m).

#include <iwlomap/mapper_backend.h>
#include <iwlomap/mpi/distributed_mapper.h>
#include <iwlomap/synthetic_scan.h>

#include <iwlomap/filters/cloud_conversions.h>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>

#include <algorithm>
#include <map>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <string>
#include <vector>

namespace {

using iwlomap::mpi::DistributedMapper;
using iwlomap::mpi::DistributedStats;

struct Scan {
  Eigen::Vector3d origin;
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
};

struct Workload {
  std::string name;
  std::vector<Scan> scans;
  double resolution;
  double max_range;
  iwlomap::IwloParams params;
};

double now() { return std::chrono::duration<double>(std::chrono::steady_clock::now().time_since_epoch()).count(); }

// Measured per-scan figures of one workload, the inputs of the scaling model.
struct Measured {
  std::string name;
  double cast = 0.0;   // seconds to cast one scan and pack its observations (rank 0 in (c))
  double apply = 0.0;  // seconds to apply one scan's worth of observations (rank 0 in (c), per scan)
  double bytes = 0.0;  // bytes one scan's observations take on the wire, all owners together
  double plain = 0.0;  // seconds per scan in one process (a)
  std::uint32_t tile_voxels = 0;  // the shard edge of (c)
};

// Per scan, the observations it sends to each tile: the voxels a map of that scan alone holds.
using TileLoads = std::vector<std::vector<std::pair<iwlomap::VoxelKey, double>>>;
TileLoads tile_loads(const Workload& w, std::uint32_t tile_voxels) {
  TileLoads loads(w.scans.size());
  for (std::size_t s = 0; s < w.scans.size(); ++s) {
    auto map = iwlomap::make_backend("RAM", w.resolution);
    map->set_params(w.params);
    map->insert_scan(w.scans[s].origin, w.scans[s].points, w.scans[s].intensities, w.max_range);
    std::map<iwlomap::VoxelKey, double> per_tile;
    map->for_each_voxel([&](const iwlomap::VoxelKey& k, const iwlomap::VoxelState&) {
      per_tile[iwlomap::mpi::tile_of_voxel(k, tile_voxels)] += 1.0;
    });
    loads[s].assign(per_tile.begin(), per_tile.end());
  }
  return loads;
}

// Load of the busiest of \p n ranks over the mean when a round of n consecutive scans (cycled)
// is applied by their owners, averaged over the rounds that start at each scan.
double imbalance(const TileLoads& loads, int n) {
  double sum = 0.0;
  for (std::size_t start = 0; start < loads.size(); ++start) {
    std::vector<double> load(static_cast<std::size_t>(n), 0.0);
    for (int k = 0; k < n; ++k)
      for (const auto& [t, c] : loads[(start + static_cast<std::size_t>(k)) % loads.size()])
        load[static_cast<std::size_t>(iwlomap::mpi::owner_of_tile(t, n))] += c;
    double total = 0.0, most = 0.0;
    for (const double l : load) {
      total += l;
      most = std::max(most, l);
    }
    sum += most / (total / n);
  }
  return sum / static_cast<double>(loads.size());
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

std::vector<Scan> ouster(const std::string& dir) {
  std::vector<Scan> frames;
  for (int k = 0; k < 3; ++k) {
    char name[64];
    std::snprintf(name, sizeof name, "/frame_%03d_world.pcd", k);
    pcl::PointCloud<pcl::PointXYZI> c;
    if (!std::filesystem::exists(dir + name) || pcl::io::loadPCDFile(dir + name, c) < 0) return {};
    Scan s;
    s.origin = c.sensor_origin_.head<3>().cast<double>();
    iwlomap::cloud_to_matrices(c, nullptr, 255.0, s.points, s.intensities);
    frames.push_back(std::move(s));
  }
  std::vector<Scan> scans;
  for (int i = 0; i < 12; ++i) scans.push_back(frames[static_cast<std::size_t>(i % 3)]);
  return scans;
}

std::vector<Scan> courtyard() {
  std::vector<Scan> scans;
  for (int i = 0; i < 12; ++i) {
    iwlomap::SyntheticScanOptions o;
    o.sensor_xy = {-15.0 + 2.7 * i, (i % 3 - 1) * 6.0};
    o.seed = static_cast<std::uint32_t>(i + 1);
    const iwlomap::SyntheticScan s = iwlomap::make_synthetic_scan(o);
    scans.push_back({s.origin, s.points, s.intensities});
  }
  return scans;
}

// The scans in rounds over the ranks of \p map; returns seconds (the slowest rank's).
double distributed(DistributedMapper& map, const Workload& w) {
  MPI_Barrier(MPI_COMM_WORLD);
  const double t0 = now();
  const std::size_t n = static_cast<std::size_t>(map.ranks());
  for (std::size_t round = 0; round * n < w.scans.size(); ++round) {
    const std::size_t i = round * n + static_cast<std::size_t>(map.rank());
    if (i < w.scans.size())
      map.insert_scan(w.scans[i].origin, w.scans[i].points, w.scans[i].intensities, w.max_range);
    else
      map.pass();
  }
  return now() - t0;
}

}  // namespace

int main(int argc, char** argv) {
  MPI_Init(&argc, &argv);
  int rank = 0, ranks = 1;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  MPI_Comm_size(MPI_COMM_WORLD, &ranks);
  int rounds = 5;
  std::string data = IWLOMAP_BENCH_DATA_DIR;
  iwlomap::mpi::DistributedOptions shard;  // --tile-size: the shard edge of (b) and (c)
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--rounds") && i + 1 < argc) {
      rounds = std::max(1, std::atoi(argv[++i]));
    } else if (!std::strcmp(argv[i], "--data") && i + 1 < argc) {
      data = argv[++i];
    } else if (!std::strcmp(argv[i], "--tile-size") && i + 1 < argc) {
      shard.tile_size = std::atof(argv[++i]);
    } else {
      if (rank == 0) std::fprintf(stderr, "usage: mpirun -np N %s [--rounds R] [--data DIR] [--tile-size M]\n", argv[0]);
      MPI_Finalize();
      return 2;
    }
  }
  // Rank 0 alone, for (a) and (b).
  MPI_Comm solo = MPI_COMM_NULL;
  MPI_Comm_split(MPI_COMM_WORLD, rank == 0 ? 0 : MPI_UNDEFINED, 0, &solo);

  std::vector<Workload> workloads;
  iwlomap::IwloParams lidar;
  lidar.intensity_threshold = 1.0;
  lidar.intensity_max = 255.0;
  if (auto s = ouster(data + "/ouster_os1_128_3frames"); !s.empty())
    workloads.push_back({"Ouster OS-1 frames x12, 0.1 m, 25 m", std::move(s), 0.1, 25.0, lidar});
  else if (rank == 0)
    std::printf("(no Ouster frames in %s: that workload is skipped)\n", data.c_str());
  iwlomap::IwloParams synth = lidar;
  synth.intensity_threshold = 5.0;
  workloads.push_back({"synthetic courtyard x12, 0.1 m", courtyard(), 0.1, -1.0, synth});

  if (rank == 0)
    std::printf("bench_mpi: %d rank(s), %d round(s), shard edge %s, medians; times for all 12 scans of a workload\n",
                ranks, rounds, shard.tile_size > 0 ? (std::to_string(shard.tile_size) + " m").c_str() : "default (one block)");
  std::vector<Measured> measured;
  for (const Workload& w : workloads) {
    std::vector<double> plain, one, all;
    DistributedStats last;
    std::uint64_t sent_total = 0;
    std::uint32_t shard_voxels = 0;
    for (int r = 0; r < rounds; ++r) {
      if (rank == 0) {
        auto map = iwlomap::make_backend("RAM", w.resolution);
        map->set_params(w.params);
        const double t0 = now();
        for (const Scan& s : w.scans) map->insert_scan(s.origin, s.points, s.intensities, w.max_range);
        plain.push_back(now() - t0);
        DistributedMapper d(solo, w.resolution, w.params, shard);
        const double t1 = now();
        for (const Scan& s : w.scans) d.insert_scan(s.origin, s.points, s.intensities, w.max_range);
        one.push_back(now() - t1);
      }
      DistributedMapper d(MPI_COMM_WORLD, w.resolution, w.params, shard);
      const double mine = distributed(d, w);
      double slowest = 0.0;
      MPI_Reduce(&mine, &slowest, 1, MPI_DOUBLE, MPI_MAX, 0, MPI_COMM_WORLD);
      all.push_back(slowest);
      const std::uint64_t sent = d.stats().bytes_sent;
      MPI_Reduce(&sent, &sent_total, 1, MPI_UINT64_T, MPI_SUM, 0, MPI_COMM_WORLD);
      last = d.stats();
      shard_voxels = d.tile_voxels();
    }
    // Rank 0's split of its time in the last round of (c).
    if (rank != 0) continue;
    const double n = static_cast<double>(w.scans.size());
    const double a = median(plain), b = median(one), c = median(all);
    std::printf("\n%s (%zu scans)\n", w.name.c_str(), w.scans.size());
    std::printf("  (a) one process, RAM map        %8.1f ms/scan  %6.2f scans/s\n", 1e3 * a / n, n / a);
    std::printf("  (b) DistributedMapper, 1 rank   %8.1f ms/scan  %6.2f scans/s  (b)/(a) time %.2fx\n", 1e3 * b / n,
                n / b, b / a);
    std::printf("  (c) DistributedMapper, %d ranks  %8.1f ms/scan  %6.2f scans/s  speedup (a)/(c) %.2fx, (b)/(c) %.2fx\n",
                ranks, 1e3 * c / n, n / c, a / c, b / c);
    std::printf("      bytes sent between ranks: %.0f per scan (%.2f MiB for all scans)\n",
                static_cast<double>(sent_total) / n, static_cast<double>(sent_total) / (1024.0 * 1024.0));
    std::printf("      rank 0 in (c), last round: cast %.1f ms, exchange+wait %.1f ms, apply %.1f ms per round of %d scans\n",
                1e3 * last.cast_seconds / static_cast<double>(last.rounds),
                1e3 * last.exchange_seconds / static_cast<double>(last.rounds),
                1e3 * last.apply_seconds / static_cast<double>(last.rounds), ranks);
    // One scan's wire volume: a scan sends (N - 1) / N of its observations to other ranks.
    const double rounds_done = static_cast<double>(last.rounds);
    measured.push_back({w.name, last.cast_seconds / rounds_done, last.apply_seconds / rounds_done,
                        static_cast<double>(sent_total) / n * ranks / std::max(1, ranks - 1), a / n, shard_voxels});
  }

  // The model for 8-64 nodes, from this run's per-scan figures (see docs/scale-out.md).
  if (rank == 0 && ranks > 1) {
    struct Net {
      const char* name;
      double bandwidth;  // bytes/s per node, each direction
      double latency;    // seconds per message
    };
    const Net nets[] = {{"10 GbE", 1.25e9, 30e-6}, {"100 Gb/s InfiniBand", 12.5e9, 3e-6}};
    std::printf("\nScaling model: a round of N scans on N nodes takes cast + apply x imbalance(N) + wire,\n"
                "wire = volume x (N-1)/N / bandwidth + (N-1) x latency (network figures assumed, not measured)\n");
    for (std::size_t wi = 0; wi < measured.size(); ++wi) {
      const Measured& m = measured[wi];
      const Workload& w = workloads[wi];
      std::printf("\n%s, shards of %u voxels: cast %.1f ms, apply %.1f ms, %.2f MB on the wire per scan; one process %.1f ms/scan\n",
                  m.name.c_str(), m.tile_voxels, 1e3 * m.cast, 1e3 * m.apply, m.bytes / 1e6, 1e3 * m.plain);
      std::printf("  %5s %10s", "nodes", "imbalance");
      for (const Net& net : nets) std::printf("  %22s", net.name);
      std::printf("\n  %5s %10s", "", "(max/mean)");
      for (std::size_t k = 0; k < 2; ++k) std::printf("  %22s", "scans/s (x one proc.)");
      std::printf("\n");
      // The imbalance of (c)'s shards, and beside it that of the Disk shards' default edge.
      const TileLoads loads = tile_loads(w, m.tile_voxels);
      const auto disk_voxels = static_cast<std::uint32_t>(
          std::max(1L, std::lround(iwlomap::mpi::kDiskShardSize / w.resolution / 8.0)) * 8);
      const TileLoads disk = tile_loads(w, disk_voxels);
      for (const int nodes : {2, 8, 16, 32, 64}) {
        const double imb = imbalance(loads, nodes);
        std::printf("  %5d %10.2f", nodes, imb);
        for (const Net& net : nets) {
          const double wire = m.bytes * (nodes - 1) / nodes / net.bandwidth + (nodes - 1) * net.latency;
          const double round = m.cast + m.apply * imb + wire;
          const double rate = nodes / round;
          std::printf("  %12.1f (%5.1fx)", rate, rate * m.plain);
        }
        std::printf("   with %.1f m shards: imbalance %.2f", disk_voxels * w.resolution, imbalance(disk, nodes));
        std::printf("\n");
      }
    }
  }
  if (solo != MPI_COMM_NULL) MPI_Comm_free(&solo);
  MPI_Finalize();
  return 0;
}
