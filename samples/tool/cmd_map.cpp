// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap map`: integrate clouds into one map and write its occupied voxels.

#include "args.h"
#include "cloud_io.h"
#include "commands.h"
#include "map_options.h"
#include "map_outputs.h"
#include "config_file.h"
#include "progress.h"

#include <iwlomap/async_mapper.h>
#include <iwlomap/filters/cloud_conversions.h>
#include <iwlomap/voxel_colors.h>

#include <iwlomap/trajectory_io.h>

#ifdef IWLOMAP_HAVE_REGISTRATION
#include "registration_options.h"

#include <iwlomap/registration/registered_mapper.h>
#endif
#ifdef IWLOMAP_HAVE_SLAM
#include <iwlomap/slam/pose_graph_mapper.h>
#endif

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <optional>
#include <vector>

namespace iwlomap::tool {

#ifdef IWLOMAP_HAVE_MPI
// cmd_map_mpi.cpp
int run_map_mpi(const Args& args, const std::vector<std::string>& inputs, const std::optional<std::string>& output,
                bool quiet);
#endif

namespace {

const char* kHelp = R"(usage: iwlomap map [options] INPUT... [-o OUT.pcd|OUT.ply]

Integrates the clouds INPUT... (.pcd or .ply, in this order) into one IWLO occupancy map and
writes the occupied voxels (voxel centres, intensity = occupancy probability). Points are taken
in the map frame as stored; each file's sensor origin (the PCD VIEWPOINT) is the ray origin.
A file without an intensity field gives every point the intensity --intensity-max. When an
input has colour (an rgb or rgba field; red, green, blue in a .ply), each occupied voxel gets the
mean colour of the hits that fell in it (counted as the map counts hits), written as an rgb field
beside the intensity and used by --snapshot; voxels hit only by uncoloured points are black.

output:
  -o, --output FILE         occupied voxels as .pcd or .ply (binary)
  --async                   read the next file while the previous one is integrated (a background
                            thread integrates; the map is the same)
  --mean-positions          write each occupied voxel at the mean position of the hits that fell
                            in it (sub-voxel surface estimate) instead of its centre; hit
                            statistics are gathered from this run on (every backend; a disk map
                            keeps them in its tiles)
  --no-colors               ignore the inputs' colours: no rgb field, the snapshot by height
  --register                register each file against the map so far before integrating it
                            (initial guess: its VIEWPOINT pose with the last correction; the
                            first file goes in as given); the summary lists the corrections
  --loop-closure            with --register: register each file against submaps of the files
                            before it, search older submaps for loop closures, optimize a pose
                            graph over all files (Ceres), then integrate every file at its
                            optimized pose; the summary names the closures found and refused
  --write-poses FILE        the sensor pose each file was integrated at: TUM (t x y z qx qy qz qw;
                            t = the cloud's stamp in seconds, or its index when it has none), or
                            KITTI (12 numbers a line) for a FILE ending in .kitti
  --mpi                     run on the ranks of an MPI job (mpirun -np N iwlomap map --mpi ...):
                            file i is read and ray-cast by rank i mod N, each voxel is updated by
                            the rank owning its tile, and the map equals the one-process map;
                            RAM shards are 8^3 blocks; with --backend disk, --tiles DIR holds one
                            map per rank (DIR/rank-K) and a manifest, in tiles of --tile-size
                            (default 6.4 m). Rank 0 writes the outputs (for --octomap and
                            --snapshot it gathers the whole map); --async, --register,
                            --mean-positions and --no-rays are not available, and colours are
                            not kept
  --split-points            with --mpi: every file is one round of all ranks, each casting its
                            1/N of the points (for few large files; each rank reads the whole
                            file); the map is the same
  --config FILE.yaml        read options from FILE: one 'option: value' line each, the options
                            below without their dashes ('resolution: 0.1', 'sensor: lidar',
                            'intensity-threshold: 35', flags as 'no-adaptive: true'); inputs,
                            outputs and --tiles stay on the command line, which wins over the file
  --print-config            print the effective configuration (the preset, every IWLO parameter,
                            resolution, max-range, backend, threads) as a --config file, and exit
)";

}  // namespace

// "0.023 m": three decimals, for the summary.
[[maybe_unused]] std::string metres(double m) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3f m", m);
  return buf;
}

int run_map(const std::vector<std::string>& argv) {
  auto value_opts = map_value_options();
  value_opts.insert({"-o", "--output", "--octomap", "--snapshot", "--write-poses"});
  auto flag_opts = map_flag_options();
  flag_opts.insert({"-h", "--help", "-q", "--quiet", "--async", "--mean-positions", "--no-colors", "--register",
                    "--loop-closure", "--mpi", "--split-points", "--print-config"});
  // What a --config file may set: the map's options, not inputs, outputs or other files.
  std::set<std::string> configurable = map_value_options();
  configurable.merge(map_flag_options());
  configurable.insert({"--mean-positions", "--no-colors", "--register", "--loop-closure"});
#ifdef IWLOMAP_HAVE_REGISTRATION
  value_opts.merge(registration_value_options());
  flag_opts.merge(registration_flag_options());
  for (const std::string& o : registration_value_options()) configurable.insert(o);
  for (const std::string& o : registration_flag_options()) configurable.insert(o);
#endif
  configurable.erase("--tiles");
  const Args args = args_with_config(argv, value_opts, flag_opts, configurable);
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp << map_outputs_help() << map_options_help(true, SensorPreset::kLidar) << "  -q, --quiet               no summary, no progress bar\n";
#ifdef IWLOMAP_HAVE_REGISTRATION
    std::cout << registration_options_help();
#endif
    return 0;
  }
  if (args.flag("--print-config")) {
    std::cout << config_yaml(map_setup_from(args, SensorPreset::kLidar, std::nullopt, /*open_map=*/false), "map");
    return 0;
  }
  const auto& inputs = args.positional();
  if (inputs.empty()) throw UsageError("no input file");
  const auto output = args.value("-o") ? args.value("-o") : args.value("--output");
  const bool quiet = args.flag("-q") || args.flag("--quiet");
  if (args.flag("--split-points") && !args.flag("--mpi")) throw UsageError("--split-points needs --mpi");
  if (args.flag("--mpi")) {
#ifdef IWLOMAP_HAVE_MPI
    return run_map_mpi(args, inputs, output, quiet);
#else
    throw std::runtime_error("--mpi: this build has no MPI layer (IWLOMAP_WITH_MPI, Debian: libopenmpi-dev)");
#endif
  }
  // Every output is checked before any work and written only when all of them can be.
  OutputFiles files(args);
  if (output) files.add("-o", *output, {".pcd", ".ply"});
  const auto poses_out = args.value("--write-poses");
  if (poses_out) files.add("--write-poses", *poses_out, {".txt", ".tum", ".kitti"});
  const MapOutputs extra = map_outputs_from(args, files);

  const MapSetup setup = map_setup_from(args, SensorPreset::kLidar);
  MapCommit commit(setup.map);
  const bool mean_positions = args.flag("--mean-positions");
  if (mean_positions) setup.map->set_hit_accumulation(true);
  const bool keep_colors = !args.flag("--no-colors");
  std::optional<VoxelColorMeans> colors;  // from the first coloured input on
  const bool async = args.flag("--async");
  if (async && !setup.ray_casting) throw UsageError("--async needs ray casting (drop --no-rays)");
  const bool register_scans = args.flag("--register");
  if (register_scans && (async || !setup.ray_casting))
    throw UsageError("--register needs ray casting and runs without --async");
#ifndef IWLOMAP_HAVE_REGISTRATION
  if (register_scans) throw std::runtime_error("--register: this build has no registration layer (IWLOMAP_WITH_REGISTRATION)");
#endif
  const bool loop_closure = args.flag("--loop-closure");
  if (loop_closure && !register_scans) throw UsageError("--loop-closure needs --register");
#ifndef IWLOMAP_HAVE_SLAM
  if (loop_closure)
    throw std::runtime_error("--loop-closure: this build has no SLAM layer (IWLOMAP_WITH_SLAM, Debian: libceres-dev)");
#endif
  std::size_t registered_files = 0;
  std::vector<std::string> corrections;
  std::vector<Eigen::Isometry3d> integrated_poses;  // per file, for --write-poses
  std::vector<double> stamps;
  bool all_stamped = true;
  const auto started = std::chrono::steady_clock::now();
  std::size_t points = 0;
  // With --loop-closure, a first pass finds every file's pose (registration against submaps, loop
  // closures, the pose graph); the second pass below integrates each file at its pose.
  std::vector<Eigen::Isometry3d> slam_poses;
  std::string closure_summary;
#ifdef IWLOMAP_HAVE_SLAM
  if (loop_closure) {
    slam::PoseGraphMapperOptions so;
    so.resolution = setup.map->get_resolution();
    so.params = setup.map->get_params();
    so.max_range = setup.max_range;
    so.rays = setup.rays;
    so.matcher = registration_options_from(args);
    so.closure_matcher.max_range = so.matcher.max_range;
    slam::PoseGraphMapper mapper(ExecutionMode::kParallel, so);
    Progress progress("registering", inputs.size(), !quiet);
    std::vector<slam::SlamScanReport> reports;
    std::vector<Eigen::Isometry3d> given;
    for (std::size_t i = 0; i < inputs.size(); ++i) {
      const std::string name = std::filesystem::path(inputs[i]).filename().string();
      progress.update(i, name);
      const LoadedCloud in = load_cloud(inputs[i], static_cast<float>(setup.params.intensity_max));
      Eigen::MatrixXd xyz;
      Eigen::VectorXd intensity;
      cloud_to_matrices(*in.cloud, nullptr, setup.params.intensity_max, xyz, intensity);
      const Eigen::Isometry3d pose = viewpoint_pose(*in.cloud);
      given.push_back(pose);
      reports.push_back(mapper.add_scan(pose, (xyz.rowwise() - pose.translation().transpose()) * pose.linear(), intensity));
      progress.update(i + 1, name);
    }
    show_status(!quiet, "optimizing the pose graph");
    // The poses only: the map is built from the files at these poses below, into the chosen backend.
    mapper.optimize();
    (void)mapper.write_map();
    slam_poses = mapper.poses();
    const slam::SlamSummary sum = mapper.summary();
    for (std::size_t i = 0; i < inputs.size(); ++i) {
      const slam::SlamScanReport& r = reports[i];
      if (r.registered) ++registered_files;
      corrections.push_back(std::filesystem::path(inputs[i]).filename().string() + ": " +
                            (r.registered ? "registered" : i == 0 ? "first scan, as given" : "not registered (" + r.reason + ")") +
                            ", moved " + metres((slam_poses[i].translation() - given[i].translation()).norm()));
    }
    std::size_t accepted = 0;
    for (const slam::LoopClosure& c : mapper.loop_closures()) accepted += c.rejected ? 0 : 1;
    closure_summary = "loop closures: " + std::to_string(sum.closure_attempts) + " searched, " +
                      std::to_string(sum.closures_found) + " found, " + std::to_string(sum.closures_refused_by_matcher) +
                      " refused by the match-quality model, " + std::to_string(sum.closures_rejected_by_optimizer) +
                      " rejected by the pose graph, " + std::to_string(accepted) + " kept";
    for (const slam::LoopClosure& c : mapper.loop_closures())
      closure_summary += "\n  " + std::filesystem::path(inputs[c.scan]).filename().string() + " to submap " +
                         std::to_string(c.submap) + " (from " +
                         std::filesystem::path(inputs[mapper.submap_first_scan(c.submap)]).filename().string() +
                         "): " + (c.rejected ? "rejected" : "kept");
  }
#endif
  {
    Progress progress("mapping", inputs.size(), !quiet);
    IntensityWarning warning("map");
    std::optional<AsyncMapper> background;
    if (async) background.emplace(setup.map, ExecutionMode::kParallel, 2);
#ifdef IWLOMAP_HAVE_REGISTRATION
    std::optional<registration::RegisteredMapper> registered;
    if (register_scans && !loop_closure) {
      registration::RegisteredMapperOptions ro;
      ro.matcher = registration_options_from(args);
      ro.max_range = setup.max_range;
      registered.emplace(setup.map, ExecutionMode::kSequential, ro);
    }
#else
    constexpr bool registered = false;
#endif
    for (std::size_t i = 0; i < inputs.size(); ++i) {
      const std::string name = std::filesystem::path(inputs[i]).filename().string();
      progress.update(i, name);
      const LoadedCloud in = load_cloud(inputs[i], static_cast<float>(setup.params.intensity_max));
      points += in.cloud->size();
      if (in.has_intensity) {
        Eigen::VectorXd intensity(static_cast<Eigen::Index>(in.cloud->size()));
        for (std::size_t k = 0; k < in.cloud->size(); ++k) intensity[static_cast<Eigen::Index>(k)] = (*in.cloud)[k].intensity;
        warning.check(inputs[i], intensity, setup.params);
      }
      Eigen::Isometry3d file_pose = viewpoint_pose(*in.cloud);
      Eigen::Vector3d origin = file_pose.translation();
      const std::uint64_t stamp = in.cloud->header.stamp;  // microseconds, PCL's convention
      stamps.push_back(stamp ? static_cast<double>(stamp) * 1e-6 : static_cast<double>(i));
      all_stamped = all_stamped && stamp != 0;
      Eigen::MatrixXd xyz;
      Eigen::VectorXd intensity;
      if (background || (in.colors && keep_colors) || registered || loop_closure)
        cloud_to_matrices(*in.cloud, nullptr, setup.params.intensity_max, xyz, intensity);
      if (loop_closure || registered) {
        // The file's points are in the map frame at its VIEWPOINT pose: back to the sensor frame,
        // then to the pose the pose graph gave it, or the registration finds (a registered file
        // goes into the map here; the colours below use the pose too).
        const Eigen::MatrixXd sensor = (xyz.rowwise() - origin.transpose()) * file_pose.linear();
        if (loop_closure) {
          file_pose = slam_poses[i];
        } else {
#ifdef IWLOMAP_HAVE_REGISTRATION
          registered->integrate(file_pose, sensor, intensity);
          const registration::RegisteredScan r = registered->sync().front();
          if (r.registered) ++registered_files;
          corrections.push_back(name + ": " + (r.registered ? "registered" : r.match.reason.empty() ? "first scan, as given" : "not registered (" + r.match.reason + ")") +
                                ", moved " + metres((r.integrated_pose.translation() - origin).norm()));
          file_pose = r.integrated_pose;
#endif
        }
        origin = file_pose.translation();
        xyz = (sensor * file_pose.linear().transpose()).rowwise() + origin.transpose();
      }
      integrated_poses.push_back(file_pose);
      if (in.colors && keep_colors) {
        // The hits the map counts, so a voxel's colour is that of the points that made it occupied.
        if (!colors) colors.emplace(setup.map->get_resolution());
        if (setup.ray_casting)
          colors->add_scan(origin, xyz, intensity, *in.colors, setup.map->get_params(), setup.max_range);
        else
          colors->add_observations(xyz, intensity, std::vector<bool>(static_cast<std::size_t>(xyz.rows()), true),
                                   *in.colors, setup.map->get_params());
      }
      // The bar moves within the file as its rays are cast and its voxels updated (not with
      // --async, whose scans go in on another thread).
      if (!background) setup.map->set_progress_callback(progress_within(progress, i, name));
      if (background)
        background->integrate(origin, std::move(xyz), std::move(intensity), setup.max_range);
      else if (loop_closure)
        setup.map->insert_scan(origin, xyz, intensity, setup.max_range);
      else if (!registered)  // (a registered file went in above)
        try {
          integrate_cloud(*setup.map, *in.cloud, nullptr, setup.ray_casting, setup.max_range);
        } catch (const std::invalid_argument& e) {  // the library's word on this file's data
          throw std::runtime_error("'" + inputs[i] + "': " + e.what());
        }
      setup.map->set_progress_callback({});
      progress.update(i + 1, name);
    }
    if (background) background->sync();
  }
  if (const std::size_t skipped = setup.map->get_num_skipped_points(); skipped > 0)
    warn_skipped_points("map", skipped, points, setup.map->get_resolution(), setup.ray_casting);
  // A disk map is complete and durable before any output describes it: a failing final flush
  // fails the run before an output is written (and leaves the map as it was).
  setup.map->set_progress_callback([quiet](const ProgressReport& r) {
    show_status(!quiet, "writing the map's tiles: " + std::to_string(r.done) + " of " + std::to_string(r.total));
  });
  commit.commit();
  setup.map->set_progress_callback({});
  const auto mapped = std::chrono::steady_clock::now();
  Progress writing("writing", static_cast<std::size_t>(output.has_value()) + map_outputs_count(extra) +
                                  static_cast<std::size_t>(poses_out.has_value()), !quiet);
  std::size_t written_items = 0;
  if (output) writing.update(written_items, std::filesystem::path(*output).filename().string());
  const double threshold = setup.params.occupied_threshold;
  const Eigen::MatrixXd voxels =
      mean_positions ? setup.map->get_occupied_mean_positions(threshold) : setup.map->get_occupied_voxels(threshold);
  pcl::PointCloud<pcl::PointXYZI> occupied;
  voxels_to_cloud(voxels, occupied);
  std::size_t coloured = 0;
  if (colors)
    for (Eigen::Index i = 0; i < voxels.rows(); ++i) coloured += colors->hits(voxels.row(i).head<3>().transpose()) > 0;
  const MapCloudInfo info{setup.map->get_resolution(), mean_positions};
  if (output && colors)
    save_cloud(files.temporary(*output), occupied, colors->colors_at(voxels), *output, info);
  else if (output)
    save_cloud(files.temporary(*output), occupied, *output, info);
  written_items += output ? 1 : 0;
  SnapshotMarks marks;  // each file's sensor position, joined in order
  marks.sensor_positions = positions_of(integrated_poses);
  written_items = write_map_outputs(extra, files, *setup.map, threshold, colors ? &*colors : nullptr,
                                    MapOutputsProgress{&writing, written_items}, marks);
  if (poses_out) {
    writing.update(written_items, std::filesystem::path(*poses_out).filename().string());
    write_trajectory(files.temporary(*poses_out), integrated_poses, all_stamped ? stamps : std::vector<double>{},
                     trajectory_format_of(*poses_out));
    ++written_items;
  }
  files.commit();
  writing.update(written_items);
  writing.finish();
  const double seconds = std::chrono::duration<double>(mapped - started).count();
  const double writing_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - mapped).count();
  if (!quiet) {
    std::cout << "mapped " << inputs.size() << " file(s), " << points << " points ("
              << setup.map->get_num_skipped_points() << " skipped) at " << setup.map->get_resolution() << " m, "
              << setup.map->get_backend_type() << " backend, " << sensor_preset_name(setup.sensor)
              << " preset: " << setup.map->get_num_known_voxels() << " known voxels, "
              << occupied.size() << " occupied (p > " << threshold << ")"
              << (colors ? ", " + std::to_string(coloured) + " of them coloured" : std::string()) << " in " << seconds
              << " s; outputs written in " << writing_seconds << " s\n";
    if (register_scans) {
      std::cout << "registered " << registered_files << " of " << inputs.size() << " file(s)\n";
      for (const std::string& c : corrections) std::cout << "  " << c << "\n";
      if (loop_closure) std::cout << closure_summary << "\n";
    }
    for (const std::string& written : files.paths()) std::cout << "wrote " << written << "\n";
  }
  return 0;
}

}  // namespace iwlomap::tool
