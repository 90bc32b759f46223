// SPDX-License-Identifier: BSD-3-Clause
// SonarPoseGraphMapper on short simulated surveys (tests/support/sonar_sim.h) whose navigation
// drifts: a survey that runs its first line again closes loops and ends closer to the truth than
// its navigation; one that never revisits a line with the same heading finds no closure and maps
// every ping at its navigation pose; submaps are cut at turns; bad input.

#include "iwlomap/slam/sonar_pose_graph_mapper.h"

#include "iwlomap/probability_updater.h"
#include "sonar_sim.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <stdexcept>
#include <tuple>
#include <vector>

namespace iwlomap::slam {
namespace {

constexpr double kResolution = 0.1;

// The benchmark's survey with a smaller sonar (64 beams, 96 rays per fan), a ping every
// `spacing` metres, light noise and navigation drift of 1 % of the distance travelled.
bench::SonarSimulation simulate(int legs, std::uint32_t seed, double spacing) {
  bench::SonarSimOptions o;
  o.beams = 64;
  o.elevation_rays = 96;
  o.ping_spacing = spacing;
  o.noise = bench::light_noise();
  o.drift = 0.01;
  o.seed = seed;
  o.legs = legs;
  return bench::simulate_sonar_survey(o);
}

// Out and back: the return leg sees the first leg's seabed from the other heading only.
const bench::SonarSimulation& out_and_back() {
  static const bench::SonarSimulation sim = simulate(2, 2, 0.4);  // 81 pings a leg
  return sim;
}

std::shared_ptr<ProbabilityUpdater> empty_map() {
  auto map = std::make_shared<ProbabilityUpdater>(kResolution);
  IwloParams p;
  p.intensity_threshold = 35.0;
  map->set_params(p);
  return map;
}

SonarImageProjector projector() {
  SonarProjectorParams p;
  p.intensity_threshold = 35.0;
  return SonarImageProjector(kResolution, p);
}

std::map<std::tuple<int, int, int>, double> log_odds_of(const IMapperBackend& map) {
  std::map<std::tuple<int, int, int>, double> out;
  map.for_each_voxel([&](const VoxelKey& k, const VoxelState& s) { out[{k.x, k.y, k.z}] = s.log_odds; });
  return out;
}

double rms_position_error(const bench::SonarSimulation& sim, const std::vector<Eigen::Isometry3d>& poses) {
  double sum = 0.0;
  for (std::size_t i = 0; i < poses.size(); ++i)
    sum += (sim.pings[i].pose.translation() - poses[i].translation()).squaredNorm();
  return std::sqrt(sum / static_cast<double>(poses.size()));
}

std::vector<Eigen::Isometry3d> navigation(const bench::SonarSimulation& sim) {
  std::vector<Eigen::Isometry3d> out;
  for (const bench::SimulatedPing& ping : sim.pings) out.push_back(ping.nav_pose);
  return out;
}

void feed(SonarPoseGraphMapper& mapper, const bench::SonarSimulation& sim) {
  for (const bench::SimulatedPing& ping : sim.pings)
    mapper.integrate(ping.nav_pose, make_sonar_image_view(ping.image), sim.geometry);
}

TEST(SonarPoseGraphMapper, ARepeatedLineClosesLoopsAndCorrectsTheDrift) {
  const bench::SonarSimulation sim = simulate(3, 1, 0.2);
  auto map = empty_map();
  SonarPoseGraphMapperOptions o;
  o.pings_per_submap = 40;  // 8 m
  SonarPoseGraphMapper mapper(map, projector(), o);
  feed(mapper, sim);
  mapper.finish();
  const SonarSlamSummary sum = mapper.summary();
  EXPECT_EQ(sum.pings, sim.pings.size());
  EXPECT_GE(sum.closures_found, 2u);
  EXPECT_GE(sum.optimizations, 1u);
  const double nav = rms_position_error(sim, navigation(sim));
  const double corrected = rms_position_error(sim, mapper.poses());
  std::printf("RMS position error: navigation %.3f m, loop closure %.3f m; %zu closures\n", nav, corrected,
              sum.closures_found);
  EXPECT_GT(nav, 0.3);
  EXPECT_LT(corrected, 0.5 * nav);
  // Depth stays the navigation's: only x, y and yaw are corrected.
  const std::vector<Eigen::Isometry3d> poses = mapper.poses();
  for (std::size_t i = 0; i < poses.size(); ++i)
    EXPECT_NEAR(poses[i].translation().z(), sim.pings[i].nav_pose.translation().z(), 1e-6) << "ping " << i;
  // Every closure pairs submaps at least closure_min_submap_gap apart, of one heading.
  for (const SonarLoopClosure& c : mapper.loop_closures()) EXPECT_GE(c.submap, c.target + 2);
  EXPECT_GT(map->get_num_known_voxels(), 0u);
}

TEST(SonarPoseGraphMapper, WithoutARevisitedLineItMapsAtTheNavigationPoses) {
  const bench::SonarSimulation& sim = out_and_back();
  auto map = empty_map();
  SonarPoseGraphMapperOptions o;
  o.pings_per_submap = 20;
  SonarPoseGraphMapper mapper(map, projector(), o);
  feed(mapper, sim);
  mapper.finish();
  EXPECT_EQ(mapper.summary().closures_found, 0u);
  EXPECT_EQ(mapper.summary().optimizations, 0u);
  const std::vector<Eigen::Isometry3d> poses = mapper.poses();
  ASSERT_EQ(poses.size(), sim.pings.size());
  for (std::size_t i = 0; i < poses.size(); ++i)
    EXPECT_TRUE(poses[i].isApprox(sim.pings[i].nav_pose, 1e-12)) << "ping " << i;
  // The map is the navigation's map, voxel for voxel.
  auto reference = empty_map();
  const SonarImageProjector p = projector();
  for (const bench::SimulatedPing& ping : sim.pings)
    static_cast<void>(p.integrate(*reference, make_sonar_image_view(ping.image), sim.geometry, ping.nav_pose));
  EXPECT_EQ(log_odds_of(*map), log_odds_of(*reference));
}

TEST(SonarPoseGraphMapper, SubmapsAreCutAtTurns) {
  const bench::SonarSimulation& sim = out_and_back();
  SonarPoseGraphMapperOptions o;
  o.pings_per_submap = 50;
  SonarPoseGraphMapper mapper(empty_map(), projector(), o);
  feed(mapper, sim);
  mapper.finish();
  const std::vector<SonarSubmapReport>& submaps = mapper.submaps();
  // 50 + 31 pings on the first leg, then the same on the way back.
  ASSERT_EQ(submaps.size(), 4u);
  EXPECT_EQ(submaps[0].pings, 50u);
  EXPECT_EQ(submaps[1].pings, 31u);
  EXPECT_EQ(submaps[2].first_ping, 81u);
  EXPECT_EQ(submaps[3].first_ping + submaps[3].pings, sim.pings.size());
}

TEST(SonarPoseGraphMapper, RefusesBadInput) {
  EXPECT_THROW(SonarPoseGraphMapper(nullptr, projector()), std::invalid_argument);
  EXPECT_THROW(SonarPoseGraphMapper(std::make_shared<ProbabilityUpdater>(0.2), projector()), std::invalid_argument);
  SonarPoseGraphMapperOptions bad;
  bad.pings_per_submap = 0;
  EXPECT_THROW(SonarPoseGraphMapper(empty_map(), projector(), bad), std::invalid_argument);
  bad = {};
  bad.max_fitness_rmse = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(SonarPoseGraphMapper(empty_map(), projector(), bad), std::invalid_argument);
  bad = {};
  bad.odometry_rotation_sigma_per_metre = 0.0;
  EXPECT_THROW(SonarPoseGraphMapper(empty_map(), projector(), bad), std::invalid_argument);

  SonarPoseGraphMapper mapper(empty_map(), projector());
  const SonarImage8 image = SonarImage8::Constant(40, 8, 10);
  SonarGeometry geometry;
  for (int b = 0; b < 8; ++b) geometry.bearings.push_back(-0.2 + 0.05 * b);
  geometry.range_resolution = 0.05;
  geometry.max_range = 2.0;
  Eigen::Isometry3d nan_pose = Eigen::Isometry3d::Identity();
  nan_pose.translation().x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(mapper.integrate(nan_pose, make_sonar_image_view(image), geometry), std::invalid_argument);
  mapper.integrate(Eigen::Isometry3d::Identity(), make_sonar_image_view(image), geometry);
  mapper.finish();
  EXPECT_EQ(mapper.poses().size(), 1u);
  EXPECT_THROW(mapper.finish(), std::logic_error);
  EXPECT_THROW(mapper.integrate(Eigen::Isometry3d::Identity(), make_sonar_image_view(image), geometry),
               std::logic_error);
}

}  // namespace
}  // namespace iwlomap::slam
