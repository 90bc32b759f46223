// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// RegisteredSonarMapper: sonar mapping with registration. One imaging-sonar ping cannot be
/// registered on its own: it says where echoes are in range and bearing but not in elevation (an
/// echo is an arc across the vertical aperture, see SonarImageProjector). Consecutive pings seen
/// from poses a little apart settle the elevation, and over a short stretch the navigation's drift
/// is small. So the mapper gathers `pings_per_submap` consecutive pings into a submap (a small RAM
/// map built at the navigation poses, relative to the submap's first ping), registers the
/// submap's occupied voxels against the map built so far with ScanMatcher (initial guess: the
/// first ping's navigation pose composed with the last correction), and integrates the submap's
/// pings into the map at the corrected poses. A submap that does not register (no overlap, a flat
/// seabed that leaves x, y and yaw free, too few occupied voxels) keeps the last correction.
///
/// Frames: as SonarImageProjector (sonar frame +X forward, +Y right, +Z down); poses are sonar
/// frame to map frame, metres. Sequential or on a background thread (BackgroundJob); both run the
/// same steps in the same order, so the maps and results are identical.

#include <iwlomap/background_job.h>
#include <iwlomap/mapper_backend.h>
#include <iwlomap/registration/scan_matcher.h>
#include <iwlomap/sonar_image_projector.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

namespace iwlomap::registration {

struct RegisteredSonarMapperOptions {
  RegisteredSonarMapperOptions();
  /// How a submap is registered. Defaults differ from ScanMatcherOptions' in three ways: the
  /// match-quality model is off and unconstrained directions are refused, not held (the model's
  /// thresholds were set on lidar scenes; max_fitness_rmse below is this mapper's test), and two
  /// more, both
  /// measured on the simulated survey of bench_sonar_accuracy (docs/accuracy.md): the coarse
  /// stage is off, because a forward-looking sonar's submap lies mostly beyond the map's frontier
  /// and over a flat seabed the branch and bound scores highest where it pulls the submap back
  /// into the mapped area (1.8 m and 7 degrees from a guess 2 cm off); and ICP is planar (x, y and
  /// yaw), since depth, roll and pitch come from the vehicle's pressure and attitude sensors and
  /// the seabed constrains nothing else.
  ScanMatcherOptions matcher;
  /// A registration whose RMS point-to-plane residual exceeds this is rejected (metres; negative:
  /// 1.2 times the map's resolution; 0: no limit). Sonar submaps and maps keep the parts of echo
  /// arcs that no later ping cleared, shaped by the viewing direction; where they dominate, ICP
  /// converges to a wrong pose with a residual over a voxel. On the simulated survey, fits within
  /// 15 cm of the truth had residuals of 0.036-0.102 m at 0.1 m voxels, wrong ones 0.136-0.2 m.
  double max_fitness_rmse = -1.0;
  /// Consecutive pings in one submap (>= 1). More pings settle the echoes' elevation better and
  /// see more structure; fewer follow a faster drift. The default is 8 m of travel at a ping
  /// every 0.1 m: on the simulated survey, submaps of 2 m registered against an earlier survey's
  /// map 4 times in 33, of 8 m 8 times in 9.
  int pings_per_submap = 80;
  /// A submap with fewer occupied voxels than this is not registered (>= 8, ICP's minimum).
  int min_submap_voxels = 50;
};

/// What happened to one submap.
struct RegisteredSubmap {
  std::size_t first_ping = 0;  ///< index of its first ping since construction
  std::size_t pings = 0;
  std::size_t occupied_voxels = 0;  ///< in the submap: the points registered
  Eigen::Isometry3d given_pose = Eigen::Isometry3d::Identity();     ///< first ping's navigation pose
  Eigen::Isometry3d initial_guess = Eigen::Isometry3d::Identity();  ///< with the last correction
  /// The correction applied to every ping of the submap: map pose = correction * navigation pose.
  Eigen::Isometry3d correction = Eigen::Isometry3d::Identity();
  /// false: the first submap, too few voxels, no convergence, or a residual over max_fitness_rmse
  bool registered = false;
  ScanMatchResult match;    ///< the registration (empty when it did not run)
  std::vector<Eigen::Isometry3d> integrated_poses;  ///< per ping: where it went into the map
  /// The projector's counts over the submap's pings as integrated (SonarObservations).
  std::size_t observations = 0, beams_with_return = 0, beams_without_return = 0;
};

class RegisteredSonarMapper {
 public:
  /// \p map receives the pings (it may hold a map already: the first submap is then registered
  /// too); \p projector turns a ping into observations (its resolution must be the map's).
  /// Throws std::invalid_argument for a null map, a resolution mismatch or bad options.
  RegisteredSonarMapper(std::shared_ptr<IMapperBackend> map, SonarImageProjector projector, ExecutionMode mode,
                        RegisteredSonarMapperOptions options = {}, std::size_t queue_capacity = 2);

  /// Adds a ping taken at \p nav_pose (the navigation's sonar pose, sonar to map frame). The image
  /// is copied. Every pings_per_submap pings a submap is queued: sequential mode processes it
  /// before returning, parallel mode returns at once unless queue_capacity submaps are waiting.
  /// Throws std::invalid_argument for a non-finite pose, an empty image or a geometry that does
  /// not fit it.
  void integrate(const Eigen::Isometry3d& nav_pose, const SonarImageView& image, const SonarGeometry& geometry);

  /// Queues the pings gathered so far as a (shorter) submap, waits for every queued submap and
  /// returns what happened to each since the last sync(), in order; rethrows the first error.
  std::vector<RegisteredSubmap> sync();

  /// The current correction (map pose = correction * navigation pose), after sync().
  [[nodiscard]] Eigen::Isometry3d correction();

  /// The map, after sync().
  [[nodiscard]] IMapperBackend& map();

 private:
  struct Ping {
    Eigen::Isometry3d nav_pose;
    SonarGeometry geometry;
    SonarImageCopy image;
  };
  struct Submap {
    std::size_t first_ping = 0;
    std::vector<Ping> pings;
  };
  struct State {
    std::shared_ptr<IMapperBackend> map;
    SonarImageProjector projector;
    RegisteredSonarMapperOptions options;
    Eigen::Isometry3d correction = Eigen::Isometry3d::Identity();
  };
  static RegisteredSubmap process(Submap&& submap, State& state);
  void submit_pending();

  int pings_per_submap_;
  std::size_t pings_seen_ = 0;
  Submap pending_;
  BackgroundJob<Submap, State, RegisteredSubmap> job_;
};

}  // namespace iwlomap::registration
