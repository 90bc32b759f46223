// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap sonar`: map the pings of Oculus .raw files into one IWLO map and write its occupied voxels.

#include "args.h"
#include "cloud_io.h"
#include "commands.h"
#include "map_options.h"
#include "map_outputs.h"
#include "output_files.h"
#include "progress.h"

#include <iwlomap/filters/cloud_conversions.h>
#include <iwlomap/oculus_reader.h>
#include <iwlomap/sonar_image_projector.h>
#include <iwlomap/sonar_preset.h>

#ifdef IWLOMAP_HAVE_REGISTRATION
#include <iwlomap/registration/registered_sonar_mapper.h>
#endif
#ifdef IWLOMAP_HAVE_SLAM
#include <iwlomap/slam/sonar_pose_graph_mapper.h>
#endif

#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <fstream>
#include <iostream>
#include <optional>
#include <sstream>
#include <stdexcept>

namespace iwlomap::tool {

namespace {

constexpr double kPi = 3.14159265358979323846;

const char* kHelp = R"(usage: iwlomap sonar PINGS.raw... -o OUT.pcd|OUT.ply [--poses POSES.txt] [options]

Maps imaging-sonar pings into one IWLO occupancy map and writes the occupied voxels (voxel
centres, intensity = occupancy probability). PINGS.raw are files of Oculus SimplePingResult (v1)
messages; their pings are taken in file order. Each ping becomes one observation per voxel: per
beam, free space up to the first echo above --intensity-threshold beyond --min-range, spread over
the vertical aperture, and an occupied arc (plus --band metres) at the echo.

Sonar frame: +X forward, +Y right (positive bearings), +Z down.

output:
  -o, --output FILE         occupied voxels as .pcd or .ply (binary)
  -q, --quiet               no summary, no progress bar

poses:
  --poses FILE              one sonar pose (sonar frame to map frame) per ping, in ping order;
                            without it every ping is at the origin, in the sonar frame. One pose
                            per line ('#' starts a comment, blank lines are skipped), either
                              x y z roll pitch yaw         metres and degrees, R = Rz(yaw) Ry(pitch) Rx(roll)
                              x y z qw qx qy qz            metres and a unit quaternion
                              r11 r12 r13 x r21 r22 r23 y r31 r32 r33 z   a 3x4 row-major [R|t] (KITTI)

sonar:
  --aperture DEG            vertical aperture of the beams in degrees (default 20; the file does
                            not record it: Oculus M-series heads have 12-20 degrees)
  --min-range M             no evidence closer than M metres (default 0)
  --max-range M             no evidence beyond M metres (> 0; default and 'none': each ping's
                            range setting)
  --stride V                range step of the samples along a beam, in voxels (default 0.5)
  --elevation-spacing V     spacing of the samples across the aperture, in voxels (default 1)
  --band M                  length of the occupied band after the first echo, metres (default 0)
  --detector NAME           how a beam's first echo is found: threshold (default: the first bin
                            above --intensity-threshold), ca-cfar or os-cfar (the first bin
                            whose power exceeds the noise level of the 16 bins before it, 2 guard
                            bins apart, by the factor for --false-alarm-rate; cell averaging or
                            ordered statistic; the bin must also exceed --intensity-threshold)
  --false-alarm-rate P      CFAR: probability that a bin of noise alone is an echo (default 0.001)
  --no-return free|nothing  a beam without echo: free water up to the max range (default), or
                            no evidence
  --sonar-preset            the sonar preset (include/iwlomap/sonar_preset.h, docs/accuracy.md)
                            instead of the reference defaults: --detector os-cfar, each echo
                            weighted by its strength over the CFAR threshold (0.5 at the
                            threshold, 0.88 at 11 dB above it), and the map's --sharpness 0
                            --l-occ 3 --l-free -0.8 --decay-rate 0 --min-alpha 1 --l-min -2
                            --l-max 3.5 --threshold 0.8: a weak echo seen once is not occupied.
                            Options given override it (--detector threshold also turns the SNR
                            weight off).
  --intensity-threshold I is both the echo threshold of the projection and the map's threshold.
  --no-rays and --rays do not apply: a sonar ping is always projected as above.

registration (corrects drifting navigation poses against the map):
  --register                gather the pings into submaps (built at their --poses), register each
                            against the map so far (x, y and yaw by point-to-plane ICP; depth,
                            roll and pitch as given) and integrate its pings at the corrected
                            poses. It works best against a map of an earlier survey: continue one
                            with --backend disk --tiles DIR. Against the map a survey builds
                            itself it rarely finds a fit it can trust (docs/accuracy.md), and
                            then keeps the poses as given.
  --loop-closure            with --register, for a survey that revisits its own lines (a leg
                            run again with the same heading): no registration against the map
                            so far; instead each submap (also cut where the heading turns by
                            more than 30 degrees) is matched against the older pings of the same
                            seabed (branch and bound in +-2 m and +-5 degrees, then ICP), the
                            matches found join a pose graph over the submaps with the
                            navigation's motion (solved with Ceres, a robust loss for the
                            matches), and every ping is then mapped at its corrected pose
                            (docs/slam.md). The map given (--tiles) is continued, not matched.
  --submap-pings K          pings per submap (default 80; aim at about 8 m of travel)
  --write-poses FILE.txt    the pose each ping was integrated at, one per line, as
                            x y z qw qx qy qz (a --poses format)

A --snapshot shows the sonar's track; when the sonar's +z (down) points along the map's +z on
average (an NED frame, or no --poses), the map's z is depth: the picture puts the surface on top
and colours by depth.
)";

// One pose per non-empty line; see kHelp for the three accepted forms.
std::vector<Eigen::Isometry3d> read_poses(const std::string& path) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot open the pose file " + path);
  std::vector<Eigen::Isometry3d> poses;
  std::string line;
  for (int number = 1; std::getline(in, line); ++number) {
    if (const auto hash = line.find('#'); hash != std::string::npos) line.erase(hash);
    std::istringstream s(line);
    std::vector<double> v;
    std::string word;
    while (s >> word) {
      char* end = nullptr;
      const double d = std::strtod(word.c_str(), &end);
      if (end != word.c_str() + word.size() || !std::isfinite(d))
        throw std::runtime_error(path + ":" + std::to_string(number) + ": '" + word + "' is not a finite number");
      v.push_back(d);
    }
    if (v.empty()) continue;
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    if (v.size() == 6) {
      const double deg = kPi / 180.0;
      pose.linear() = (Eigen::AngleAxisd(v[5] * deg, Eigen::Vector3d::UnitZ()) *
                       Eigen::AngleAxisd(v[4] * deg, Eigen::Vector3d::UnitY()) *
                       Eigen::AngleAxisd(v[3] * deg, Eigen::Vector3d::UnitX()))
                          .toRotationMatrix();
      pose.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
    } else if (v.size() == 7) {
      const Eigen::Quaterniond q(v[3], v[4], v[5], v[6]);
      if (std::abs(q.norm() - 1.0) > 1e-3)
        throw std::runtime_error(path + ":" + std::to_string(number) + ": the quaternion's norm is " +
                                 shortest(q.norm()) + ", not 1");
      pose.linear() = q.normalized().toRotationMatrix();
      pose.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
    } else if (v.size() == 12) {
      Eigen::Matrix3d r;
      r << v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10];
      if ((r.transpose() * r - Eigen::Matrix3d::Identity()).norm() > 1e-3 || r.determinant() < 0.0)
        throw std::runtime_error(path + ":" + std::to_string(number) + ": the 3x3 part is not a rotation");
      pose.linear() = r;
      pose.translation() = Eigen::Vector3d(v[3], v[7], v[11]);
    } else {
      throw std::runtime_error(path + ":" + std::to_string(number) + ": " + std::to_string(v.size()) +
                               " numbers; a pose has 6 (x y z roll pitch yaw), 7 (x y z qw qx qy qz) or 12 (3x4 [R|t])");
    }
    poses.push_back(pose);
  }
  return poses;
}

}  // namespace

int run_sonar(const std::vector<std::string>& argv) {
  auto value_opts = map_value_options();
  value_opts.insert({"-o", "--output", "--octomap", "--snapshot", "--poses", "--aperture", "--min-range", "--stride", "--elevation-spacing",
                     "--band", "--no-return", "--submap-pings", "--write-poses", "--detector",
                     "--false-alarm-rate"});
  value_opts.erase("--rays");  // a ping is projected, not cast as rays
  auto flag_opts = map_flag_options();
  flag_opts.erase("--no-rays");
  flag_opts.insert({"-h", "--help", "-q", "--quiet", "--register", "--loop-closure", "--sonar-preset"});
  const Args args(argv, value_opts, flag_opts);
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp << map_outputs_help() << map_options_help(/*rays=*/false, SensorPreset::kSonar);
    return 0;
  }
  const auto& inputs = args.positional();
  if (inputs.empty()) throw UsageError("no input file (PINGS.raw)");
  const auto output = args.value("-o") ? args.value("-o") : args.value("--output");
  if (!output) throw UsageError("no output file (-o OUT.pcd)");
  OutputFiles files(args);
  files.add("-o", *output, {".pcd", ".ply"});
  const MapOutputs extra = map_outputs_from(args, files);
  const bool quiet = args.flag("-q") || args.flag("--quiet");
  const auto poses_out = args.value("--write-poses");
  if (poses_out) files.add("--write-poses", *poses_out, {".txt"});
  const bool register_pings = args.flag("--register");
  const long submap_pings = args.integer("--submap-pings", 80);
  if (submap_pings < 1) throw UsageError("--submap-pings must be >= 1, got " + std::to_string(submap_pings));
  if (args.value("--submap-pings") && !register_pings) throw UsageError("--submap-pings needs --register");
#ifndef IWLOMAP_HAVE_REGISTRATION
  if (register_pings) throw std::runtime_error("--register: this build has no registration layer (IWLOMAP_WITH_REGISTRATION)");
#endif
  const bool loop_closure = args.flag("--loop-closure");
  if (loop_closure && !register_pings) throw UsageError("--loop-closure needs --register");
#ifndef IWLOMAP_HAVE_SLAM
  if (loop_closure)
    throw std::runtime_error("--loop-closure: this build has no SLAM layer (IWLOMAP_WITH_SLAM, Debian: libceres-dev)");
#endif

  const bool use_preset = args.flag("--sonar-preset");
  if (use_preset && args.has("--sensor"))
    throw UsageError("--sonar-preset sets the map's parameters: leave out --sensor (the IWLO options still apply)");
  // --intensity-threshold and the other IWLO options apply over the preset in map_setup_from().
  const SonarPreset preset = sonar_preset();
  const MapSetup setup = use_preset ? map_setup_from(args, SensorPreset::kSonar, preset.map)
                                    : map_setup_from(args, SensorPreset::kSonar);
  MapCommit commit(setup.map);
  SonarProjectorParams params = use_preset ? preset.projector : SonarProjectorParams{};
  params.intensity_threshold = setup.params.intensity_threshold;
  params.free_sample_stride = args.number("--stride", params.free_sample_stride);
  params.elevation_sample_spacing = args.number("--elevation-spacing", params.elevation_sample_spacing);
  params.occupied_band = args.number("--band", params.occupied_band);
  const std::string no_return = args.value("--no-return").value_or("free");
  if (no_return == "free")
    params.no_return = SonarNoReturn::kFreeToMaxRange;
  else if (no_return == "nothing")
    params.no_return = SonarNoReturn::kNothing;
  else
    throw UsageError("--no-return must be free or nothing, got '" + no_return + "'");
  const std::string detector = args.value("--detector").value_or(use_preset ? "os-cfar" : "threshold");
  if (detector == "threshold")
    params.detector = SonarDetector::kThreshold;
  else if (detector == "ca-cfar")
    params.detector = SonarDetector::kCellAveragingCfar;
  else if (detector == "os-cfar")
    params.detector = SonarDetector::kOrderedStatisticCfar;
  else
    throw UsageError("--detector must be threshold, ca-cfar or os-cfar, got '" + detector + "'");
  // The SNR weight measures echoes against the CFAR threshold: a fixed threshold has none.
  if (params.detector == SonarDetector::kThreshold) params.snr_weight.enabled = false;
  params.cfar.false_alarm_rate = args.number("--false-alarm-rate", params.cfar.false_alarm_rate);
  if (args.value("--false-alarm-rate") && params.detector == SonarDetector::kThreshold)
    throw UsageError("--false-alarm-rate needs --detector ca-cfar or os-cfar");
  const double aperture_deg = args.number("--aperture", 20.0);
  if (!(aperture_deg >= 0.0 && aperture_deg < 180.0))
    throw UsageError("--aperture must be in [0, 180) degrees, got " + shortest(aperture_deg));
  const double min_range = args.number("--min-range", 0.0);
  // "none" (or no option): each ping's own range; 0 or a negative value is a mistake.
  const std::optional<double> max_range = args.positive_or_none("--max-range");
  std::optional<SonarImageProjector> projector;
  try {
    projector.emplace(setup.map->get_resolution(), params);
  } catch (const std::invalid_argument& e) {
    throw UsageError(e.what());
  }

  const auto started = std::chrono::steady_clock::now();
  std::vector<OculusPing> pings;
  for (const std::string& input : inputs) {
    std::vector<OculusPing> more = read_oculus_pings(input);
    for (OculusPing& p : more) pings.push_back(std::move(p));
  }
  std::vector<Eigen::Isometry3d> poses(pings.size(), Eigen::Isometry3d::Identity());
  if (const auto pose_file = args.value("--poses")) {
    poses = read_poses(*pose_file);
    if (poses.size() != pings.size())
      throw std::runtime_error(*pose_file + " has " + std::to_string(poses.size()) + " poses for " +
                               std::to_string(pings.size()) + " pings; one pose per ping is needed");
  }

  std::size_t observations = 0, with_return = 0, beams = 0;
  std::vector<Eigen::Isometry3d> integrated = poses;  // where each ping went into the map
  std::string registration_summary;
#ifdef IWLOMAP_HAVE_SLAM
  std::optional<slam::SonarPoseGraphMapper> closing;
  if (loop_closure) {
    slam::SonarPoseGraphMapperOptions so;
    so.pings_per_submap = static_cast<int>(std::min<long>(submap_pings, 1L << 30));
    closing.emplace(setup.map, *projector, so);
  }
#endif
  {
    Progress progress(loop_closure ? "matching submaps" : "mapping", pings.size(), !quiet);
#ifdef IWLOMAP_HAVE_REGISTRATION
    std::optional<registration::RegisteredSonarMapper> registered;
    if (register_pings && !loop_closure) {
      registration::RegisteredSonarMapperOptions ro;
      ro.pings_per_submap = static_cast<int>(std::min<long>(submap_pings, 1L << 30));
      registered.emplace(setup.map, *projector, ExecutionMode::kSequential, ro);
    }
#endif
    for (std::size_t i = 0; i < pings.size(); ++i) {
      const OculusPing& ping = pings[i];
      SonarGeometry geometry = ping.geometry(aperture_deg * kPi / 180.0, min_range);
      if (max_range) geometry.max_range = *max_range;
#ifdef IWLOMAP_HAVE_SLAM
      if (closing) {
        closing->integrate(poses[i], ping.image_view(), geometry);
        progress.update(i + 1, "ping " + std::to_string(ping.ping_id));
        continue;
      }
#endif
#ifdef IWLOMAP_HAVE_REGISTRATION
      if (registered) {
        registered->integrate(poses[i], ping.image_view(), geometry);
        progress.update(i + 1, "ping " + std::to_string(ping.ping_id));
        continue;
      }
#endif
      const SonarObservations obs = projector->integrate(*setup.map, ping.image_view(), geometry, poses[i]);
      observations += obs.size();
      with_return += obs.beams_with_return;
      beams += obs.beams_with_return + obs.beams_without_return;
      progress.update(i + 1, "ping " + std::to_string(ping.ping_id));
    }
#ifdef IWLOMAP_HAVE_REGISTRATION
    if (registered) {
      std::size_t count = 0, accepted = 0;
      for (const registration::RegisteredSubmap& submap : registered->sync()) {
        ++count;
        accepted += submap.registered ? 1 : 0;
        for (std::size_t k = 0; k < submap.pings; ++k) integrated[submap.first_ping + k] = submap.integrated_poses[k];
        observations += submap.observations;
        with_return += submap.beams_with_return;
        beams += submap.beams_with_return + submap.beams_without_return;
      }
      registration_summary = "registered " + std::to_string(accepted) + " of " + std::to_string(count) + " submap(s)" +
                             (accepted < count ? "; the others kept the last correction" : "");
    }
#endif
  }
#ifdef IWLOMAP_HAVE_SLAM
  if (closing) {
    {
      Progress integrating("mapping at the corrected poses", pings.size(), !quiet);
      closing->finish([&](std::size_t done, std::size_t) { integrating.update(done); });
    }
    integrated = closing->poses();
    const slam::SonarSlamSummary sum = closing->summary();
    observations = sum.observations;
    with_return = sum.beams_with_return;
    beams = sum.beams_with_return + sum.beams_without_return;
    registration_summary = "loop closure: " + std::to_string(sum.submaps) + " submap(s), " +
                           std::to_string(sum.closures_found) + " closure(s) found, " +
                           std::to_string(sum.closures_refused) + " refused by the matcher, " +
                           std::to_string(sum.closures_rejected_by_optimizer) + " rejected by the optimizer";
  }
#endif
  // As `map`: the disk map's one commit, before any output describes it.
  commit.commit();
  if (poses_out) {
    files.write(*poses_out, [&](const std::string& file) {
      std::ofstream out(file);
      out.precision(17);
      out << "# x y z qw qx qy qz: the sonar pose (sonar frame to map frame) each ping was integrated at\n";
      for (const Eigen::Isometry3d& pose : integrated) {
        const Eigen::Quaterniond q(pose.linear());
        out << pose.translation().x() << ' ' << pose.translation().y() << ' ' << pose.translation().z() << ' '
            << q.w() << ' ' << q.x() << ' ' << q.y() << ' ' << q.z() << '\n';
      }
      if (!out.flush()) throw std::runtime_error("cannot write " + file);
    });
  }
  pcl::PointCloud<pcl::PointXYZI> occupied;
  occupied_to_cloud(*setup.map, setup.params.occupied_threshold, occupied);
  save_cloud(files.temporary(*output), occupied, *output, MapCloudInfo{setup.map->get_resolution(), false});
  // The snapshot: the sonar's track; the map's z is depth when the sonar's +z (down in its own
  // frame) points along the map's +z on average.
  SnapshotMarks marks;
  marks.sensor_positions = positions_of(integrated);
  double down = 0.0;
  for (const Eigen::Isometry3d& pose : integrated) down += pose.linear()(2, 2);
  marks.z_down = down > 0.0;
  write_map_outputs(extra, files, *setup.map, setup.params.occupied_threshold, nullptr, {}, marks);
  files.commit();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  if (!quiet) {
    std::cout << "mapped " << pings.size() << " ping(s) from " << inputs.size() << " file(s): " << with_return << " of "
              << beams << " beams with an echo, " << observations << " voxel observations at "
              << setup.map->get_resolution() << " m, " << setup.map->get_backend_type()
              << " backend: " << setup.map->get_num_known_voxels() << " known voxels, " << occupied.size()
              << " occupied (p > " << setup.params.occupied_threshold << ") in " << seconds << " s\n";
    if (!registration_summary.empty()) std::cout << registration_summary << "\n";
    for (const std::string& written : files.paths()) std::cout << "wrote " << written << "\n";
  }
  return 0;
}

}  // namespace iwlomap::tool
