// SPDX-License-Identifier: BSD-3-Clause
#include "detail/scan_scratch.h"

#include "detail/batch_input.h"
#include "iwlomap/ray_caster.h"

#include <cmath>

namespace iwlomap::detail {

ScanScratch::Block& ScanScratch::block(const VoxelKey& block_key) {
  const auto next = static_cast<std::uint32_t>(blocks_.size());
  const std::uint32_t i = block_index_.insert(block_key, next);
  if (i == next) blocks_.push_back(Block{block_key, {}, {}});
  return blocks_[i];
}

void ScanScratch::add_hit(const VoxelKey& k, double intensity) {
  const auto next = static_cast<std::uint32_t>(hits_.size());
  const std::uint32_t i = hit_index_.insert(k, next);
  if (i == next) {
    hits_.push_back({k, intensity});
    const int bit = index_in_block(k);
    block(block_of(k)).hit[static_cast<std::size_t>(bit >> 6)] |= std::uint64_t{1} << (bit & 63);
    last_ = -1;  // block() may have reallocated blocks_
  } else if (intensity > hits_[i].intensity) {
    hits_[i].intensity = intensity;
  }
}

std::size_t ScanScratch::collect(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                 const Eigen::VectorXd& intensities, double max_range, double resolution) {
  blocks_.clear();
  block_index_.clear_keep_capacity();
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
  return blocks_.capacity() * sizeof(Block) + hits_.capacity() * sizeof(Hit) + block_index_.bytes() +
         hit_index_.bytes();
}

void ScanScratch::release() {
  blocks_ = {};
  hits_ = {};
  block_index_.reset();
  hit_index_.reset();
  last_ = -1;
}

}  // namespace iwlomap::detail
