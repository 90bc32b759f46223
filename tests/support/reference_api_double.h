// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// A backend written against the reference API alone: only IMapperBackend's required methods, as
// a user's own backend or a test double would be. Everything else comes from IMapperBackend's
// defaults. Its voxels are a std::map updated with iwlo::apply_observation(), the reference math.

#include "iwlomap/iwlo.h"
#include "iwlomap/mapper_backend.h"
#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <cmath>
#include <cstdint>
#include <map>
#include <stdexcept>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap::test_support {

class ReferenceApiDouble : public IMapperBackend {
 public:
  explicit ReferenceApiDouble(double resolution) : resolution_(resolution) {}

  void batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                         const std::vector<bool>& is_occupied) override {
    if (points.rows() != intensities.size() || static_cast<std::size_t>(points.rows()) != is_occupied.size())
      throw std::invalid_argument("ReferenceApiDouble: size mismatch");
    ++batches_;
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
      const Eigen::Vector3d p = points.row(i).transpose();
      if (!p.allFinite() || !std::isfinite(intensities[i])) continue;
      auto& [log_odds, count] = voxels_[world_to_key(p, resolution_)];
      iwlo::apply_observation(log_odds, count, intensities[i], is_occupied[static_cast<std::size_t>(i)], 1.0, params_);
    }
  }
  void set_iwlo_params(double sharpness, double decay_rate, double min_alpha, double L_min, double L_max) override {
    IwloParams p = params_;
    p.sharpness = sharpness;
    p.decay_rate = decay_rate;
    p.min_alpha = min_alpha;
    p.L_min = L_min;
    p.L_max = L_max;
    set(p);
  }
  void set_log_odds_params(double log_odds_occupied, double log_odds_free) override {
    IwloParams p = params_;
    p.log_odds_occupied = log_odds_occupied;
    p.log_odds_free = log_odds_free;
    set(p);
  }
  void set_intensity_params(double intensity_threshold, double intensity_max) override {
    IwloParams p = params_;
    p.intensity_threshold = intensity_threshold;
    p.intensity_max = intensity_max;
    set(p);
  }
  void set_adaptive_params(bool enabled, double threshold, double max_ratio) override {
    IwloParams p = params_;
    p.adaptive_enabled = enabled;
    p.adaptive_threshold = threshold;
    p.adaptive_max_ratio = max_ratio;
    set(p);
  }
  void set_occupied_threshold(double threshold) override {
    IwloParams p = params_;
    p.occupied_threshold = threshold;
    set(p);
  }
  Eigen::MatrixXd get_occupied_voxels(double min_probability = 0.5) const override {
    if (min_probability < 0.0) min_probability = 0.5;
    std::vector<std::pair<VoxelKey, double>> rows;
    for (const auto& [k, v] : voxels_) {
      const double p = iwlo::probability(v.first);
      if (p > min_probability) rows.emplace_back(k, p);
    }
    Eigen::MatrixXd out(static_cast<Eigen::Index>(rows.size()), 4);
    for (std::size_t i = 0; i < rows.size(); ++i) {
      const Eigen::Vector3d c = key_to_center(rows[i].first, resolution_);
      out.row(static_cast<Eigen::Index>(i)) << c.x(), c.y(), c.z(), rows[i].second;
    }
    return out;
  }
  MemoryStats get_memory_usage() const override {
    return MemoryStats{voxels_.size(), voxels_.size(), static_cast<double>(voxels_.size()) * 64.0 / 1048576.0, 1.0};
  }
  double get_resolution() const override { return resolution_; }
  size_t get_num_nodes() const override { return voxels_.size(); }
  void clear() override { voxels_.clear(); }
  std::string get_backend_type() const override { return "ReferenceDouble"; }

  /// The stored state, for the tests (log-odds, count by key).
  [[nodiscard]] const std::map<VoxelKey, std::pair<float, std::uint16_t>>& voxels() const { return voxels_; }
  [[nodiscard]] int batches() const { return batches_; }

 private:
  void set(const IwloParams& p) {
    p.validate();
    params_ = p;
  }

  double resolution_;
  IwloParams params_;
  std::map<VoxelKey, std::pair<float, std::uint16_t>> voxels_;
  int batches_ = 0;
};

}  // namespace iwlomap::test_support
