// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/mapper_backend.h"

#include "backends/backend_access.h"
#include "integrate/batch_input.h"
#include "integrate/phase_clock.h"
#include "integrate/scan_scratch.h"
#include "model/checks.h"
#include "iwlomap/voxel_box.h"

#include <algorithm>
#include <memory>
#include <cstdint>
#include <limits>
#include <optional>
#include <stdexcept>
#include <string>
#include <thread>

namespace iwlomap {

namespace {

[[noreturn]] void not_supported(const IMapperBackend& b, const std::string& what, const char* feature) {
  throw std::logic_error("iwlomap: the " + b.get_backend_type() + " backend does not implement " + what +
                         " (supports(BackendFeature::" + feature + ") is false)");
}

}  // namespace

// ---- the defaults of IMapperBackend, built on the reference API's required methods ----

bool IMapperBackend::supports(BackendFeature) const { return false; }

void IMapperBackend::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                       const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights) {
  (void)detail::validate_batch(points, intensities, is_occupied, &weights, get_resolution());
  if (!(weights.array() == 1.0).all()) not_supported(*this, "per-point weights other than 1", "kWeights");
  batch_update_iwlo(points, intensities, is_occupied);
}

void IMapperBackend::insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                 const Eigen::VectorXd& intensities, double max_range) {
  ScanPhaseTimes& phases = last_scan_phases();
  detail::PhaseClock total = detail::start_scan_phases(phases, get_num_threads());
  const double r = get_resolution();
  detail::check_scan_input(origin, points, intensities, max_range, r);
  detail::ScanScratch scratch;
  const std::size_t skipped = scratch.collect(origin, points, intensities, max_range, r, get_ray_model(),
                                              get_num_threads(), &get_progress_callback(), nullptr, &phases);
  {
    detail::PhaseClock updating(&phases.updating);
    detail::apply_scratch_by_batches(*this, scratch);
  }
  default_skipped_ += skipped;
}

void detail::apply_scratch_by_batches(IMapperBackend& map, const ScanScratch& scratch) {
  const double r = map.get_resolution();
  // Every voxel's one observation of the scan, at the voxel's centre, in batches of kRows rows.
  constexpr Eigen::Index kRows = Eigen::Index{1} << 16;
  Eigen::MatrixXd rows(kRows, 3);
  Eigen::VectorXd values(kRows);
  std::vector<bool> flags(static_cast<std::size_t>(kRows));
  Eigen::Index n = 0;
  const auto flush = [&] {
    if (n == kRows) {
      map.batch_update_iwlo(rows, values, flags);
    } else if (n > 0) {
      map.batch_update_iwlo(rows.topRows(n), values.head(n),
                            std::vector<bool>(flags.begin(), flags.begin() + static_cast<std::ptrdiff_t>(n)));
    }
    n = 0;
  };
  const auto add = [&](const VoxelKey& key, double intensity, bool occupied) {
    rows.row(n) = key_to_center(key, r).transpose();
    values[n] = intensity;
    flags[static_cast<std::size_t>(n)] = occupied;
    if (++n == kRows) flush();
  };
  scratch.for_each_free(0, scratch.num_chunks(),
                        [&](const VoxelKey& block_key, int index) { add(detail::voxel_of(block_key, index), 0.0, false); });
  scratch.for_each_hit([&](const VoxelKey& key, double intensity) { add(key, intensity, true); });
  flush();
}

void detail::BackendAccess::apply_collected_scan(IMapperBackend& map, const ScanScratch& scratch) {
  auto* ram = dynamic_cast<ProbabilityUpdater*>(&map);
  auto* disk = ram == nullptr ? dynamic_cast<OutofcoreTileMapper*>(&map) : nullptr;
  if (ram == nullptr && disk == nullptr) {
    apply_scratch_by_batches(map, scratch);
    return;
  }
  // Their own scan path merges the scan's hit statistics, which only a walk of the points gives.
  if (map.get_hit_accumulation() && scratch.statistics() == nullptr)
    throw std::logic_error("iwlomap: a collected scan carries no points for the hit statistics; turn them off");
  if (ram != nullptr)
    apply_to_ram(*ram, scratch);
  else
    apply_to_disk(*disk, scratch);
}

void detail::BackendAccess::for_each_known_block(const IMapperBackend& map, const KnownBlockVisit& visit) {
  if (const auto* ram = dynamic_cast<const ProbabilityUpdater*>(&map)) {
    for_each_known_block_ram(*ram, visit);
  } else if (const auto* disk = dynamic_cast<const OutofcoreTileMapper*>(&map)) {
    for_each_known_block_disk(*disk, visit);
  } else {
    auto group = std::make_unique<KnownBlockGrouper>(visit);
    map.for_each_voxel(
        [&group](const VoxelKey& k, const VoxelState& v) { group->add(k, static_cast<float>(v.log_odds)); });
    group->finish();
  }
}

std::optional<VoxelState> IMapperBackend::query(const Eigen::Vector3d&) const {
  not_supported(*this, "query()", "kQuery");
}

void IMapperBackend::for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>&) const {
  not_supported(*this, "for_each_voxel()", "kQuery");
}

size_t IMapperBackend::get_num_skipped_points() const { return default_skipped_; }

void IMapperBackend::set_params(const IwloParams& params) {
  params.validate();
  set_iwlo_params(params.sharpness, params.decay_rate, params.min_alpha, params.L_min, params.L_max);
  set_log_odds_params(params.log_odds_occupied, params.log_odds_free);
  set_intensity_params(params.intensity_threshold, params.intensity_max);
  set_adaptive_params(params.adaptive_enabled, params.adaptive_threshold, params.adaptive_max_ratio);
  set_occupied_threshold(params.occupied_threshold);
  default_params_ = params;
}

IwloParams IMapperBackend::get_params() const { return default_params_; }

std::unique_ptr<IMapperBackend> IMapperBackend::clone() const { not_supported(*this, "clone()", "kClone"); }

void IMapperBackend::set_num_threads(int threads) {
  if (threads < 0)
    throw std::invalid_argument("iwlomap: set_num_threads: threads must be >= 0 (0 = all hardware threads), got " +
                                std::to_string(threads));
  num_threads_ = threads > 0 ? threads : static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
}

bool BackendBase::supports(BackendFeature) const { return true; }

void BackendBase::modify_params(const std::function<void(IwloParams&)>& change) {
  IwloParams p = get_params();
  change(p);
  p.validate();
  set_params(p);
}

// Each setter changes its fields of a validated copy, so a rejected value leaves every parameter
// as it was.
void BackendBase::set_iwlo_params(double sharpness, double decay_rate, double min_alpha, double L_min, double L_max) {
  modify_params([&](IwloParams& p) {
    p.sharpness = sharpness;
    p.decay_rate = decay_rate;
    p.min_alpha = min_alpha;
    p.L_min = L_min;
    p.L_max = L_max;
  });
}

void BackendBase::set_log_odds_params(double log_odds_occupied, double log_odds_free) {
  modify_params([&](IwloParams& p) {
    p.log_odds_occupied = log_odds_occupied;
    p.log_odds_free = log_odds_free;
  });
}

void BackendBase::set_intensity_params(double intensity_threshold, double intensity_max) {
  modify_params([&](IwloParams& p) {
    p.intensity_threshold = intensity_threshold;
    p.intensity_max = intensity_max;
  });
}

void BackendBase::set_adaptive_params(bool enabled, double threshold, double max_ratio) {
  modify_params([&](IwloParams& p) {
    p.adaptive_enabled = enabled;
    p.adaptive_threshold = threshold;
    p.adaptive_max_ratio = max_ratio;
  });
}

void BackendBase::set_occupied_threshold(double threshold) {
  modify_params([&](IwloParams& p) { p.occupied_threshold = threshold; });
}

// Declared with VoxelBox (voxel_box.h); defined on the backends floor, which it reads.
std::optional<VoxelBox> known_voxel_box(const IMapperBackend& map) {
  constexpr std::int32_t kLow = std::numeric_limits<std::int32_t>::min();
  constexpr std::int32_t kHigh = std::numeric_limits<std::int32_t>::max();
  VoxelBox box{{kHigh, kHigh, kHigh}, {kLow, kLow, kLow}};
  bool any = false;
  map.for_each_voxel([&](const VoxelKey& k, const VoxelState&) {
    any = true;
    box.min = {std::min(box.min.x, k.x), std::min(box.min.y, k.y), std::min(box.min.z, k.z)};
    box.max = {std::max(box.max.x, k.x), std::max(box.max.y, k.y), std::max(box.max.z, k.z)};
  });
  if (!any) return std::nullopt;
  return box;
}

const char* progress_stage_name(ProgressStage stage) noexcept {
  switch (stage) {
    case ProgressStage::kCastingRays:
      return "casting rays";
    case ProgressStage::kUpdatingVoxels:
      return "updating voxels";
    case ProgressStage::kWritingTiles:
      return "writing tiles";
    case ProgressStage::kWritingFile:
      return "writing the file";
  }
  return "working";
}

}  // namespace iwlomap
