// SPDX-License-Identifier: BSD-3-Clause
// PoseGraphMapper around a small synthetic street block (70 x 50 m, a 16-beam lidar every 5 m,
// navigation drifting 2 % of the distance and 1 degree per 10 m): scans register, the loop is
// closed and brings the trajectory nearer the truth than registration alone, a false closure is
// rejected, sequential and parallel mode give the same poses and map bit for bit, and terminate()
// leaves the poses as they were.

#include "iwlomap/slam/pose_graph_mapper.h"

#include "iwlomap/sensor_preset.h"
#include "iwlomap/synthetic_world.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <stdexcept>
#include <vector>

namespace iwlomap::slam {
namespace {

constexpr double kDeg = 3.14159265358979323846 / 180.0;

struct Loop {
  std::vector<Eigen::Isometry3d> truth, nav;
  std::vector<LidarFrame> frames;
};

const Loop& loop() {
  static const Loop l = [] {
    StreetLoopOptions street;
    street.block_x = 70.0;
    street.block_y = 50.0;
    const SyntheticWorld world = SyntheticWorld::street_loop(street);
    Loop out;
    out.truth = SyntheticWorld::street_loop_trajectory(street, 5.0);
    out.truth.push_back(out.truth[0]);  // back at the start: the loop closes
    out.truth.push_back(out.truth[1]);
    LidarOptions lidar;
    lidar.rings = 16;
    lidar.columns = 360;
    lidar.max_range = 30.0;
    out.nav.push_back(out.truth[0]);
    for (std::size_t i = 0; i < out.truth.size(); ++i) {
      if (i > 0) {
        Eigen::Isometry3d step = out.truth[i - 1].inverse() * out.truth[i];
        const double d = step.translation().norm();
        step.translation() *= 1.02;
        step.linear() = Eigen::AngleAxisd(0.1 * kDeg * d, Eigen::Vector3d::UnitZ()).toRotationMatrix() * step.linear();
        out.nav.push_back(out.nav.back() * step);
      }
      out.frames.push_back(world.scan(out.truth[i], lidar, static_cast<std::uint32_t>(i + 1)));
    }
    return out;
  }();
  return l;
}

PoseGraphMapperOptions options(bool closures) {
  PoseGraphMapperOptions o;
  o.params = sensor_preset_params(SensorPreset::kLidar);
  o.scans_per_submap = 8;
  o.loop_closure = closures;
  o.max_range = 30.0;
  o.matcher.max_range = 30.0;
  o.closure_matcher.max_range = 30.0;
  return o;
}

// Adds the first \p n scans of the loop (all by default).
void add_all(PoseGraphMapper& mapper, std::size_t n = static_cast<std::size_t>(-1)) {
  const Loop& l = loop();
  for (std::size_t i = 0; i < std::min(n, l.truth.size()); ++i)
    (void)mapper.add_scan(l.nav[i], l.frames[i].points, l.frames[i].intensities);
}

double ate(const std::vector<Eigen::Isometry3d>& p) {
  const Loop& l = loop();
  double s = 0.0;
  for (std::size_t i = 0; i < p.size(); ++i) s += (p[i].translation() - l.truth[i].translation()).squaredNorm();
  return std::sqrt(s / static_cast<double>(p.size()));
}

TEST(PoseGraphMapper, ClosesTheLoopTheSameInBothModesAndRejectsAFalseClosure) {
  PoseGraphMapper open(ExecutionMode::kSequential, options(false));
  add_all(open);
  PoseGraphMapper seq(ExecutionMode::kSequential, options(true));
  add_all(seq);
  PoseGraphMapper par(ExecutionMode::kParallel, options(true));
  add_all(par);
  // A false closure: the scan in the middle of the loop, said to lie 6 m and 20 degrees from
  // where it is in the first submap.
  const std::size_t middle = loop().truth.size() / 2;
  Eigen::Isometry3d wrong = Eigen::Isometry3d::Identity();
  wrong.translation() = Eigen::Vector3d(6.0, 0.0, 0.0);
  wrong.linear() = Eigen::AngleAxisd(20.0 * kDeg, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  for (PoseGraphMapper* m : {&seq, &par}) {
    (void)m->add_loop_closure(middle, 0, wrong, information_from_sigmas(0.1, 0.01));
    m->finish();
  }
  const SlamSummary s = seq.summary();
  const double ate_open = ate(open.poses()), ate_closed = ate(seq.poses());
  std::printf("%zu scans, %zu registered, %zu submaps, %zu closures found in %zu attempts, %zu rejected; "
              "ATE %.3f m registration only, %.3f m with the loop closed; navigation %.3f m\n",
              s.scans, s.registered, s.submaps, s.closures_found, s.closure_attempts, s.closures_rejected_by_optimizer,
              ate_open, ate_closed, ate(loop().nav));
  EXPECT_GE(s.registered * 100, s.scans * 95);
  EXPECT_GE(s.closures_found, 1u);
  EXPECT_EQ(s.closures_rejected_by_optimizer, 1u);
  EXPECT_TRUE(seq.loop_closures().back().rejected);
  EXPECT_LT(ate_closed, ate_open);
  EXPECT_LT(ate_closed, 0.2);

  const std::vector<Eigen::Isometry3d> a = seq.poses(), b = par.poses();
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) EXPECT_TRUE(a[i].isApprox(b[i], 0.0)) << "scan " << i;
  const Eigen::MatrixXd ma = seq.map()->get_occupied_voxels(0.7), mb = par.map()->get_occupied_voxels(0.7);
  EXPECT_EQ(ma.rows(), mb.rows());
  EXPECT_TRUE(ma.isApprox(mb, 0.0));
  // The global map is the scans re-integrated at the final poses.
  const Eigen::MatrixXd rebuilt = seq.build_map()->get_occupied_voxels(0.7);
  EXPECT_TRUE(rebuilt.isApprox(ma, 0.0));
}

// An optimisation's output reaches the poses only through write_map(), so a terminated job
// leaves them as they were however far it got: three submaps of scans are enough to show it.
TEST(PoseGraphMapper, TerminateLeavesThePosesAsTheyWere) {
  PoseGraphMapper m(ExecutionMode::kParallel, options(false));
  add_all(m, 16);
  ASSERT_GE(m.summary().submaps, 3u);
  const std::vector<Eigen::Isometry3d> before = m.poses();
  m.optimize();
  m.terminate();
  EXPECT_FALSE(m.is_running());
  EXPECT_FALSE(m.write_map());
  const std::vector<Eigen::Isometry3d> after = m.poses();
  for (std::size_t i = 0; i < before.size(); ++i) EXPECT_TRUE(before[i].isApprox(after[i], 0.0));
}

TEST(PoseGraphMapper, RefusesBadInput) {
  PoseGraphMapperOptions o;
  o.scans_per_submap = 1;
  EXPECT_THROW(PoseGraphMapper(ExecutionMode::kSequential, o), std::invalid_argument);
  o = PoseGraphMapperOptions{};
  o.resolution = 0.0;
  EXPECT_THROW(PoseGraphMapper(ExecutionMode::kSequential, o), std::invalid_argument);
  PoseGraphMapper m(ExecutionMode::kSequential);
  Eigen::Isometry3d nan_pose = Eigen::Isometry3d::Identity();
  nan_pose.translation().x() = std::nan("");
  EXPECT_THROW((void)m.add_scan(nan_pose, Eigen::MatrixXd::Zero(3, 3), Eigen::VectorXd::Zero(3)), std::invalid_argument);
  EXPECT_THROW((void)m.add_scan(Eigen::Isometry3d::Identity(), Eigen::MatrixXd::Zero(3, 3), Eigen::VectorXd::Zero(2)),
               std::invalid_argument);
  EXPECT_THROW((void)m.add_scan(Eigen::Isometry3d::Identity(), Eigen::MatrixXd::Constant(2, 3, std::nan("")),
                                Eigen::VectorXd::Zero(2)),
               std::invalid_argument);
  EXPECT_THROW((void)m.add_loop_closure(0, 0, Eigen::Isometry3d::Identity(), Matrix6d::Identity()), std::out_of_range);
}

}  // namespace
}  // namespace iwlomap::slam
