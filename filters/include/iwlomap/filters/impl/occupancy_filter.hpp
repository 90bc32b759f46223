// SPDX-License-Identifier: BSD-3-Clause
#pragma once

#include "iwlomap/filters/occupancy_filter.h"

#include "iwlomap/filters/cloud_conversions.h"

#include <iwlomap/probability_updater.h>

#include <pcl/console/print.h>

#include <cmath>
#include <stdexcept>
#include <string>

namespace iwlomap {
template <typename PointT>
OccupancyFilter<PointT>::OccupancyFilter() {
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
void OccupancyFilter<PointT>::setBackend(std::shared_ptr<IMapperBackend> backend) {
  if (!backend) throw std::invalid_argument("OccupancyFilter::setBackend: the backend is null");
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
  }
  if (params_pending_) {
    map_->set_params(params_);
    params_pending_ = false;
  }
  if (threads_pending_) {
    map_->set_num_threads(num_threads_);
    threads_pending_ = false;
  }
  if (mean_positions_ && !map_->get_hit_accumulation()) map_->set_hit_accumulation(true);
}

template <typename PointT>
void OccupancyFilter<PointT>::applyFilter(PointCloud& output) {
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
  integrate_cloud(*map_, *input_, indices_.get(), ray_casting_, max_range_);
  occupied_to_cloud(*map_, params_.occupied_threshold, output, mean_positions_);
}

}  // namespace iwlomap
