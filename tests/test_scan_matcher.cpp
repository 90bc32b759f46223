// SPDX-License-Identifier: BSD-3-Clause
// ScanMatcher (coarse branch and bound, then point-to-plane ICP): recovery of known poses from
// large initial errors on the courtyard and a scene of pillars, the degenerate single plane, scans
// that miss the map, bad input, and the recorded Ouster frames against their SLAM poses.

#include "iwlomap/registration/registered_mapper.h"
#include "iwlomap/registration/scan_matcher.h"

#include "iwlomap/probability_updater.h"
#include "iwlomap/sensor_preset.h"
#include "iwlomap/synthetic_scan.h"
#include "iwlomap/synthetic_world.h"
#include "repetitions.h"

#include <gtest/gtest.h>

#ifdef IWLOMAP_TEST_WITH_PCL
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>
#endif

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <random>
#include <stdexcept>
#include <vector>

namespace iwlomap::registration {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

struct Scene {
  std::shared_ptr<ProbabilityUpdater> map;
  Eigen::MatrixXd scan_sensor;  // a second sample of the scene, sensor frame
  Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
};

// A map (0.2 m, lidar preset, mean hit positions) of \p world seen from \p origin, and a scan.
Scene make_scene(const Eigen::MatrixXd& map_points, const Eigen::MatrixXd& scan_points, const Eigen::Vector3d& origin) {
  Scene s;
  s.map = std::make_shared<ProbabilityUpdater>(0.2);
  s.map->set_params(sensor_preset_params(SensorPreset::kLidar));
  s.map->set_hit_accumulation(true);
  s.map->insert_scan(origin, map_points, Eigen::VectorXd::Constant(map_points.rows(), 100.0));
  s.truth.translation() = origin;
  s.scan_sensor = scan_points.rowwise() - origin.transpose();
  return s;
}

const Scene& courtyard() {
  static const Scene s = [] {
    const SyntheticScan a = make_synthetic_scan();
    SyntheticScanOptions o;
    o.seed = 2;  // another noise draw of the same scene
    const SyntheticScan b = make_synthetic_scan(o);
    Eigen::MatrixXd every_fourth(b.points.rows() / 4, 3);
    for (Eigen::Index i = 0; i < every_fourth.rows(); ++i) every_fourth.row(i) = b.points.row(4 * i);
    return make_scene(a.points, every_fourth, a.origin);
  }();
  return s;
}

Eigen::MatrixXd pillars(std::uint32_t seed, double noise) { return make_pillar_scene(seed, noise); }

const Scene& pillar_scene() {
  static const Scene s = make_scene(pillars(1, 0.005), pillars(2, 0.01), Eigen::Vector3d(0.3, -0.2, 1.2));
  return s;
}

Eigen::Isometry3d perturbed(const Eigen::Isometry3d& pose, const Eigen::Vector3d& dt, double dyaw) {
  Eigen::Isometry3d p = pose;
  p.linear() = Eigen::AngleAxisd(dyaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() * pose.linear();
  p.translation() += dt;
  return p;
}

double angle_between(const Eigen::Isometry3d& a, const Eigen::Isometry3d& b) {
  return Eigen::AngleAxisd(a.linear().transpose() * b.linear()).angle();
}

// >= 50 initial errors up to 0.8 m (horizontal), 0.3 m (vertical) and 8 degrees: the pose within
// 3 cm and 0.3 degrees in at least 95 % of the trials.
void expect_recovery(const Scene& s, std::uint32_t seed) {
  ScanMatcher matcher(*s.map);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const int trials = test_support::repetitions(50, 12);
  int good = 0;
  double worst_t = 0.0, worst_r = 0.0;
  for (int trial = 0; trial < trials; ++trial) {
    Eigen::Vector3d dt(u(rng), u(rng), 0.3 * u(rng));
    dt.head<2>() *= 0.8 * std::abs(u(rng)) / std::max(1e-9, dt.head<2>().norm());
    const Eigen::Isometry3d initial = perturbed(s.truth, dt, 8.0 * kDeg * u(rng));
    const ScanMatchResult r = matcher.match(s.scan_sensor, initial);
    const double et = (r.pose.translation() - s.truth.translation()).norm();
    const double er = angle_between(r.pose, s.truth);
    if (r.converged && et <= 0.03 && er <= 0.3 * kDeg) ++good;
    if (r.converged) {
      worst_t = std::max(worst_t, et);
      worst_r = std::max(worst_r, er);
    }
    EXPECT_TRUE(r.converged) << "trial " << trial << ": " << r.reason;
  }
  EXPECT_GE(good, trials - 2) << "of " << trials << "; worst converged error " << worst_t << " m, " << worst_r / kDeg << " deg";
  std::printf("recovered %d of %d; worst converged error %.4f m, %.4f deg\n", good, trials, worst_t, worst_r / kDeg);
}

TEST(ScanMatcher, RecoversTheCourtyardPoseFromLargeInitialErrors) { expect_recovery(courtyard(), 3); }

TEST(ScanMatcher, RecoversThePillarScenePoseFromLargeInitialErrors) { expect_recovery(pillar_scene(), 4); }

// A single plane constrains z, roll and pitch only: refused as degenerate when asked to, and by
// default accepted with x, y and yaw held at the initial pose and only the constrained directions
// corrected.
TEST(ScanMatcher, ASinglePlaneIsDegenerateAndItsFreeDirectionsAreHeldAtThePrior) {
  Eigen::MatrixXd plane(4000, 3);
  std::mt19937 rng(1);
  std::uniform_real_distribution<double> u(-8.0, 8.0);
  for (Eigen::Index i = 0; i < plane.rows(); ++i) plane.row(i) << u(rng), u(rng), 0.0;
  const Scene s = make_scene(plane, plane, Eigen::Vector3d(0.0, 0.0, 1.5));
  ScanMatcherOptions o;
  o.coarse = false;  // a plane matches anywhere in x, y and yaw: only ICP can say so
  o.quality.hold_unconstrained = false;
  const Eigen::Isometry3d initial = perturbed(s.truth, {0.3, 0.2, 0.05}, 0.02);
  const ScanMatchResult r = ScanMatcher(*s.map, o).match(s.scan_sensor, initial);
  EXPECT_FALSE(r.converged);
  EXPECT_NE(r.reason.find("degenerate"), std::string::npos) << r.reason;
  ASSERT_EQ(r.unobservable.cols(), 3);
  // The free directions span x, y translation and rotation about z.
  for (Eigen::Index c = 0; c < 3; ++c) {
    const auto v = r.unobservable.col(c);
    EXPECT_NEAR(v(2) * v(2) + v(3) * v(3) + v(4) * v(4), 0.0, 1e-6) << v.transpose();
  }
  EXPECT_GE(r.covariance(0, 0), 1e5);
  EXPECT_LT(r.covariance(2, 2), 1e-3);  // z is well constrained
  EXPECT_TRUE(r.pose.isApprox(initial));  // the initial pose, unchanged

  o.quality.hold_unconstrained = true;
  const ScanMatchResult held = ScanMatcher(*s.map, o).match(s.scan_sensor, initial);
  EXPECT_TRUE(held.converged) << held.reason;
  EXPECT_EQ(held.held_directions, 3);
  EXPECT_NEAR(held.pose.translation().z(), s.truth.translation().z(), 0.01);      // corrected
  EXPECT_NEAR(held.pose.translation().x(), initial.translation().x(), 1e-6);      // held
  EXPECT_NEAR(held.pose.translation().y(), initial.translation().y(), 1e-6);      // held
  const Eigen::Matrix3d turn = held.pose.linear() * initial.linear().transpose();
  EXPECT_NEAR(std::atan2(turn(1, 0), turn(0, 0)), 0.0, 1e-6);                     // yaw held
  EXPECT_GE(held.covariance(0, 0), 1e5);
}

// ICP alone from the identity pose (1.5 m below the courtyard's sensor) settles 0.8 m off with
// every wall paired: without the match-quality model that is reported converged; with it, the
// ground's poor fit refuses it.
TEST(ScanMatcher, TheQualityModelRefusesAWrongPoseThatIcpReportsConverged) {
  const Scene& s = courtyard();
  ScanMatcherOptions o;
  o.coarse = false;
  ScanMatcherOptions off = o;
  off.quality.min_inlier_fraction = 0.0;
  off.quality.min_axis_support = 0.0;
  off.quality.max_free_conflict = 1.0;
  const Eigen::Isometry3d initial = Eigen::Isometry3d::Identity();
  const ScanMatchResult wrong = ScanMatcher(*s.map, off).match(s.scan_sensor, initial);
  ASSERT_TRUE(wrong.converged) << wrong.reason;
  EXPECT_GT((wrong.pose.translation() - s.truth.translation()).norm(), 0.3);
  const ScanMatchResult r = ScanMatcher(*s.map, o).match(s.scan_sensor, initial);
  EXPECT_FALSE(r.converged);
  EXPECT_NE(r.reason.find("match quality"), std::string::npos) << r.reason;
  EXPECT_TRUE(r.pose.isApprox(initial));
  EXPECT_LT(r.axis_support.z(), 0.7);
  // At the true pose every statistic is near its best.
  const ScanMatchResult right = ScanMatcher(*s.map, o).match(s.scan_sensor, s.truth);
  EXPECT_TRUE(right.converged) << right.reason;
  EXPECT_GT(right.inlier_fraction, 0.9);
  EXPECT_GT(right.axis_support.minCoeff(), 0.9);
  EXPECT_LT(right.free_conflict, 0.1);
}

TEST(ScanMatcher, PlanarIcpHoldsHeightRollAndPitch) {
  const Scene& s = pillar_scene();
  Eigen::Isometry3d initial = perturbed(s.truth, {0.15, -0.1, 0.04}, 2.0 * kDeg);
  initial.linear() = initial.linear() * Eigen::AngleAxisd(0.5 * kDeg, Eigen::Vector3d::UnitX()).toRotationMatrix();
  ScanMatcherOptions o;
  o.coarse = false;
  o.icp.planar = true;
  const ScanMatchResult r = ScanMatcher(*s.map, o).match(s.scan_sensor, initial);
  ASSERT_TRUE(r.converged) << r.reason;
  EXPECT_NEAR(r.pose.translation().z(), initial.translation().z(), 1e-9);
  // The turn from the initial pose to the result is about the map's z axis only.
  const Eigen::Matrix3d turn = r.pose.linear() * initial.linear().transpose();
  EXPECT_NEAR(turn(2, 2), 1.0, 1e-12);
  EXPECT_NEAR((turn * Eigen::Vector3d::UnitZ() - Eigen::Vector3d::UnitZ()).norm(), 0.0, 1e-9);
  EXPECT_LE((r.pose.translation() - s.truth.translation()).head<2>().norm(), 0.03);
  const double yaw_error = std::atan2(turn(1, 0), turn(0, 0)) + 2.0 * kDeg;  // the turn undoes the 2 degrees
  EXPECT_LE(std::abs(yaw_error), 0.3 * kDeg);
  for (const int k : {2, 3, 4}) {
    EXPECT_EQ(r.covariance.row(k).norm(), 0.0) << k;
    EXPECT_EQ(r.covariance.col(k).norm(), 0.0) << k;
  }
  EXPECT_GT(r.covariance(0, 0), 0.0);
  EXPECT_EQ(r.unobservable.cols(), 0);
  // 6 DoF from the same guess moves the height back to the truth.
  o.icp.planar = false;
  const ScanMatchResult full = ScanMatcher(*s.map, o).match(s.scan_sensor, initial);
  ASSERT_TRUE(full.converged) << full.reason;
  EXPECT_LE(std::abs(full.pose.translation().z() - s.truth.translation().z()), 0.03);
}

TEST(ScanMatcher, AScanThatMissesTheMapIsNotConverged) {
  const Scene& s = courtyard();
  const Eigen::Isometry3d far = perturbed(s.truth, {500.0, 0.0, 0.0}, 0.0);
  const ScanMatchResult coarse = ScanMatcher(*s.map).match(s.scan_sensor, far);
  EXPECT_FALSE(coarse.converged);
  EXPECT_NE(coarse.reason.find("coarse"), std::string::npos) << coarse.reason;
  EXPECT_TRUE(coarse.pose.isApprox(far));
  ScanMatcherOptions fine_only;
  fine_only.coarse = false;
  const ScanMatchResult fine = ScanMatcher(*s.map, fine_only).match(s.scan_sensor, far);
  EXPECT_FALSE(fine.converged);
  EXPECT_NE(fine.reason.find("correspondences"), std::string::npos) << fine.reason;
  ProbabilityUpdater empty(0.2);
  const ScanMatchResult none = ScanMatcher(empty).match(s.scan_sensor, s.truth);
  EXPECT_FALSE(none.converged);
  EXPECT_NE(none.reason.find("empty"), std::string::npos) << none.reason;
}

TEST(ScanMatcher, BadInputThrows) {
  const Scene& s = courtyard();
  ScanMatcher matcher(*s.map);
  EXPECT_THROW((void)matcher.match(Eigen::MatrixXd(0, 3), s.truth), std::invalid_argument);
  EXPECT_THROW((void)matcher.match(Eigen::MatrixXd::Constant(5, 3, std::nan("")), s.truth), std::invalid_argument);
  Eigen::Isometry3d nan_pose = s.truth;
  nan_pose.translation().y() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW((void)matcher.match(s.scan_sensor, nan_pose), std::invalid_argument);
  ScanMatcherOptions o;
  o.window.linear_xy = 0.0;
  EXPECT_THROW(ScanMatcher(*s.map, o), std::invalid_argument);
  o = ScanMatcherOptions{};
  o.window.angular_yaw = -1.0;
  EXPECT_THROW(ScanMatcher(*s.map, o), std::invalid_argument);
  o = ScanMatcherOptions{};
  o.icp.max_correspondence_distance = 0.0;
  EXPECT_THROW(ScanMatcher(*s.map, o), std::invalid_argument);
  o = ScanMatcherOptions{};
  o.coarse = o.fine = false;
  EXPECT_THROW(ScanMatcher(*s.map, o), std::invalid_argument);
  EXPECT_THROW(MapSurface(Eigen::MatrixXd::Zero(3, 3)), std::invalid_argument);
}

// Six scans of the pillar scene along a path whose navigation drifts 8 cm and 0.5 degrees per
// scan: the mapper corrects every pose to within 3 cm / 0.3 degrees of the truth, in sequential
// and background mode alike (the same poses and the same map, bit for bit).
TEST(RegisteredMapper, CorrectsADriftingPathTheSameInBothModes) {
  const Eigen::MatrixXd world = pillars(7, 0.005);
  std::vector<Eigen::Isometry3d> truth, given;
  for (int k = 0; k < 6; ++k) {
    Eigen::Isometry3d t = Eigen::Isometry3d::Identity();
    t.linear() = Eigen::AngleAxisd(0.02 * k, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    t.translation() = Eigen::Vector3d(0.5 * k, 0.2 * k, 1.2);
    truth.push_back(t);
    given.push_back(perturbed(t, Eigen::Vector3d(0.08 * k, 0.0, 0.0), 0.5 * kDeg * k));
  }
  const auto scan_of = [&](int k) {  // another sample of the scene in the sensor frame of pose k
    const Eigen::MatrixXd w = pillars(100 + static_cast<std::uint32_t>(k), 0.01);
    return Eigen::MatrixXd((w.rowwise() - truth[k].translation().transpose()) * truth[k].linear());
  };
  const auto run = [&](ExecutionMode mode) {
    auto map = std::make_shared<ProbabilityUpdater>(0.2);
    map->set_params(sensor_preset_params(SensorPreset::kLidar));
    map->set_hit_accumulation(true);
    RegisteredMapper mapper(map, mode);
    for (int k = 0; k < 6; ++k) {
      const Eigen::MatrixXd scan = scan_of(k);
      mapper.integrate(given[k], scan, Eigen::VectorXd::Constant(scan.rows(), 100.0));
    }
    std::vector<RegisteredScan> results = mapper.sync();
    return std::make_pair(std::move(results), map->get_occupied_voxels(0.7));
  };
  const auto [sequential, seq_map] = run(ExecutionMode::kSequential);
  const auto [parallel, par_map] = run(ExecutionMode::kParallel);
  ASSERT_EQ(sequential.size(), 6u);
  ASSERT_EQ(parallel.size(), 6u);
  EXPECT_FALSE(sequential[0].registered);  // nothing to register against yet
  for (int k = 1; k < 6; ++k) {
    const RegisteredScan& r = sequential[static_cast<std::size_t>(k)];
    EXPECT_TRUE(r.registered) << "scan " << k << ": " << r.match.reason;
    EXPECT_LE((r.integrated_pose.translation() - truth[k].translation()).norm(), 0.03) << "scan " << k;
    EXPECT_LE(angle_between(r.integrated_pose, truth[k]), 0.3 * kDeg) << "scan " << k;
    // From the second registered scan on, the guess carries the last correction: closer to the
    // truth than the drifting pose.
    if (k >= 2) {
      EXPECT_LT((r.initial_guess.translation() - truth[k].translation()).norm(),
                (given[k].translation() - truth[k].translation()).norm())
          << "scan " << k;
    }
    EXPECT_TRUE(r.integrated_pose.isApprox(parallel[static_cast<std::size_t>(k)].integrated_pose, 0.0)) << "scan " << k;
  }
  EXPECT_TRUE(seq_map.isApprox(par_map, 0.0));
  EXPECT_EQ(seq_map.rows(), par_map.rows());
}

TEST(RegisteredMapper, RefusesBadInput) {
  EXPECT_THROW(RegisteredMapper(nullptr, ExecutionMode::kSequential), std::invalid_argument);
  auto map = std::make_shared<ProbabilityUpdater>(0.2);
  RegisteredMapper mapper(map, ExecutionMode::kSequential);
  Eigen::Isometry3d nan_pose = Eigen::Isometry3d::Identity();
  nan_pose.translation().x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW(mapper.integrate(nan_pose, Eigen::MatrixXd::Zero(3, 3), Eigen::VectorXd::Zero(3)), std::invalid_argument);
  EXPECT_THROW(mapper.integrate(Eigen::Isometry3d::Identity(), Eigen::MatrixXd::Zero(3, 3), Eigen::VectorXd::Zero(2)),
               std::invalid_argument);
  RegisteredMapperOptions o;
  o.matcher.window.linear_z = -1.0;
  EXPECT_THROW(RegisteredMapper(map, ExecutionMode::kParallel, o), std::invalid_argument);
}

#ifdef IWLOMAP_TEST_WITH_PCL
// Frames 1 and 2 of the Ouster recording against the map of frame 0, from initial guesses 0.5 m /
// 5 degrees off the recorded SLAM poses: within 5 cm / 0.5 degrees of them.
TEST(ScanMatcherData, OusterFramesRegisterAgainstTheFirstFrame) {
  const std::filesystem::path dir = std::filesystem::path(IWLOMAP_SHARED_DATA_DIR) / "ouster_os1_128_3frames";
  if (!std::filesystem::exists(dir / "frame_000_world.pcd")) GTEST_SKIP() << "no Ouster frames in " << dir;
  struct Frame {
    Eigen::MatrixXd world;
    Eigen::VectorXd intensity;
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  };
  const auto load = [&](int k) {
    pcl::PointCloud<pcl::PointXYZI> c;
    char name[64];
    std::snprintf(name, sizeof name, "frame_%03d_world.pcd", k);
    if (pcl::io::loadPCDFile((dir / name).string(), c) < 0) throw std::runtime_error("cannot read the frame");
    Frame f;
    f.world.resize(static_cast<Eigen::Index>(c.size()), 3);
    f.intensity.resize(static_cast<Eigen::Index>(c.size()));
    for (std::size_t i = 0; i < c.size(); ++i) {
      f.world.row(static_cast<Eigen::Index>(i)) << c[i].x, c[i].y, c[i].z;
      f.intensity[static_cast<Eigen::Index>(i)] = c[i].intensity;
    }
    f.pose.linear() = c.sensor_orientation_.cast<double>().normalized().toRotationMatrix();
    f.pose.translation() = c.sensor_origin_.head<3>().cast<double>();
    return f;
  };
  const Frame f0 = load(0);
  ProbabilityUpdater map(0.2);
  map.set_params(sensor_preset_params(SensorPreset::kLidar));
  map.set_hit_accumulation(true);
  map.insert_scan(f0.pose.translation(), f0.world, f0.intensity, 60.0);
  ScanMatcher matcher(map);
  for (int k : {1, 2}) {
    const Frame f = load(k);
    // The frame in its sensor frame: p_sensor = pose^-1 p_world.
    const Eigen::MatrixXd sensor = ((f.world.rowwise() - f.pose.translation().transpose()) * f.pose.linear());
    for (const double sign : {1.0, -1.0}) {
      const Eigen::Isometry3d initial = perturbed(f.pose, sign * Eigen::Vector3d(0.35, -0.35, 0.0), sign * 5.0 * kDeg);
      const ScanMatchResult r = matcher.match(sensor, initial);
      const double et = (r.pose.translation() - f.pose.translation()).norm();
      const double er = angle_between(r.pose, f.pose);
      std::printf("frame %d, initial error %+.2f: converged %d, residual to the SLAM pose %.4f m, %.4f deg, "
                  "rmse %.4f m, %d iterations, %zu of %zu paired\n",
                  k, sign, r.converged, et, er / kDeg, r.fitness_rmse, r.iterations, r.pairs, r.scan_points);
      EXPECT_TRUE(r.converged) << r.reason;
      EXPECT_LE(et, 0.05);
      EXPECT_LE(er, 0.5 * kDeg);
    }
  }
}
#endif

}  // namespace
}  // namespace iwlomap::registration
