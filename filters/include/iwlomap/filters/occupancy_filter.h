// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// OccupancyFilter: a pcl::FilterIndices that integrates each input cloud into an IWLO occupancy
/// map and returns the occupied voxels of the whole map, or the input points that lie in occupied
/// voxels. A pcl::PCLPointCloud2 input goes through pointcloud2_to_xyzi() (pointcloud2.h) first.

#include <iwlomap/iwlo.h>
#include <iwlomap/mapper_backend.h>
#include <iwlomap/sensor_preset.h>
#include <iwlomap/voxel_colors.h>

#include <pcl/filters/filter_indices.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>

#include <memory>
#include <string>

namespace iwlomap {

/// What OccupancyFilter::filter() outputs.
enum class OutputMode {
  /// The occupied voxels of the whole map so far, one point per voxel (the default).
  kMap,
  /// The input points (within setIndices()) that lie in occupied voxels after this frame was
  /// integrated, with all their fields untouched: a transient point (a moving object in space the
  /// map has seen free, speckle) is removed, so the filter cleans each frame.
  /// getRemovedIndices() (construct with extract_removed_indices = true), setNegative(),
  /// setKeepOrganized() and setUserFilterValue() work as for PCL's index filters
  /// (pcl::FilterIndices); filter(pcl::Indices&) gives this selection in every mode.
  kInputPoints,
};

/// Integrates clouds into an occupancy map, one call of filter() per frame, and outputs the map's
/// occupied voxels (or, in OutputMode::kInputPoints, the frame's points in occupied voxels).
///
/// As a pcl::FilterIndices<PointT>, `filter(pcl::Indices& indices)` integrates the frame like
/// filter(cloud) and returns the indices (into the input cloud) of the points that lie in occupied
/// voxels after it, whatever the output mode (a map voxel has no input index); setNegative()
/// returns the others instead, and getRemovedIndices() holds the complement when the filter was
/// constructed with extract_removed_indices = true. A point with a non-finite coordinate lies in
/// no voxel and is never returned.
///
/// Input: points in metres in the map frame, as PCL stores them; `sensor_origin_` of the input
/// cloud is the sensor position in that frame (the ray origin), and `sensor_orientation_` is only
/// carried along (the points are not rotated). `setIndices()` is honoured; points with a NaN or
/// infinite coordinate or intensity are skipped (the map counts them). A point type without an
/// `intensity` field (e.g. pcl::PointXYZ) gives every point the intensity `intensity_max`, so every
/// point is a full-weight hit.
///
/// Output (OutputMode::kMap, the default; see OutputMode::kInputPoints for the other): one point
/// per occupied voxel of the whole map (all frames so far), at the voxel centre
/// (or at the mean of the hits that fell in it, setOutputMeanPositions());
/// `intensity` (where the type has it) is the occupancy probability in (threshold, 1]; `r`, `g`,
/// `b` (where the type has colour) are the voxel's mean colour (setColorMeans()). The output
/// is unorganised (height 1) and dense; header, sensor origin and orientation are the input's.
/// An empty input integrates nothing and returns the current map. In-place use
/// (`f.filter(*cloud)` with `cloud` the input) works.
///
/// Precompiled for pcl::PointXYZI, PointXYZINormal, PointXYZ, PointXYZRGB, PointXYZRGBA and
/// PointXYZL; any other point type with x, y and z compiles by including
/// `iwlomap/filters/impl/occupancy_filter.hpp`, which this header includes itself when
/// PCL_NO_PRECOMPILE is defined (PCL's convention). Types without an intensity field count every
/// point as a full-weight hit; in OutputMode::kMap the output points of a type with colour carry
/// their voxel's mean colour and those of other types no label or other field (a voxel has none);
/// in OutputMode::kInputPoints every field of a kept point is the input's.
template <typename PointT>
class OccupancyFilter : public pcl::FilterIndices<PointT> {
  using PointCloud = typename pcl::FilterIndices<PointT>::PointCloud;

 public:
  using Ptr = std::shared_ptr<OccupancyFilter<PointT>>;
  using ConstPtr = std::shared_ptr<const OccupancyFilter<PointT>>;

  /// \param extract_removed_indices keep the indices of the input points kInputPoints mode
  ///        removes, for getRemovedIndices() (as PCL's filters)
  explicit OccupancyFilter(bool extract_removed_indices = false);

  /// Voxel edge in metres (default 0.05) of the map created on first use. Throws
  /// std::invalid_argument for a value <= 0 or not finite, std::logic_error once a map exists with
  /// another resolution.
  void setResolution(double resolution);
  [[nodiscard]] double getResolution() const { return map_ ? map_->get_resolution() : resolution_; }

  /// Uses \p backend as the map (any IMapperBackend: RAM, Disk, OctoMap). Its resolution and
  /// contents are kept; the filter's IWLO parameters are applied to it at the next filter() call
  /// only if setIwloParams() or setOccupiedThreshold() was called. Throws std::invalid_argument
  /// for a null pointer.
  void setBackend(std::shared_ptr<IMapperBackend> backend);

  /// The map (created with the current resolution on first call when none was set).
  [[nodiscard]] std::shared_ptr<IMapperBackend> getMap();

  /// All IWLO parameters (validated: throws std::invalid_argument). Applied to the map at the next
  /// filter() call.
  void setIwloParams(const IwloParams& params);
  [[nodiscard]] const IwloParams& getIwloParams() const { return params_; }

  /// Sets every IWLO parameter to those of \p preset (sensor_preset_params()), applied to the map
  /// at the next filter(). The default parameters are the reference API's, kSonar: an echo at or
  /// below intensity_threshold (35) is free space. For lidar clouds use kLidar (every return is a
  /// hit, however dark; moved obstacles clear as in OctoMap), for depth cameras kDepthCamera. When
  /// a frame's intensities do not suit the parameters (more than 90 % of its points at or below
  /// the threshold, or all equal and at or below it), filter() logs one PCL_WARN naming the
  /// preset to use, once per filter.
  void setSensorPreset(SensorPreset preset) { setIwloParams(sensor_preset_params(preset)); }

  /// kMap (default) or kInputPoints (see OutputMode).
  void setOutputMode(OutputMode mode) { output_mode_ = mode; }
  [[nodiscard]] OutputMode getOutputMode() const { return output_mode_; }
  // From pcl::FilterIndices, for kInputPoints and filter(pcl::Indices&):
  // setNegative(true) selects the points that would be removed instead of those kept (off by
  // default); setKeepOrganized(true) keeps the input's size and organisation in kInputPoints, the
  // removed points' x, y and z set to the value of setUserFilterValue() (NaN by default).

  /// Probability above which a voxel is output (default 0.7, in (0, 1)).
  void setOccupiedThreshold(double threshold);
  [[nodiscard]] double getOccupiedThreshold() const { return params_.occupied_threshold; }

  /// Rays longer than this (metres) are clipped and give no hit; negative: unlimited (default).
  void setMaxRange(double max_range);
  [[nodiscard]] double getMaxRange() const { return max_range_; }

  /// On (default): free space is ray-cast from the input's sensor origin to every point. Off: every
  /// point is one observation, occupied iff its intensity exceeds the threshold (sonar pipelines).
  void setRayCasting(bool enabled) { ray_casting_ = enabled; }
  [[nodiscard]] bool getRayCasting() const { return ray_casting_; }

  /// Threads the map may use to integrate a cloud (IMapperBackend::set_num_threads(): 1 by
  /// default, 0 = all hardware threads); the map is identical whatever the count. Applied to the
  /// map at the next filter(). Throws std::invalid_argument for a negative count.
  void setNumThreads(int threads);
  [[nodiscard]] int getNumThreads() const { return num_threads_; }

  /// The voxels a ray marks free (IMapperBackend::set_ray_model()): RayModel::kExact (default),
  /// every voxel the ray crosses, or RayModel::kFast, a 26-connected line with up to three times
  /// fewer steps and fewer free voxels. Applied to the map at the next filter().
  void setRayModel(RayModel model) {
    ray_model_ = model;
    ray_model_pending_ = true;
  }
  [[nodiscard]] RayModel getRayModel() const { return ray_model_; }

  /// On: each occupied voxel is output at the mean position of the hits that fell in it (a
  /// sub-voxel estimate of the surface, see iwlomap/hit_statistics.h) instead of its centre; a
  /// voxel without accumulated hits stays at its centre. Off by default. Turning it on turns hit
  /// accumulation on in the map at the next filter() (RAM backend; other backends throw
  /// std::logic_error there), so only hits integrated from then on count. Turning it off does not
  /// turn accumulation off.
  void setOutputMeanPositions(bool enabled) { mean_positions_ = enabled; }
  [[nodiscard]] bool getOutputMeanPositions() const { return mean_positions_; }

  /// On (the default for point types with an rgb or rgba field): every voxel keeps the running
  /// mean colour of the hits that fell in it (VoxelColorMeans, beside the map, any backend), and
  /// the kMap output carries it in r, g, b (0, 0, 0 for a voxel without coloured hits, e.g. one
  /// occupied before colours were kept). Off: no colour is kept and the output's r, g, b are 0.
  /// Turning it off forgets the colours. Throws std::invalid_argument when turned on for a point
  /// type without colour.
  void setColorMeans(bool enabled);
  [[nodiscard]] bool getColorMeans() const { return color_means_; }
  /// The per-voxel mean colours (at the map's resolution), or null when setColorMeans() is off or
  /// no map exists yet.
  [[nodiscard]] std::shared_ptr<const VoxelColorMeans> getVoxelColors() const { return colors_; }

 protected:
  using pcl::FilterIndices<PointT>::filter_name_;
  using pcl::FilterIndices<PointT>::input_;
  using pcl::FilterIndices<PointT>::indices_;
  using pcl::FilterIndices<PointT>::removed_indices_;
  using pcl::FilterIndices<PointT>::extract_removed_indices_;
  using pcl::FilterIndices<PointT>::negative_;
  using pcl::FilterIndices<PointT>::keep_organized_;
  using pcl::FilterIndices<PointT>::user_filter_value_;

  /// Integrates input_ (restricted to indices_) into the map and writes its occupied voxels (or
  /// the input points in them, OutputMode::kInputPoints).
  void applyFilter(PointCloud& output) override;
  /// Integrates input_ (restricted to indices_) into the map and writes the indices of the input
  /// points in occupied voxels (the others with setNegative()).
  void applyFilter(pcl::Indices& indices) override;

 private:
  void ensureMap();
  void integrateInput();
  // The input indices selected after integration (those in occupied voxels, or the others when
  // negative_), in the order of indices_; the rest go to removed_indices_ when kept.
  void selectInputPoints(pcl::Indices& selected);
  void outputInputPoints(PointCloud& output);

  std::shared_ptr<IMapperBackend> map_;
  double resolution_ = 0.05;
  IwloParams params_;
  bool params_pending_ = true;  // apply params_ to the map at the next filter()
  double max_range_ = -1.0;
  bool ray_casting_ = true;
  int num_threads_ = 1;
  bool threads_pending_ = false;  // apply num_threads_ to the map at the next filter()
  RayModel ray_model_ = RayModel::kExact;
  bool ray_model_pending_ = false;  // apply ray_model_ to the map at the next filter()
  bool mean_positions_ = false;
  bool color_means_ = pcl::traits::has_color_v<PointT>;
  std::shared_ptr<VoxelColorMeans> colors_;  // with color_means_, created with the map
  bool intensity_warned_ = false;  // the PCL_WARN of setSensorPreset() was logged
  OutputMode output_mode_ = OutputMode::kMap;
};

}  // namespace iwlomap

#ifdef PCL_NO_PRECOMPILE
#include "iwlomap/filters/impl/occupancy_filter.hpp"
#endif
