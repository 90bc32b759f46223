// SPDX-License-Identifier: BSD-3-Clause
// The SLAM layer: the pose graph (Ceres) with a true and a false loop closure.

#include "iwlomap/slam/pose_graph.h"

#include "iwlomap/optimizer.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <cstdio>
#include <vector>

namespace iwlomap::slam {
namespace {

constexpr double kPi = 3.14159265358979323846;

Eigen::Isometry3d pose(double x, double y, double yaw) {
  Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
  p.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  p.translation() = Eigen::Vector3d(x, y, 0.0);
  return p;
}

// A square of 40 poses; odometry with a heading bias, one true closure and a false one.
TEST(PoseGraph, ALoopClosureRemovesDriftAndAFalseClosureIsRejected) {
  std::vector<Eigen::Isometry3d> truth;
  for (int i = 0; i < 40; ++i) {
    const int side = i / 10, k = i % 10;
    const double yaw = side * kPi / 2;
    const Eigen::Vector2d corner[4] = {{0, 0}, {10, 0}, {10, 10}, {0, 10}};
    const Eigen::Vector2d dir(std::cos(yaw), std::sin(yaw));
    truth.push_back(pose(corner[side].x() + k * dir.x(), corner[side].y() + k * dir.y(), yaw));
  }
  PoseGraph g;
  g.nodes.push_back(truth[0]);
  const Eigen::Isometry3d bias = pose(0.02, 0.0, 0.01);  // per step
  for (int i = 1; i < 40; ++i) {
    PoseConstraint c;
    c.from = static_cast<std::size_t>(i - 1);
    c.to = static_cast<std::size_t>(i);
    c.kind = ConstraintKind::kOdometry;
    c.measurement = truth[i - 1].inverse() * truth[i] * bias;
    c.information = information_from_sigmas(0.05, 0.01);
    g.constraints.push_back(c);
    g.nodes.push_back(g.nodes.back() * c.measurement);
  }
  const double drift = (g.nodes.back().translation() - truth.back().translation()).norm();
  PoseConstraint closure;
  closure.from = 0;
  closure.to = 39;
  closure.measurement = truth[0].inverse() * truth[39];
  closure.information = information_from_sigmas(0.02, 0.002);
  closure.robust = true;
  closure.kind = ConstraintKind::kLoopClosure;
  g.constraints.push_back(closure);
  PoseConstraint wrong = closure;
  wrong.to = 20;
  wrong.measurement = pose(3.0, -2.0, 0.5);  // node 20 is nowhere near there
  g.constraints.push_back(wrong);

  const PoseGraphSolution s = solve_pose_graph(g);
  double worst = 0.0;
  for (std::size_t i = 0; i < truth.size(); ++i)
    worst = std::max(worst, (s.nodes[i].translation() - truth[i].translation()).norm());
  std::printf("drift %.3f m; after the closure the worst node is %.3f m off; %d solves\n", drift, worst, s.solves);
  EXPECT_GT(drift, 1.0);
  EXPECT_LT(worst, 0.3 * drift);
  EXPECT_FALSE(s.rejected[g.constraints.size() - 2]);
  EXPECT_TRUE(s.rejected.back());
  // The same graph gives the same poses, bit for bit.
  const PoseGraphSolution again = solve_pose_graph(g);
  for (std::size_t i = 0; i < truth.size(); ++i) EXPECT_TRUE(again.nodes[i].isApprox(s.nodes[i], 0.0));

  std::atomic<bool> stop{true};
  EXPECT_THROW((void)solve_pose_graph(g, {}, StopToken(&stop)), StopRequested);
  PoseGraph bad = g;
  bad.constraints[0].to = 99;
  EXPECT_THROW((void)solve_pose_graph(bad), std::invalid_argument);
}

}  // namespace
}  // namespace iwlomap::slam
