// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// PoseGraphMapper: mapping over long runs. Each scan comes with its navigation pose; the front
/// end registers it against the oldest active submap (ScanMatcher in the submap's frame: ICP from
/// the prior first, branch and bound only when that is refused) and, when it registered, inserts
/// it into the active submaps (two overlap, as each new submap starts halfway through the
/// previous one). A refused scan stays out of the submaps, so it cannot pull the next scans'
/// registrations after it; RefusedScanPolicy says whether it enters the global map at its prior.
/// Finished submaps are loop-closure candidates: a scan near an older submap is matched against
/// it in a large window (branch and bound, then ICP, then the match-quality model with a higher
/// score floor). A pose graph over scans and submaps (each scan in the submaps it was inserted
/// into; odometry where registration does not tie consecutive scans; loop closures with a robust
/// loss) is solved by Ceres (Optimizer: on a worker in parallel mode) when a closure is found and
/// by finish().
///
/// The global map is the scans re-integrated at their optimized poses, in scan order, into a new
/// IWLO map: the map a user would get by mapping every scan at its best pose. The IWLO update is
/// not additive (the learning rate depends on each voxel's observation count), so fusing the
/// submaps' log-odds would not give that map; re-integration does. It runs inside the
/// optimization job of finish() (and of every optimization with rebuild_map_on_optimize),
/// stoppable between scans, so in parallel mode it costs the caller nothing.
///
/// Frames: the navigation frame ("world"); the local frame of the front end (the navigation frame
/// corrected scan by scan, never by loop closures, so it depends on the scans alone); each
/// submap's frame (its first scan's local pose). Poses are sensor to frame, metres.
///
/// Sequential and parallel modes build the same graph (candidate searches use local poses only)
/// and finish() solves it from the same initial values, so the final poses and map are identical.

#include <iwlomap/background_job.h>
#include <iwlomap/mapper_backend.h>
#include <iwlomap/optimizer.h>
#include <iwlomap/registration/scan_matcher.h>
#include <iwlomap/slam/pose_graph.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstddef>
#include <functional>
#include <memory>
#include <string>
#include <vector>

namespace iwlomap::slam {

/// What happens to a scan whose registration is refused.
enum class RefusedScanPolicy {
  kIntegrateAtPrior,  ///< insert it into the global map at its prior (navigation composed with the last correction)
  kHoldBack,          ///< keep it out of the global map (its pose stays in the graph, through odometry)
};

struct PoseGraphMapperOptions {
  double resolution = 0.2;  ///< voxel edge of the submaps and the global map, metres
  /// Makes an empty map (a submap or the global map) of this resolution; default: RAM.
  std::function<std::unique_ptr<IMapperBackend>(double resolution)> make_map;
  IwloParams params;        ///< IWLO parameters of every map (e.g. sensor_preset_params(kLidar))
  double max_range = -1.0;  ///< rays are clipped here when integrating (metres; < 0: unlimited)
  RayModel rays = RayModel::kExact;  ///< the ray model of every map (IMapperBackend::set_ray_model())
  int scans_per_submap = 20;  ///< a submap takes this many scans; a new one starts every half of it
  registration::ScanMatcherOptions matcher;  ///< the front end's registration
  RefusedScanPolicy refused = RefusedScanPolicy::kIntegrateAtPrior;
  bool loop_closure = true;
  /// Loop-closure matching: a large window and a higher floor than the front end's.
  registration::ScanMatcherOptions closure_matcher = default_closure_matcher();
  int closure_stride = 3;              ///< every k-th scan searches for a closure
  /// A finished submap is a candidate for a scan when one of its scans lies within this distance
  /// (metres, local frame) and its last scan at least scans_per_submap scans back.
  double closure_max_distance = 15.0;
  /// Standard deviations of the constraints (metres, radians): a scan in its submap (registered;
  /// a direction the scan did not constrain takes unconstrained_sigma), a loop closure, and the
  /// navigation's motion per metre travelled (plus a floor).
  double submap_translation_sigma = 0.02, submap_rotation_sigma = 0.002;
  double closure_translation_sigma = 0.1, closure_rotation_sigma = 0.01;
  double odometry_translation_sigma_per_metre = 0.02, odometry_rotation_sigma_per_metre = 0.002;
  double odometry_translation_sigma_floor = 0.01, odometry_rotation_sigma_floor = 0.001;
  double unconstrained_sigma = 10.0;
  PoseGraphOptions solver;
  /// Rebuild the global map inside every optimization (in parallel mode on the worker), or only in
  /// finish() (false: between finish() calls map() holds each scan where it was inserted).
  bool rebuild_map_on_optimize = false;

  [[nodiscard]] static registration::ScanMatcherOptions default_closure_matcher();
  /// Throws std::invalid_argument naming the first bad value.
  void validate() const;
};

/// What happened to one scan.
struct SlamScanReport {
  std::size_t index = 0;
  bool registered = false;   ///< the front end's match converged
  bool integrated = true;    ///< false when held back (refused and RefusedScanPolicy::kHoldBack)
  std::string reason;        ///< why the registration was refused (empty when registered)
  int held_directions = 0;   ///< directions the scene left unconstrained, kept at the prior
  std::size_t submap = 0;    ///< the submap it was registered against
  Eigen::Isometry3d local_pose = Eigen::Isometry3d::Identity();  ///< front end's pose, local frame
  std::vector<std::size_t> closures;  ///< indices into loop_closures() found with this scan
};

/// A loop closure found (accepted by the matcher) and what the optimizer made of it.
struct LoopClosure {
  std::size_t scan = 0;
  std::size_t submap = 0;
  Eigen::Isometry3d relative = Eigen::Isometry3d::Identity();  ///< scan in the submap's frame
  double coarse_score = 0.0;
  double inlier_fraction = 0.0;
  bool external = false;  ///< added by add_loop_closure()
  bool rejected = false;  ///< dropped as an outlier by the last optimization
};

/// Counts for a run's summary.
struct SlamSummary {
  std::size_t scans = 0, registered = 0, refused = 0, held_back = 0, submaps = 0;
  std::size_t closure_attempts = 0, closures_found = 0, closures_refused_by_matcher = 0;
  std::size_t closures_rejected_by_optimizer = 0, optimizations = 0;
};

namespace detail {
struct SlamScan;
struct SlamGraphData;
struct SlamContext {};
struct SlamOutput;
}  // namespace detail

class PoseGraphMapper : private Optimizer<std::shared_ptr<const detail::SlamGraphData>, detail::SlamContext,
                                          std::shared_ptr<const detail::SlamOutput>> {
 public:
  /// Throws std::invalid_argument for bad options.
  explicit PoseGraphMapper(ExecutionMode mode, PoseGraphMapperOptions options = {});
  ~PoseGraphMapper() override;
  PoseGraphMapper(const PoseGraphMapper&) = delete;
  PoseGraphMapper& operator=(const PoseGraphMapper&) = delete;

  /// Adds a scan: \p points_sensor (N x 3, metres, sensor frame; non-finite rows skipped),
  /// \p intensities (N), \p navigation_pose (sensor to world). Registers and inserts it, searches
  /// for a loop closure and, when one is found, starts an optimization (in parallel mode on the
  /// worker: the call does not wait for it). Throws std::invalid_argument for bad input.
  SlamScanReport add_scan(const Eigen::Isometry3d& navigation_pose, Eigen::MatrixXd points_sensor,
                          Eigen::VectorXd intensities);

  /// A constraint from elsewhere (a surveyed fix, a closure found by the caller): scan \p scan lies
  /// at \p relative in submap \p submap's frame, with \p information (see PoseConstraint). Robust:
  /// it may be rejected as an outlier like the closures found here. Returns its index in
  /// loop_closures(). Throws std::out_of_range for an unknown scan or submap.
  std::size_t add_loop_closure(std::size_t scan, std::size_t submap, const Eigen::Isometry3d& relative,
                               const Matrix6d& information);

  using Optimizer::is_running;
  using Optimizer::optimize;
  using Optimizer::terminate;
  using Optimizer::write_map;

  /// Optimizes the whole graph and rebuilds the global map, waits for both and applies them: the
  /// poses and the map are then final for the scans so far.
  void finish();

  /// Best pose of every scan so far (sensor to world): optimized where an optimization was applied
  /// (write_map(), finish()), otherwise its local pose carried by the newest correction.
  [[nodiscard]] std::vector<Eigen::Isometry3d> poses() const;
  /// The global map: the scans at their poses() as of the last finish() (or applied optimization
  /// with rebuild_map_on_optimize), plus the scans since where they were inserted. finish()
  /// replaces it with a new map object; one obtained before stays valid, and stale.
  [[nodiscard]] std::shared_ptr<IMapperBackend> map() const { return map_; }
  /// The global map rebuilt from every scan at poses() (checks \p stop between scans).
  [[nodiscard]] std::unique_ptr<IMapperBackend> build_map(const StopToken& stop = StopToken()) const;

  [[nodiscard]] const std::vector<LoopClosure>& loop_closures() const noexcept { return closures_; }
  [[nodiscard]] SlamSummary summary() const;
  [[nodiscard]] std::size_t num_submaps() const noexcept { return submaps_.size(); }
  /// The first scan of submap \p submap (its frame is that scan's local pose). Throws
  /// std::out_of_range for an unknown submap.
  [[nodiscard]] std::size_t submap_first_scan(std::size_t submap) const;
  [[nodiscard]] const PoseGraphMapperOptions& options() const noexcept { return options_; }

 private:
  using Scan = detail::SlamScan;
  struct Submap;
  std::shared_ptr<const detail::SlamGraphData> get_graph_data() override;
  void init_context(detail::SlamContext&) override {}
  std::shared_ptr<const detail::SlamOutput> run(const std::shared_ptr<const detail::SlamGraphData>& data,
                                                detail::SlamContext&, const StopToken& stop) override;
  void write_result(const std::shared_ptr<const detail::SlamOutput>& output) override;

  [[nodiscard]] std::unique_ptr<IMapperBackend> new_map() const;
  void insert(IMapperBackend& map, const Scan& scan, const Eigen::Isometry3d& pose) const;
  void search_closure(std::size_t scan_index, SlamScanReport& report);
  [[nodiscard]] Eigen::Isometry3d correction() const;

  PoseGraphMapperOptions options_;
  std::vector<std::shared_ptr<const Scan>> scans_;
  std::vector<Eigen::Isometry3d> navigation_;  // given poses
  std::vector<Eigen::Isometry3d> local_;       // front end's poses
  std::vector<Eigen::Isometry3d> optimized_;   // per scan, from the last applied optimization
  std::vector<bool> integrated_;
  std::vector<bool> registered_;  // registered with every direction constrained
  std::vector<std::unique_ptr<Submap>> submaps_;
  std::vector<PoseConstraint> constraints_;     // node numbering: see get_graph_data()
  std::vector<std::size_t> closure_constraint_; // per loop closure, its index in constraints_
  std::vector<LoopClosure> closures_;
  std::shared_ptr<IMapperBackend> map_;
  std::size_t applied_scans_ = 0;  // scans covered by the last applied optimization
  bool finishing_ = false;         // finish()'s optimization rebuilds the map
  SlamSummary summary_;
};

}  // namespace iwlomap::slam
