// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap register`: where does a scan fit a map? Prints the sensor pose in the map frame.

#include "args.h"
#include "commands.h"

#include <iostream>
#include <stdexcept>

#ifdef IWLOMAP_HAVE_REGISTRATION
#include "cloud_io.h"
#include "registration_options.h"
#include "voxel_cloud.h"

#include <iwlomap/registration/scan_matcher.h>

#include "map_open.h"

#include <cstdio>
#include <optional>
#endif

namespace iwlomap::tool {

namespace {

const char* kHelp = R"(usage: iwlomap register --map MAP --scan SCAN.pcd|SCAN.ply [options]

Registers a scan against a map: branch and bound over the map's max grids in a search window
around an initial pose, then point-to-plane ICP. MAP is a .pcd/.ply cloud of voxel centres (as
'iwlomap map' writes; intensity = probability), a disk-backend tile directory or a .bt/.ot file.
SCAN holds points in the sensor frame (metres). The output ends with one line

  pose x y z qw qx qy qz

(metres; unit quaternion): the scan's sensor pose in the map frame, preceded by score, rmse,
iterations and converged. ICP aligns to a MAP cloud's own points: voxel centres place a surface
up to half a voxel off, and the pose with them; 'iwlomap map --mean-positions' writes the mean hit
positions instead, which are on the surface. A map cloud that 'iwlomap map', 'sonar' or 'export'
wrote records its resolution in a header comment. Exit code 1 when the registration did not
converge (the pose line then gives the initial pose), with the reason on standard error.

options:
  --map MAP                 the map
  --scan FILE               the scan, sensor frame
  --initial "X Y Z ROLL PITCH YAW"   initial sensor pose in the map frame (metres, degrees;
                            roll about x, pitch about y, yaw about z, applied z-y-x; default: the
                            scan file's VIEWPOINT)
  --resolution M            voxel edge of a MAP cloud (default: the one its header records, else
                            inferred from its voxel centres; refused when it differs from the
                            recorded one)
)";

}  // namespace

int run_register(const std::vector<std::string>& argv) {
#ifndef IWLOMAP_HAVE_REGISTRATION
  const Args args(argv, {}, {"-h", "--help"});
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp;
    return 0;
  }
  throw std::runtime_error("this iwlomap was built without the registration layer (IWLOMAP_WITH_REGISTRATION)");
#else
  auto value_opts = registration_value_options();
  value_opts.insert({"--map", "--scan", "--initial", "--resolution"});
  auto flag_opts = registration_flag_options();
  flag_opts.insert({"-h", "--help"});
  const Args args(argv, value_opts, flag_opts);
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp << registration_options_help();
    return 0;
  }
  if (!args.positional().empty()) throw UsageError("unexpected argument '" + args.positional().front() + "'");
  const auto map_path = args.value("--map");
  const auto scan_path = args.value("--scan");
  if (!map_path) throw UsageError("no map (--map MAP)");
  if (!scan_path) throw UsageError("no scan (--scan SCAN.pcd)");
  const registration::ScanMatcherOptions options = registration_options_from(args);
  const auto resolution = args.resolution();

  const LoadedCloud scan = load_cloud(*scan_path, 255.0f);
  Eigen::Isometry3d initial = Eigen::Isometry3d::Identity();
  if (const auto text = args.value("--initial")) {
    initial = pose_from_text("--initial", *text);
  } else {
    initial = viewpoint_pose(*scan.cloud);
  }
  Eigen::MatrixXd points(static_cast<Eigen::Index>(scan.cloud->size()), 3);
  for (std::size_t i = 0; i < scan.cloud->size(); ++i)
    points.row(static_cast<Eigen::Index>(i)) << (*scan.cloud)[i].x, (*scan.cloud)[i].y, (*scan.cloud)[i].z;

  // A stored map's occupied voxels are the ICP target; a cloud's own points otherwise (mean hit
  // positions when 'iwlomap map --mean-positions' wrote them), read once for both uses.
  std::unique_ptr<IMapperBackend> map;
  std::optional<registration::ScanMatcher> matcher;
  if (is_map_path(*map_path)) {
    map = open_map(*map_path);
    matcher.emplace(*map, options);
  } else {
    const LoadedCloud cloud = load_cloud(*map_path, 0.9f);
    map = map_from_voxel_cloud(cloud, *map_path, resolution);
    Eigen::MatrixXd surface(static_cast<Eigen::Index>(cloud.cloud->size()), 3);
    for (std::size_t i = 0; i < cloud.cloud->size(); ++i)
      surface.row(static_cast<Eigen::Index>(i)) << (*cloud.cloud)[i].x, (*cloud.cloud)[i].y, (*cloud.cloud)[i].z;
    matcher.emplace(*map, surface, options);
  }
  const registration::ScanMatchResult r = matcher->match(points, initial);
  const Eigen::Quaterniond q(r.pose.linear());
  std::printf("score %.6f\nrmse %.6f\niterations %d\nconverged %s\n", r.score, r.fitness_rmse, r.iterations,
              r.converged ? "yes" : "no");
  std::printf("pose %.6f %.6f %.6f %.9f %.9f %.9f %.9f\n", r.pose.translation().x(), r.pose.translation().y(),
              r.pose.translation().z(), q.w(), q.x(), q.y(), q.z());
  std::fflush(stdout);
  if (!r.converged) {
    std::cerr << "iwlomap register: not converged: " << r.reason << "\n";
    return 1;
  }
  return 0;
#endif
}

}  // namespace iwlomap::tool
