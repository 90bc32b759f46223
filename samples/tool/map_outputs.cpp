// SPDX-License-Identifier: BSD-3-Clause
#include "map_outputs.h"

#include "args.h"
#include "progress.h"

#include <filesystem>
#include <stdexcept>

#ifdef IWLOMAP_HAVE_OCTOMAP
#include <iwlomap/octomap/octree_mapper.h>
#endif
#ifdef IWLOMAP_HAVE_VIEWER
#include <iwlomap/viewer/snapshot_renderer.h>
#endif

namespace iwlomap::tool {

const char* map_outputs_help() {
  return R"(  --octomap FILE            also write the map as an OctoMap file: .bt (occupancy) or .ot (full
                            log-odds), for octovis, RViz and OctoMap's tools
  --snapshot FILE           also write a PNG snapshot of the occupied voxels (through $DISPLAY,
                            else a private Xvfb the command starts itself)
)";
}

MapOutputs map_outputs_from(const Args& args, OutputFiles& files) {
  MapOutputs out;
  out.octomap = args.value("--octomap");
  out.snapshot = args.value("--snapshot");
  if (out.octomap) {
    files.add("--octomap", *out.octomap, {".bt", ".ot"});
#ifndef IWLOMAP_HAVE_OCTOMAP
    throw std::runtime_error("--octomap: this build has no OctoMap layer (configure with IWLOMAP_WITH_OCTOMAP=ON)");
#endif
  }
  if (out.snapshot) {
    files.add("--snapshot", *out.snapshot, {".png"});
#ifdef IWLOMAP_HAVE_VIEWER
    viewer::SnapshotRenderer::check_display();  // fail now, not after a long mapping run
#else
    throw std::runtime_error("--snapshot: this build has no VTK viewer layer (configure with IWLOMAP_WITH_VIEWER=ON)");
#endif
  }
  return out;
}

Eigen::MatrixXd positions_of(const std::vector<Eigen::Isometry3d>& poses) {
  Eigen::MatrixXd positions(static_cast<Eigen::Index>(poses.size()), 3);
  for (std::size_t i = 0; i < poses.size(); ++i)
    positions.row(static_cast<Eigen::Index>(i)) = poses[i].translation().transpose();
  return positions;
}

std::size_t map_outputs_count(const MapOutputs& outputs) {
  return static_cast<std::size_t>(outputs.octomap.has_value()) + static_cast<std::size_t>(outputs.snapshot.has_value());
}

std::size_t write_map_outputs(const MapOutputs& outputs, const OutputFiles& files, IMapperBackend& map,
                              double min_probability, const VoxelColorMeans* colors, MapOutputsProgress progress,
                              const SnapshotMarks& marks) {
  std::size_t item = progress.first_item;
  const auto starting = [&](const std::string& path) {
    if (progress.bar != nullptr) progress.bar->update(item, std::filesystem::path(path).filename().string());
  };
#ifdef IWLOMAP_HAVE_OCTOMAP
  if (outputs.octomap) {
    starting(*outputs.octomap);
    const ProgressCallback blocks =
        progress.bar != nullptr
            ? progress_within(*progress.bar, item, std::filesystem::path(*outputs.octomap).filename().string())
            : ProgressCallback();
    files.write(*outputs.octomap, [&](const std::string& file) {
      export_octomap(map, file, map.get_params().occupied_threshold, blocks);
    });
    ++item;
  }
#endif
#ifdef IWLOMAP_HAVE_VIEWER
  if (outputs.snapshot) {
    starting(*outputs.snapshot);
    const Eigen::MatrixXd voxels = map.get_occupied_voxels(min_probability);
    viewer::SnapshotOptions options;
    options.title = "iwlomap: " + std::to_string(voxels.rows()) + " occupied voxels at " +
                    shortest(map.get_resolution()) + " m";
    options.sensor_positions = marks.sensor_positions;
    options.z_down = marks.z_down;
    if (colors != nullptr) {
      options.color_by = viewer::ColorBy::kRgb;
      options.voxel_rgb = colors->colors_at(voxels);
    }
    files.write(*outputs.snapshot, [&](const std::string& file) {
      viewer::SnapshotRenderer::render_png(voxels, map.get_resolution(), options, file);
    });
    ++item;
  }
#endif
  (void)outputs;
  (void)files;
  (void)map;
  (void)min_probability;
  (void)colors;
  (void)starting;
  (void)marks;
  return item;
}

}  // namespace iwlomap::tool
