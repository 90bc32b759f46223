// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap render`: a PNG snapshot of a voxel map, drawn off screen.

#include "args.h"
#include "commands.h"

#include <iostream>
#include <stdexcept>

#ifdef IWLOMAP_HAVE_VIEWER
#include "cloud_io.h"
#include "voxel_cloud.h"
#include "map_open.h"
#include "map_outputs.h"
#include "output_files.h"

#include <iwlomap/viewer/pcl_adapter.h>
#include <iwlomap/trajectory_io.h>
#include <iwlomap/viewer/snapshot_renderer.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <optional>
#include <sstream>
#include <vector>
#endif

namespace iwlomap::tool {

namespace {

const char* kHelp = R"(usage: iwlomap render IN.pcd|IN.ply|IN.bt|IN.ot|TILE_DIR -o OUT.png [options]

Draws a voxel map into a PNG image, off screen. A .pcd/.ply input holds voxel centres (what
'iwlomap map' writes) with the occupancy probability as intensity; a stored map (a disk-backend
tile directory, or a .bt/.ot OctoMap file with the OctoMap layer) is opened at its own resolution
and its occupied voxels (p > 0.7) are drawn. A .pcd/.ply whose points lie on no voxel grid (a
raw scan) is drawn as points of 2 pixels, unless --resolution is given.

Rendering goes through an X server: $DISPLAY when it can be opened, else a private virtual one
(Xvfb, Debian package xvfb) that the command starts and stops itself.

output:
  -o, --output FILE           the PNG image to write
  --width N, --height N       image size in pixels (default 1280 x 960)
  --title TEXT                a title at the top of the image

camera (parallel projection framing the whole map unless --perspective):
  --camera iso|top|front|side   iso: from the +x/-y side, 50 deg above the horizon (default);
                              top: plan view, +y up; front: from -y; side: from +x
  --eye X,Y,Z --target X,Y,Z  explicit camera in metres (replaces --camera; both needed)
  --up X,Y,Z                  up direction of the explicit camera (default 0,0,1)
  --perspective               a 30 degree perspective camera instead of a parallel one

voxels:
  --color probability|height|fixed|rgb   colour by occupancy probability, by height, one
                              colour, or each voxel's own colour (the rgb field of a .pcd/.ply,
                              e.g. the mean colours 'iwlomap map' writes; default height)
  --color-range MIN,MAX       the values spread over the colour map (default: probability
                              0.5,1; height: the map's z range)
  --fixed-color COLOR         the colour of --color fixed
  --no-color-bar              no colour bar
  --points                    draw points instead of cubes (faster for huge maps)
  --point-size PX             size of --points in pixels (default 3; 2 for a raw scan)
  --resolution M              voxel edge in metres (default: inferred from the voxel centres)
  --background COLOR          background colour (default #f2f3f5)
  --no-lighting               flat colours, exactly as the colour map gives them
  --no-axes                   no axes triad (x red, y green, z blue) in the lower-left corner
  --no-scale-bar              no scale bar (parallel views draw one beside the triad)
  --z-down                    the map's +z points down (a sonar or NED frame): the views are
                              turned so the surface is on top, and height colours read as depth
  --trajectory FILE           draw the sensor positions of a TUM or KITTI (.kitti) pose file as
                              markers joined by a line, the last one larger (as 'map
                              --write-poses' and 'sonar --write-poses' write them)

COLOR is #rrggbb or R,G,B with components in [0, 1].
)";

#ifdef IWLOMAP_HAVE_VIEWER

Eigen::Vector3d parse_vector(const std::string& option, const std::string& text) {
  const auto v = parse_list(option, text, 3);
  return {v[0], v[1], v[2]};
}

viewer::Rgb parse_color(const std::string& option, const std::string& text) {
  if (text.size() == 7 && text[0] == '#') {
    const auto hex = [&](std::size_t at) {
      const std::string byte = text.substr(at, 2);
      char* end = nullptr;
      const long v = std::strtol(byte.c_str(), &end, 16);
      if (end != byte.c_str() + 2) throw UsageError(option + " needs #rrggbb or R,G,B, got '" + text + "'");
      return static_cast<double>(v) / 255.0;
    };
    return {hex(1), hex(3), hex(5)};
  }
  const auto v = parse_list(option, text, 3);
  for (double c : v)
    if (c < 0.0 || c > 1.0) throw UsageError(option + " components must be in [0, 1], got '" + text + "'");
  return {v[0], v[1], v[2]};
}

viewer::SnapshotOptions options_from(const Args& args) {
  viewer::SnapshotOptions o;
  o.width = static_cast<int>(args.integer("--width", o.width));
  o.height = static_cast<int>(args.integer("--height", o.height));
  o.title = args.value("--title").value_or("");

  const std::string camera = args.value("--camera").value_or("iso");
  if (camera == "iso")
    o.camera = viewer::CameraPreset::kIso;
  else if (camera == "top")
    o.camera = viewer::CameraPreset::kTop;
  else if (camera == "front")
    o.camera = viewer::CameraPreset::kFront;
  else if (camera == "side")
    o.camera = viewer::CameraPreset::kSide;
  else
    throw UsageError("--camera must be iso, top, front or side, got '" + camera + "'");
  const auto eye = args.value("--eye"), target = args.value("--target"), up = args.value("--up");
  if (eye || target || up) {
    if (!eye || !target) throw UsageError("an explicit camera needs both --eye and --target");
    if (args.has("--camera")) throw UsageError("--camera and --eye/--target exclude each other");
    viewer::CameraPose pose;
    pose.eye = parse_vector("--eye", *eye);
    pose.target = parse_vector("--target", *target);
    pose.up = up ? parse_vector("--up", *up) : Eigen::Vector3d::UnitZ();
    o.camera_pose = pose;
  }
  o.perspective = args.flag("--perspective");

  const std::string color = args.value("--color").value_or("height");
  if (color == "probability")
    o.color_by = viewer::ColorBy::kProbability;
  else if (color == "height")
    o.color_by = viewer::ColorBy::kHeight;
  else if (color == "fixed")
    o.color_by = viewer::ColorBy::kFixed;
  else if (color == "rgb")
    o.color_by = viewer::ColorBy::kRgb;
  else
    throw UsageError("--color must be probability, height, fixed or rgb, got '" + color + "'");
  if (const auto range = args.value("--color-range")) {
    const auto r = parse_list("--color-range", *range, 2);
    o.color_min = r[0];
    o.color_max = r[1];
  }
  if (const auto c = args.value("--fixed-color")) o.fixed_color = parse_color("--fixed-color", *c);
  if (const auto c = args.value("--background")) o.background = parse_color("--background", *c);
  o.color_bar = !args.flag("--no-color-bar");
  o.shape = args.flag("--points") ? viewer::VoxelShape::kPoints : viewer::VoxelShape::kCubes;
  o.point_size = args.number("--point-size", o.point_size);
  o.lighting = !args.flag("--no-lighting");
  o.axes = !args.flag("--no-axes");
  o.scale_bar = !args.flag("--no-scale-bar");
  o.z_down = args.flag("--z-down");
  if (const auto path = args.value("--trajectory"))
    o.sensor_positions = positions_of(read_trajectory(*path, trajectory_format_of(*path)));
  try {
    o.validate();
  } catch (const std::invalid_argument& e) {
    throw UsageError(e.what());
  }
  return o;
}

#endif  // IWLOMAP_HAVE_VIEWER

}  // namespace

int run_render(const std::vector<std::string>& argv) {
  const Args args(argv,
                  {"-o", "--output", "--width", "--height", "--title", "--camera", "--eye", "--target", "--up",
                   "--color", "--color-range", "--fixed-color", "--point-size", "--resolution", "--background",
                   "--trajectory"},
                  {"-h", "--help", "--perspective", "--no-color-bar", "--points", "--no-lighting", "--no-axes",
                   "--no-scale-bar", "--z-down"});
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp;
    return 0;
  }
#ifndef IWLOMAP_HAVE_VIEWER
  throw std::runtime_error(
      "this iwlomap was built without the snapshot renderer: install libvtk9-dev and reconfigure with "
      "-DIWLOMAP_WITH_VIEWER=ON");
#else
  if (args.positional().empty()) throw UsageError("no input file");
  if (args.positional().size() > 1) throw UsageError("one input file only, got also '" + args.positional()[1] + "'");
  const std::string input = args.positional().front();
  const std::string in_ext = extension(input);
  const bool stored_map = is_map_path(input);
  if (!stored_map && in_ext != ".pcd" && in_ext != ".ply")
    throw UsageError("the input must be a .pcd or .ply cloud of voxel centres, a tile directory or a .bt/.ot map, got '" +
                     input + "'");
  const auto output = args.value("-o") ? args.value("-o") : args.value("--output");
  if (!output) throw UsageError("no output file (-o OUT.png)");
  OutputFiles files(args);
  files.add("-o", *output, {".png"});
  viewer::SnapshotOptions options = options_from(args);
  const auto resolution_option = args.resolution();

  // Fail before reading a large file when the picture cannot be drawn anyway.
  viewer::SnapshotRenderer::check_display();

  const auto started = std::chrono::steady_clock::now();
  Eigen::MatrixXd voxels;
  double resolution = 0.0;
  bool raw_points = false;
  if (options.color_by == viewer::ColorBy::kRgb && stored_map)
    throw UsageError("--color rgb needs a .pcd/.ply with an rgb field; a stored map keeps no colours");
  if (stored_map) {  // the occupied voxels of a stored map, at its own resolution
    const auto map = open_map(input);
    voxels = map->get_occupied_voxels(map->get_params().occupied_threshold);
    resolution = map->get_resolution();
  } else {
    const LoadedCloud cloud = load_cloud(input, 1.0f);
    voxels = viewer::cloud_to_voxels(*cloud.cloud);
    if (options.color_by == viewer::ColorBy::kRgb) {
      if (!cloud.colors) throw std::runtime_error("--color rgb: '" + input + "' has no rgb or rgba field");
      options.voxel_rgb = *cloud.colors;
    }
  }
  if (!stored_map) {  // a cloud does not say its voxel size: take the option, or infer it
    const auto inferred = infer_resolution(voxels);
    if (resolution_option) {
      resolution = *resolution_option;
    } else if (inferred && on_voxel_lattice(voxels, *inferred)) {
      resolution = *inferred;
    } else if (voxels.rows() > 1) {
      // A raw scan: drawn as points (their size in pixels, not metres), which needs no voxel size;
      // the resolution then only pads the view's bounding box (1/1000 of its extent).
      const Eigen::Vector3d extent =
          voxels.leftCols<3>().colwise().maxCoeff().transpose() - voxels.leftCols<3>().colwise().minCoeff().transpose();
      resolution = std::max(extent.maxCoeff() / 1000.0, 1e-3);
      options.shape = viewer::VoxelShape::kPoints;
      if (!args.has("--point-size")) options.point_size = 2.0;
      raw_points = true;
    } else {
      throw UsageError("cannot infer the voxel size of '" + input + "' (fewer than two distinct voxels): give --resolution");
    }
  }
  if (options.color_by == viewer::ColorBy::kProbability && voxels.rows() > 0 &&
      (voxels.col(3).minCoeff() < 0.0 || voxels.col(3).maxCoeff() > 1.0))
    std::cerr << "iwlomap render: note: intensities of '" << input
              << "' are not all in [0, 1], so they are not occupancy probabilities; colours are clamped\n";
  files.write(*output, [&](const std::string& file) { viewer::SnapshotRenderer::render_png(voxels, resolution, options, file); });
  files.commit();
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count();
  std::cout << "wrote " << *output << ": "
            << (raw_points ? std::to_string(voxels.rows()) + " points (not a voxel cloud: drawn as points; --resolution M draws cubes)"
                           : std::to_string(voxels.rows()) + " voxels of " + shortest(resolution) + " m" +
                                 (stored_map || resolution_option ? "" : " (inferred)"))
            << ", " << options.width << " x " << options.height << " in "
            << seconds << " s\n";
  return 0;
#endif
}

}  // namespace iwlomap::tool
