// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The optional outputs of a mapping command: an OctoMap file (.bt/.ot) and a PNG snapshot. Each
// needs a layer (OctoMap, VTK) that a build may leave out; then the option fails with a clear error.

#include "output_files.h"

#include <iwlomap/mapper_backend.h>
#include <iwlomap/voxel_colors.h>

#include <Eigen/Geometry>

#include <optional>
#include <string>
#include <vector>

namespace iwlomap::tool {

struct MapOutputs {
  std::optional<std::string> octomap;   ///< .bt or .ot
  std::optional<std::string> snapshot;  ///< .png
};

/// Reads --octomap and --snapshot, adds them to \p files and checks, before any work, that they
/// can be written: the paths, the layers of this build, and an X display for the snapshot. Throws
/// UsageError or std::runtime_error.
[[nodiscard]] MapOutputs map_outputs_from(const class Args& args, OutputFiles& files);

/// The number of outputs \p outputs asks for (0 to 2).
[[nodiscard]] std::size_t map_outputs_count(const MapOutputs& outputs);

/// What the snapshot marks beside the voxels: the sensor positions (N x 3, map frame; a line
/// joins them), and a map frame whose +z points down (sonar: depth, surface on top).
struct SnapshotMarks {
  Eigen::MatrixXd sensor_positions = Eigen::MatrixXd(0, 3);
  bool z_down = false;
};

/// The translations of \p poses, one row each (N x 3): sensor positions for a snapshot.
[[nodiscard]] Eigen::MatrixXd positions_of(const std::vector<Eigen::Isometry3d>& poses);

/// A bar that write_map_outputs() moves: each output is one item, from \p first_item on.
struct MapOutputsProgress {
  class Progress* bar = nullptr;
  std::size_t first_item = 0;
};

/// Writes the requested outputs of \p map into their temporaries in \p files (the snapshot shows
/// voxels with p > \p min_probability, in their mean colours when \p colors is given, else by
/// height), moving \p progress's bar (within the OctoMap file as its blocks are written). Returns
/// the item after the last one written.
std::size_t write_map_outputs(const MapOutputs& outputs, const OutputFiles& files, IMapperBackend& map,
                              double min_probability, const VoxelColorMeans* colors = nullptr,
                              MapOutputsProgress progress = {}, const SnapshotMarks& marks = {});

/// Help lines for --octomap and --snapshot.
[[nodiscard]] const char* map_outputs_help();

}  // namespace iwlomap::tool
