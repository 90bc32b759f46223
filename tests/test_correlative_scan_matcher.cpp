// SPDX-License-Identifier: BSD-3-Clause
// CorrelativeScanMatcher3D: branch and bound against exhaustive search over the same discretised
// windows, recovery of a displaced scan, and bad input.

#include "iwlomap/registration/correlative_scan_matcher.h"
#include "iwlomap/correlative_scan_matcher.h"  // the deprecated path still compiles
#include "iwlomap/probability_updater.h"
#include "iwlomap/sensor_preset.h"
#include "iwlomap/synthetic_scan.h"
#include "repetitions.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <stdexcept>
#include <type_traits>

namespace iwlomap::registration {
namespace {

// The old names are aliases of the registration layer's (deprecated: a warning where used).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wdeprecated-declarations"
static_assert(std::is_same_v<iwlomap::CorrelativeScanMatcher3D, CorrelativeScanMatcher3D>);
static_assert(std::is_same_v<iwlomap::SearchWindow3D, SearchWindow3D>);
#pragma GCC diagnostic pop

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

// The courtyard mapped at 0.2 m from its true sensor pose, and every 16th of its points in the
// sensor frame (translation only: the synthetic sensor is level and looks along +x).
struct Scene {
  ProbabilityUpdater map{0.2};
  Eigen::MatrixXd scan_sensor;
  Eigen::Isometry3d truth = Eigen::Isometry3d::Identity();
  Scene() {
    const SyntheticScan s = make_synthetic_scan();
    map.set_params(sensor_preset_params(SensorPreset::kLidar));
    map.insert_scan(s.origin, s.points, s.intensities);
    truth.translation() = s.origin;
    const Eigen::Index n = s.points.rows() / 16;
    scan_sensor.resize(n, 3);
    for (Eigen::Index i = 0; i < n; ++i) scan_sensor.row(i) = s.points.row(16 * i) - s.origin.transpose();
  }
};

const Scene& scene() {
  static const Scene s;
  return s;
}

Eigen::Isometry3d perturbed(const Eigen::Isometry3d& pose, const Eigen::Vector3d& dt, double dyaw) {
  Eigen::Isometry3d p = pose;
  p.linear() = Eigen::AngleAxisd(dyaw, Eigen::Vector3d::UnitZ()).toRotationMatrix() * pose.linear();
  p.translation() += dt;
  return p;
}

void expect_same(const CoarseMatch& a, const CoarseMatch& b, int trial) {
  EXPECT_EQ(a.found, b.found) << "trial " << trial;
  EXPECT_EQ(a.score_sum, b.score_sum) << "trial " << trial;
  EXPECT_TRUE(a.pose.isApprox(b.pose, 1e-12)) << "trial " << trial << "\n"
                                               << a.pose.matrix() << "\nvs\n" << b.pose.matrix();
}

TEST(CorrelativeScanMatcher3D, BranchAndBoundEqualsExhaustiveSearch) {
  const Scene& s = scene();
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  SearchWindow3D window;
  window.linear_xy = 0.6;  // 3 voxels each way
  window.linear_z = 0.4;   // 2 voxels
  window.angular_yaw = 2.0 * kDeg;
  int pruned_trials = 0;
  const int trials = test_support::repetitions(24, 6);
  for (int trial = 0; trial < trials; ++trial) {
    const Eigen::Isometry3d initial =
        perturbed(s.truth, Eigen::Vector3d(0.5 * u(rng), 0.5 * u(rng), 0.2 * u(rng)), 2.0 * kDeg * u(rng));
    const double min_score = trial % 3 == 0 ? 0.4 : 0.0;
    const auto matcher = CorrelativeScanMatcher3D::for_scan(s.map, s.scan_sensor, initial, window, 3);
    const CoarseMatch fast = matcher.match(s.scan_sensor, initial, window, min_score);
    const CoarseMatch slow = matcher.match_exhaustive(s.scan_sensor, initial, window, min_score);
    expect_same(fast, slow, trial);
    EXPECT_EQ(slow.nodes_visited, slow.candidates);
    if (fast.nodes_visited < fast.candidates) ++pruned_trials;
  }
  EXPECT_GT(pruned_trials, trials / 2) << "branch and bound should visit fewer nodes than there are candidates";
}

TEST(CorrelativeScanMatcher3D, TiesGoToTheFirstCandidateInBothSearches) {
  ProbabilityUpdater empty(0.2);  // every pose scores 0
  const Eigen::MatrixXd scan = Eigen::MatrixXd::Random(50, 3) * 3.0;
  SearchWindow3D window;
  window.linear_xy = 0.4;
  window.linear_z = 0.2;
  window.angular_yaw = 1.0 * kDeg;
  const auto matcher = CorrelativeScanMatcher3D::for_scan(empty, scan, Eigen::Isometry3d::Identity(), window, 2);
  const CoarseMatch fast = matcher.match(scan, Eigen::Isometry3d::Identity(), window);
  const CoarseMatch slow = matcher.match_exhaustive(scan, Eigen::Isometry3d::Identity(), window);
  expect_same(fast, slow, 0);
  EXPECT_EQ(fast.score_sum, 0u);
  EXPECT_NEAR(fast.pose.translation().x(), -0.4, 1e-12);  // the first translation of the window
  const CoarseMatch none = matcher.match(scan, Eigen::Isometry3d::Identity(), window, 0.1);
  EXPECT_FALSE(none.found);
  EXPECT_FALSE(none.reason.empty());
  EXPECT_TRUE(none.pose.isApprox(Eigen::Isometry3d::Identity()));
}

// From errors up to 0.8 m and 8 degrees, the coarse match lands within a voxel of the true pose and
// within a yaw step of its heading.
TEST(CorrelativeScanMatcher3D, RecoversTheTruePoseToWithinTheDiscretisation) {
  const Scene& s = scene();
  std::mt19937 rng(17);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  SearchWindow3D window;  // 1 m, 0.5 m, 10 degrees
  int good = 0;
  const int trials = 12;
  for (int trial = 0; trial < trials; ++trial) {
    Eigen::Vector3d dt(u(rng), u(rng), 0.3 * u(rng));
    dt.head<2>() *= 0.8 / std::max(1.0, dt.head<2>().norm());
    const double dyaw = 8.0 * kDeg * u(rng);
    const Eigen::Isometry3d initial = perturbed(s.truth, dt, dyaw);
    const auto matcher = CorrelativeScanMatcher3D::for_scan(s.map, s.scan_sensor, initial, window);
    const CoarseMatch m = matcher.match(s.scan_sensor, initial, window, 0.3);
    ASSERT_TRUE(m.found) << m.reason;
    const Eigen::Isometry3d error = s.truth.inverse() * m.pose;
    const double yaw_error = std::abs(Eigen::AngleAxisd(error.linear()).angle());
    if (error.translation().norm() <= 1.5 * 0.2 && yaw_error <= m.yaw_step + 1e-9) ++good;
    EXPECT_LT(m.nodes_visited, m.candidates / 4) << "trial " << trial;
  }
  EXPECT_GE(good, trials - 1);
}

TEST(CorrelativeScanMatcher3D, BadInputThrowsNamingIt) {
  const Scene& s = scene();
  SearchWindow3D window;
  const auto matcher = CorrelativeScanMatcher3D::for_scan(s.map, s.scan_sensor, s.truth, window, 2);
  EXPECT_THROW((void)matcher.match(Eigen::MatrixXd(0, 3), s.truth, window), std::invalid_argument);
  EXPECT_THROW((void)matcher.match(Eigen::MatrixXd::Constant(3, 3, std::nan("")), s.truth, window),
               std::invalid_argument);
  Eigen::Isometry3d nan_pose = s.truth;
  nan_pose.translation().x() = std::numeric_limits<double>::quiet_NaN();
  EXPECT_THROW((void)matcher.match(s.scan_sensor, nan_pose, window), std::invalid_argument);
  for (double bad : {0.0, -1.0, std::numeric_limits<double>::infinity()}) {
    SearchWindow3D w = window;
    w.linear_xy = bad;
    EXPECT_THROW((void)matcher.match(s.scan_sensor, s.truth, w), std::invalid_argument) << bad;
    w = window;
    w.angular_yaw = bad;
    EXPECT_THROW((void)matcher.match(s.scan_sensor, s.truth, w), std::invalid_argument) << bad;
  }
  EXPECT_THROW((void)matcher.match(s.scan_sensor, s.truth, window, 1.5), std::invalid_argument);
  EXPECT_THROW((void)matcher.match(Eigen::MatrixXd::Zero(4, 2), s.truth, window), std::invalid_argument);
}

}  // namespace
}  // namespace iwlomap::registration
