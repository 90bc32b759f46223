// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// A deterministic synthetic lidar scan with intensities, for demos, tests and benchmarks when no
/// recorded data is at hand.
///
/// The scene: a walled courtyard 40 m x 30 m (walls 10 m high), a flat ground at z = 0, three
/// boxes, a pole and a low wall. A spinning lidar with `rings` beams between -25 and +15 degrees
/// elevation and `columns` azimuth steps sits at (0, 0, sensor_height). Every beam hits something
/// (the courtyard is closed), so the scan has rings * columns points, at ranges up to about 26 m.
/// Intensities are reflectivities by material (asphalt dark, walls grey, boxes bright), scaled by
/// the cosine of the incidence angle, with seeded noise, in 0..255.

#include <Eigen/Core>

#include <cstdint>

namespace iwlomap {

struct SyntheticScanOptions {
  int rings = 64;                ///< elevation beams
  int columns = 1024;            ///< azimuth steps per turn
  double sensor_height = 1.5;    ///< metres above the ground
  Eigen::Vector2d sensor_xy{0.0, 0.0};  ///< sensor position in the courtyard, metres
  double range_noise = 0.01;     ///< standard deviation of the range noise, metres
  double intensity_noise = 8.0;  ///< standard deviation of the intensity noise
  std::uint32_t seed = 1;        ///< noise seed; the same seed gives the same scan everywhere
};

struct SyntheticScan {
  Eigen::Vector3d origin;        ///< sensor position, metres, map frame
  Eigen::MatrixXd points;        ///< N x 3 endpoints, metres, map frame
  Eigen::VectorXd intensities;   ///< N intensities in 0..255
};

/// Generates the scan (throws std::invalid_argument for rings or columns < 1, or a sensor outside
/// the courtyard).
[[nodiscard]] SyntheticScan make_synthetic_scan(const SyntheticScanOptions& options = {});

}  // namespace iwlomap
