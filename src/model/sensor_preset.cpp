// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/sensor_preset.h"

#include <cmath>
#include <initializer_list>
#include <sstream>

namespace iwlomap {

IwloParams sensor_preset_params(SensorPreset preset) {
  IwloParams p;
  if (preset == SensorPreset::kSonar) return p;
  // Lidar: a return is a surface whatever its reflectivity; the clearing speed follows OctoMap
  // (tests/test_sensor_preset.cpp measures both).
  p.intensity_threshold = -1.0;
  p.L_max = 3.5;
  // OctoMap's lower clamp (p = 0.12): an obstacle that appears in space long seen free is
  // occupied after 6 returns (OctoMap: 4), instead of the 21 that L_min = -10 takes after 20 free
  // observations (tests/test_sensor_preset.cpp).
  p.L_min = -2.0;
  p.log_odds_free = -1.35;
  p.adaptive_enabled = false;
  // Depth cameras: intensity 0 (or none: the callers' intensity_max) and anything above it is a
  // return of full weight u = 1, so the weight is the same for every point.
  if (preset == SensorPreset::kDepthCamera) p.intensity_max = 0.0;
  return p;
}

const char* sensor_preset_name(SensorPreset preset) {
  switch (preset) {
    case SensorPreset::kSonar: return "sonar";
    case SensorPreset::kLidar: return "lidar";
    case SensorPreset::kDepthCamera: return "depth";
  }
  return "sonar";
}

std::optional<SensorPreset> parse_sensor_preset(const std::string& name) {
  for (SensorPreset p : {SensorPreset::kSonar, SensorPreset::kLidar, SensorPreset::kDepthCamera})
    if (name == sensor_preset_name(p)) return p;
  return std::nullopt;
}

bool IntensityCheck::thins_map() const {
  if (points == 0) return false;
  return at_or_below_threshold * 2 > points || (all_equal && at_or_below_threshold == points);
}

std::string IntensityCheck::advice() const {
  if (!thins_map()) return {};
  std::ostringstream s;
  s << at_or_below_threshold << " of " << points << " points have an intensity at or below the threshold"
    << (all_equal ? " (all intensities are equal)" : "")
    << " and count as free space, as a sonar without echo; for lidar or depth-camera clouds use the "
       "lidar or depth preset (every return is a hit)";
  return s.str();
}

IntensityCheck check_intensities(const Eigen::VectorXd& intensities, const IwloParams& params) {
  IntensityCheck c;
  bool first = true;
  double value = 0.0;
  bool equal = true;
  for (Eigen::Index i = 0; i < intensities.size(); ++i) {
    const double v = intensities[i];
    if (!std::isfinite(v)) continue;
    ++c.points;
    if (v <= params.intensity_threshold) ++c.at_or_below_threshold;
    if (first) {
      value = v;
      first = false;
    } else if (v != value) {
      equal = false;
    }
  }
  c.all_equal = c.points >= 2 && equal;
  return c;
}

}  // namespace iwlomap
