// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The map options shared by the tool's commands that build a map: backend, resolution, sensor
// preset and IWLO parameters.

#include "args.h"

#include <iwlomap/iwlo.h>
#include <iwlomap/mapper_backend.h>
#include <iwlomap/sensor_preset.h>

#include <cstddef>
#include <memory>
#include <optional>
#include <set>
#include <string>

namespace iwlomap::tool {

struct MapSetup {
  std::shared_ptr<IMapperBackend> map;
  IwloParams params;
  SensorPreset sensor = SensorPreset::kSonar;
  bool ray_casting = true;
  RayModel rays = RayModel::kExact;  // --rays
  double max_range = -1.0;
  std::size_t memory_limit = 0;  // bytes (set_map_memory_limit()); 0: none
  // What the options chose, for a caller that builds its own map (--mpi).
  std::string backend;            // "ram", "disk" or "octomap"
  BackendOptions backend_options;
  double resolution = 0.05;
  int threads = 1;
};

[[nodiscard]] std::set<std::string> map_value_options();
[[nodiscard]] std::set<std::string> map_flag_options();
/// Help lines for the map options; \p rays false leaves out --max-range and --no-rays (for
/// commands that cast no rays from points, as `sonar`, which gives --max-range its own meaning).
[[nodiscard]] std::string map_options_help(bool rays, SensorPreset default_sensor);

/// The --max-memory default: 3/4 of the physical memory, or half of the address space left under
/// RLIMIT_AS when that is less.
[[nodiscard]] std::size_t default_memory_limit();
/// When \p bytes pass default_memory_limit(): "about X GB, more than the memory budget of Y GB
/// (...)", for a refusal before anything is allocated; else empty.
[[nodiscard]] std::string beyond_memory_budget(double bytes);
/// A --max-memory value: bytes, with an optional K, M, G or T suffix (powers of 1024); 'none' is 0.
[[nodiscard]] std::size_t parse_memory_size(const std::string& text);

/// Builds the backend and parameters the options ask for (preset first, explicit options over it),
/// and sets the process's map memory limit (--max-memory).
/// \p default_sensor: the preset without --sensor (`map`: lidar, `sonar`: sonar).
/// \p base: the IWLO parameters the options override instead of the --sensor preset's (--sensor is
/// then not read: a caller passing a base refuses it). With \p open_map false the map is not
/// built (MapSetup::map stays empty): the caller builds it from the recorded choices.
[[nodiscard]] MapSetup map_setup_from(const Args& args, SensorPreset default_sensor,
                                      const std::optional<IwloParams>& base = std::nullopt, bool open_map = true);

/// A run's map commit: commit() flushes the map (a disk map's one commit of the run); a run that
/// leaves before it (an error, a signal's exception) rolls a disk map back, so that a failed run
/// leaves the map on disk exactly as it was. Declare it right after the map, before anything that
/// holds the map in another thread, so that those stop first.
class MapCommit {
 public:
  explicit MapCommit(std::shared_ptr<IMapperBackend> map) : map_(std::move(map)) {}
  ~MapCommit();
  MapCommit(const MapCommit&) = delete;
  MapCommit& operator=(const MapCommit&) = delete;
  void commit();

 private:
  std::shared_ptr<IMapperBackend> map_;
  bool committed_ = false;
};

/// Warns on stderr that \p skipped of \p points points were left out of the map, and why: not
/// finite, or (with ray casting) farther from the sensor origin than the longest ray.
void warn_skipped_points(const char* command, std::size_t skipped, std::size_t points, double resolution,
                         bool ray_casting);

/// Warns once per run, on stderr, when a cloud's intensities do not suit the parameters (most of
/// its points would be free space: check_intensities()), naming the file and the preset to use.
class IntensityWarning {
 public:
  explicit IntensityWarning(const char* command) : command_(command) {}
  void check(const std::string& file, const Eigen::VectorXd& intensities, const IwloParams& params);

 private:
  const char* command_;
  bool warned_ = false;
};

}  // namespace iwlomap::tool
