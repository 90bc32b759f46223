// SPDX-License-Identifier: BSD-3-Clause
//
// bench_outputs: what writing a map's files costs beside building the map, as `iwlomap map ...
// --octomap map.bt` does it. One process, single thread, the library's defaults (no retained
// memory, no warm-up round), rounds interleaved:
//
//   map      insert_scan() of one scan into a fresh RAM map (lidar preset)
//   .bt/.ot  export_octomap() of that map
//   OcTree   the same .bt through an octomap::OcTree (a leaf set per voxel, updateInnerOccupancy(),
//            prune(), writeBinaryConst()), as iwlomap wrote it before this writer; its bytes must
//            equal export_octomap()'s or the program fails
//   occupied get_occupied_voxels(), what the PCD / PLY writers start from
//
// Each write's median is printed beside the mapping median and as a ratio to it.
//
// Usage: bench_outputs [--pcd FILE] [--resolution R] [--rounds N] [--no-octree]
//   --pcd FILE     a binary PCD (x y z intensity, VIEWPOINT = sensor) instead of the synthetic
//                  64 x 1024 scan of `iwlomap generate`

#include "bench_pcd.h"
#include "bench_util.h"
#include "iwlomap/octomap/octree_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/sensor_preset.h"
#include "iwlomap/synthetic_scan.h"

#include <octomap/OcTree.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <stdexcept>
#include <string>
#include <unistd.h>
#include <vector>

namespace {

using iwlomap::bench::elapsed;
using iwlomap::bench::median;
using iwlomap::bench::now;

struct Options {
  std::string pcd;
  double resolution = 0.05;
  int rounds = 5;
  bool octree = true;
};

Options parse(int argc, char** argv) {
  Options o;
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const auto value = [&]() -> std::string { return iwlomap::bench::option_value(argc, argv, i); };
    if (a == "--pcd") o.pcd = value();
    else if (a == "--resolution") o.resolution = std::stod(value());
    else if (a == "--rounds") o.rounds = std::stoi(value());
    else if (a == "--no-octree") o.octree = false;
    else throw std::invalid_argument("unknown option " + a + " (see the comment at the top of bench_outputs.cpp)");
  }
  if (!(o.resolution > 0.0) || o.rounds < 1) throw std::invalid_argument("--resolution > 0 and --rounds >= 1");
  return o;
}

std::string file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// The .bt as an OcTree writes it: every voxel a max-likelihood leaf, then inner nodes and pruning.
void write_through_octree(const iwlomap::IMapperBackend& map, const std::string& path) {
  octomap::OcTree tree(map.get_resolution());
  const float occupied = tree.getClampingThresMaxLog();
  const float free = tree.getClampingThresMinLog();
  const double threshold = map.get_params().occupied_threshold;
  map.for_each_voxel([&](const iwlomap::VoxelKey& k, const iwlomap::VoxelState& v) {
    const octomap::OcTreeKey key(static_cast<octomap::key_type>(k.x + 32768), static_cast<octomap::key_type>(k.y + 32768),
                                 static_cast<octomap::key_type>(k.z + 32768));
    const float value = v.probability > threshold ? occupied : free;
    tree.setNodeValue(key, value, /*lazy_eval=*/true)->setLogOdds(value);
  });
  tree.updateInnerOccupancy();
  tree.prune();
  std::ofstream out(path, std::ios::binary);
  if (!tree.writeBinaryConst(out)) throw std::runtime_error("OcTree::writeBinaryConst failed");
}

}  // namespace

int main(int argc, char** argv) try {
  const Options o = parse(argc, argv);
  Eigen::Vector3d origin;
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
  if (o.pcd.empty()) {
    const iwlomap::SyntheticScan scan = iwlomap::make_synthetic_scan();
    origin = scan.origin;
    points = scan.points;
    intensities = scan.intensities;
  } else {
    iwlomap::bench::PcdCloud cloud = iwlomap::bench::read_pcd(o.pcd);
    origin = cloud.origin;
    points = std::move(cloud.points);
    intensities = std::move(cloud.intensities);
  }
  const std::string dir = (std::filesystem::temp_directory_path() / ("bench_outputs." + std::to_string(getpid()))).string();
  std::filesystem::create_directories(dir);
  std::printf("bench_outputs: %s, %lld points, %.3g m, %d rounds, single thread, library defaults\n",
              o.pcd.empty() ? "synthetic scan (iwlomap generate)" : o.pcd.c_str(), static_cast<long long>(points.rows()),
              o.resolution, o.rounds);
  iwlomap::bench::print_build();

  std::vector<double> map_ms, bt_ms, ot_ms, tree_ms, occupied_ms;
  std::size_t voxels = 0, bt_bytes = 0, ot_bytes = 0;
  for (int round = 0; round < o.rounds; ++round) {
    iwlomap::ProbabilityUpdater map(o.resolution);
    map.set_params(iwlomap::sensor_preset_params(iwlomap::SensorPreset::kLidar));
    auto t0 = now();
    map.insert_scan(origin, points, intensities);
    map_ms.push_back(elapsed(t0, now()).wall_ms);
    voxels = map.get_num_known_voxels();

    t0 = now();
    iwlomap::export_octomap(map, dir + "/map.bt");
    bt_ms.push_back(elapsed(t0, now()).wall_ms);
    t0 = now();
    iwlomap::export_octomap(map, dir + "/map.ot");
    ot_ms.push_back(elapsed(t0, now()).wall_ms);
    t0 = now();
    const Eigen::MatrixXd occupied = map.get_occupied_voxels(map.get_params().occupied_threshold);
    occupied_ms.push_back(elapsed(t0, now()).wall_ms);
    if (o.octree) {
      t0 = now();
      write_through_octree(map, dir + "/octree.bt");
      tree_ms.push_back(elapsed(t0, now()).wall_ms);
      iwlomap::bench::settle_heap();
      if (round == 0 && file_bytes(dir + "/octree.bt") != file_bytes(dir + "/map.bt"))
        throw std::runtime_error("export_octomap() and the OcTree wrote different .bt files");
    }
    bt_bytes = std::filesystem::file_size(dir + "/map.bt");
    ot_bytes = std::filesystem::file_size(dir + "/map.ot");
  }
  std::filesystem::remove_all(dir);

  const double m = median(map_ms);
  std::printf("  map: %zu known voxels; .bt %.1f MiB, .ot %.1f MiB\n", voxels, bt_bytes / 1048576.0, ot_bytes / 1048576.0);
  std::printf("  %-34s %9.1f ms\n", "insert_scan into a fresh map", m);
  const auto row = [&](const char* what, const std::vector<double>& v) {
    if (!v.empty()) std::printf("  %-34s %9.1f ms  %5.2fx mapping\n", what, median(v), median(v) / m);
  };
  row("export_octomap .bt", bt_ms);
  row("export_octomap .ot", ot_ms);
  row(".bt through an OcTree (before)", tree_ms);
  row("get_occupied_voxels (PCD/PLY)", occupied_ms);
  if (!tree_ms.empty())
    std::printf("  .bt: export_octomap is %.1fx faster than through an OcTree; bytes identical\n",
                median(tree_ms) / median(bt_ms));
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "bench_outputs: %s\n", e.what());
  return 1;
}
