// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// SnapshotRenderer: draws the occupied voxels of a map into a PNG file or an RGB buffer, off
/// screen, with no window. VTK is used only in the implementation; this header needs Eigen and
/// the standard library only.
///
/// Display: Debian's VTK 9.1 renders only through an X server. A render uses $DISPLAY when it can
/// be opened; otherwise the first render of the process starts a private virtual X server (Xvfb,
/// or the program $IWLOMAP_XVFB names) on a free display, kept until the process ends and killed
/// with it. Only when neither works does a render throw DisplayError (naming $DISPLAY, why Xvfb
/// could not be used, and xvfb-run) before VTK touches X, instead of VTK aborting the process.

#include "iwlomap/mapper_backend.h"
#include "iwlomap/viewer/color_map.h"
#include "iwlomap/voxel_colors.h"

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap::viewer {

/// Thrown when neither $DISPLAY nor a private Xvfb can be used; the message names both.
struct DisplayError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

/// Viewing directions that frame the whole map. All look at the centre of the map's bounding box.
enum class CameraPreset {
  kIso,    ///< from the +x/-y side, 50 degrees above the horizon: +x to the lower right, +y to the upper right, z up
  kTop,    ///< plan view: looking down -z, +y up in the image, +x to the right
  kFront,  ///< elevation from -y: looking along +y, z up, +x to the right
  kSide,   ///< elevation from +x: looking along -x, z up, +y to the right
};

/// An explicit camera: eye and target in metres (map frame), up a direction (need not be unit
/// length, must not be parallel to target - eye).
struct CameraPose {
  Eigen::Vector3d eye = Eigen::Vector3d(0.0, 0.0, 10.0);
  Eigen::Vector3d target = Eigen::Vector3d::Zero();
  Eigen::Vector3d up = Eigen::Vector3d::UnitY();
};

/// What a voxel's colour shows.
enum class ColorBy {
  kProbability,  ///< occupancy probability (column 3) through ColorMap::probability()
  kHeight,       ///< z of the voxel centre through ColorMap::height()
  kFixed,        ///< SnapshotOptions::fixed_color for every voxel (no colour bar)
  /// Each voxel's own colour from SnapshotOptions::voxel_rgb (e.g. VoxelColorMeans::colors_at()
  /// of the same rows; no colour bar)
  kRgb,
};

/// How a voxel is drawn.
enum class VoxelShape {
  kCubes,   ///< a cube of the map resolution centred on the voxel (instanced glyphs)
  kPoints,  ///< a point of point_size pixels at the voxel centre (cheaper, for huge maps)
};

struct SnapshotOptions {
  int width = 1280;   ///< image width in pixels, in [16, 8192]
  int height = 960;   ///< image height in pixels, in [16, 8192]

  CameraPreset camera = CameraPreset::kIso;
  /// When set, replaces the preset: the view goes from eye to target with this up direction.
  std::optional<CameraPose> camera_pose;
  /// false (default): parallel projection, scaled so the cubes (and sensor positions) as seen from
  /// the camera fill 90% of the limiting dimension of the map area (the image minus the colour-bar
  /// and title bands), centred on them (an explicit pose puts its target at the centre; only its
  /// direction matters). true: a
  /// 30-degree perspective camera; presets move back until the bounding sphere fits, an explicit
  /// pose is used as given.
  bool perspective = false;

  ColorBy color_by = ColorBy::kHeight;
  Rgb fixed_color{0.72, 0.74, 0.78};
  /// The value range spread over the colour map; values outside are clamped to its ends.
  /// Unset: probability [0.5, 1] (the range occupied voxels can have, so maps compare), height
  /// [min z, max z] of the voxel centres.
  std::optional<double> color_min;
  std::optional<double> color_max;
  /// ColorBy::kRgb: one (r, g, b) row per row of the voxel matrix, in the same order.
  ColorMatrix voxel_rgb;
  /// A labelled colour bar on the right (ignored for ColorBy::kFixed and kRgb).
  bool color_bar = true;
  /// The colour bar's title; empty: "probability", or for ColorBy::kHeight "height (m)" ("depth
  /// (m)" with z_down).
  std::string color_bar_title;

  /// The map frame's +z points down (a sonar or NED frame, where z is depth): the camera presets
  /// are turned half a turn about +x so the surface is on top (kTop then looks along +z with +x to
  /// the right and +y down the image), and the height colour bar reads "depth (m)".
  bool z_down = false;
  /// An axes triad in the lower-left corner, turned as the view is: x red, y green, z blue.
  bool axes = true;
  /// A scale bar beside the triad: a round length in metres (1, 2 or 5 times a power of ten) drawn
  /// to the map's scale. Parallel views only (a perspective view has no single scale).
  bool scale_bar = true;
  /// Sensor positions in metres (map frame), N x 3 (N may be 0), joined in order by a dark line
  /// when there are two or more (the trajectory), each one marked when there are at most 20, the
  /// last one by a larger marker. They are framed with the voxels.
  Eigen::MatrixXd sensor_positions = Eigen::MatrixXd(0, 3);

  VoxelShape shape = VoxelShape::kCubes;
  double point_size = 3.0;  ///< pixels, for VoxelShape::kPoints; in (0, 64]

  Rgb background{0.95, 0.953, 0.96};  ///< light grey: the colour ramps keep their contrast on it
  /// Shading by a light beside the camera plus some ambient light, so cube faces read in 3D.
  /// false: every voxel shows exactly its colour-map colour (flat), e.g. for pixel checks.
  bool lighting = true;
  /// Drawn at the top centre when not empty.
  std::string title;

  /// Throws std::invalid_argument naming the first bad field and its value.
  void validate() const;
};

/// An 8-bit RGB image, rows from top to bottom, 3 bytes per pixel.
struct RgbImage {
  int width = 0;
  int height = 0;
  std::vector<std::uint8_t> rgb;  ///< width * height * 3 bytes

  /// The pixel in column \p x (from the left) and row \p y (from the top); throws
  /// std::out_of_range naming x and y when outside the image.
  [[nodiscard]] std::array<std::uint8_t, 3> pixel(int x, int y) const;
};

/// Writes \p image as a PNG file. Throws std::invalid_argument for an image whose buffer size does
/// not match width x height x 3, std::runtime_error naming the path when it cannot be written.
/// Needs no display.
void write_png(const RgbImage& image, const std::string& path);

/// Off-screen snapshots of occupied voxels. Each call opens the display, renders in a hidden
/// window and releases everything again (nothing is kept between calls). Safe to call from any
/// thread: renders are serialised internally, because Xlib and VTK's factories are not thread-safe.
class SnapshotRenderer {
 public:
  SnapshotRenderer() = delete;

  /// Renders \p voxels_xyzp, an N x 4 matrix of rows (x, y, z, p) as returned by
  /// IMapperBackend::get_occupied_voxels() (voxel centres in metres, map frame; p the occupancy
  /// probability, only used by ColorBy::kProbability), as cubes of edge \p resolution metres.
  /// Rows with a non-finite coordinate (or a non-finite p under ColorBy::kProbability) are skipped.
  /// An empty matrix gives the background (and title) only.
  /// Throws std::invalid_argument for a matrix without 4 columns, ColorBy::kRgb with a voxel_rgb
  /// whose row count differs from the matrix's, a resolution that is not a
  /// positive finite number or invalid options; DisplayError when no display can be opened;
  /// std::runtime_error when VTK fails to render.
  [[nodiscard]] static RgbImage render(const Eigen::MatrixXd& voxels_xyzp, double resolution,
                                       const SnapshotOptions& options);

  /// As render(), then writes the image to \p path as PNG (std::runtime_error naming the path when
  /// it cannot be written).
  static void render_png(const Eigen::MatrixXd& voxels_xyzp, double resolution, const SnapshotOptions& options,
                         const std::string& path);

  /// Renders the voxels of \p map with probability > \p min_probability at the map's resolution.
  /// A negative \p min_probability (the default) means the map's occupied threshold
  /// (IMapperBackend::get_params().occupied_threshold).
  [[nodiscard]] static RgbImage render(IMapperBackend& map, const SnapshotOptions& options,
                                       double min_probability = -1.0);
  static void render_png(IMapperBackend& map, const SnapshotOptions& options, const std::string& path,
                         double min_probability = -1.0);

  /// Throws DisplayError when neither $DISPLAY nor a private Xvfb can be used (e.g. to fail before
  /// a long mapping run rather than after it); may start the private Xvfb. Does nothing otherwise.
  static void check_display();
};

}  // namespace iwlomap::viewer
