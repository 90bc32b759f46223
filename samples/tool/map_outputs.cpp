// SPDX-License-Identifier: BSD-3-Clause
#include "map_outputs.h"

#include "args.h"

#include <stdexcept>

#ifdef IWLOMAP_HAVE_OCTOMAP
#include <iwlomap/octree_mapper.h>
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

void write_map_outputs(const MapOutputs& outputs, const OutputFiles& files, IMapperBackend& map, double min_probability,
                       const VoxelColorMeans* colors) {
#ifdef IWLOMAP_HAVE_OCTOMAP
  if (outputs.octomap) files.write(*outputs.octomap, [&](const std::string& file) { export_octomap(map, file); });
#endif
#ifdef IWLOMAP_HAVE_VIEWER
  if (outputs.snapshot) {
    const Eigen::MatrixXd voxels = map.get_occupied_voxels(min_probability);
    viewer::SnapshotOptions options;
    options.title = "iwlomap: " + std::to_string(voxels.rows()) + " occupied voxels at " +
                    shortest(map.get_resolution()) + " m";
    if (colors != nullptr) {
      options.color_by = viewer::ColorBy::kRgb;
      options.voxel_rgb = colors->colors_at(voxels);
    }
    files.write(*outputs.snapshot, [&](const std::string& file) {
      viewer::SnapshotRenderer::render_png(voxels, map.get_resolution(), options, file);
    });
  }
#endif
  (void)outputs;
  (void)files;
  (void)map;
  (void)min_probability;
  (void)colors;
}

}  // namespace iwlomap::tool
