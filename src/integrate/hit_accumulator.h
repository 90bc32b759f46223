// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The RAM backend's optional per-voxel hit statistics (hit_statistics.h), kept beside the block
// grid rather than in detail::Voxel, so that a map without them pays nothing and the voxel stays
// within 8 bytes. Cells live in 8^3 blocks keyed like the grid's blocks (allocated on first
// touch, found through a FlatKeyMap, last block cached). A cell is 32 bytes: the sum of hit
// offsets from the voxel centre in double (offsets rather than positions keep the sum small, so
// millions of hits far from the origin still give a mean to well under a micrometre) and two
// saturating 32-bit counters.

#include "storage/block_grid.h"
#include "storage/flat_key_map.h"
#include "iwlomap/hit_statistics.h"
#include "iwlomap/ray_caster.h"
#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

namespace iwlomap::detail {

struct HitCell {
  std::array<double, 3> offset_sum{};  // sum over hits of (hit - voxel centre), metres
  std::uint32_t hits = 0;
  std::uint32_t visits = 0;
};
static_assert(sizeof(HitCell) == 32, "a hit cell is 32 bytes");

class HitAccumulator {
 public:
  explicit HitAccumulator(double resolution) : resolution_(resolution) {}

  void add_visit(const VoxelKey& k) {
    HitCell& c = cell(k);
    c.visits = saturating_increment(c.visits);
  }

  // Once hits saturate, further positions are dropped too, so the mean stays the mean of the
  // hits it counts.
  void add_hit(const VoxelKey& k, const Eigen::Vector3d& point) {
    HitCell& c = cell(k);
    c.visits = saturating_increment(c.visits);
    if (c.hits == std::numeric_limits<std::uint32_t>::max()) return;
    ++c.hits;
    const Eigen::Vector3d d = point - key_to_center(k, resolution_);
    for (int a = 0; a < 3; ++a) c.offset_sum[static_cast<std::size_t>(a)] += d[a];
  }

  // The statistics of a batch the map has applied (so it was valid): every row whose point and
  // intensity are finite (the rows prepare_batch() keeps) is a visit, and a hit when it is an
  // occupied observation (flag set, intensity above the threshold).
  void add_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                 const std::vector<bool>& is_occupied, double intensity_threshold) {
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
      const Eigen::Vector3d p = points.row(i).transpose();
      if (!p.allFinite() || !std::isfinite(intensities[i])) continue;
      const VoxelKey k = world_to_key(p, resolution_);
      if (is_occupied[static_cast<std::size_t>(i)] && intensities[i] > intensity_threshold)
        add_hit(k, p);
      else
        add_visit(k);
    }
  }

  // The statistics of a scan the map has applied, per ray as GMapping counts beams (see
  // hit_statistics.h). The rays are cast again because the scan scratch merges them per voxel;
  // the endpoint arithmetic is ScanScratch::collect_range()'s, so the voxels are the same.
  void add_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                double max_range, double intensity_threshold) {
    const bool clip = max_range > 0.0;
    const auto visit = [this](const VoxelKey& k) { add_visit(k); };
    for (Eigen::Index i = 0; i < points.rows(); ++i) {
      const Eigen::Vector3d p = points.row(i).transpose();
      const double intensity = intensities[i];
      if (!p.allFinite() || !std::isfinite(intensity)) continue;
      const Eigen::Vector3d d = p - origin;
      const double range = d.norm();
      const bool beyond = clip && range > max_range;
      const Eigen::Vector3d end_point = beyond ? Eigen::Vector3d(origin + d * (max_range / range)) : p;
      cast_ray(origin, end_point, resolution_, visit);
      if (beyond) continue;
      if (intensity > intensity_threshold)
        add_hit(world_to_key(p, resolution_), p);
      else
        add_visit(world_to_key(p, resolution_));
    }
  }

  [[nodiscard]] const HitCell* find(const VoxelKey& k) const noexcept {
    const std::uint32_t i = index_.find(block_of(k));
    if (i == FlatKeyMap::kEmpty) return nullptr;
    return &blocks_[i]->cells[static_cast<std::size_t>(index_in_block(k))];
  }

  [[nodiscard]] HitStatistics statistics(const VoxelKey& k, const HitCell& c) const {
    HitStatistics s;
    s.hits = c.hits;
    s.visits = c.visits;
    s.mean_hit_position = mean_position(k, c);
    s.entropy = cell_entropy(c.hits, c.visits);
    return s;
  }

  [[nodiscard]] Eigen::Vector3d mean_position(const VoxelKey& k, const HitCell& c) const {
    const Eigen::Vector3d centre = key_to_center(k, resolution_);
    if (c.hits == 0) return centre;
    const double n = static_cast<double>(c.hits);
    return centre + Eigen::Vector3d(c.offset_sum[0] / n, c.offset_sum[1] / n, c.offset_sum[2] / n);
  }

  void clear() {
    blocks_.clear();
    blocks_.shrink_to_fit();
    index_.reset();
    last_ = nullptr;
  }

  [[nodiscard]] std::size_t bytes() const noexcept {
    return sizeof(*this) + blocks_.size() * sizeof(Block) + blocks_.capacity() * sizeof(blocks_[0]) + index_.bytes();
  }

 private:
  struct Block {
    std::array<HitCell, kBlockVoxels> cells{};
  };

  static std::uint32_t saturating_increment(std::uint32_t v) noexcept {
    return v == std::numeric_limits<std::uint32_t>::max() ? v : v + 1;
  }

  HitCell& cell(const VoxelKey& k) {
    const VoxelKey b = block_of(k);
    if (last_ == nullptr || last_key_ != b) {
      const auto next = static_cast<std::uint32_t>(blocks_.size());
      const std::uint32_t i = index_.insert(b, next);
      if (i == next) blocks_.push_back(std::make_unique<Block>());
      last_ = blocks_[i].get();
      last_key_ = b;
    }
    return last_->cells[static_cast<std::size_t>(index_in_block(k))];
  }

  double resolution_;
  std::vector<std::unique_ptr<Block>> blocks_;
  FlatKeyMap index_;
  Block* last_ = nullptr;
  VoxelKey last_key_{};
};

}  // namespace iwlomap::detail
