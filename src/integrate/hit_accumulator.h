// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Optional per-voxel hit statistics (hit_statistics.h), kept beside a block grid rather than in
// detail::Voxel, so that a map without them pays nothing and the voxel stays within 8 bytes.
// Cells live in 8^3 blocks keyed like the grid's blocks (allocated on first touch, found through a
// FlatKeyMap, last block cached). A cell is 32 bytes: the sum of hit offsets from the voxel centre
// in double (offsets rather than positions keep the sum small, so millions of hits far from the
// origin still give a mean to well under a micrometre) and two saturating 32-bit counters.
//
// Every backend accumulates a scan the same way, so that their statistics agree bit for bit: the
// scan's ray walk (ScanScratch::collect(), RayStatistics) fills a ScanHits of its own, which is
// then merged into the map's (merge()), block by block; a batch adds its rows in call order.

#include "model/checks.h"
#include "storage/block_grid.h"
#include "storage/flat_key_map.h"
#include "storage/grid_reads.h"
#include "iwlomap/hit_statistics.h"
#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap::detail {

struct HitCell {
  std::array<double, 3> offset_sum{};  // sum over hits of (hit - voxel centre), metres
  std::uint32_t hits = 0;
  std::uint32_t visits = 0;
};
static_assert(sizeof(HitCell) == 32, "a hit cell is 32 bytes");

/// The hit statistics of one scan before they join a map's (HitAccumulator::merge()), gathered
/// by the scan's ray walk (ScanScratch::collect()): visit counts in 8^3 blocks of 32-bit counters
/// (2 KiB a block, an eighth of a HitAccumulator block: a ray step writes 4 bytes, not a 32-byte
/// cell), and each hit voxel's hit count and sum of offsets, added in ray order. Its buffers are
/// kept between scans.
class ScanHits {
 public:
  using Counts = std::array<std::uint32_t, kBlockVoxels>;  // index_in_block() order
  struct HitSum {
    std::array<double, 3> offset_sum{};  // sum over hits of (hit - voxel centre), metres
    std::uint32_t hits = 0;
  };

  /// Empties the statistics (keeping the buffers) for a scan at \p resolution.
  void reset(double resolution) {
    resolution_ = resolution;
    blocks_ = 0;
    block_index_.clear_keep_capacity();
    hit_index_.clear_keep_capacity();
    hit_keys_.clear();
    hits_.clear();
    last_ = nullptr;
  }

  void add_visit(const VoxelKey& k) {
    std::uint32_t& c = counts(block_of(k))[static_cast<std::size_t>(index_in_block(k))];
    c = saturating_add(c, 1);
  }
  /// A visit, and a hit at \p point.
  void add_hit(const VoxelKey& k, const Eigen::Vector3d& point) {
    add_visit(k);
    const auto next = static_cast<std::uint32_t>(hits_.size());
    const std::uint32_t i = hit_index_.insert(k, next);
    if (i == next) {
      hits_.emplace_back();
      hit_keys_.push_back(k);
    }
    HitSum& h = hits_[i];
    if (h.hits == std::numeric_limits<std::uint32_t>::max()) return;
    ++h.hits;
    const Eigen::Vector3d d = point - key_to_center(k, resolution_);
    for (int a = 0; a < 3; ++a) h.offset_sum[static_cast<std::size_t>(a)] += d[a];
  }
  /// Adds \p other's visit counts (a thread's walk; its hits are not taken).
  void add_visits(const ScanHits& other) {
    other.for_each_block([this](const VoxelKey& b, const Counts& from) {
      Counts& to = counts(b);
      for (std::size_t i = 0; i < to.size(); ++i) to[i] = saturating_add(to[i], from[i]);
    });
  }

  /// Calls fn(block_key, const Counts&) for every block with a visit.
  template <class Fn>
  void for_each_block(Fn&& fn) const {
    for (std::size_t i = 0; i < blocks_; ++i) fn(block_keys_[i], counts_[i]);
  }
  /// Calls fn(voxel key, const HitSum&) for every voxel with a hit, in the order of its first hit.
  template <class Fn>
  void for_each_hit(Fn&& fn) const {
    for (std::size_t i = 0; i < hits_.size(); ++i) fn(hit_keys_[i], hits_[i]);
  }

  [[nodiscard]] std::size_t bytes() const noexcept {
    return counts_.capacity() * sizeof(Counts) + block_keys_.capacity() * sizeof(VoxelKey) + block_index_.bytes() +
           hit_index_.bytes() + hit_keys_.capacity() * sizeof(VoxelKey) + hits_.capacity() * sizeof(HitSum);
  }

  static std::uint32_t saturating_add(std::uint32_t v, std::uint32_t d) noexcept {
    return v > std::numeric_limits<std::uint32_t>::max() - d ? std::numeric_limits<std::uint32_t>::max() : v + d;
  }

 private:
  Counts& counts(const VoxelKey& b) {
    if (last_ != nullptr && last_key_ == b) return *last_;
    const auto next = static_cast<std::uint32_t>(blocks_);
    const std::uint32_t i = block_index_.insert(b, next);
    if (i == next) {
      // Blocks past blocks_ are kept from earlier scans and zeroed on reuse.
      if (blocks_ == counts_.size()) {
        counts_.emplace_back();
        block_keys_.push_back(b);
      } else {
        counts_[blocks_].fill(0);
        block_keys_[blocks_] = b;
      }
      ++blocks_;
    }
    last_ = &counts_[i];
    last_key_ = b;
    return *last_;
  }

  double resolution_ = 1.0;
  std::vector<Counts> counts_;
  std::vector<VoxelKey> block_keys_;
  std::size_t blocks_ = 0;  // of counts_ in use
  FlatKeyMap block_index_;
  FlatKeyMap hit_index_;
  std::vector<VoxelKey> hit_keys_;
  std::vector<HitSum> hits_;
  Counts* last_ = nullptr;
  VoxelKey last_key_{};
};

class HitAccumulator {
 public:
  struct Block {
    std::array<HitCell, kBlockVoxels> cells{};  // index_in_block() order
  };

  explicit HitAccumulator(double resolution) : resolution_(resolution) {}
  HitAccumulator(const HitAccumulator& other) : resolution_(other.resolution_), keys_(other.keys_), index_(other.index_) {
    blocks_.reserve(other.blocks_.size());
    for (const auto& b : other.blocks_) blocks_.push_back(std::make_unique<Block>(*b));
  }
  HitAccumulator& operator=(const HitAccumulator&) = delete;

  void add_visit(const VoxelKey& k) {
    HitCell& c = cell(k);
    c.visits = saturating_add(c.visits, 1);
  }

  // Once hits saturate, further positions are dropped too, so the mean stays the mean of the
  // hits it counts.
  void add_hit(const VoxelKey& k, const Eigen::Vector3d& point) {
    HitCell& c = cell(k);
    c.visits = saturating_add(c.visits, 1);
    if (c.hits == std::numeric_limits<std::uint32_t>::max()) return;
    ++c.hits;
    const Eigen::Vector3d d = point - key_to_center(k, resolution_);
    for (int a = 0; a < 3; ++a) c.offset_sum[static_cast<std::size_t>(a)] += d[a];
  }

  /// Row \p i of a batch the map has applied (so it was valid): a visit, and a hit when it is an
  /// occupied observation (flag set, intensity above the threshold). Non-finite rows count nothing.
  void add_row(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities, const std::vector<bool>& is_occupied,
               Eigen::Index i, double intensity_threshold) {
    const Eigen::Vector3d p = points.row(i).transpose();
    if (!p.allFinite() || !std::isfinite(intensities[i])) return;
    const VoxelKey k = world_to_key(p, resolution_);
    if (is_occupied[static_cast<std::size_t>(i)] && intensities[i] > intensity_threshold)
      add_hit(k, p);
    else
      add_visit(k);
  }

  /// Every row of a batch, in order.
  void add_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                 const std::vector<bool>& is_occupied, double intensity_threshold) {
    for (Eigen::Index i = 0; i < points.rows(); ++i) add_row(points, intensities, is_occupied, i, intensity_threshold);
  }

  /// Calls fn(block_key, const Block&) for every block, in the order they were first touched.
  template <class Fn>
  void for_each_block(Fn&& fn) const {
    for (std::size_t i = 0; i < blocks_.size(); ++i) fn(keys_[i], *blocks_[i]);
  }

  /// Adds \p from's cells to block \p block_key's: counts saturating (hits that no longer fit are
  /// dropped with their positions), offset sums added.
  void merge(const VoxelKey& block_key, const Block& from) {
    Block& to = block(block_key);
    for (std::size_t i = 0; i < from.cells.size(); ++i) {
      const HitCell& f = from.cells[i];
      if (f.visits == 0) continue;
      HitCell& t = to.cells[i];
      t.visits = saturating_add(t.visits, f.visits);
      if (f.hits == 0 || f.hits > std::numeric_limits<std::uint32_t>::max() - t.hits) {
        if (f.hits != 0) t.hits = std::numeric_limits<std::uint32_t>::max();
        continue;
      }
      t.hits += f.hits;
      for (std::size_t a = 0; a < 3; ++a) t.offset_sum[a] += f.offset_sum[a];
    }
  }
  /// merge() of every block of \p from.
  void merge(const HitAccumulator& from) {
    from.for_each_block([this](const VoxelKey& b, const Block& cells) { merge(b, cells); });
  }

  /// Adds a scan's visit counts of block \p block_key (saturating).
  void merge_visits(const VoxelKey& block_key, const ScanHits::Counts& from) {
    Block& to = block(block_key);
    for (std::size_t i = 0; i < from.size(); ++i)
      if (from[i] != 0) to.cells[i].visits = saturating_add(to.cells[i].visits, from[i]);
  }
  /// Adds a scan's hits of voxel \p k, by the rules of merge().
  void merge_hits(const VoxelKey& k, const ScanHits::HitSum& from) {
    HitCell& t = cell(k);
    if (from.hits > std::numeric_limits<std::uint32_t>::max() - t.hits) {
      t.hits = std::numeric_limits<std::uint32_t>::max();
      return;
    }
    t.hits += from.hits;
    for (std::size_t a = 0; a < 3; ++a) t.offset_sum[a] += from.offset_sum[a];
  }
  /// Adds every statistic of a scan.
  void merge(const ScanHits& scan) {
    scan.for_each_block([this](const VoxelKey& b, const ScanHits::Counts& c) { merge_visits(b, c); });
    scan.for_each_hit([this](const VoxelKey& k, const ScanHits::HitSum& h) { merge_hits(k, h); });
  }

  [[nodiscard]] const HitCell* find(const VoxelKey& k) const noexcept {
    const std::uint32_t i = index_.find(block_of(k));
    if (i == FlatKeyMap::kEmpty) return nullptr;
    return &blocks_[i]->cells[static_cast<std::size_t>(index_in_block(k))];
  }

  /// The statistics of voxel \p k, or nullopt when it was never visited.
  [[nodiscard]] std::optional<HitStatistics> statistics(const VoxelKey& k) const {
    const HitCell* c = find(k);
    if (c == nullptr || c->visits == 0) return std::nullopt;
    HitStatistics s;
    s.hits = c->hits;
    s.visits = c->visits;
    s.mean_hit_position = mean_position(k, *c);
    s.entropy = cell_entropy(c->hits, c->visits);
    return s;
  }

  /// The mean hit position of voxel \p k, or its centre when it holds no hit.
  [[nodiscard]] Eigen::Vector3d mean_position(const VoxelKey& k) const {
    const HitCell* c = find(k);
    return c != nullptr ? mean_position(k, *c) : key_to_center(k, resolution_);
  }

  [[nodiscard]] bool empty() const noexcept { return blocks_.empty(); }

  void clear() {
    blocks_.clear();
    blocks_.shrink_to_fit();
    keys_.clear();
    keys_.shrink_to_fit();
    index_.reset();
    last_ = nullptr;
  }

  [[nodiscard]] std::size_t bytes() const noexcept {
    return sizeof(*this) + blocks_.size() * sizeof(Block) + blocks_.capacity() * sizeof(blocks_[0]) +
           keys_.capacity() * sizeof(VoxelKey) + index_.bytes();
  }

 private:
  static std::uint32_t saturating_add(std::uint32_t v, std::uint32_t d) noexcept {
    return ScanHits::saturating_add(v, d);
  }

  [[nodiscard]] Eigen::Vector3d mean_position(const VoxelKey& k, const HitCell& c) const {
    const Eigen::Vector3d centre = key_to_center(k, resolution_);
    if (c.hits == 0) return centre;
    const double n = static_cast<double>(c.hits);
    return centre + Eigen::Vector3d(c.offset_sum[0] / n, c.offset_sum[1] / n, c.offset_sum[2] / n);
  }

  Block& block(const VoxelKey& b) {
    if (last_ == nullptr || last_key_ != b) {
      const auto next = static_cast<std::uint32_t>(blocks_.size());
      const std::uint32_t i = index_.insert(b, next);
      if (i == next) {
        blocks_.push_back(std::make_unique<Block>());
        keys_.push_back(b);
      }
      last_ = blocks_[i].get();
      last_key_ = b;
    }
    return *last_;
  }
  HitCell& cell(const VoxelKey& k) { return block(block_of(k)).cells[static_cast<std::size_t>(index_in_block(k))]; }

  double resolution_;
  std::vector<std::unique_ptr<Block>> blocks_;
  std::vector<VoxelKey> keys_;  // of blocks_
  FlatKeyMap index_;
  Block* last_ = nullptr;
  VoxelKey last_key_{};
};

/// The hit statistics of a map held in one HitAccumulator (RAM, OctoMap): on, off, read.
class HitStatisticsOf {
 public:
  explicit HitStatisticsOf(double resolution) : resolution_(resolution) {}
  HitStatisticsOf(const HitStatisticsOf& o)
      : resolution_(o.resolution_), hits_(o.hits_ ? std::make_unique<HitAccumulator>(*o.hits_) : nullptr) {}
  HitStatisticsOf& operator=(const HitStatisticsOf&) = delete;

  /// On: starts from empty statistics unless already on; off: frees them.
  void set_enabled(bool enabled) {
    if (!enabled)
      hits_.reset();
    else if (!hits_)
      hits_ = std::make_unique<HitAccumulator>(resolution_);
  }
  [[nodiscard]] bool enabled() const noexcept { return hits_ != nullptr; }
  /// The accumulator, or std::logic_error naming \p caller when accumulation is off.
  [[nodiscard]] const HitAccumulator& get(const char* caller) const {
    if (!hits_)
      throw std::logic_error(std::string("iwlomap: ") + caller +
                             " needs hit accumulation, which is off (set_hit_accumulation(true))");
    return *hits_;
  }
  [[nodiscard]] HitAccumulator* get() noexcept { return hits_.get(); }

  void add_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities, const std::vector<bool>& is_occupied,
                 double intensity_threshold) {
    if (hits_) hits_->add_batch(points, intensities, is_occupied, intensity_threshold);
  }
  /// Adds a scan's statistics (ScanScratch::statistics(); nothing for null).
  void add_scan(const ScanHits* scan) {
    if (hits_ && scan != nullptr) hits_->merge(*scan);
  }
  void clear() {
    if (hits_) hits_->clear();
  }
  /// Empty statistics at another resolution (a map that took a file's resolution).
  void reset(double resolution) {
    resolution_ = resolution;
    if (hits_) hits_ = std::make_unique<HitAccumulator>(resolution_);
  }
  [[nodiscard]] std::size_t bytes() const noexcept { return hits_ ? hits_->bytes() : 0; }

 private:
  double resolution_;
  std::unique_ptr<HitAccumulator> hits_;
};

/// get_occupied_mean_positions() of a map held in one grid: get_occupied_voxels()'s rows, in its
/// order, at the voxels' mean hit positions.
[[nodiscard]] inline Eigen::MatrixXd occupied_mean_matrix(const BlockGrid& grid, const iwlo::VoxelFormat& f,
                                                          const HitAccumulator& hits, double min_probability) {
  return rows_to_matrix(occupied_rows([&grid](auto&& fn) { for_each_known(grid, fn); }, f,
                                      resolve_min_probability(min_probability),
                                      [&hits](const VoxelKey& key) { return hits.mean_position(key); }));
}

}  // namespace iwlomap::detail
