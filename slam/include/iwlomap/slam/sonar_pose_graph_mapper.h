// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// SonarPoseGraphMapper: sonar surveys that revisit their own lines, mapped without a prior map.
///
/// A forward-looking sonar's submap does not register against the survey's own map along a leg
/// (the seabed ahead is new, and the echo arcs that no later ping cleared depend on the viewing
/// direction: docs/accuracy.md). It does register against a submap of the same seabed seen from
/// the same heading, as a repeat survey registers against an earlier survey's chart. So the
/// mapper cuts the pings into submaps (every `pings_per_submap` pings, and where the heading
/// turns by more than `max_submap_turn_deg`), builds each at the navigation poses in a
/// gravity-aligned frame (its first ping's position and heading), and matches each new submap
/// against every older submap of about the same place and heading: branch and bound in x, y and
/// yaw from the current estimate, then planar ICP, accepted under a residual limit; depth, roll
/// and pitch stay the navigation's (pressure and attitude sensors observe them). A pose graph
/// over the submaps (the navigation's motion between consecutive submaps, the accepted closures
/// with a robust loss) is solved with Ceres after each closure, which spreads the drift found at
/// each closure back over the legs between. finish() integrates every ping into the map at its
/// corrected pose: the correction (submap pose * submap frame^-1) interpolated between the
/// submap's and the next one's by the ping's place between their first pings, times the ping's
/// navigation pose.
///
/// Frames: as SonarImageProjector (sonar frame +X forward, +Y right, +Z down); poses are sonar
/// frame to map frame (+z up), metres. One thread: the calls run in the caller's thread.

#include <iwlomap/mapper_backend.h>
#include <iwlomap/registration/scan_matcher.h>
#include <iwlomap/slam/pose_graph.h>
#include <iwlomap/sonar_image_projector.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstddef>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace iwlomap::slam {

struct SonarPoseGraphMapperOptions {
  /// Sets `matcher` as RegisteredSonarMapperOptions does (planar: x, y and yaw; the match-quality
  /// model off, its thresholds were set on lidar scenes; max_fitness_rmse is this mapper's test),
  /// but with branch and bound first in +-2 m and +-5 degrees: a closure must find the drift of a
  /// whole loop, beyond ICP's reach, and its target covers the submap's seabed, so the search is
  /// not drawn toward a map's frontier as registration against the map so far is.
  SonarPoseGraphMapperOptions();
  /// Consecutive pings in one submap at most (>= 1): 8 m at a ping every 0.1 m.
  int pings_per_submap = 80;
  /// A new submap starts where the navigation heading differs from the submap's first ping's by
  /// more than this (degrees, > 0): a submap seen from one heading, so that its echo arcs match
  /// those of another pass with that heading.
  double max_submap_turn_deg = 30.0;
  /// A submap with fewer occupied voxels than this takes no part in loop closure (>= 8).
  int min_submap_voxels = 50;
  registration::ScanMatcherOptions matcher;
  /// A closure whose RMS point-to-plane residual exceeds this is refused (metres; negative: 1.2
  /// times the map's resolution; 0: no limit).
  double max_fitness_rmse = -1.0;
  /// A new submap is matched against an older one when the centres of the seabed they saw (the
  /// mean of their occupied voxels, at the current estimates) lie within this distance (metres,
  /// horizontally), their mean headings within
  /// closure_max_heading_difference_deg, and at least closure_min_submap_gap submaps apart (so
  /// never against the submap just before, whose seabed only abuts it).
  double closure_max_distance = 5.0;
  double closure_max_heading_difference_deg = 45.0;
  int closure_min_submap_gap = 2;
  /// A submap of fewer pings (the end of a leg, cut by a turn) takes no part in loop closure.
  int min_closure_pings = 20;
  /// Standard deviations of the constraints (metres, radians): a closure, and the navigation's
  /// motion between consecutive submaps per metre travelled (plus a floor).
  /// The heading's: a vehicle's gyro holds heading far better than a seabed patch fixes yaw (on
  /// the simulated survey, closures were 0.2-1.4 degrees off).
  double closure_translation_sigma = 0.1, closure_rotation_sigma = 0.02;
  double odometry_translation_sigma_per_metre = 0.02, odometry_rotation_sigma_per_metre = 0.0005;
  double odometry_translation_sigma_floor = 0.01, odometry_rotation_sigma_floor = 0.001;
  PoseGraphOptions solver;
  /// Throws std::invalid_argument naming the first bad value.
  void validate() const;
};

/// A loop closure: a submap matched against an older one.
struct SonarLoopClosure {
  std::size_t submap = 0;  ///< the newer submap
  std::size_t target = 0;  ///< the older submap it was matched against
  /// The newer submap's frame in the older one's (a submap's frame: its first ping's navigation
  /// position and heading, gravity-aligned).
  Eigen::Isometry3d relative = Eigen::Isometry3d::Identity();
  double fitness_rmse = 0.0;  ///< metres
  bool rejected = false;      ///< dropped as an outlier by the last optimization
};

/// What happened to one submap.
struct SonarSubmapReport {
  std::size_t first_ping = 0;
  std::size_t pings = 0;
  std::size_t occupied_voxels = 0;
  std::size_t closure_attempts = 0;  ///< older submaps it was matched against
  std::size_t closures = 0;          ///< of those, accepted by the residual limit
  /// Why the attempts were refused, one line per refusal ("submap 2: the residual ... ").
  std::vector<std::string> refusals;
};

struct SonarSlamSummary {
  std::size_t pings = 0, submaps = 0;
  std::size_t closure_attempts = 0, closures_found = 0, closures_refused = 0;
  std::size_t closures_rejected_by_optimizer = 0, optimizations = 0;
  /// The projector's counts over the pings as finish() integrated them (SonarObservations).
  std::size_t observations = 0, beams_with_return = 0, beams_without_return = 0;
};

class SonarPoseGraphMapper {
 public:
  /// \p map receives the pings in finish() (it may hold a map already; it is not registered
  /// against); \p projector turns a ping into observations (its resolution must be the map's).
  /// Throws std::invalid_argument for a null map, a resolution mismatch or bad options.
  SonarPoseGraphMapper(std::shared_ptr<IMapperBackend> map, SonarImageProjector projector,
                       SonarPoseGraphMapperOptions options = {});
  ~SonarPoseGraphMapper();
  SonarPoseGraphMapper(const SonarPoseGraphMapper&) = delete;
  SonarPoseGraphMapper& operator=(const SonarPoseGraphMapper&) = delete;

  /// Adds a ping taken at \p nav_pose (the navigation's sonar pose, sonar to map frame); the
  /// image is copied. A submap that this ping completes is built and matched before returning.
  /// Throws std::invalid_argument for a non-finite pose, an empty image or a geometry that does
  /// not fit it, std::logic_error after finish().
  void integrate(const Eigen::Isometry3d& nav_pose, const SonarImageView& image, const SonarGeometry& geometry);

  /// Closes the last submap (solving the graph when it closes a loop) and integrates every ping
  /// into the map at its corrected pose, in the order given, calling \p progress (if set) with
  /// the pings integrated so far and their total. Call once; later integrate() or finish() throw
  /// std::logic_error.
  void finish(const std::function<void(std::size_t done, std::size_t total)>& progress = {});

  /// Per ping: its corrected pose (sonar to map frame); before finish(), the estimate so far
  /// (pings of the open submap: the last closed submap's correction).
  [[nodiscard]] std::vector<Eigen::Isometry3d> poses() const;
  [[nodiscard]] const std::vector<SonarSubmapReport>& submaps() const noexcept { return reports_; }
  [[nodiscard]] const std::vector<SonarLoopClosure>& loop_closures() const noexcept { return closures_; }
  [[nodiscard]] SonarSlamSummary summary() const;
  /// The map (complete after finish()).
  [[nodiscard]] IMapperBackend& map() noexcept { return *map_; }

 private:
  struct Ping;
  struct Submap;
  void close_submap();
  void match_against_older(std::size_t index);
  void optimize();
  [[nodiscard]] Eigen::Isometry3d estimate_of(std::size_t submap) const;

  std::shared_ptr<IMapperBackend> map_;
  SonarImageProjector projector_;
  SonarPoseGraphMapperOptions options_;
  std::vector<Ping> pings_;
  std::size_t open_first_ = 0;  // first ping of the open submap
  std::vector<Submap> submaps_;
  std::vector<Eigen::Isometry3d> estimates_;  // per submap: its frame's pose in the map frame
  std::vector<PoseConstraint> constraints_;
  std::vector<std::size_t> closure_constraint_;  // per closure: its index in constraints_
  std::vector<SonarLoopClosure> closures_;
  std::vector<SonarSubmapReport> reports_;
  std::size_t optimizations_ = 0;
  std::size_t observations_ = 0, beams_with_return_ = 0, beams_without_return_ = 0;
  bool finished_ = false;
};

}  // namespace iwlomap::slam
