// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Per-scan scratch for insert_scan(): it turns the rays of one scan into at most one observation
// per voxel before any backend storage is touched. Free voxels are bits in the masks of 32^3-voxel
// chunks (a ray step costs a bit-set, and a hash look-up only when the ray enters another chunk,
// about every 40 steps); each chunk lists its hits (voxel, intensity) as the rays bring them, and
// a hit voxel takes the largest intensity of its list when the scratch is read. Inside a chunk the
// bits are laid out block by block (64 blocks of 8^3 voxels, 512 bits each), so that applying the
// scratch visits each grid block once. Occupied wins over free. Because OR and max commute, the result
// does not depend on the order of the rays, which is what lets rays be cast in any order or on
// several threads and still give bit-identical maps.

#include "integrate/hit_accumulator.h"
#include "storage/block_grid.h"
#include "storage/flat_key_map.h"
#include "iwlomap/progress.h"
#include "iwlomap/ray_caster.h"
#include "iwlomap/scan_phases.h"
#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <algorithm>
#include <array>
#include <tuple>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace iwlomap::detail {

/// A scan's hit statistics, gathered by ScanScratch::collect() in its own ray walk (ScanHits):
/// each voxel a ray crosses gets a visit, and the voxel of the ray's end a hit (intensity above
/// \p intensity_threshold) or a visit, per ray as GMapping counts beams (hit_statistics.h).
/// Visits are counts, so the threads' walks add up in any order; the hits, whose positions are
/// summed in floating point, are added on the calling thread in ray order. The result is the
/// same for any thread count.
struct RayStatistics {
  double intensity_threshold;
};

class ScanScratch {
 public:
  static constexpr int kChunkShift = 5;                                  // 32 voxels
  static constexpr int kBlocksPerChunkEdge = 1 << (kChunkShift - kBlockShift);  // 4
  static constexpr int kBlocksPerChunk = kBlocksPerChunkEdge * kBlocksPerChunkEdge * kBlocksPerChunkEdge;
  static constexpr int kWordsPerBlock = kBlockVoxels / 64;  // 8
  // One ray's end in a chunk: the voxel's bit (bit_in_chunk()) and the point's intensity.
  struct HitRecord {
    std::uint32_t bit;
    double intensity;
  };
  struct Chunk {
    VoxelKey key;  // chunk coordinate (voxel key >> 5)
    std::array<std::uint64_t, kBlocksPerChunk * kWordsPerBlock> free{};  // voxels crossed by a ray
    std::array<std::uint64_t, kBlocksPerChunk * kWordsPerBlock> hit{};   // voxels holding an endpoint
    std::vector<HitRecord> hits;  // every endpoint, in no order; several may share a voxel
  };

  /// Casts every ray of one scan into the scratch (cleared first). Inputs must have passed
  /// check_scan_input(). Throws std::out_of_range for an endpoint whose key does not fit in int32
  /// (the map is untouched, since nothing is applied yet). Returns the number of skipped points.
  /// With \p threads > 1 the threads take blocks of rays from a shared counter, each casting into a
  /// scratch of its own, and the scratches are merged (OR of the free bits, max of the hit
  /// intensities): the observations are bit-identical to threads = 1. An out-of-range point
  /// throws the error of the lowest such index, as in one thread. With \p progress, reports
  /// ProgressStage::kCastingRays (points walked) from the calling thread; an exception of the
  /// callback ends the collection (the map is untouched, as above). With \p stats, also gathers
  /// the scan's hit statistics (RayStatistics).
  /// \p rays chooses the voxels a ray marks free (RayModel). With \p phases, adds the time of the
  /// ray walk to phases->casting_rays and of the merge (and the statistics' ray ends) to
  /// phases->merging.
  std::size_t collect(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                      const Eigen::VectorXd& intensities, double max_range, double resolution, RayModel rays,
                      int threads = 1, const ProgressCallback* progress = nullptr,
                      const RayStatistics* stats = nullptr, ScanPhaseTimes* phases = nullptr);

  /// Calls fn(block_key, cells) for every grid block (8^3) that holds an observation, free or
  /// hit, with \p cells (a CellMask) holding each cell of the block (see index_in_block()) that
  /// holds one, in (z, y, x) order of chunk keys: an order that depends on the scan only, never on
  /// which thread cast which ray, so backends that allocate blocks and cells in this order stay
  /// identical for any thread count.
  template <class Fn>
  void for_each_block(Fn&& fn) const {
    for (const std::size_t ci : chunk_order()) {
      for (int b = 0; b < kBlocksPerChunk; ++b) {
        const CellMask cells = block_cells(ci, b);
        if (cells.any()) fn(block_key(ci, b), cells);
      }
    }
  }
  /// The chunks in (z, y, x) order of their keys, the order of for_each_block().
  [[nodiscard]] std::vector<std::size_t> chunk_order() const {
    std::vector<std::size_t> order(chunks_.size());
    for (std::size_t i = 0; i < order.size(); ++i) order[i] = i;
    std::sort(order.begin(), order.end(), [this](std::size_t a, std::size_t b) {
      const VoxelKey& ka = chunks_[a].key;
      const VoxelKey& kb = chunks_[b].key;
      return std::tie(ka.z, ka.y, ka.x) < std::tie(kb.z, kb.y, kb.x);
    });
    return order;
  }
  /// Block \p b (0 .. kBlocksPerChunk - 1) of chunk \p ci: its key, and the cells that hold an
  /// observation (free or hit).
  [[nodiscard]] VoxelKey block_key(std::size_t ci, int b) const noexcept { return block_key_of(chunks_[ci], b); }
  [[nodiscard]] CellMask block_cells(std::size_t ci, int b) const noexcept {
    const Chunk& c = chunks_[ci];
    CellMask cells;
    for (int w = 0; w < kWordsPerBlock; ++w) {
      const std::size_t word = static_cast<std::size_t>(b * kWordsPerBlock + w);
      cells |= cells_of_mask_word(c.free[word] | c.hit[word], w);
    }
    return cells;
  }

  /// Buffers of allocate_scan() (scan_apply.h), kept with the scratch so that they are reused from
  /// scan to scan and freed with it: each chunk's block cell masks, and the cell growths of a pass.
  struct AllocationWork {
    std::vector<CellMask> masks;  // kBlocksPerChunk per chunk, in chunk order
    std::vector<BlockGrid::CellGrowth> growths;  // tag: the block's index in masks
  };
  [[nodiscard]] AllocationWork& allocation_work() const noexcept { return work_; }

  /// The free-voxel part of for_each_observation() restricted to chunks [begin, end), for
  /// backends that apply disjoint chunk ranges on several threads.
  template <class FreeFn>
  void for_each_free(std::size_t begin, std::size_t end, FreeFn&& free_fn) const {
    for (std::size_t ci = begin; ci < end; ++ci) {
      const Chunk& c = chunks_[ci];
      for (int b = 0; b < kBlocksPerChunk; ++b) {
        const VoxelKey block_key = block_key_of(c, b);
        for (int w = 0; w < kWordsPerBlock; ++w) {
          const std::size_t word = static_cast<std::size_t>(b * kWordsPerBlock + w);
          std::uint64_t bits = c.free[word] & ~c.hit[word];
          while (bits != 0) {
            const int bit = __builtin_ctzll(bits);
            bits &= bits - 1;
            free_fn(block_key, w * 64 + bit);
          }
        }
      }
    }
  }

  /// Calls fn(block_key) for every grid block of chunk \p ci that holds an observation, free or hit.
  template <class Fn>
  void for_each_block_in(std::size_t ci, Fn&& fn) const {
    const Chunk& c = chunks_[ci];
    for (int b = 0; b < kBlocksPerChunk; ++b) {
      std::uint64_t any = 0;
      for (int w = 0; w < kWordsPerBlock; ++w) {
        const std::size_t word = static_cast<std::size_t>(b * kWordsPerBlock + w);
        any |= c.free[word] | c.hit[word];
      }
      if (any != 0) fn(block_key_of(c, b));
    }
  }

  /// Every observation of chunks [begin, end), grid block by grid block: for each block, \p free_fn
  /// (block_key, index_in_block) for every free voxel that holds no hit, then \p hit_fn(block_key,
  /// index_in_block, intensity) for every hit voxel with its largest intensity. A chunk's blocks
  /// belong to no other chunk, so threads may apply disjoint chunk ranges.
  template <class FreeFn, class HitFn>
  void for_each_observation_in(std::size_t begin, std::size_t end, FreeFn&& free_fn, HitFn&& hit_fn) const {
    std::vector<double> best;  // the chunk's hit voxels' intensities, in bit order
    for (std::size_t ci = begin; ci < end; ++ci) {
      const Chunk& c = chunks_[ci];
      largest_intensities(c, best);
      std::size_t next_hit = 0;
      for (int b = 0; b < kBlocksPerChunk; ++b) {
        const VoxelKey block_key = block_key_of(c, b);
        for (int w = 0; w < kWordsPerBlock; ++w) {
          const std::size_t word = static_cast<std::size_t>(b * kWordsPerBlock + w);
          for (std::uint64_t bits = c.free[word] & ~c.hit[word]; bits != 0; bits &= bits - 1)
            free_fn(block_key, w * 64 + __builtin_ctzll(bits));
        }
        for (int w = 0; w < kWordsPerBlock; ++w) {
          for (std::uint64_t bits = c.hit[static_cast<std::size_t>(b * kWordsPerBlock + w)]; bits != 0; bits &= bits - 1) {
            const int index = w * 64 + __builtin_ctzll(bits);
            hit_fn(block_key, index, best[next_hit++]);
          }
        }
      }
    }
  }

  /// Empties the scratch (keeping its buffers), to be filled by add_free_cells() and add_hit().
  void reset() { clear(); }
  /// Marks free the cells of grid block \p block_key whose bits are set in \p cells (bit i of
  /// cells[i / 64]: voxel_of(block_key, i), as for_each_free() numbers them). With add_hit(), this
  /// rebuilds elsewhere a scratch that for_each_free() and for_each_hit() described, for the
  /// distributed mapper: the rebuilt scratch gives the same observations.
  void add_free_cells(const VoxelKey& block_key, const std::uint64_t (&cells)[kWordsPerBlock]) {
    constexpr int m = kBlocksPerChunkEdge - 1;
    constexpr int shift = kChunkShift - kBlockShift;
    const VoxelKey ck{block_key.x >> shift, block_key.y >> shift, block_key.z >> shift};
    if (last_ < 0 || chunks_[static_cast<std::size_t>(last_)].key != ck) last_ = static_cast<std::int64_t>(chunk(ck));
    const int b = (block_key.x & m) | ((block_key.y & m) << 2) | ((block_key.z & m) << 4);
    for (int w = 0; w < kWordsPerBlock; ++w)
      chunks_[static_cast<std::size_t>(last_)].free[static_cast<std::size_t>(b * kWordsPerBlock + w)] |= cells[w];
  }
  /// A hit in voxel \p k (the largest intensity of several is kept).
  void add_hit(const VoxelKey& k, double intensity);

  [[nodiscard]] std::size_t num_chunks() const noexcept { return chunks_.size(); }
  /// The hit statistics of the last collect() that was asked for them (RayStatistics), else null.
  [[nodiscard]] const ScanHits* statistics() const noexcept { return has_statistics_ ? &ray_hits_ : nullptr; }

  /// Calls free_fn(block_key, index_in_block) once per free voxel that holds no hit, grouped by
  /// grid block (8^3) so consecutive calls share a block, then hit_fn(key, intensity) once per
  /// hit voxel with its largest intensity.
  template <class FreeFn, class HitFn>
  void for_each_observation(FreeFn&& free_fn, HitFn&& hit_fn) const {
    for_each_free(0, chunks_.size(), free_fn);
    for_each_hit(hit_fn);
  }

  /// The hit part of for_each_observation(): hit_fn(key, intensity) once per hit voxel, with its
  /// largest intensity, chunk by chunk.
  template <class HitFn>
  void for_each_hit(HitFn&& hit_fn) const {
    std::vector<double> best;
    for (const Chunk& c : chunks_) {
      largest_intensities(c, best);
      std::size_t next_hit = 0;
      for (std::size_t w = 0; w < c.hit.size(); ++w)
        for (std::uint64_t bits = c.hit[w]; bits != 0; bits &= bits - 1)
          hit_fn(voxel_in_chunk(c, static_cast<unsigned>(w * 64) + static_cast<unsigned>(__builtin_ctzll(bits))),
                 best[next_hit++]);
    }
  }

  /// Bytes held by the scratch buffers (kept between scans to avoid reallocation).
  [[nodiscard]] std::size_t bytes() const noexcept;
  /// Releases the buffers.
  void release();

 private:
  [[nodiscard]] static VoxelKey block_key_of(const Chunk& c, int b) noexcept {
    return {c.key.x * kBlocksPerChunkEdge + (b & 3), c.key.y * kBlocksPerChunkEdge + ((b >> 2) & 3),
            c.key.z * kBlocksPerChunkEdge + (b >> 4)};
  }
  void clear();
  // Casts rays [begin, end), counting a visit in ray_hits_ for every voxel a ray crosses when
  // \p visits. An out-of-range point throws, or with \p first_bad is recorded there (the lowest
  // index) and skipped.
  std::size_t collect_range(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                            const Eigen::VectorXd& intensities, double max_range, double resolution,
                            RayModel rays, Eigen::Index begin, Eigen::Index end, Eigen::Index* first_bad,
                            bool visits);
  // Takes in the first \p count helpers' rays: new chunks added on this thread, then on up to
  // \p threads threads (each chunk on one) their bits ORed and their hit lists appended.
  void merge_helpers(std::size_t count, std::size_t threads);
  // Fills \p best with the largest intensity of each hit voxel of \p c, in bit order: the k-th
  // set bit of c.hit gets best[k]. A record's slot is the count of hit bits below its own.
  static void largest_intensities(const Chunk& c, std::vector<double>& best);
  // The key of the voxel of bit \p bit of chunk \p c (the inverse of bit_in_chunk()).
  [[nodiscard]] static VoxelKey voxel_in_chunk(const Chunk& c, unsigned bit) noexcept {
    return voxel_of(block_key_of(c, static_cast<int>(bit / kBlockVoxels)), static_cast<int>(bit % kBlockVoxels));
  }
  // collect() without clearing first, counting visits as collect_range() does.
  std::size_t cast_rays(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                        const Eigen::VectorXd& intensities, double max_range, double resolution, RayModel rays,
                        int threads, const ProgressCallback* progress, bool visits, ScanPhaseTimes* phases);
  void add_ray_ends(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                    double max_range, double resolution, const RayStatistics& stats);

  // Bit of voxel k inside its chunk: block-major, then index_in_block().
  [[nodiscard]] static constexpr std::size_t bit_in_chunk(const VoxelKey& k) noexcept {
    constexpr int m = kBlocksPerChunkEdge - 1;
    const int b = ((k.x >> kBlockShift) & m) | (((k.y >> kBlockShift) & m) << 2) | (((k.z >> kBlockShift) & m) << 4);
    return static_cast<std::size_t>(b * kBlockVoxels + index_in_block(k));
  }
  // bit_in_chunk() is the OR of one part per axis, each a function of the voxel's coordinate
  // inside its chunk (0..31; the part of coordinate 0 is 0): mark_ray() keeps the three parts
  // and, on a step, looks up the part of the axis that moved.
  struct AxisBits {
    std::uint16_t x[1 << kChunkShift], y[1 << kChunkShift], z[1 << kChunkShift];
  };
  [[nodiscard]] static constexpr AxisBits axis_bits() noexcept {
    AxisBits b{};
    for (std::int32_t l = 0; l < (1 << kChunkShift); ++l) {
      b.x[l] = static_cast<std::uint16_t>(bit_in_chunk({l, 0, 0}));
      b.y[l] = static_cast<std::uint16_t>(bit_in_chunk({0, l, 0}));
      b.z[l] = static_cast<std::uint16_t>(bit_in_chunk({0, 0, l}));
    }
    return b;
  }
  std::size_t chunk(const VoxelKey& chunk_key);
  // Marks free every voxel cast_ray() visits from \p origin to \p end, calling visit(key) for each.
  template <class Visit>
  void mark_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& end, double resolution, Visit&& visit);
  // The same for cast_line() (RayModel::kFast).
  template <class Visit>
  void mark_line(const Eigen::Vector3d& origin, const Eigen::Vector3d& end, double resolution, Visit&& visit);

  std::vector<Chunk> chunks_;
  FlatKeyMap chunk_index_;
  std::int64_t last_ = -1;
  std::vector<ScanScratch> helpers_;  // per-thread scratches, kept between scans
  std::vector<std::uint32_t> merge_slots_;  // merge_helpers(): this scratch's chunk of each helper chunk
  ScanHits ray_hits_;                 // RayStatistics (a helper's: its visits only)
  bool has_statistics_ = false;
  mutable AllocationWork work_;  // a workspace, not part of the scan's observations
};

}  // namespace iwlomap::detail
