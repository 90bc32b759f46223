// SPDX-License-Identifier: BSD-3-Clause
// Sensor presets through the public API: what a single dark return gives, how fast a moved
// obstacle clears, and the intensity check that warns when a cloud does not suit the parameters.
#include "iwlomap/probability_updater.h"
#include "iwlomap/sensor_preset.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <string>

namespace iwlomap {
namespace {

double probability_of(ProbabilityUpdater& map, const Eigen::Vector3d& p) {
  const auto v = map.query(p);
  return v ? v->probability : 0.5;
}

// A map with \p params after one scan of one point at \p intensity, 3 m from the sensor.
double single_return(const IwloParams& params, double intensity) {
  ProbabilityUpdater map(0.1);
  map.set_params(params);
  Eigen::MatrixXd point(1, 3);
  point << 3.05, 0.05, 0.05;
  map.insert_scan(Eigen::Vector3d(0.05, 0.05, 0.05), point, Eigen::VectorXd::Constant(1, intensity), -1.0);
  return probability_of(map, Eigen::Vector3d(3.05, 0.05, 0.05));
}

// Observations of the other kind after \p first observations of one kind (hits when
// \p hits_first, else free) of intensity \p intensity, until the voxel crosses the occupied
// threshold (p > 0.7 to p <= 0.7 after hits, the other way after free observations).
int observations_to_flip(const IwloParams& params, bool hits_first, int first, double intensity) {
  ProbabilityUpdater map(0.1);
  map.set_params(params);
  Eigen::MatrixXd point(1, 3);
  point << 1.05, 1.05, 1.05;
  const Eigen::VectorXd value = Eigen::VectorXd::Constant(1, intensity);
  for (int i = 0; i < first; ++i) map.batch_update_iwlo(point, value, {hits_first});
  int n = 0;
  while ((probability_of(map, point.row(0).transpose()) > params.occupied_threshold) == hits_first && n < 1000) {
    map.batch_update_iwlo(point, value, {!hits_first});
    ++n;
  }
  return n;
}

int free_observations_to_clear(const IwloParams& params, int hits) { return observations_to_flip(params, true, hits, 200.0); }
int hits_to_occupy(const IwloParams& params, int frees, double intensity) {
  return observations_to_flip(params, false, frees, intensity);
}

// The same count in OctoMap with its defaults (hit 0.7, miss 0.4, clamping at 0.12 and 0.97).
int octomap_observations_to_flip(bool hits_first, int first) {
  const double hit = std::log(0.7 / 0.3), miss = std::log(0.4 / 0.6);
  const double bottom = std::log(0.1192 / 0.8808), top = std::log(0.97 / 0.03);
  double l = 0.0;
  for (int i = 0; i < first; ++i) l = std::clamp(l + (hits_first ? hit : miss), bottom, top);
  int n = 0;
  while ((1.0 / (1.0 + std::exp(-l)) > 0.7) == hits_first) {
    l = std::clamp(l + (hits_first ? miss : hit), bottom, top);
    ++n;
  }
  return n;
}

int octomap_free_observations_to_clear(int hits) { return octomap_observations_to_flip(true, hits); }
int octomap_hits_to_occupy(int frees) { return octomap_observations_to_flip(false, frees); }

TEST(SensorPreset, SonarIsTheReferenceDefaults) {
  const IwloParams s = sensor_preset_params(SensorPreset::kSonar), d;
  EXPECT_EQ(s.intensity_threshold, d.intensity_threshold);
  EXPECT_EQ(s.L_max, d.L_max);
  EXPECT_EQ(s.log_odds_free, d.log_odds_free);
  EXPECT_EQ(s.adaptive_enabled, d.adaptive_enabled);
  EXPECT_EQ(s.occupied_threshold, d.occupied_threshold);
}

TEST(SensorPreset, LidarMakesASingleDarkReturnOccupiedWhereSonarDoesNot) {
  for (double intensity : {0.0, 1.0, 20.0}) {
    EXPECT_GT(single_return(sensor_preset_params(SensorPreset::kLidar), intensity), 0.7) << intensity;
    EXPECT_GT(single_return(sensor_preset_params(SensorPreset::kDepthCamera), intensity), 0.7) << intensity;
    EXPECT_LT(single_return(sensor_preset_params(SensorPreset::kSonar), intensity), 0.5) << intensity;
  }
  EXPECT_GT(single_return(sensor_preset_params(SensorPreset::kSonar), 200.0), 0.7);
}

TEST(SensorPreset, LidarClearsAMovedObstacleAsFastAsOctoMap) {
  const int octomap = octomap_free_observations_to_clear(20);
  EXPECT_EQ(octomap, 7);
  const int lidar = free_observations_to_clear(sensor_preset_params(SensorPreset::kLidar), 20);
  EXPECT_LE(lidar, 8);
  EXPECT_LE(lidar, octomap);
  EXPECT_EQ(free_observations_to_clear(sensor_preset_params(SensorPreset::kDepthCamera), 20), lidar);
  // The sonar defaults keep a settled voxel far longer (speckle must not erase the seabed).
  EXPECT_GT(free_observations_to_clear(sensor_preset_params(SensorPreset::kSonar), 20), 3 * lidar);
}

// The other direction: an obstacle that appears where the map saw free space (a parked car, a
// moved box) is occupied after 6 returns however long the space was free, because L_min is
// OctoMap's lower clamp (OctoMap: 4; with L_min -10, 21 after 20 free observations); the sonar
// defaults take far longer.
TEST(SensorPreset, LidarOccupiesANewObstacleInFreeSpaceWithinSixReturns) {
  EXPECT_EQ(octomap_hits_to_occupy(20), 4);
  IwloParams deep = sensor_preset_params(SensorPreset::kLidar);
  deep.L_min = -10.0;
  for (const double intensity : {0.0, 100.0, 255.0}) {
    SCOPED_TRACE(intensity);
    const int lidar = hits_to_occupy(sensor_preset_params(SensorPreset::kLidar), 20, intensity);
    EXPECT_LE(lidar, 6);
    EXPECT_EQ(hits_to_occupy(sensor_preset_params(SensorPreset::kLidar), 200, intensity), lidar);
    EXPECT_GE(hits_to_occupy(deep, 20, intensity), 2 * lidar);
  }
  EXPECT_GT(hits_to_occupy(sensor_preset_params(SensorPreset::kSonar), 20, 200.0), 8);
}

TEST(SensorPreset, DepthCameraWeighsEveryReturnAlike) {
  const IwloParams p = sensor_preset_params(SensorPreset::kDepthCamera);
  EXPECT_EQ(single_return(p, 0.0), single_return(p, 255.0));
  const IwloParams l = sensor_preset_params(SensorPreset::kLidar);
  EXPECT_LT(single_return(l, 0.0), single_return(l, 255.0));
}

TEST(SensorPreset, NamesRoundTrip) {
  for (SensorPreset p : {SensorPreset::kSonar, SensorPreset::kLidar, SensorPreset::kDepthCamera})
    EXPECT_EQ(parse_sensor_preset(sensor_preset_name(p)), p);
  EXPECT_FALSE(parse_sensor_preset("radar"));
}

TEST(IntensityCheck, FlagsCloudsTheParametersWouldTurnIntoFreeSpace) {
  const IwloParams sonar = sensor_preset_params(SensorPreset::kSonar);
  const IwloParams lidar = sensor_preset_params(SensorPreset::kLidar);
  const Eigen::VectorXd zeros = Eigen::VectorXd::Zero(100);
  IntensityCheck c = check_intensities(zeros, sonar);
  EXPECT_EQ(c.points, 100u);
  EXPECT_EQ(c.at_or_below_threshold, 100u);
  EXPECT_TRUE(c.all_equal);
  EXPECT_TRUE(c.thins_map());
  EXPECT_NE(c.advice().find("lidar"), std::string::npos) << c.advice();
  EXPECT_FALSE(check_intensities(zeros, lidar).thins_map());

  Eigen::VectorXd mostly_dark = Eigen::VectorXd::Constant(100, 10.0);
  mostly_dark.head(49).setConstant(200.0);  // 51 % at or below 35: most returns are free space
  EXPECT_TRUE(check_intensities(mostly_dark, sonar).thins_map());
  mostly_dark.head(50).setConstant(200.0);  // half
  EXPECT_FALSE(check_intensities(mostly_dark, sonar).thins_map());
  EXPECT_TRUE(check_intensities(mostly_dark, sonar).advice().empty());

  Eigen::VectorXd bright_equal = Eigen::VectorXd::Constant(10, 200.0);
  bright_equal[3] = std::nan("");
  c = check_intensities(bright_equal, sonar);
  EXPECT_EQ(c.points, 9u);
  EXPECT_TRUE(c.all_equal);
  EXPECT_FALSE(c.thins_map());  // equal but above the threshold: every point is a hit
  EXPECT_FALSE(check_intensities(Eigen::VectorXd(), sonar).thins_map());
}

}  // namespace
}  // namespace iwlomap
