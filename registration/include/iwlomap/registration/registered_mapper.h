// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// RegisteredMapper: mapping with registration. Each scan comes with the pose its navigation gave
/// (odometry, dead reckoning); the mapper registers the scan against the map built so far, starting
/// from that pose composed with the last correction (a constant-velocity model of the drift), and
/// integrates it at the corrected pose. Sequential or on a background thread (BackgroundJob); both
/// run the same steps in the same order, so the maps and results are identical.

#include <iwlomap/background_job.h>
#include <iwlomap/mapper_backend.h>
#include <iwlomap/registration/scan_matcher.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <memory>
#include <vector>

namespace iwlomap::registration {

struct RegisteredMapperOptions {
  ScanMatcherOptions matcher;  ///< how each scan is registered
  /// Rays longer than this are clipped when integrating (metres; negative: unlimited).
  double max_range = -1.0;
};

/// What happened to one scan.
struct RegisteredScan {
  Eigen::Isometry3d given_pose = Eigen::Isometry3d::Identity();       ///< as passed to integrate()
  Eigen::Isometry3d initial_guess = Eigen::Isometry3d::Identity();    ///< given pose with the last correction
  Eigen::Isometry3d integrated_pose = Eigen::Isometry3d::Identity();  ///< where the scan went into the map
  bool registered = false;  ///< false: the first scan (nothing to register against) or no convergence
  ScanMatchResult match;    ///< the registration (empty for the first scan)
};

class RegisteredMapper {
 public:
  /// \p map receives the scans (it may hold a map already: the first scan is then registered
  /// too). Throws std::invalid_argument for a null map or bad options.
  RegisteredMapper(std::shared_ptr<IMapperBackend> map, ExecutionMode mode, RegisteredMapperOptions options = {},
                   std::size_t queue_capacity = 4);

  /// Queues a scan: \p points_sensor (N x 3, metres, sensor frame), \p intensities (N), \p pose
  /// the navigation's sensor pose (sensor to map). Sequential mode runs it before returning;
  /// parallel mode returns at once unless queue_capacity scans are waiting.
  void integrate(const Eigen::Isometry3d& pose, Eigen::MatrixXd points_sensor, Eigen::VectorXd intensities);
  /// The same for a scan without intensities: every point is a return at the map's intensity_max
  /// as the scan is integrated.
  void integrate(const Eigen::Isometry3d& pose, Eigen::MatrixXd points_sensor);

  /// Waits for every queued scan; returns what happened to each since the last sync(), in order,
  /// and rethrows the first error of a scan.
  std::vector<RegisteredScan> sync();

  /// The current correction (map pose = correction * given pose), after sync().
  [[nodiscard]] Eigen::Isometry3d correction();

  /// The map, after sync().
  [[nodiscard]] IMapperBackend& map();

 private:
  void submit(const Eigen::Isometry3d& pose, Eigen::MatrixXd points_sensor, Eigen::VectorXd intensities,
              bool all_returns);
  struct Scan {
    Eigen::Isometry3d pose;
    Eigen::MatrixXd points;
    Eigen::VectorXd intensities;
    bool all_returns = false;  // no intensities: each point at the map's intensity_max
  };
  struct State {
    std::shared_ptr<IMapperBackend> map;
    RegisteredMapperOptions options;
    Eigen::Isometry3d correction = Eigen::Isometry3d::Identity();
  };
  static RegisteredScan process(Scan&& scan, State& state, const StopToken& stop);
  BackgroundJob<Scan, State, RegisteredScan> job_;
};

}  // namespace iwlomap::registration
