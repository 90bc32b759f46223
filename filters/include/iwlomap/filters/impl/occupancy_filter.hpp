// SPDX-License-Identifier: BSD-3-Clause
#pragma once

#include "iwlomap/filters/occupancy_filter.h"

#include "iwlomap/filters/cloud_conversions.h"

#include <iwlomap/probability_updater.h>

#include <pcl/console/print.h>
// FilterIndices' own applyFilter(PointCloud&), which the base's vtable names, for point types
// that PCL did not precompile.
#include <pcl/filters/impl/filter_indices.hpp>

#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>
#include <stdexcept>
#include <string>

namespace iwlomap {
template <typename PointT>
OccupancyFilter<PointT>::OccupancyFilter(bool extract_removed_indices)
    : pcl::FilterIndices<PointT>(extract_removed_indices) {
  filter_name_ = "OccupancyFilter";
}

template <typename PointT>
void OccupancyFilter<PointT>::setResolution(double resolution) {
  if (!(std::isfinite(resolution) && resolution > 0.0))
    throw std::invalid_argument("OccupancyFilter::setResolution: resolution must be finite and > 0, got " +
                                std::to_string(resolution));
  if (map_ && map_->get_resolution() != resolution)
    throw std::logic_error("OccupancyFilter::setResolution: the map already exists at resolution " +
                           std::to_string(map_->get_resolution()) + "; set the resolution before the first filter()");
  resolution_ = resolution;
}

template <typename PointT>
void OccupancyFilter<PointT>::setColorMeans(bool enabled) {
  if (enabled && !pcl::traits::has_color_v<PointT>)
    throw std::invalid_argument("OccupancyFilter::setColorMeans: the point type has no rgb or rgba field");
  color_means_ = enabled;
  if (!enabled) colors_.reset();
}

template <typename PointT>
void OccupancyFilter<PointT>::setBackend(std::shared_ptr<IMapperBackend> backend) {
  if (!backend) throw std::invalid_argument("OccupancyFilter::setBackend: the backend is null");
  colors_.reset();  // the colours were those of the previous map
  map_ = std::move(backend);
  resolution_ = map_->get_resolution();
  params_pending_ = false;
}

template <typename PointT>
std::shared_ptr<IMapperBackend> OccupancyFilter<PointT>::getMap() {
  ensureMap();
  return map_;
}

template <typename PointT>
void OccupancyFilter<PointT>::setIwloParams(const IwloParams& params) {
  params.validate();
  params_ = params;
  params_pending_ = true;
}

template <typename PointT>
void OccupancyFilter<PointT>::setOccupiedThreshold(double threshold) {
  IwloParams p = params_;
  p.occupied_threshold = threshold;
  p.validate();
  params_ = p;
  params_pending_ = true;
}

template <typename PointT>
void OccupancyFilter<PointT>::setMaxRange(double max_range) {
  if (std::isnan(max_range))
    throw std::invalid_argument("OccupancyFilter::setMaxRange: max_range is NaN (use a negative value for no limit)");
  max_range_ = max_range;
}

template <typename PointT>
void OccupancyFilter<PointT>::setNumThreads(int threads) {
  if (threads < 0)
    throw std::invalid_argument("OccupancyFilter::setNumThreads: threads must be >= 0, got " + std::to_string(threads));
  num_threads_ = threads;
  threads_pending_ = true;
}

template <typename PointT>
void OccupancyFilter<PointT>::ensureMap() {
  if (!map_) {
    map_ = std::make_shared<ProbabilityUpdater>(resolution_);
    params_pending_ = true;
    threads_pending_ = true;
    ray_model_pending_ = true;
  }
  if (params_pending_) {
    map_->set_params(params_);
    params_pending_ = false;
  }
  if (threads_pending_) {
    map_->set_num_threads(num_threads_);
    threads_pending_ = false;
  }
  if (ray_model_pending_) {
    map_->set_ray_model(ray_model_);
    ray_model_pending_ = false;
  }
  if (mean_positions_ && !map_->get_hit_accumulation()) map_->set_hit_accumulation(true);
  if (color_means_ && !colors_) colors_ = std::make_shared<VoxelColorMeans>(map_->get_resolution());
}

template <typename PointT>
void OccupancyFilter<PointT>::integrateInput() {
  ensureMap();
  if (!intensity_warned_) {
    const IwloParams p = map_->get_params();
    const std::size_t n = indices_ ? indices_->size() : input_->size();
    Eigen::VectorXd intensities(static_cast<Eigen::Index>(n));
    for (std::size_t i = 0; i < n; ++i)
      intensities[static_cast<Eigen::Index>(i)] =
          point_intensity((*input_)[indices_ ? static_cast<std::size_t>((*indices_)[i]) : i], p.intensity_max);
    const IntensityCheck check = check_intensities(intensities, p);
    if (check.thins_map()) {
      PCL_WARN("[iwlomap::%s::applyFilter] %s: setSensorPreset(iwlomap::SensorPreset::kLidar)\n", filter_name_.c_str(),
               check.advice().c_str());
      intensity_warned_ = true;
    }
  }
  integrate_cloud(*map_, *input_, indices_.get(), ray_casting_, max_range_, colors_.get());
}

template <typename PointT>
void OccupancyFilter<PointT>::applyFilter(PointCloud& output) {
  integrateInput();
  if (output_mode_ == OutputMode::kInputPoints)
    outputInputPoints(output);
  else
    occupied_to_cloud(*map_, params_.occupied_threshold, output, mean_positions_, colors_.get());
}

template <typename PointT>
void OccupancyFilter<PointT>::applyFilter(pcl::Indices& indices) {
  integrateInput();
  selectInputPoints(indices);
}

template <typename PointT>
void OccupancyFilter<PointT>::selectInputPoints(pcl::Indices& selected) {
  const double threshold = map_->get_params().occupied_threshold;
  const PointCloud& in = *input_;
  const std::size_t n = indices_ ? indices_->size() : in.size();
  selected.clear();
  removed_indices_->clear();
  for (std::size_t i = 0; i < n; ++i) {
    const auto index = indices_ ? (*indices_)[i] : static_cast<pcl::index_t>(i);
    const PointT& p = in[static_cast<std::size_t>(index)];
    const bool finite = std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z);
    bool occupied = false;
    if (finite) {
      const auto state = map_->query(Eigen::Vector3d(p.x, p.y, p.z));
      occupied = state && state->probability > threshold;
    }
    // A non-finite point lies in no voxel: it is removed in both modes.
    if (finite && occupied != negative_)
      selected.push_back(index);
    else if (extract_removed_indices_)
      removed_indices_->push_back(index);
  }
}

template <typename PointT>
void OccupancyFilter<PointT>::outputInputPoints(PointCloud& output) {
  pcl::Indices selected;
  selectInputPoints(selected);
  const PointCloud& in = *input_;
  const auto header = in.header;
  const auto origin = in.sensor_origin_;
  const auto orientation = in.sensor_orientation_;
  if (keep_organized_) {
    // The input's layout; a point not selected (or outside indices_) gets the user filter value
    // in x, y and z (in-place use: output may be the input).
    std::vector<bool> kept(in.size(), false);
    for (const pcl::index_t i : selected) kept[static_cast<std::size_t>(i)] = true;
    PointCloud out = in;
    const float value = user_filter_value_;
    bool replaced = false;
    for (std::size_t j = 0; j < out.size(); ++j)
      if (!kept[j]) {
        out[j].x = out[j].y = out[j].z = value;
        replaced = true;
      }
    if (replaced && !std::isfinite(value)) out.is_dense = false;
    output = std::move(out);
  } else {
    PointCloud out;
    out.reserve(selected.size());
    for (const pcl::index_t i : selected) out.push_back(in[static_cast<std::size_t>(i)]);
    out.width = static_cast<std::uint32_t>(out.size());
    out.height = 1;
    out.is_dense = true;
    output = std::move(out);
  }
  output.header = header;
  output.sensor_origin_ = origin;
  output.sensor_orientation_ = orientation;
}

}  // namespace iwlomap
