// SPDX-License-Identifier: BSD-3-Clause
// RegisteredSonarMapper on a short simulated survey (tests/support/sonar_sim.h) whose navigation
// drifts: the same submaps, corrections and map in sequential and background mode; a survey
// registered against the map of an earlier survey of the same site ends closer to the true poses
// than its navigation; bad input.

#include "iwlomap/registration/registered_sonar_mapper.h"

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

namespace iwlomap::registration {
namespace {

constexpr double kResolution = 0.1;

// Both legs of the benchmark's survey, a ping every 0.4 m, with a smaller sonar (64 beams, 96 rays
// per fan) and navigation drift of 1 % of the distance travelled.
bench::SonarSimulation simulate(std::uint32_t seed, double drift) {
  bench::SonarSimOptions o;
  o.beams = 64;
  o.elevation_rays = 96;
  o.ping_spacing = 0.4;
  o.noise = bench::light_noise();
  o.drift = drift;
  o.seed = seed;
  return bench::simulate_sonar_survey(o);
}

const bench::SonarSimulation& survey() {
  static const bench::SonarSimulation sim = simulate(3, 0.01);
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

double position_error(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return (a.translation() - b.translation()).norm();
}

// Runs pings [first, first + pings) of the survey in sequential and in background mode (a submap
// every 10 pings) and checks that both give the same submaps, corrections and map.
void expect_same_in_both_modes(std::size_t first, std::size_t pings) {
  const bench::SonarSimulation& sim = survey();
  ASSERT_LE(first + pings, sim.pings.size());
  const auto run = [&](ExecutionMode mode) {
    auto map = empty_map();
    RegisteredSonarMapperOptions o;
    o.pings_per_submap = 10;
    RegisteredSonarMapper mapper(map, projector(), mode, o);
    for (std::size_t i = first; i < first + pings; ++i)
      mapper.integrate(sim.pings[i].nav_pose, make_sonar_image_view(sim.pings[i].image), sim.geometry);
    std::vector<RegisteredSubmap> submaps = mapper.sync();
    return std::make_tuple(std::move(submaps), log_odds_of(*map), mapper.correction());
  };
  const auto [sequential, seq_map, seq_correction] = run(ExecutionMode::kSequential);
  const auto [parallel, par_map, par_correction] = run(ExecutionMode::kParallel);
  ASSERT_EQ(sequential.size(), (pings + 9) / 10);
  ASSERT_EQ(sequential.size(), parallel.size());
  std::size_t integrated = 0;
  std::size_t matched = 0;  // submaps matched against the map (registered or refused)
  for (std::size_t i = 0; i < sequential.size(); ++i) {
    EXPECT_EQ(sequential[i].first_ping, integrated);
    integrated += sequential[i].pings;
    const auto min_voxels = static_cast<std::size_t>(RegisteredSonarMapperOptions{}.min_submap_voxels);
    matched += i > 0 && sequential[i].occupied_voxels >= min_voxels ? 1 : 0;
    EXPECT_EQ(sequential[i].registered, parallel[i].registered) << i;
    EXPECT_TRUE(sequential[i].correction.isApprox(parallel[i].correction, 0.0)) << i;
    ASSERT_EQ(sequential[i].integrated_poses.size(), sequential[i].pings);
    // Every beam of every ping was projected once, as integrated.
    EXPECT_EQ(sequential[i].beams_with_return + sequential[i].beams_without_return, sequential[i].pings * 64);
    EXPECT_GT(sequential[i].observations, 0u);
    EXPECT_EQ(sequential[i].observations, parallel[i].observations);
  }
  EXPECT_EQ(integrated, pings);
  EXPECT_FALSE(sequential.front().registered);  // nothing to register against yet
  EXPECT_GE(matched, sequential.size() / 2);    // the background mode had matches to run
  EXPECT_TRUE(seq_correction.isApprox(par_correction, 0.0));
  EXPECT_EQ(seq_map, par_map);
  EXPECT_GT(seq_map.size(), 1000u * sequential.size());
}

// Both legs: the second registers against the first.
TEST(RegisteredSonarMapper, SameSubmapsAndMapInBothModes) { expect_same_in_both_modes(0, survey().pings.size()); }

// Six submaps around the turn (the end of the first leg, the start of the second, which registers
// against it): the short run that the ThreadSanitizer stage of the test command takes (the whole
// survey is a five-minute run under the sanitizer).
TEST(RegisteredSonarMapper, SameInBothModesOnAShortRun) { expect_same_in_both_modes(60, 60); }

// A repeat survey of a charted site: the map of an earlier survey (other noise, true poses) is
// there, the new survey's navigation drifts. Registered against the chart, the new survey's
// poses end much closer to the truth than its navigation.
TEST(RegisteredSonarMapper, ARepeatSurveyRegistersAgainstTheChart) {
  const bench::SonarSimulation& sim = survey();
  auto map = empty_map();
  const SonarImageProjector p = projector();
  const bench::SonarSimulation earlier = simulate(4, 0.0);
  for (const bench::SimulatedPing& ping : earlier.pings)
    static_cast<void>(p.integrate(*map, make_sonar_image_view(ping.image), sim.geometry, ping.pose));
  RegisteredSonarMapperOptions o;
  o.pings_per_submap = 20;  // 8 m of travel, as the default at a ping every 0.1 m
  RegisteredSonarMapper mapper(map, p, ExecutionMode::kSequential, o);
  double nav_error = 0.0, registered_error = 0.0;
  for (const bench::SimulatedPing& ping : sim.pings)
    mapper.integrate(ping.nav_pose, make_sonar_image_view(ping.image), sim.geometry);
  const std::vector<RegisteredSubmap> submaps = mapper.sync();
  std::size_t i = 0, registered = 0;
  for (const RegisteredSubmap& s : submaps) {
    registered += s.registered ? 1 : 0;
    EXPECT_TRUE(s.registered) << "submap at ping " << s.first_ping << ": " << s.match.reason;
    for (const Eigen::Isometry3d& pose : s.integrated_poses) {
      nav_error += position_error(sim.pings[i].nav_pose, sim.pings[i].pose);
      registered_error += position_error(pose, sim.pings[i].pose);
      ++i;
    }
  }
  nav_error /= static_cast<double>(i);
  registered_error /= static_cast<double>(i);
  std::printf("%zu of %zu submaps registered; mean position error %.3f m, navigation %.3f m\n", registered,
              submaps.size(), registered_error, nav_error);
  EXPECT_GT(nav_error, 0.3);
  EXPECT_LT(registered_error, 0.2 * nav_error);
}

TEST(RegisteredSonarMapper, RefusesBadInput) {
  const SonarImageProjector p = projector();
  EXPECT_THROW(RegisteredSonarMapper(nullptr, p, ExecutionMode::kSequential), std::invalid_argument);
  EXPECT_THROW(RegisteredSonarMapper(std::make_shared<ProbabilityUpdater>(0.2), p, ExecutionMode::kSequential),
               std::invalid_argument);  // resolution mismatch
  RegisteredSonarMapperOptions o;
  o.pings_per_submap = 0;
  EXPECT_THROW(RegisteredSonarMapper(empty_map(), p, ExecutionMode::kSequential, o), std::invalid_argument);
  o = RegisteredSonarMapperOptions{};
  o.min_submap_voxels = 7;
  EXPECT_THROW(RegisteredSonarMapper(empty_map(), p, ExecutionMode::kSequential, o), std::invalid_argument);
  o = RegisteredSonarMapperOptions{};
  o.max_fitness_rmse = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(RegisteredSonarMapper(empty_map(), p, ExecutionMode::kSequential, o), std::invalid_argument);
  o = RegisteredSonarMapperOptions{};
  o.matcher.icp.max_iterations = 0;
  EXPECT_THROW(RegisteredSonarMapper(empty_map(), p, ExecutionMode::kParallel, o), std::invalid_argument);

  RegisteredSonarMapper mapper(empty_map(), p, ExecutionMode::kSequential);
  const bench::SonarSimulation& sim = survey();
  const SonarImageView view = make_sonar_image_view(sim.pings.front().image);
  Eigen::Isometry3d nan_pose = Eigen::Isometry3d::Identity();
  nan_pose.translation().y() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(mapper.integrate(nan_pose, view, sim.geometry), std::invalid_argument);
  EXPECT_THROW(mapper.integrate(Eigen::Isometry3d::Identity(), SonarImageView{}, sim.geometry), std::invalid_argument);
  SonarGeometry fewer = sim.geometry;
  fewer.bearings.pop_back();  // one bearing short of the image's beams
  EXPECT_THROW(mapper.integrate(Eigen::Isometry3d::Identity(), view, fewer), std::invalid_argument);
  EXPECT_TRUE(mapper.sync().empty());  // nothing was queued
}

}  // namespace
}  // namespace iwlomap::registration
