// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap map --mpi`: the map command on the ranks of an MPI job (iwlomap::mpi::DistributedMapper).

#include "args.h"
#include "cloud_io.h"
#include "commands.h"
#include "map_options.h"
#include "map_outputs.h"
#include "output_files.h"
#include "progress.h"

#include <iwlomap/filters/cloud_conversions.h>
#include <iwlomap/mpi/distributed_mapper.h>

#include <chrono>
#include <exception>
#include <cstdint>
#include <filesystem>
#include <iostream>
#include <optional>

namespace iwlomap::tool {

namespace {

// MPI is initialised here (the tool without --mpi never touches it) and finalised on return.
class MpiSession {
 public:
  MpiSession() {
    int initialised = 0;
    MPI_Initialized(&initialised);
    if (!initialised) MPI_Init(nullptr, nullptr);
  }
  ~MpiSession() {
    int finalised = 0;
    MPI_Finalized(&finalised);
    if (!finalised) MPI_Finalize();
  }
  MpiSession(const MpiSession&) = delete;
  MpiSession& operator=(const MpiSession&) = delete;
};

}  // namespace

int run_map_mpi(const Args& args, const std::vector<std::string>& inputs, const std::optional<std::string>& output,
                bool quiet) {
  for (const char* refused : {"--async", "--register", "--mean-positions", "--no-rays"})
    if (args.has(refused)) throw UsageError(std::string(refused) + " is not available with --mpi");
  MpiSession session;
  int rank = 0;
  int ranks = 1;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  MPI_Comm_size(MPI_COMM_WORLD, &ranks);
  // A rank that fails on its own (a file it cannot read, an output it cannot write) ends the job:
  // the others would wait for it forever. mpirun reports the abort.
  try {
    const MapSetup setup = map_setup_from(args, SensorPreset::kLidar, std::nullopt, /*open_map=*/false);
    if (setup.backend == "octomap") throw UsageError("--mpi maps on ram or disk shards, not octomap");
    mpi::DistributedOptions options;
    options.backend = setup.backend;
    options.threads = std::max(1, setup.threads);
    options.rays = setup.rays;
    double resolution = setup.resolution;
    if (setup.backend == "disk") {
      options.directory = setup.backend_options.directory;
      options.cache_tiles = setup.backend_options.cache_tiles;
      options.tile_size = args.has("--tile-size") ? setup.backend_options.tile_size : 0.0;  // 0: the default
      // A distributed map continues with its stored geometry unless the options say otherwise.
      std::error_code ec;
      if (std::filesystem::exists(std::filesystem::path(options.directory) / mpi::kManifestName, ec)) {
        const mpi::DistributedManifest m = mpi::read_manifest(options.directory);
        if (!args.has("--resolution")) resolution = m.resolution;
        if (!args.has("--tile-size")) options.tile_size = m.tile_size;
      }
    }
    // The outputs are rank 0's: it checks them before any work, and every rank learns the verdict
    // (a rank 0 that stopped alone would leave the others waiting in the first collective call).
    OutputFiles files(args);
    MapOutputs extra;
    int verdict = 0;  // 0 ok, else the exit code
    std::exception_ptr failure;
    if (rank == 0) {
      try {
        if (output) files.add("-o", *output, {".pcd", ".ply"});
        extra = map_outputs_from(args, files);
      } catch (const UsageError&) {
        failure = std::current_exception();
        verdict = 2;
      } catch (const std::exception&) {
        failure = std::current_exception();
        verdict = 1;
      }
    }
    MPI_Bcast(&verdict, 1, MPI_INT, 0, MPI_COMM_WORLD);
    if (verdict != 0) {
      if (rank == 0) std::rethrow_exception(failure);
      return verdict;
    }
    const bool whole_map = args.has("--octomap") || args.has("--snapshot");

    const auto started = std::chrono::steady_clock::now();
    mpi::DistributedMapper map(MPI_COMM_WORLD, resolution, setup.params, options);
    std::uint64_t points = 0;
    const bool split_points = args.flag("--split-points");
    if (split_points) {
      // Every file by all ranks together, each casting its share of the points (one scan per round).
      Progress progress("mapping (" + std::to_string(ranks) + " ranks, points split)", inputs.size(), !quiet && rank == 0);
      for (std::size_t i = 0; i < inputs.size(); ++i) {
        const LoadedCloud in = load_cloud(inputs[i], static_cast<float>(setup.params.intensity_max));
        Eigen::MatrixXd xyz;
        Eigen::VectorXd intensity;
        cloud_to_matrices(*in.cloud, nullptr, setup.params.intensity_max, xyz, intensity);
        const Eigen::Index n = xyz.rows();
        const Eigen::Index begin = n * rank / ranks, end = n * (rank + 1) / ranks;
        if (rank == 0) points += static_cast<std::uint64_t>(n);
        map.insert_scan_part(in.cloud->sensor_origin_.head<3>().cast<double>(), xyz.middleRows(begin, end - begin),
                             intensity.segment(begin, end - begin), setup.max_range);
        progress.update(i + 1);
      }
    } else {
      // Round robin: file i on rank i mod N in round i / N, so the map keeps the files' order.
      const std::size_t rounds = (inputs.size() + static_cast<std::size_t>(ranks) - 1) / static_cast<std::size_t>(ranks);
      Progress progress("mapping (" + std::to_string(ranks) + " ranks)", inputs.size(), !quiet && rank == 0);
      for (std::size_t round = 0; round < rounds; ++round) {
        const std::size_t i = round * static_cast<std::size_t>(ranks) + static_cast<std::size_t>(rank);
        if (i < inputs.size()) {
          const LoadedCloud in = load_cloud(inputs[i], static_cast<float>(setup.params.intensity_max));
          points += in.cloud->size();
          Eigen::MatrixXd xyz;
          Eigen::VectorXd intensity;
          cloud_to_matrices(*in.cloud, nullptr, setup.params.intensity_max, xyz, intensity);
          map.insert_scan(in.cloud->sensor_origin_.head<3>().cast<double>(), xyz, intensity, setup.max_range);
        } else {
          map.pass();
        }
        progress.update(std::min(inputs.size(), (round + 1) * static_cast<std::size_t>(ranks)));
      }
    }
    map.flush();
    const double threshold = setup.params.occupied_threshold;
    const Eigen::MatrixXd voxels = map.gather_occupied_voxels(threshold, 0);
    // --octomap and --snapshot: the whole map gathered on rank 0 into a RAM map (its log-odds).
    const auto gathered = whole_map ? map.gather_voxels(0) : std::vector<std::pair<VoxelKey, VoxelState>>{};
    const std::size_t known = map.num_nodes();
    const std::size_t skipped = map.num_skipped_points();
    std::uint64_t all_points = 0, sent = 0;
    const std::uint64_t mine_sent = map.stats().bytes_sent;
    MPI_Reduce(&points, &all_points, 1, MPI_UINT64_T, MPI_SUM, 0, MPI_COMM_WORLD);
    MPI_Reduce(&mine_sent, &sent, 1, MPI_UINT64_T, MPI_SUM, 0, MPI_COMM_WORLD);
    if (rank != 0) return 0;
    if (skipped > 0) warn_skipped_points("map", skipped, static_cast<std::size_t>(all_points), resolution, true);
    if (output) {
      pcl::PointCloud<pcl::PointXYZI> occupied;
      voxels_to_cloud(voxels, occupied);
      save_cloud(files.temporary(*output), occupied, *output, MapCloudInfo{resolution, false});
    }
    if (whole_map) {
      const auto whole = make_backend("RAM", resolution);
      whole->set_params(setup.params);
      Eigen::MatrixXd centres(static_cast<Eigen::Index>(gathered.size()), 3);
      Eigen::VectorXd log_odds(static_cast<Eigen::Index>(gathered.size()));
      for (std::size_t i = 0; i < gathered.size(); ++i) {
        centres.row(static_cast<Eigen::Index>(i)) = key_to_center(gathered[i].first, resolution).transpose();
        log_odds[static_cast<Eigen::Index>(i)] = gathered[i].second.log_odds;
      }
      whole->set_log_odds(centres, log_odds);
      write_map_outputs(extra, files, *whole, threshold);
    }
    files.commit();
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
    if (!quiet) {
      std::cout << "mapped " << inputs.size() << " file(s), " << all_points << " points (" << skipped << " skipped) at "
                << resolution << " m on " << ranks << " rank(s), " << (setup.backend == "disk" ? "Disk" : "RAM")
                << " shards of " << map.tile_voxels() << " voxels, " << sensor_preset_name(setup.sensor)
                << " preset: " << known << " known voxels, " << voxels.rows() << " occupied (p > " << threshold
                << "); " << sent << " bytes of observations sent between ranks, in " << seconds << " s\n";
      for (const std::string& written : files.paths()) std::cout << "wrote " << written << "\n";
    }
    return 0;
  } catch (const UsageError&) {
    // Every rank reads the same options, so every rank is here: rank 0 reports it.
    if (rank == 0) throw;
    return 2;
  } catch (const mpi::DistributedError&) {
    // Every rank has it (naming the rank that failed): rank 0 reports it.
    if (rank == 0) throw;
    return 1;
  } catch (const std::exception& e) {
    if (ranks == 1) throw;
    std::cerr << "iwlomap map: rank " << rank << ": error: " << e.what() << "\n";
    MPI_Abort(MPI_COMM_WORLD, 1);
  }
  return 1;
}

}  // namespace iwlomap::tool
