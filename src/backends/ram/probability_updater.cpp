// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/probability_updater.h"

#include "backends/backend_access.h"
#include "backends/pimpl.h"
#include "integrate/phase_clock.h"
#include "integrate/absolute_log_odds.h"
#include "integrate/batch_apply.h"
#include "integrate/batch_input.h"
#include "integrate/progress_report.h"
#include "integrate/block_sorted_batch.h"
#include "integrate/voxel_update.h"
#include "storage/block_grid.h"
#include "storage/grid_reads.h"
#include "integrate/hit_accumulator.h"
#include "integrate/scan_apply.h"
#include "integrate/scan_scratch.h"

#include <algorithm>
#include <array>
#include <cstdint>
#include <exception>
#include <memory>
#include <stdexcept>
#include <utility>

namespace iwlomap {

struct ProbabilityUpdater::Impl {
  explicit Impl(double res) : resolution(res) {}
  // A copy holds the same voxels (in the same iteration order), parameters, counts and hit
  // statistics, and scratch of its own.
  Impl(const Impl& o)
      : resolution(o.resolution), updater(o.updater), grid(o.grid.clone()), known(o.known), skipped(o.skipped),
        hits(o.hits) {}

  // The batch is validated first (nothing changes when it throws for its input), then applied by
  // the shared kernel with the grid's own block look-up.
  void apply_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                   const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights) {
    const std::size_t skip = detail::validate_batch(points, intensities, is_occupied, weights, resolution);
    if (points.rows() == 0) return;
    const detail::FloorDivider divide(resolution);
    if (detail::BlockSortedBatch::suits(points, intensities, skip, divide)) {
      // Scattered points: regrouped by block (block_sorted_batch.h), for the same map. The
      // scratch (22 bytes a row and a table of at most 8) lives for this call only.
      detail::BlockSortedBatch sorted;
      if (sorted.build(points, intensities, is_occupied, skip, divide)) {
        skipped += skip;
        detail::apply_block_sorted(sorted, detail::OneGrid(grid), {intensities, is_occupied, weights}, updater, known);
        return;
      }
    }
    struct Locate {
      detail::BlockGrid& grid_;
      detail::VoxelBlock& block(std::size_t, const VoxelKey& block_key, std::size_t slot) {
        return grid_.get_or_create(block_key, slot);
      }
      detail::BlockGrid& grid(std::size_t) { return grid_; }
    };
    detail::apply_batch(detail::PointRows(points, intensities, resolution, skip != 0),
                        static_cast<std::size_t>(points.rows()), Locate{grid}, {intensities, is_occupied, weights},
                        updater, {known, skipped});
  }

  void set(const IwloParams& p) {
    detail::Updater next(p);
    detail::convert_voxels(grid, updater.format(), next.format());
    updater = std::move(next);
  }

  double resolution;
  detail::Updater updater;
  detail::BlockGrid grid;
  detail::ScanScratch scratch;
  std::size_t known = 0;
  std::size_t skipped = 0;
  detail::HitStatisticsOf hits{resolution};
};

ProbabilityUpdater::ProbabilityUpdater(double resolution) {
  detail::check_resolution(resolution);
  impl_ = std::make_unique<Impl>(resolution);
}

IWLOMAP_DEFINE_PIMPL_MEMBERS(ProbabilityUpdater)

void ProbabilityUpdater::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                           const std::vector<bool>& is_occupied) {
  Impl& m = impl();
  m.apply_batch(points, intensities, is_occupied, nullptr);
  m.hits.add_batch(points, intensities, is_occupied, m.updater.params().intensity_threshold);
}

void ProbabilityUpdater::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                           const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights) {
  Impl& m = impl();
  m.apply_batch(points, intensities, is_occupied, &weights);
  m.hits.add_batch(points, intensities, is_occupied, m.updater.params().intensity_threshold);
}

namespace {

// Applies a collected scan (one observation per voxel) to the grid on up to \p threads threads
// (scan_apply.h), reporting ProgressStage::kUpdatingVoxels (scratch chunks) to \p progress; an
// exception of the callback is kept in \p deferred and the scan applied in full.
template <class Impl>
void apply_collected(Impl& m, const detail::ScanScratch& scratch, int threads, const ProgressCallback* progress,
                     std::exception_ptr& deferred, ScanPhaseTimes* phases = nullptr) {
  detail::OneGrid locate(m.grid);
  detail::allocate_scan(scratch, m.grid, locate, threads, phases);
  detail::StageProgress report(progress, ProgressStage::kUpdatingVoxels, scratch.num_chunks() + 1, &deferred);
  const detail::Updater& updater = m.updater;
  m.known += detail::apply_scan(
      scratch, {}, threads, locate,
      [&updater](detail::VoxelBlock& b, int index, const VoxelKey&, double intensity, bool occupied) {
        return detail::observe_voxel(b, b.existing(index), intensity, occupied, 1.0, updater);
      },
      report, 0, phases ? &phases->updating : nullptr);
}

}  // namespace

void ProbabilityUpdater::insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                     const Eigen::VectorXd& intensities, double max_range) {
  Impl& m = impl();
  ScanPhaseTimes& phases = last_scan_phases();
  detail::PhaseClock total = detail::start_scan_phases(phases, get_num_threads());
  detail::check_scan_input(origin, points, intensities, max_range, m.resolution);
  const int threads = get_num_threads();
  const ProgressCallback* progress = &get_progress_callback();
  const detail::RayStatistics ray_stats{m.updater.params().intensity_threshold};
  const detail::RayStatistics* stats = m.hits.enabled() ? &ray_stats : nullptr;
  const std::size_t skip = m.scratch.collect(origin, points, intensities, max_range, m.resolution, get_ray_model(),
                                             threads, progress, stats, &phases);
  std::exception_ptr deferred;
  apply_collected(m, m.scratch, threads, progress, deferred, &phases);
  m.skipped += skip;
  m.hits.add_scan(m.scratch.statistics());
  total.stop();
  if (deferred) std::rethrow_exception(deferred);
}

void detail::BackendAccess::apply_to_ram(ProbabilityUpdater& map, const ScanScratch& scratch) {
  ProbabilityUpdater::Impl& m = map.impl();
  std::exception_ptr deferred;
  apply_collected(m, scratch, map.get_num_threads(), &map.get_progress_callback(), deferred);
  m.hits.add_scan(scratch.statistics());
  if (deferred) std::rethrow_exception(deferred);
}

void ProbabilityUpdater::set_params(const IwloParams& params) { impl().set(params); }
IwloParams ProbabilityUpdater::get_params() const { return impl().updater.params(); }

void ProbabilityUpdater::set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) {
  Impl& m = impl();
  std::vector<detail::AbsoluteLogOdds> values;
  const std::size_t skip = detail::prepare_log_odds(points, log_odds, m.updater.params(), m.resolution, values);
  detail::BlockAccessor acc(m.grid);
  for (const detail::AbsoluteLogOdds& a : values) {
    detail::VoxelBlock* b = nullptr;
    detail::Voxel& v = acc.voxel(a.key, b);
    if (detail::set_voxel_log_odds(*b, v, a.log_odds, m.updater.format())) ++m.known;
  }
  m.skipped += skip;
}

Eigen::MatrixXd ProbabilityUpdater::get_occupied_voxels(double min_probability) const {
  return detail::occupied_matrix(impl().grid, impl().updater.format(), impl().resolution, min_probability);
}

std::optional<VoxelState> ProbabilityUpdater::query(const Eigen::Vector3d& point) const {
  return detail::query_point(impl().grid, impl().updater.format(), impl().resolution, point);
}

void ProbabilityUpdater::for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>& visit) const {
  detail::for_each_state(impl().grid, impl().updater.format(), visit);
}

void detail::BackendAccess::for_each_known_block_ram(const ProbabilityUpdater& map, const KnownBlockVisit& visit) {
  std::uint16_t index[detail::kBlockVoxels];
  float log_odds[detail::kBlockVoxels];
  const iwlo::VoxelFormat& f = map.impl().updater.format();
  for (const detail::VoxelBlock* b : map.impl().grid.blocks()) {
    if (b->known == 0) continue;
    std::size_t n = 0;
    b->for_each_slot([&](int i, const detail::Voxel& v) {  // branch-free: unknown slots are overwritten
      index[n] = static_cast<std::uint16_t>(i);
      log_odds[n] = f.log_odds(v.word);
      n += v.known() ? 1 : 0;
    });
    visit(b->key, index, log_odds, n);
  }
}

void ProbabilityUpdater::set_hit_accumulation(bool enabled) { impl().hits.set_enabled(enabled); }

bool ProbabilityUpdater::get_hit_accumulation() const { return impl().hits.enabled(); }

std::optional<HitStatistics> ProbabilityUpdater::hit_statistics(const Eigen::Vector3d& point) const {
  const Impl& m = impl();
  return m.hits.get("hit_statistics()").statistics(world_to_key_checked(point, m.resolution));
}

Eigen::MatrixXd ProbabilityUpdater::get_occupied_mean_positions(double min_probability) {
  const Impl& m = impl();
  return detail::occupied_mean_matrix(m.grid, m.updater.format(), m.hits.get("get_occupied_mean_positions()"), min_probability);
}

std::unique_ptr<IMapperBackend> ProbabilityUpdater::clone() const {
  const Impl& m = impl();
  auto copy = std::make_unique<ProbabilityUpdater>(m.resolution);
  copy->impl_ = std::make_unique<Impl>(m);
  copy->set_num_threads(get_num_threads());
  copy->set_ray_model(get_ray_model());
  return copy;
}

MemoryStats ProbabilityUpdater::get_memory_usage() const {
  const Impl& m = impl();
  const std::size_t bytes = sizeof(Impl) + m.grid.bytes() + m.scratch.bytes() + m.hits.bytes();
  const std::size_t slots = m.grid.num_slots();
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
  m.known = 0;
  m.skipped = 0;
  m.hits.clear();
}

size_t ProbabilityUpdater::prune() {
  Impl& m = impl();
  m.scratch.release();
  return m.grid.prune();
}

}  // namespace iwlomap
