// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap generate`: a synthetic lidar scan to try the tool on without recorded data.

#include "args.h"
#include "cloud_io.h"
#include "commands.h"
#include "output_files.h"

#include <iwlomap/synthetic_scan.h>

#include <cstdint>
#include <iostream>
#include <limits>

namespace iwlomap::tool {

namespace {
const char* kHelp = R"(usage: iwlomap generate -o OUT.pcd [options]

Writes a synthetic lidar scan of a walled courtyard (40 m x 30 m, walls 10 m high, boxes, a pole
and a low wall on flat ground) with reflectivity intensities 0..255, as seen from a spinning
lidar. The sensor position is stored as the cloud's VIEWPOINT, so 'iwlomap map' casts rays from it.

options:
  -o, --output FILE   .pcd or .ply
  --rings N           elevation beams, -25..+15 degrees (default 64)
  --columns N         azimuth steps (default 1024)
  --height M          sensor height above the ground in metres (default 1.5)
  --seed S            noise seed (default 1)
)";
}  // namespace

int run_generate(const std::vector<std::string>& argv) {
  const Args args(argv, {"-o", "--output", "--rings", "--columns", "--height", "--seed"}, {"-h", "--help"});
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp;
    return 0;
  }
  const auto output = args.value("-o") ? args.value("-o") : args.value("--output");
  if (!output) throw UsageError("no output file (-o OUT.pcd)");
  if (!args.positional().empty()) throw UsageError("unexpected argument '" + args.positional().front() + "'");
  OutputFiles files;
  files.add("-o", *output, {".pcd", ".ply"});
  SyntheticScanOptions opt;
  opt.rings = static_cast<int>(args.integer("--rings", opt.rings));
  opt.columns = static_cast<int>(args.integer("--columns", opt.columns));
  opt.sensor_height = args.number("--height", opt.sensor_height);
  const long seed = args.integer("--seed", 1, 0, std::numeric_limits<std::uint32_t>::max());
  if (seed < 0) throw UsageError("--seed must be >= 0");
  opt.seed = static_cast<std::uint32_t>(seed);
  if (opt.rings < 1 || opt.columns < 1) throw UsageError("--rings and --columns must be >= 1");
  const SyntheticScan scan = make_synthetic_scan(opt);

  pcl::PointCloud<pcl::PointXYZI> cloud;
  cloud.resize(static_cast<std::size_t>(scan.points.rows()));
  for (Eigen::Index i = 0; i < scan.points.rows(); ++i) {
    auto& p = cloud[static_cast<std::size_t>(i)];
    p.x = static_cast<float>(scan.points(i, 0));
    p.y = static_cast<float>(scan.points(i, 1));
    p.z = static_cast<float>(scan.points(i, 2));
    p.intensity = static_cast<float>(scan.intensities[i]);
  }
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  cloud.height = 1;
  cloud.is_dense = true;
  cloud.sensor_origin_ = Eigen::Vector4f(static_cast<float>(scan.origin.x()), static_cast<float>(scan.origin.y()),
                                         static_cast<float>(scan.origin.z()), 0.0f);
  save_cloud(files.temporary(*output), cloud, *output);
  files.commit();
  std::cout << "wrote " << *output << ": " << cloud.size() << " points, sensor at (" << scan.origin.transpose()
            << ")\n";
  return 0;
}

}  // namespace iwlomap::tool
