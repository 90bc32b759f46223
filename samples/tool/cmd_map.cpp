// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap map`: integrate clouds into one map and write its occupied voxels.

#include "args.h"
#include "cloud_io.h"
#include "commands.h"
#include "map_options.h"
#include "map_outputs.h"
#include "progress.h"

#include <iwlomap/async_mapper.h>
#include <iwlomap/filters/cloud_conversions.h>
#include <iwlomap/voxel_colors.h>

#ifdef IWLOMAP_HAVE_REGISTRATION
#include "registration_options.h"

#include <iwlomap/registration/registered_mapper.h>
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
  value_opts.insert({"-o", "--output", "--octomap", "--snapshot"});
  auto flag_opts = map_flag_options();
  flag_opts.insert({"-h", "--help", "-q", "--quiet", "--async", "--mean-positions", "--no-colors", "--register", "--mpi", "--split-points"});
#ifdef IWLOMAP_HAVE_REGISTRATION
  value_opts.merge(registration_value_options());
  flag_opts.merge(registration_flag_options());
#endif
  const Args args(argv, value_opts, flag_opts);
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp << map_outputs_help() << map_options_help() << "  -q, --quiet               no summary, no progress bar\n";
#ifdef IWLOMAP_HAVE_REGISTRATION
    std::cout << registration_options_help();
#endif
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
  OutputFiles files;
  if (output) files.add("-o", *output, {".pcd", ".ply"});
  const MapOutputs extra = map_outputs_from(args, files);

  const MapSetup setup = map_setup_from(args);
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
  std::size_t registered_files = 0;
  std::vector<std::string> corrections;
  const auto started = std::chrono::steady_clock::now();
  std::size_t points = 0;
  {
    Progress progress("mapping", inputs.size(), !quiet);
    IntensityWarning warning("map");
    std::optional<AsyncMapper> background;
    if (async) background.emplace(setup.map, ExecutionMode::kParallel, 2);
#ifdef IWLOMAP_HAVE_REGISTRATION
    std::optional<registration::RegisteredMapper> registered;
    if (register_scans) {
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
      Eigen::Vector3d origin = in.cloud->sensor_origin_.head<3>().cast<double>();
      Eigen::MatrixXd xyz;
      Eigen::VectorXd intensity;
      if (background || (in.colors && keep_colors) || registered)
        cloud_to_matrices(*in.cloud, nullptr, setup.params.intensity_max, xyz, intensity);
#ifdef IWLOMAP_HAVE_REGISTRATION
      if (registered) {
        // The file's points are in the map frame at its VIEWPOINT pose: back to the sensor frame,
        // registered, integrated at the corrected pose (which the colours below then use).
        Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
        pose.linear() = in.cloud->sensor_orientation_.cast<double>().normalized().toRotationMatrix();
        pose.translation() = origin;
        const Eigen::MatrixXd sensor = (xyz.rowwise() - origin.transpose()) * pose.linear();
        registered->integrate(pose, sensor, intensity);
        const registration::RegisteredScan r = registered->sync().front();
        if (r.registered) ++registered_files;
        corrections.push_back(name + ": " + (r.registered ? "registered" : r.match.reason.empty() ? "first scan, as given" : "not registered (" + r.match.reason + ")") +
                              ", moved " + metres((r.integrated_pose.translation() - origin).norm()));
        origin = r.integrated_pose.translation();
        xyz = (sensor * r.integrated_pose.linear().transpose()).rowwise() + origin.transpose();
      }
#endif
      if (in.colors && keep_colors) {
        // The hits the map counts, so a voxel's colour is that of the points that made it occupied.
        if (!colors) colors.emplace(setup.map->get_resolution());
        if (setup.ray_casting)
          colors->add_scan(origin, xyz, intensity, *in.colors, setup.map->get_params(), setup.max_range);
        else
          colors->add_observations(xyz, intensity, std::vector<bool>(static_cast<std::size_t>(xyz.rows()), true),
                                   *in.colors, setup.map->get_params());
      }
      if (background)
        background->integrate(origin, std::move(xyz), std::move(intensity), setup.max_range);
      else if (!registered)  // (a registered file went in above)
        integrate_cloud(*setup.map, *in.cloud, nullptr, setup.ray_casting, setup.max_range);
      progress.update(i + 1, name);
    }
    if (background) background->sync();
  }
  if (const std::size_t skipped = setup.map->get_num_skipped_points(); skipped > 0)
    warn_skipped_points("map", skipped, points, setup.map->get_resolution(), setup.ray_casting);
  // A disk map is complete and durable before any output describes it: a failing final flush
  // fails the run before an output is written.
  setup.map->flush();
  show_status(!quiet, "writing the outputs");
  const double threshold = setup.params.occupied_threshold;
  const Eigen::MatrixXd voxels =
      mean_positions ? setup.map->get_occupied_mean_positions(threshold) : setup.map->get_occupied_voxels(threshold);
  pcl::PointCloud<pcl::PointXYZI> occupied;
  voxels_to_cloud(voxels, occupied);
  std::size_t coloured = 0;
  if (colors)
    for (Eigen::Index i = 0; i < voxels.rows(); ++i) coloured += colors->hits(voxels.row(i).head<3>().transpose()) > 0;
  if (output && colors)
    save_cloud(files.temporary(*output), occupied, colors->colors_at(voxels), *output);
  else if (output)
    save_cloud(files.temporary(*output), occupied, *output);
  write_map_outputs(extra, files, *setup.map, threshold, colors ? &*colors : nullptr);
  files.commit();
  show_status(!quiet, "");
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  if (!quiet) {
    std::cout << "mapped " << inputs.size() << " file(s), " << points << " points ("
              << setup.map->get_num_skipped_points() << " skipped) at " << setup.map->get_resolution() << " m, "
              << setup.map->get_backend_type() << " backend, " << sensor_preset_name(setup.sensor)
              << " preset: " << setup.map->get_num_nodes() << " known voxels, "
              << occupied.size() << " occupied (p > " << threshold << ")"
              << (colors ? ", " + std::to_string(coloured) + " of them coloured" : std::string()) << " in " << seconds
              << " s\n";
    if (register_scans) {
      std::cout << "registered " << registered_files << " of " << inputs.size() << " file(s)\n";
      for (const std::string& c : corrections) std::cout << "  " << c << "\n";
    }
    for (const std::string& written : files.paths()) std::cout << "wrote " << written << "\n";
  }
  return 0;
}

}  // namespace iwlomap::tool
