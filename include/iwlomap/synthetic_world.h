// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// A deterministic synthetic lidar world larger than the sensor's range, for SLAM benchmarks and
/// tests (odometry drift, loop closure): axis-aligned boxes on a flat ground, a spinning lidar that
/// casts rays into them, and a street loop with a trajectory that goes once around it.
///
/// Units are metres and radians. The world frame has z up; the ground is the plane z = ground_z.
/// A sensor pose maps the sensor frame (x forward, y left, z up) to the world frame. The same
/// inputs and seeds give the same boxes, poses and scans on every platform.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstdint>
#include <vector>

namespace iwlomap {

/// An axis-aligned solid box, world frame, metres: lo <= hi on every axis.
struct WorldBox {
  Eigen::Vector3d lo, hi;
  double reflectivity = 0.5;  ///< in [0, 1]; 1 returns intensity 255 at normal incidence
};

/// A spinning lidar: `rings` beams between min_elevation and max_elevation, swept through
/// `columns` azimuths per turn starting at the sensor's +x axis and turning counter-clockwise.
struct LidarOptions {
  int rings = 32;                  ///< elevation beams, evenly spaced (one ring: midway)
  int columns = 1024;              ///< azimuth steps per turn
  double min_elevation = -0.4363;  ///< radians (-25 deg), >= -pi/2
  double max_elevation = 0.2618;   ///< radians (+15 deg), >= min_elevation, <= pi/2
  double max_range = 40.0;         ///< metres; beams that hit nothing within it give no point
  double range_noise = 0.02;       ///< standard deviation along the beam, metres (0: exact)
  double intensity_noise = 8.0;    ///< standard deviation of the intensity, in 0..255 units

  /// Throws std::invalid_argument naming the bad value (rings or columns < 1, elevations out of
  /// order or beyond +-pi/2, max_range not positive and finite, a noise negative or not finite).
  void validate() const;
};

/// One turn of the lidar, in beam order (ring by ring, column by column within a ring).
struct LidarFrame {
  Eigen::MatrixXd points;       ///< N x 3 endpoints, SENSOR frame, metres
  /// N intensities: reflectivity * 255 * cos(incidence) + noise, clamped to 0..255.
  Eigen::VectorXd intensities;
};

struct StreetLoopOptions {
  double block_x = 200.0, block_y = 150.0;  ///< size of the street loop's centreline rectangle, metres
  double street_width = 14.0;               ///< kerb to kerb, metres (>= 11: lane plus parked cars)
  std::uint32_t seed = 1;                   ///< placement of buildings, gaps, poles, parked cars
};

/// An immutable set of boxes on a ground plane. Rays are traced through a 2-D grid of the boxes'
/// footprints, so a ray tests only the boxes near its path, and a scan's cost hardly grows with
/// the size of the world.
class SyntheticWorld {
 public:
  /// Throws std::invalid_argument for a box with lo > hi or non-finite corners, a reflectivity
  /// (box or ground) outside [0, 1], or a non-finite ground_z.
  explicit SyntheticWorld(std::vector<WorldBox> boxes, double ground_z = 0.0, double ground_reflectivity = 0.15);

  /// A rectangular street loop (centreline from (0,0) to (block_x, block_y), ground at z = 0)
  /// lined on both sides by buildings of varied footprint and height (6-25 m) with gaps between
  /// them, poles and trees every 15-25 m on the pavements, parked cars (about 4.5 x 1.8 x 1.5 m)
  /// along the kerbs, all placed from `seed`. Nothing stands on the driving lane (within 3 m of
  /// the centreline). Throws std::invalid_argument for street_width < 11, a block side shorter
  /// than street_width + 20, or non-finite sizes.
  [[nodiscard]] static SyntheticWorld street_loop(const StreetLoopOptions& options = {});

  /// Sensor poses (sensor to world; x forward along the street, z up, y left, at height
  /// `sensor_height` above z = 0) along the closed centreline, counter-clockwise around the
  /// rectangle, with corners rounded to a 6 m radius so that the heading changes smoothly. The
  /// first pose is where the bottom street's straight begins, (6, 0), heading +x. The spacing is
  /// `step` adjusted (by at most half a step in total) so that a whole number of steps fits the
  /// loop: the pose after the last one would be the first. Throws std::invalid_argument for
  /// step <= 0, a non-finite or non-positive sensor_height, or options street_loop() rejects.
  [[nodiscard]] static std::vector<Eigen::Isometry3d> street_loop_trajectory(const StreetLoopOptions& options,
                                                                             double step, double sensor_height = 1.8);

  /// One lidar turn from `sensor_pose` (sensor to world), without motion during the turn. Range
  /// and intensity noise come from `seed`: the same seed gives the same frame. The noisy range is
  /// clamped to [0, max_range]. Throws what lidar.validate() throws.
  [[nodiscard]] LidarFrame scan(const Eigen::Isometry3d& sensor_pose, const LidarOptions& lidar,
                                std::uint32_t seed) const;

  /// Distance along the ray from `origin` in unit direction `dir` (world frame) to the first
  /// surface (box or ground), or +infinity when there is none within max_range. A box that
  /// contains the origin is ignored (surfaces are seen from outside). Throws std::invalid_argument
  /// for a negative or NaN max_range.
  [[nodiscard]] double cast(const Eigen::Vector3d& origin, const Eigen::Vector3d& dir, double max_range) const;

  [[nodiscard]] const std::vector<WorldBox>& boxes() const noexcept { return boxes_; }
  [[nodiscard]] double ground_z() const noexcept { return ground_z_; }
  [[nodiscard]] double ground_reflectivity() const noexcept { return ground_reflectivity_; }

 private:
  // First surface within max_range: distance, and the box index (-1: ground) and entered axis.
  double trace(const Eigen::Vector3d& o, const Eigen::Vector3d& d, double max_range, int& box, int& axis) const;

  std::vector<WorldBox> boxes_;
  double ground_z_;
  double ground_reflectivity_;
  // The grid over the boxes' xy footprints: cell (ix, iy) lists
  // cell_boxes_[cell_begin_[c] .. cell_begin_[c + 1]) with c = iy * nx_ + ix.
  Eigen::Vector2d grid_origin_{0.0, 0.0};
  double cell_size_ = 1.0;
  int nx_ = 0, ny_ = 0;
  std::vector<std::uint32_t> cell_begin_;
  std::vector<std::uint32_t> cell_boxes_;
};

/// A small scene for registration tests: ground points 24 x 24 m around the origin at z = 0 and
/// twelve pillars (radius 0.3 m, 3 m tall, the same places for every seed) at 4-10 m, 38,000
/// points in all, in the world frame. \p seed draws the samples and \p noise (metres, >= 0) their
/// noise, so two seeds give two scans of one scene.
[[nodiscard]] Eigen::MatrixXd make_pillar_scene(std::uint32_t seed, double noise);

}  // namespace iwlomap
