// SPDX-License-Identifier: BSD-3-Clause
#include "detail/scan_scratch.h"

#include "detail/batch_input.h"
#include "iwlomap/ray_caster.h"

#include <cmath>

namespace iwlomap::detail {

std::size_t ScanScratch::chunk(const VoxelKey& chunk_key) {
  const auto next = static_cast<std::uint32_t>(chunks_.size());
  const std::uint32_t i = chunk_index_.insert(chunk_key, next);
  if (i == next) {
    chunks_.emplace_back();
    chunks_.back().key = chunk_key;
  }
  return i;
}

void ScanScratch::add_hit(const VoxelKey& k, double intensity) {
  const auto next = static_cast<std::uint32_t>(hits_.size());
  const std::uint32_t i = hit_index_.insert(k, next);
  if (i == next) {
    hits_.push_back({k, intensity});
    const std::size_t c = chunk({k.x >> kChunkShift, k.y >> kChunkShift, k.z >> kChunkShift});
    const std::size_t bit = bit_in_chunk(k);
    chunks_[c].hit[bit >> 6] |= std::uint64_t{1} << (bit & 63);
  } else if (intensity > hits_[i].intensity) {
    hits_[i].intensity = intensity;
  }
}

std::size_t ScanScratch::collect(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                 const Eigen::VectorXd& intensities, double max_range, double resolution) {
  chunks_.clear();
  chunk_index_.clear_keep_capacity();
  hits_.clear();
  hit_index_.clear_keep_capacity();
  last_ = -1;

  const bool clip = max_range > 0.0;
  std::size_t skipped = 0;
  const auto mark = [this](const VoxelKey& k) { mark_free(k); };
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    const Eigen::Vector3d p = points.row(i).transpose();
    const double intensity = intensities[i];
    if (!p.allFinite() || !std::isfinite(intensity)) {
      ++skipped;
      continue;
    }
    const Eigen::Vector3d d = p - origin;
    const double range = d.norm();
    const bool beyond = clip && range > max_range;
    const Eigen::Vector3d end = beyond ? Eigen::Vector3d(origin + d * (max_range / range)) : p;
    if (!is_representable(end, resolution)) throw_out_of_range(i, p, resolution);
    cast_ray(origin, end, resolution, mark);
    if (!beyond) add_hit(world_to_key(p, resolution), intensity);
  }
  return skipped;
}

std::size_t ScanScratch::bytes() const noexcept {
  return chunks_.capacity() * sizeof(Chunk) + hits_.capacity() * sizeof(Hit) + chunk_index_.bytes() +
         hit_index_.bytes();
}

void ScanScratch::release() {
  chunks_ = {};
  hits_ = {};
  chunk_index_.reset();
  hit_index_.reset();
  last_ = -1;
}

}  // namespace iwlomap::detail
