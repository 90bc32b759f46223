// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The deterministic input stream shared by test_outofcore_tile_mapper and tile_writer_helper: step
// k gives the same scan and the same weighted batch in every process, so a test can rebuild in RAM
// exactly what another process wrote to disk.

#include "iwlomap/mapper_backend.h"
#include "iwlomap/synthetic_scan.h"

#include <Eigen/Core>

#include <cstdint>
#include <random>
#include <vector>

namespace iwlomap::tile_test {

// 0.2 m voxels in 6.4 m tiles (32 voxels, 4 blocks per edge): a step touches about 8 tiles, so a
// flush writes several files and a crash can fall between two of their renames.
inline constexpr double kResolution = 0.2;
inline constexpr double kTileSize = 6.4;

/// Sensor position of step k.
inline SyntheticScan step_scan(int k) {
  SyntheticScanOptions o;
  o.rings = 6;
  o.columns = 72;
  o.sensor_xy = Eigen::Vector2d(-12.0 + 1.1 * (k % 23), -8.0 + 0.7 * (k % 17));
  o.seed = 1000u + static_cast<std::uint32_t>(k);
  return make_synthetic_scan(o);
}

/// The first call of step k >= 1: a small scan (max range 5 m) from a sensor that walks through
/// the courtyard.
inline void apply_step_scan(IMapperBackend& map, int k) {
  const SyntheticScan scan = step_scan(k);
  map.insert_scan(scan.origin, scan.points, scan.intensities, 5.0);
}

/// The second call of step k: a batch of weighted observations around the sensor.
inline void apply_step_batch(IMapperBackend& map, int k) {
  const SyntheticScan scan = step_scan(k);
  std::mt19937 rng(5000u + static_cast<std::uint32_t>(k));
  std::uniform_real_distribution<double> offset(-3.0, 3.0);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const int n = 200;
  Eigen::MatrixXd points(n, 3);
  Eigen::VectorXd intensities(n), weights(n);
  std::vector<bool> flags(n);
  for (int i = 0; i < n; ++i) {
    points.row(i) << scan.origin.x() + offset(rng), scan.origin.y() + offset(rng), 0.5 * (1.0 + offset(rng));
    intensities[i] = 255.0 * unit(rng);
    flags[static_cast<std::size_t>(i)] = unit(rng) < 0.7;
    weights[i] = unit(rng) < 0.1 ? 0.0 : 2.0 * unit(rng);
  }
  map.batch_update_iwlo(points, intensities, flags, weights);
}

/// Step k: its scan, then its batch.
inline void apply_step(IMapperBackend& map, int k) {
  apply_step_scan(map, k);
  apply_step_batch(map, k);
}

}  // namespace iwlomap::tile_test
