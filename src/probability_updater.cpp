// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/probability_updater.h"

#include "detail/batch_input.h"
#include "detail/block_grid.h"
#include "detail/param_setters.h"
#include "detail/scan_scratch.h"

#include <stdexcept>

namespace iwlomap {

struct ProbabilityUpdater::Impl {
  explicit Impl(double res) : resolution(res) {}

  // Applies one observation to the voxel \p key (the only place the grid changes).
  void apply(detail::BlockAccessor& acc, const VoxelKey& key, double intensity, bool occupied_flag,
             double weight) {
    detail::VoxelBlock& b = acc.block(detail::block_of(key));
    const int i = detail::index_in_block(key);
    if (b.count[i] == 0) {
      ++b.known;
      ++known;
    }
    iwlo::apply_observation(b.log_odds[i], b.count[i], intensity, occupied_flag, weight, params);
  }

  void apply_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                   const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights) {
    const std::size_t skip = detail::prepare_batch(points, intensities, is_occupied, weights, resolution, batch);
    detail::BlockAccessor acc(grid);
    for (const detail::Observation& o : batch) apply(acc, o.key, o.intensity, o.occupied_flag, o.weight);
    skipped += skip;
  }

  double resolution;
  IwloParams params;
  detail::BlockGrid grid;
  detail::ScanScratch scratch;
  std::vector<detail::Observation> batch;  // reused between batches
  std::size_t known = 0;
  std::size_t skipped = 0;
};

ProbabilityUpdater::ProbabilityUpdater(double resolution) {
  detail::check_resolution(resolution);
  impl_ = std::make_unique<Impl>(resolution);
}
ProbabilityUpdater::~ProbabilityUpdater() = default;
ProbabilityUpdater::ProbabilityUpdater(ProbabilityUpdater&&) noexcept = default;
ProbabilityUpdater& ProbabilityUpdater::operator=(ProbabilityUpdater&&) noexcept = default;

ProbabilityUpdater::Impl& ProbabilityUpdater::impl() {
  if (!impl_) throw std::logic_error("iwlomap: ProbabilityUpdater used after it was moved from");
  return *impl_;
}
const ProbabilityUpdater::Impl& ProbabilityUpdater::impl() const {
  if (!impl_) throw std::logic_error("iwlomap: ProbabilityUpdater used after it was moved from");
  return *impl_;
}

void ProbabilityUpdater::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                           const std::vector<bool>& is_occupied) {
  impl().apply_batch(points, intensities, is_occupied, nullptr);
}

void ProbabilityUpdater::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                           const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights) {
  impl().apply_batch(points, intensities, is_occupied, &weights);
}

void ProbabilityUpdater::insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                     const Eigen::VectorXd& intensities, double max_range) {
  Impl& m = impl();
  detail::check_scan_input(origin, points, intensities, max_range, m.resolution);
  const std::size_t skip = m.scratch.collect(origin, points, intensities, max_range, m.resolution);
  detail::BlockAccessor acc(m.grid);
  m.scratch.for_each_observation(
      [&](const VoxelKey& key, double intensity, bool occupied_flag) { m.apply(acc, key, intensity, occupied_flag, 1.0); });
  m.skipped += skip;
}

void ProbabilityUpdater::set_iwlo_params(double sharpness, double decay_rate, double min_alpha, double L_min,
                                         double L_max) {
  impl().params = detail::with_iwlo(impl().params, sharpness, decay_rate, min_alpha, L_min, L_max);
}
void ProbabilityUpdater::set_log_odds_params(double log_odds_occupied, double log_odds_free) {
  impl().params = detail::with_log_odds(impl().params, log_odds_occupied, log_odds_free);
}
void ProbabilityUpdater::set_intensity_params(double intensity_threshold, double intensity_max) {
  impl().params = detail::with_intensity(impl().params, intensity_threshold, intensity_max);
}
void ProbabilityUpdater::set_adaptive_params(bool enabled, double threshold, double max_ratio) {
  impl().params = detail::with_adaptive(impl().params, enabled, threshold, max_ratio);
}
void ProbabilityUpdater::set_occupied_threshold(double threshold) {
  impl().params = detail::with_occupied_threshold(impl().params, threshold);
}
void ProbabilityUpdater::set_params(const IwloParams& params) { impl().params = detail::validated(params); }
IwloParams ProbabilityUpdater::get_params() const { return impl().params; }

Eigen::MatrixXd ProbabilityUpdater::get_occupied_voxels(double min_probability) {
  const double threshold = detail::resolve_min_probability(min_probability);
  const Impl& m = impl();
  std::vector<double> rows;
  for (const auto& b : m.grid.blocks()) {
    for (int i = 0; i < detail::kBlockVoxels; ++i) {
      if (b->count[i] == 0) continue;
      const double p = iwlo::probability(b->log_odds[i]);
      if (!(p > threshold)) continue;
      const Eigen::Vector3d c = key_to_center(detail::voxel_of(b->key, i), m.resolution);
      rows.insert(rows.end(), {c.x(), c.y(), c.z(), p});
    }
  }
  return detail::rows_to_matrix(rows);
}

std::optional<VoxelState> ProbabilityUpdater::query(const Eigen::Vector3d& point) const {
  const Impl& m = impl();
  const VoxelKey key = world_to_key_checked(point, m.resolution);
  const detail::VoxelBlock* b = m.grid.find(detail::block_of(key));
  if (b == nullptr) return std::nullopt;
  const int i = detail::index_in_block(key);
  if (b->count[i] == 0) return std::nullopt;
  return VoxelState{b->log_odds[i], iwlo::probability(b->log_odds[i]), b->count[i]};
}

void ProbabilityUpdater::for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>& visit) const {
  for (const auto& b : impl().grid.blocks()) {
    for (int i = 0; i < detail::kBlockVoxels; ++i) {
      if (b->count[i] == 0) continue;
      visit(detail::voxel_of(b->key, i), VoxelState{b->log_odds[i], iwlo::probability(b->log_odds[i]), b->count[i]});
    }
  }
}

MemoryStats ProbabilityUpdater::get_memory_usage() const {
  const Impl& m = impl();
  const std::size_t bytes = sizeof(Impl) + m.grid.bytes() + m.scratch.bytes() +
                            m.batch.capacity() * sizeof(detail::Observation);
  const std::size_t slots = m.grid.num_blocks() * detail::kBlockVoxels;
  return MemoryStats{m.known, m.known, static_cast<double>(bytes) / (1024.0 * 1024.0),
                     slots == 0 ? 0.0 : static_cast<double>(m.known) / static_cast<double>(slots)};
}

double ProbabilityUpdater::get_resolution() const { return impl().resolution; }
size_t ProbabilityUpdater::get_num_nodes() const { return impl().known; }
size_t ProbabilityUpdater::get_num_skipped_points() const { return impl().skipped; }

void ProbabilityUpdater::clear() {
  Impl& m = impl();
  m.grid.clear();
  m.scratch.release();
  m.batch = {};
  m.known = 0;
  m.skipped = 0;
}

size_t ProbabilityUpdater::prune() {
  Impl& m = impl();
  m.scratch.release();
  m.batch = {};
  return m.grid.prune();
}

}  // namespace iwlomap
