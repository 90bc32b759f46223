// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Per-scan scratch for insert_scan(): it turns the rays of one scan into at most one observation
// per voxel before any backend storage is touched. Free voxels are bits in per-block masks (a ray
// step costs a bit-set, and a hash look-up only when the ray enters another block); hits keep the
// largest intensity per voxel. Occupied wins over free. Because OR and max commute, the result
// does not depend on the order of the rays, which is what lets rays be cast in any order or on
// several threads and still give bit-identical maps.

#include "detail/block_grid.h"
#include "detail/flat_key_map.h"
#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <array>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace iwlomap::detail {

class ScanScratch {
 public:
  struct Block {
    VoxelKey key;                          // block coordinate
    std::array<std::uint64_t, 8> free{};   // voxels crossed by a ray
    std::array<std::uint64_t, 8> hit{};    // voxels holding an endpoint
  };
  struct Hit {
    VoxelKey key;
    double intensity;
  };

  /// Casts every ray of one scan into the scratch (cleared first). Inputs must have passed
  /// check_scan_input(). Throws std::out_of_range for an endpoint whose key does not fit in int32
  /// (the map is untouched, since nothing is applied yet). Returns the number of skipped points.
  std::size_t collect(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                      const Eigen::VectorXd& intensities, double max_range, double resolution);

  [[nodiscard]] const std::vector<Block>& blocks() const noexcept { return blocks_; }
  [[nodiscard]] const std::vector<Hit>& hits() const noexcept { return hits_; }

  /// Calls fn(key, intensity, occupied_flag) once per observed voxel: first every free voxel that
  /// holds no hit (intensity 0, flag false), block by block, then every hit voxel (its largest
  /// intensity, flag true).
  template <class Fn>
  void for_each_observation(Fn&& fn) const {
    for (const Block& b : blocks_) {
      for (int w = 0; w < 8; ++w) {
        std::uint64_t bits = b.free[w] & ~b.hit[w];
        while (bits != 0) {
          const int bit = __builtin_ctzll(bits);
          bits &= bits - 1;
          fn(voxel_of(b.key, w * 64 + bit), 0.0, false);
        }
      }
    }
    for (const Hit& h : hits_) fn(h.key, h.intensity, true);
  }

  /// Bytes held by the scratch buffers (kept between scans to avoid reallocation).
  [[nodiscard]] std::size_t bytes() const noexcept;
  /// Releases the buffers.
  void release();

 private:
  Block& block(const VoxelKey& block_key);
  void mark_free(const VoxelKey& k) {
    const VoxelKey bk = block_of(k);
    if (last_ < 0 || blocks_[static_cast<std::size_t>(last_)].key != bk) last_ = static_cast<std::int64_t>(&block(bk) - blocks_.data());
    const int i = index_in_block(k);
    blocks_[static_cast<std::size_t>(last_)].free[static_cast<std::size_t>(i >> 6)] |= std::uint64_t{1} << (i & 63);
  }
  void add_hit(const VoxelKey& k, double intensity);

  std::vector<Block> blocks_;
  FlatKeyMap block_index_;
  std::vector<Hit> hits_;
  FlatKeyMap hit_index_;
  std::int64_t last_ = -1;
};

}  // namespace iwlomap::detail
