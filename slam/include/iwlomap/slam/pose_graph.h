// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// A pose graph and its least-squares solution (Ceres). Nodes are rigid poses (node to world);
/// a constraint says where node `to` was measured in the frame of node `from`. The residual of a
/// constraint is (translation error in `from`'s frame, metres; 2 x the vector part of the rotation
/// error quaternion, radians), whitened by the constraint's information matrix. Robust constraints
/// (loop closures) take a Huber loss (convex: a true closure far from the initial values still
/// pulls), and after each solve the one whose whitened error is largest beyond outlier_sigmas is
/// dropped and the graph solved again, so that false closures cannot bend the trajectory. Node 0 is held fixed (the gauge). The solution depends only on the graph:
/// the same graph gives the same poses, bit for bit (one thread, fixed iteration order).

#include <iwlomap/optimizer.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstddef>
#include <vector>

namespace iwlomap::slam {

using Matrix6d = Eigen::Matrix<double, 6, 6>;
using Vector6d = Eigen::Matrix<double, 6, 1>;

/// What a constraint came from (for reports; the solver treats kinds alike but for `robust`).
enum class ConstraintKind {
  kOdometry,     ///< the navigation's motion between consecutive scans
  kSubmap,       ///< a scan registered into a submap it was inserted into
  kLoopClosure,  ///< a scan matched against an older submap
  kExternal,     ///< added by the caller
};

struct PoseConstraint {
  std::size_t from = 0;  ///< node index
  std::size_t to = 0;    ///< node index
  Eigen::Isometry3d measurement = Eigen::Isometry3d::Identity();  ///< pose of `to` in `from`'s frame
  /// Inverse covariance of (tx, ty, tz, rx, ry, rz): metres and radians, `from`'s frame.
  Matrix6d information = Matrix6d::Identity();
  bool robust = false;  ///< Cauchy loss and outlier rejection
  ConstraintKind kind = ConstraintKind::kExternal;
};

struct PoseGraph {
  std::vector<Eigen::Isometry3d> nodes;  ///< initial values (node to world)
  std::vector<PoseConstraint> constraints;
  /// Throws std::invalid_argument for a node index out of range, a non-finite pose or an
  /// information matrix that is not symmetric positive semi-definite.
  void validate() const;
};

struct PoseGraphOptions {
  int max_iterations = 100;     ///< Levenberg-Marquardt iterations per solve
  double robust_scale = 3.0;    ///< Huber scale of robust constraints (whitened units)
  double outlier_sigmas = 5.0;  ///< a robust constraint whose whitened error exceeds this may be dropped
  int max_rejection_rounds = 10; ///< constraints dropped (one per solve), at most
  void validate() const;
};

struct PoseGraphSolution {
  std::vector<Eigen::Isometry3d> nodes;  ///< optimized (node to world)
  std::vector<bool> rejected;            ///< per constraint: dropped as an outlier
  std::vector<double> whitened_error;    ///< per constraint, at the solution
  int iterations = 0;                    ///< over all solves
  int solves = 0;
  double initial_cost = 0.0, final_cost = 0.0;
};

/// Solves \p graph. Checks \p stop every iteration and throws StopRequested when it is set.
/// Throws std::invalid_argument for a bad graph or options.
[[nodiscard]] PoseGraphSolution solve_pose_graph(const PoseGraph& graph, const PoseGraphOptions& options = {},
                                                 const StopToken& stop = StopToken());

/// The information matrix of independent errors with these standard deviations (metres, radians).
[[nodiscard]] Matrix6d information_from_sigmas(double translation_sigma, double rotation_sigma);

}  // namespace iwlomap::slam
