// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Scan-to-map registration: where does a scan (points in the sensor frame) fit the map, near an
/// initial pose? Two stages:
/// - coarse: CorrelativeScanMatcher3D, exact branch and bound over the map's max grids in a
///   search window (x, y, z, yaw), to within a voxel and a yaw step;
/// - fine: point-to-plane ICP against the map's occupied voxels (their centres, or their mean hit
///   positions when the map accumulates hits), 6 degrees of freedom, nearest neighbours from a
///   FLANN k-d tree, a Huber kernel on the residuals.
/// The result says whether it converged and why not: a scan that does not overlap the map, an
/// empty map, too few correspondences, or a scene that leaves directions unconstrained (a single
/// plane: the covariance's unobservable directions are reported) is never a silent wrong pose.
///
/// FLANN is used directly (Debian's libflann-dev, header-only k-d tree) rather than through PCL's
/// KdTreeFLANN: the layer then needs no PCL, so a core or Python user can register scans.

#include <iwlomap/registration/correlative_scan_matcher.h>
#include <iwlomap/mapper_backend.h>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cstddef>
#include <memory>
#include <optional>
#include <string>

namespace iwlomap::registration {

/// Point-to-plane ICP settings. Distances in metres, angles in radians.
struct IcpOptions {
  int max_iterations = 30;                  ///< Gauss-Newton steps at most (>= 1)
  double max_correspondence_distance = 0.5; ///< a scan point farther than this from every map point is unpaired
  double huber_delta = 0.05;                ///< residuals beyond this are down-weighted (Huber)
  double translation_tolerance = 1e-4;      ///< stop when a step moves less than this ...
  double rotation_tolerance = 1e-5;         ///< ... and turns less than this, or when three steps in
                                            ///< a row lower the mean squared residual by < 1e-4 of it
  double min_inlier_fraction = 0.3;         ///< converged needs at least this fraction of the scan paired
  /// A direction of the 6-D pose is unobservable when its eigenvalue of the normalised Hessian is
  /// below this fraction of the largest one (a plane leaves three such directions).
  double degeneracy_ratio = 1e-3;
  /// Estimate x, y and the rotation about the map's z axis only; z, roll and pitch stay those of
  /// the initial pose (for vehicles whose depth and attitude sensors observe them, such as an
  /// underwater vehicle's pressure sensor and inertial unit). Their covariance is then 0.
  bool planar = false;
  /// Quality statistics at the final pose (ScanMatchResult::inlier_fraction, axis_support): a scan
  /// point is in the overlap when a map point lies within overlap_distance (metres), and an inlier
  /// when it also lies within inlier_distance (metres; > 0, <= overlap_distance) of that map
  /// point's tangent plane.
  double inlier_distance = 0.2;
  double overlap_distance = 1.0;
  /// Throws std::invalid_argument naming the first bad value.
  void validate() const;
};

/// When a registration counts as converged. A pose that passes every test below is within the
/// search's tolerance on the scenes it was calibrated on (docs/slam.md lists them and the
/// figures); a pose that fails one is refused with the test's name in ScanMatchResult::reason and
/// the initial pose kept, so a caller never integrates a wrong pose believing it right.
struct MatchQualityOptions {
  /// The fraction of the scan's points that are inliers (IcpOptions::inlier_distance, which
  /// ScanMatcher raises to the map's resolution) must reach this.
  double min_inlier_fraction = 0.25;
  /// Of the points in the overlap (within overlap_distance of the surface), weighted by how much
  /// their surface faces each map axis, the fraction that are inliers must reach this along x, y
  /// and z: a pose that fits the ground but not the walls (or the walls but not the ground) is a
  /// wrong pose.
  double min_axis_support = 0.7;
  /// Of the scan's points that fall in voxels the map knows, at most this fraction may fall in
  /// voxels the map holds free (probability < 0.5) and off its surface (not an inlier: farther than
  /// inlier_distance from the tangent plane of a map point within overlap_distance): a scan placed
  /// where the map has seen through is misplaced. Ground voxels that grazing rays cleared hold
  /// points on the ground's plane, which do not count. Maps without free space (a voxel cloud) do
  /// not test this.
  double max_free_conflict = 0.2;
  /// ICP may move the coarse stage's pose at most this many voxels (and the yaw at most this many
  /// of the coarse stage's yaw steps, at least 1 degree): the coarse optimum and the fine one must
  /// agree.
  double max_coarse_disagreement = 2.5;
  /// A coarse optimum within this many voxels (yaw: steps) of the search window's edge in x, y or
  /// yaw may be the best the window holds of a pose beyond it: the search is repeated once around
  /// it, and the scan refused when that optimum lies at the edge again (0: never).
  double edge_margin = 0.5;
  /// Along directions the scene does not constrain (ScanMatchResult::unobservable), keep the
  /// initial pose and accept the constrained directions' correction (true), or refuse the scan as
  /// degenerate (false).
  bool hold_unconstrained = true;
  /// Throws std::invalid_argument naming the first bad value.
  void validate() const;
};

/// Both stages' settings.
struct ScanMatcherOptions {
  bool coarse = true;            ///< run the branch-and-bound stage
  bool fine = true;              ///< run ICP (from the coarse pose, or the initial one)
  SearchWindow3D window;         ///< the coarse search window
  double min_coarse_score = 0.3; ///< the coarse pose must score at least this (mean value / 255)
  /// The coarse stage scores at most this many of the reduced scan's points (every k-th): its
  /// time is proportional to the count, and a voxel-level pose needs far fewer points than ICP.
  int coarse_points = 1500;
  /// The coarse stage uses only points within this range of the sensor (metres; <= 0: max_range):
  /// its grid covers the scan at every pose of the window, so its size (and the time to build it)
  /// grows with the square of the range.
  double coarse_max_range = 25.0;
  /// Max-grid levels of the coarse stage; 0: as many as the window needs (the widest level covers
  /// the window's x extent), which keeps the grids small.
  int coarse_levels = 0;
  /// Points farther than this from the sensor are ignored (metres; <= 0: none). Bounds the coarse
  /// stage's grid, which covers the scan at every pose of the window.
  double max_range = 40.0;
  /// The scan is reduced to one point (the mean) per voxel of this edge before matching (metres;
  /// <= 0: the map's resolution).
  double scan_voxel = 0.0;
  /// ICP target: the occupied voxels' mean hit positions (when the map accumulates hits) instead
  /// of their centres.
  bool mean_hit_positions = true;
  /// ICP target: voxels with probability above this (< 0: the map's occupied threshold).
  double min_probability = -1.0;
  IcpOptions icp;
  MatchQualityOptions quality;
  void validate() const;
};

/// The outcome of one registration.
struct ScanMatchResult {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();  ///< sensor to map; the initial pose when not converged
  double score = 0.0;          ///< fraction of the (reduced) scan paired within max_correspondence_distance
  double fitness_rmse = 0.0;   ///< RMS point-to-plane distance of the pairs, metres
  int iterations = 0;          ///< ICP steps taken
  bool converged = false;
  std::string reason;          ///< why not converged (empty when converged)
  double coarse_score = 0.0;   ///< the coarse stage's score (0 when it did not run)
  std::size_t scan_points = 0; ///< points matched after range limit and voxel reduction
  std::size_t pairs = 0;       ///< correspondences at the final pose
  /// Covariance of the pose correction (tx, ty, tz in metres, then rotations about the map's x, y,
  /// z axes through the scan's centroid, radians): sigma^2 H^-1 from the ICP Hessian; 1e6 along
  /// unobservable directions.
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Identity();
  /// Unit 6-D directions (columns, same order as the covariance) the scene does not constrain.
  Eigen::Matrix<double, 6, Eigen::Dynamic> unobservable;
  /// Quality at the final pose (see IcpOptions::inlier_distance): fraction of the scan's points
  /// that are inliers, and that are in the overlap.
  double inlier_fraction = 0.0;
  double overlap_fraction = 0.0;
  /// Per map axis x, y, z: of the overlapping points, weighted by |normal component| of their
  /// nearest surface point along the axis, the inlier fraction (1 when no surface faces the axis).
  Eigen::Vector3d axis_support = Eigen::Vector3d::Ones();
  /// Fraction of the scan's points in known voxels that lie in voxels the map holds free, away from
  /// its surface (0 when the map holds no free space or ScanMatcher did not test it).
  double free_conflict = 0.0;
  /// How far ICP moved the pose from where it started (the coarse stage's pose, or the initial
  /// one), before unconstrained directions were held: metres and radians.
  double icp_shift = 0.0;
  double icp_turn = 0.0;
  /// Directions kept at the initial pose because the scene does not constrain them
  /// (MatchQualityOptions::hold_unconstrained); their covariance is kUnobservableVariance.
  int held_directions = 0;
};

/// The ICP target: points of the map's surface with normals and a k-d tree. Immutable; built once
/// per map state and reusable for many scans (match() may run concurrently).
class MapSurface {
 public:
  /// From \p points (N x 3, metres, map frame); normals from the 8 nearest neighbours (PCA).
  /// Throws std::invalid_argument for fewer than 8 finite points.
  explicit MapSurface(const Eigen::MatrixXd& points);
  /// From the occupied voxels of \p map (probability > \p min_probability; < 0: the map's
  /// threshold), at their mean hit positions when \p mean_hit_positions and the map accumulates hits.
  [[nodiscard]] static MapSurface from_map(IMapperBackend& map, double min_probability = -1.0,
                                           bool mean_hit_positions = true);
  ~MapSurface();
  MapSurface(MapSurface&&) noexcept;
  MapSurface& operator=(MapSurface&&) noexcept;

  [[nodiscard]] std::size_t size() const noexcept;
  [[nodiscard]] const Eigen::MatrixXd& points() const noexcept;   ///< N x 3
  [[nodiscard]] const Eigen::MatrixXd& normals() const noexcept;  ///< N x 3, unit

  /// Point-to-plane ICP of \p scan_sensor (N x 3, sensor frame) from \p initial (sensor to map).
  /// A scene that leaves directions unconstrained gives converged = false ("degenerate scene"),
  /// unless \p prior is given: the pose then keeps \p prior's values along those directions, takes
  /// ICP's along the others, and may converge (held_directions counts them).
  /// Throws std::invalid_argument for an empty scan or a non-finite initial pose.
  [[nodiscard]] ScanMatchResult align(const Eigen::MatrixXd& scan_sensor, const Eigen::Isometry3d& initial,
                                      const IcpOptions& options = {},
                                      const std::optional<Eigen::Isometry3d>& prior = std::nullopt) const;

  /// Distance (metres) from each row of \p points (N x 3, map frame) to the surface: to the tangent
  /// plane of the nearest surface point when that point lies within \p reach (metres), otherwise to
  /// the point itself (infinity for a non-finite row).
  [[nodiscard]] Eigen::VectorXd distances(const Eigen::MatrixXd& points, double reach) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Both stages against one map state.
class ScanMatcher {
 public:
  /// Reads \p map's occupied voxels for ICP now; the coarse stage reads \p map at each match(), so
  /// the map must outlive the matcher and not change while it matches (re-create after updates).
  explicit ScanMatcher(IMapperBackend& map, ScanMatcherOptions options = {});
  /// As above, with \p surface_points (N x 3, metres, map frame) as the ICP target instead of the
  /// map's occupied voxels: e.g. a map's mean hit positions kept in a file, which place surfaces
  /// better than voxel centres do (centres are up to half a voxel off the surface, and so can be
  /// the pose ICP finds against them).
  ScanMatcher(IMapperBackend& map, const Eigen::MatrixXd& surface_points, ScanMatcherOptions options = {});
  /// As above, with a surface built earlier (shared, e.g. one per submap for many scans).
  /// Throws std::invalid_argument for a null surface when the fine stage is on.
  ScanMatcher(IMapperBackend& map, std::shared_ptr<const MapSurface> surface, ScanMatcherOptions options = {});

  /// Registers \p scan_sensor (N x 3, metres, sensor frame; non-finite rows skipped) near
  /// \p initial (sensor to map). Throws std::invalid_argument for a scan without a finite point
  /// within max_range, a non-finite or non-rigid initial pose.
  [[nodiscard]] ScanMatchResult match(const Eigen::MatrixXd& scan_sensor, const Eigen::Isometry3d& initial) const;

  [[nodiscard]] const ScanMatcherOptions& options() const noexcept { return options_; }

 private:
  // ScanMatchResult::free_conflict of \p scan (sensor frame) at \p pose.
  [[nodiscard]] double free_conflict(const Eigen::MatrixXd& scan, const Eigen::Isometry3d& pose,
                                     const IcpOptions& icp) const;
  // Whether \p pose lies within edge_margin of the window around \p centre.
  [[nodiscard]] bool at_edge(const Eigen::Isometry3d& pose, const Eigen::Isometry3d& centre, double yaw_step) const;
  // Why a converged ICP result fails MatchQualityOptions (empty when it passes).
  [[nodiscard]] std::string quality_refusal(const ScanMatchResult& r, const IcpOptions& icp,
                                            double coarse_yaw_step) const;

  IMapperBackend& map_;
  ScanMatcherOptions options_;
  std::shared_ptr<const MapSurface> surface_;  // null when the map has too few occupied voxels
};

/// The scan reduced to one point per voxel of edge \p voxel (the mean of its points), points
/// farther than \p max_range (> 0) from the origin and non-finite rows dropped.
[[nodiscard]] Eigen::MatrixXd reduce_scan(const Eigen::MatrixXd& scan_sensor, double voxel, double max_range);

}  // namespace iwlomap::registration
