// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/viewer/snapshot_renderer.h"

#include <Eigen/Geometry>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <string>

namespace iwlomap::viewer {

namespace {

std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

std::string vec(const Eigen::Vector3d& v) { return "(" + num(v.x()) + ", " + num(v.y()) + ", " + num(v.z()) + ")"; }

void check_color(const char* field, const Rgb& c) {
  const auto unit = [](double v) { return v >= 0.0 && v <= 1.0; };
  if (!unit(c.r) || !unit(c.g) || !unit(c.b))
    throw std::invalid_argument(std::string("SnapshotOptions: ") + field + " (" + num(c.r) + ", " + num(c.g) + ", " +
                                num(c.b) + ") has a component outside [0, 1]");
}

}  // namespace

void SnapshotOptions::validate() const {
  constexpr int kMinSide = 16;
  constexpr int kMaxSide = 8192;  // larger than any offscreen framebuffer Mesa's llvmpipe allows
  if (width < kMinSide || width > kMaxSide)
    throw std::invalid_argument("SnapshotOptions: width " + std::to_string(width) + " is outside [16, 8192]");
  if (height < kMinSide || height > kMaxSide)
    throw std::invalid_argument("SnapshotOptions: height " + std::to_string(height) + " is outside [16, 8192]");
  if (camera_pose) {
    const CameraPose& c = *camera_pose;
    if (!c.eye.allFinite() || !c.target.allFinite() || !c.up.allFinite())
      throw std::invalid_argument("SnapshotOptions: camera_pose has a non-finite value: eye " + vec(c.eye) +
                                  ", target " + vec(c.target) + ", up " + vec(c.up));
    const Eigen::Vector3d view = c.target - c.eye;
    if (view.norm() <= 0.0)
      throw std::invalid_argument("SnapshotOptions: camera_pose eye and target are the same point " + vec(c.eye));
    if (c.up.norm() <= 0.0 || view.normalized().cross(c.up.normalized()).norm() < 1e-6)
      throw std::invalid_argument("SnapshotOptions: camera_pose up " + vec(c.up) +
                                  " is zero or parallel to the view direction " + vec(view));
  }
  check_color("fixed_color", fixed_color);
  check_color("background", background);
  if (color_min && !std::isfinite(*color_min))
    throw std::invalid_argument("SnapshotOptions: color_min " + num(*color_min) + " is not finite");
  if (color_max && !std::isfinite(*color_max))
    throw std::invalid_argument("SnapshotOptions: color_max " + num(*color_max) + " is not finite");
  if (color_min && color_max && !(*color_min < *color_max))
    throw std::invalid_argument("SnapshotOptions: color_min " + num(*color_min) + " is not below color_max " +
                                num(*color_max));
  if (sensor_positions.cols() != 3 && sensor_positions.rows() > 0)
    throw std::invalid_argument("SnapshotOptions: sensor_positions has " + std::to_string(sensor_positions.cols()) +
                                " columns, expected 3 (x, y, z)");
  if (!sensor_positions.allFinite())
    throw std::invalid_argument("SnapshotOptions: sensor_positions has a non-finite value");
  if (!(point_size > 0.0 && point_size <= 64.0))
    throw std::invalid_argument("SnapshotOptions: point_size " + num(point_size) + " is outside (0, 64]");
}

}  // namespace iwlomap::viewer
