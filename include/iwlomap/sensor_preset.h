// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Sensor presets: IWLO parameters for the kind of sensor a cloud comes from, and a check that
/// tells when a cloud's intensities do not suit the parameters in use (the reference defaults are
/// tuned for sonar, where an echo at or below the intensity threshold means "no echo"; applied to
/// a lidar cloud they turn most dark returns into free space).

#include <iwlomap/iwlo.h>

#include <Eigen/Core>

#include <cstddef>
#include <optional>
#include <string>

namespace iwlomap {

enum class SensorPreset {
  /// The reference API's defaults (IwloParams{}): an echo at or below intensity_threshold (35) is
  /// free space, stronger echoes are hits weighted by intensity; settled voxels are protected
  /// against contradicting evidence (adaptive scaling), so speckle does not erase them.
  kSonar,
  /// Every return is a hit, weighted by its intensity, however dark (intensity_threshold -1, so an
  /// intensity of 0 is a return too): a single return makes its voxel occupied in a fresh map
  /// (p = 0.85). Moved obstacles clear as fast as in OctoMap: a voxel hit 20 times drops to
  /// p <= 0.7 after 7 free observations, as in OctoMap with its defaults (L_max 3.5 like
  /// OctoMap's clamping at 0.97, L_free -1.35, adaptive scaling off). The other way, an obstacle
  /// that appears in space long seen free is occupied after 6 returns (OctoMap: 4), because L_min
  /// is -2 like OctoMap's clamping at 0.12.
  kLidar,
  /// As kLidar, but intensities carry no meaning (a depth camera's points): every return with an
  /// intensity >= 0 is a hit of the same weight (intensity_max 0, so every such point has u = 1).
  kDepthCamera,
};

/// The IWLO parameters of \p preset (see SensorPreset); occupied_threshold stays 0.7.
[[nodiscard]] IwloParams sensor_preset_params(SensorPreset preset);

/// "sonar", "lidar" or "depth".
[[nodiscard]] const char* sensor_preset_name(SensorPreset preset);

/// The preset named \p name ("sonar", "lidar", "depth"), or nothing.
[[nodiscard]] std::optional<SensorPreset> parse_sensor_preset(const std::string& name);

/// How a cloud's intensities fit the parameters a map uses.
struct IntensityCheck {
  std::size_t points = 0;               ///< finite intensities looked at
  std::size_t at_or_below_threshold = 0; ///< of those, at or below intensity_threshold: free space
  bool all_equal = false;               ///< every finite intensity is the same value (>= 2 points)

  /// True when most points (more than half) are at or below the threshold, or all intensities are
  /// equal and at or below it: the map would keep few of the cloud's surfaces, or none.
  [[nodiscard]] bool thins_map() const;
  /// One sentence for a user: what happens and which preset to use instead (empty when
  /// !thins_map()).
  [[nodiscard]] std::string advice() const;
};

/// Checks \p intensities (one per point; non-finite ones are ignored) against \p params.
[[nodiscard]] IntensityCheck check_intensities(const Eigen::VectorXd& intensities, const IwloParams& params);

}  // namespace iwlomap
