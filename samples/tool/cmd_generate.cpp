// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap generate`: a synthetic lidar scan to try the tool on without recorded data.

#include "args.h"
#include "cloud_io.h"
#include "commands.h"
#include "map_options.h"
#include "output_files.h"

#include <iwlomap/synthetic_scan.h>
#include <iwlomap/synthetic_world.h>
#include <iwlomap/trajectory_io.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <iomanip>
#include <sstream>
#include <filesystem>
#include <iostream>
#include <limits>
#include <string>
#include <vector>

namespace iwlomap::tool {

namespace {

// A scan of rings x columns points, checked against the memory budget before anything is made:
// about 100 bytes a point (the scan as doubles, the PCL cloud, the file buffer).
void check_scan_size(long rings, long columns) {
  const double points = static_cast<double>(rings) * static_cast<double>(columns);
  const std::string beyond = beyond_memory_budget(100.0 * points);
  if (beyond.empty()) return;
  std::ostringstream m;
  m << std::setprecision(3) << "--rings " << rings << " x --columns " << columns << " is " << points << " points, "
    << beyond;
  throw UsageError(m.str());
}
const char* kHelp = R"(usage: iwlomap generate -o OUT.pcd [options]
       iwlomap generate --street-loop DIR [options]

Writes a synthetic lidar scan of a walled courtyard (40 m x 30 m, walls 10 m high, boxes, a pole
and a low wall on flat ground) with reflectivity intensities 0..255, as seen from a spinning
lidar. The sensor position is stored as the cloud's VIEWPOINT, so 'iwlomap map' casts rays from it.

With --street-loop, writes a drive once around a city block instead (a street loop lined with
buildings, gaps, parked cars, poles and trees, larger than the lidar's range): DIR/scan_NNNN.pcd,
one scan every --step metres and two more past the start, each in the map frame at the pose a
drifting navigation gives (its VIEWPOINT, position and orientation), as a mapping pipeline
would store them; DIR/truth.tum and DIR/navigation.tum hold the true and the navigation sensor
poses (TUM: index x y z qx qy qz qw). Try: iwlomap map DIR/scan_*.pcd --sensor lidar --register
--loop-closure --write-poses poses.tum -o map.pcd, then compare poses.tum with truth.tum.

options:
  -o, --output FILE   .pcd or .ply
  --rings N           elevation beams, -25..+15 degrees (default 64; street loop 32)
  --columns N         azimuth steps (default 1024)
  --height M          sensor height above the ground in metres (default 1.5; street loop 1.8)
  --seed S            noise seed (default 1)
street loop:
  --street-loop DIR   the folder to write (created if missing; existing scan files are replaced)
  --block X,Y         the loop's size in metres (default 200,150; at least street width + 20)
  --step M            metres between scans (default 3)
  --range M           the lidar's range in metres (default 40)
  --drift P,D         the navigation's drift: P percent of the distance travelled and D degrees
                      of heading per 10 m (default 1,0.5)
)";

constexpr double kDeg = 3.14159265358979323846 / 180.0;

pcl::PointCloud<pcl::PointXYZI> cloud_of(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities) {
  pcl::PointCloud<pcl::PointXYZI> cloud;
  cloud.resize(static_cast<std::size_t>(points.rows()));
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    auto& p = cloud[static_cast<std::size_t>(i)];
    p.x = static_cast<float>(points(i, 0));
    p.y = static_cast<float>(points(i, 1));
    p.z = static_cast<float>(points(i, 2));
    p.intensity = static_cast<float>(intensities[i]);
  }
  cloud.width = static_cast<std::uint32_t>(cloud.size());
  cloud.height = 1;
  cloud.is_dense = true;
  return cloud;
}

int run_street_loop(const Args& args, const std::string& dir) {
  StreetLoopOptions street;
  if (const auto b = args.value("--block")) {
    const std::vector<double> v = parse_list("--block", *b, 2);
    street.block_x = v[0];
    street.block_y = v[1];
  }
  const double step = args.number("--step", 3.0);
  if (!(step > 0.0) || !std::isfinite(step)) throw UsageError("--step must be > 0");
  LidarOptions lidar;
  lidar.rings = static_cast<int>(args.integer("--rings", 32));
  lidar.columns = static_cast<int>(args.integer("--columns", 1024));
  if (lidar.rings < 1 || lidar.columns < 1) throw UsageError("--rings and --columns must be >= 1");
  check_scan_size(lidar.rings, lidar.columns);
  lidar.max_range = args.number("--range", 40.0);
  const double height = args.number("--height", 1.8);
  const long seed = args.integer("--seed", 1, 0, std::numeric_limits<std::uint32_t>::max());
  double drift_percent = 1.0, drift_degrees = 0.5;
  if (const auto d = args.value("--drift")) {
    const std::vector<double> v = parse_list("--drift", *d, 2);
    drift_percent = v[0];
    drift_degrees = v[1];
  }
  if (!std::isfinite(drift_percent) || !std::isfinite(drift_degrees)) throw UsageError("--drift must be finite");
  try {
    lidar.validate();
  } catch (const std::invalid_argument& e) {
    throw UsageError(e.what());
  }
  street.seed = static_cast<std::uint32_t>(seed);
  const SyntheticWorld world = [&] {
    try {
      return SyntheticWorld::street_loop(street);
    } catch (const std::invalid_argument& e) {
      throw UsageError(std::string("--block: ") + e.what());
    }
  }();
  std::vector<Eigen::Isometry3d> truth = SyntheticWorld::street_loop_trajectory(street, step, height);
  truth.push_back(truth[0]);  // on past the start, so the end of the drive overlaps its beginning
  truth.push_back(truth[1]);
  std::vector<Eigen::Isometry3d> nav{truth[0]};
  for (std::size_t i = 1; i < truth.size(); ++i) {
    Eigen::Isometry3d d = truth[i - 1].inverse() * truth[i];
    const double metres = d.translation().norm();
    d.translation() *= 1.0 + drift_percent / 100.0;
    d.linear() = Eigen::AngleAxisd(drift_degrees * kDeg * metres / 10.0, Eigen::Vector3d::UnitZ()).toRotationMatrix() *
                 d.linear();
    nav.push_back(nav.back() * d);
  }
  std::filesystem::create_directories(dir);
  OutputFiles files(args);
  std::vector<std::string> names;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "scan_%04zu.pcd", i);
    names.push_back((std::filesystem::path(dir) / name).string());
    files.add("--street-loop", names.back(), {".pcd"});
  }
  const std::string truth_path = (std::filesystem::path(dir) / "truth.tum").string();
  const std::string nav_path = (std::filesystem::path(dir) / "navigation.tum").string();
  files.add("--street-loop", truth_path, {".tum"});
  files.add("--street-loop", nav_path, {".tum"});
  std::size_t points = 0;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    const LidarFrame f = world.scan(truth[i], lidar, static_cast<std::uint32_t>(seed) * 100003u + static_cast<std::uint32_t>(i));
    // The scan as the navigation places it.
    const Eigen::MatrixXd map_frame = (f.points * nav[i].linear().transpose()).rowwise() + nav[i].translation().transpose();
    pcl::PointCloud<pcl::PointXYZI> cloud = cloud_of(map_frame, f.intensities);
    cloud.sensor_origin_ = Eigen::Vector4f(static_cast<float>(nav[i].translation().x()),
                                           static_cast<float>(nav[i].translation().y()),
                                           static_cast<float>(nav[i].translation().z()), 0.0f);
    cloud.sensor_orientation_ = Eigen::Quaterniond(nav[i].linear()).cast<float>();
    save_cloud(files.temporary(names[i]), cloud, names[i]);
    points += cloud.size();
  }
  write_trajectory(files.temporary(truth_path), truth, {}, TrajectoryFormat::kTum);
  write_trajectory(files.temporary(nav_path), nav, {}, TrajectoryFormat::kTum);
  files.commit();
  const double end_error = (nav[truth.size() - 3].translation() - truth[truth.size() - 3].translation()).norm();
  std::cout << "wrote " << truth.size() << " scans (" << points << " points) of a " << street.block_x << " x "
            << street.block_y << " m block to " << dir << ", truth.tum and navigation.tum; the navigation ends the loop "
            << end_error << " m off\n";
  return 0;
}
}  // namespace

int run_generate(const std::vector<std::string>& argv) {
  const Args args(argv, {"-o", "--output", "--rings", "--columns", "--height", "--seed", "--street-loop", "--block",
                         "--step", "--range", "--drift"},
                  {"-h", "--help"});
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp;
    return 0;
  }
  const auto output = args.value("-o") ? args.value("-o") : args.value("--output");
  if (const auto dir = args.value("--street-loop")) {
    if (output) throw UsageError("--street-loop writes a folder: no -o");
    if (!args.positional().empty()) throw UsageError("unexpected argument '" + args.positional().front() + "'");
    return run_street_loop(args, *dir);
  }
  for (const char* o : {"--block", "--step", "--range", "--drift"})
    if (args.value(o)) throw UsageError(std::string(o) + " needs --street-loop");
  if (!output) throw UsageError("no output file (-o OUT.pcd)");
  if (!args.positional().empty()) throw UsageError("unexpected argument '" + args.positional().front() + "'");
  OutputFiles files(args);
  files.add("-o", *output, {".pcd", ".ply"});
  SyntheticScanOptions opt;
  opt.rings = static_cast<int>(args.integer("--rings", opt.rings));
  opt.columns = static_cast<int>(args.integer("--columns", opt.columns));
  opt.sensor_height = args.number("--height", opt.sensor_height);
  const long seed = args.integer("--seed", 1, 0, std::numeric_limits<std::uint32_t>::max());
  if (seed < 0) throw UsageError("--seed must be >= 0");
  opt.seed = static_cast<std::uint32_t>(seed);
  if (opt.rings < 1 || opt.columns < 1) throw UsageError("--rings and --columns must be >= 1");
  check_scan_size(opt.rings, opt.columns);
  const SyntheticScan scan = make_synthetic_scan(opt);

  pcl::PointCloud<pcl::PointXYZI> cloud = cloud_of(scan.points, scan.intensities);
  cloud.sensor_origin_ = Eigen::Vector4f(static_cast<float>(scan.origin.x()), static_cast<float>(scan.origin.y()),
                                         static_cast<float>(scan.origin.z()), 0.0f);
  save_cloud(files.temporary(*output), cloud, *output);
  files.commit();
  std::cout << "wrote " << *output << ": " << cloud.size() << " points, sensor at (" << scan.origin.transpose()
            << ")\n";
  return 0;
}

}  // namespace iwlomap::tool
