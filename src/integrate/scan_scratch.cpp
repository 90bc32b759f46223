// SPDX-License-Identifier: BSD-3-Clause
#include "integrate/scan_scratch.h"

#include "integrate/batch_input.h"
#include "integrate/parallel_pieces.h"
#include "integrate/phase_clock.h"
#include "integrate/progress_report.h"
#include "storage/free_memory.h"
#include "storage/memory_limit.h"
#include "integrate/scan_ray.h"
#include "iwlomap/ray_caster.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <atomic>

namespace iwlomap::detail {

std::size_t ScanScratch::chunk(const VoxelKey& chunk_key) {
  const auto next = static_cast<std::uint32_t>(chunks_.size());
  // Growing the chunk array is where a scan's scratch takes memory (8 KiB per chunk): checked
  // against the map memory limit before the index or the array changes. While the array doubles,
  // the old one (n chunks) and the new one (2n) are both held: 3n, not the 2n that remains.
  if (chunks_.size() == chunks_.capacity() && chunk_index_.find(chunk_key) == FlatKeyMap::kEmpty)
    check_map_memory(3 * chunks_.size() * sizeof(Chunk), "the scan's ray scratch");
  const std::uint32_t i = chunk_index_.insert(chunk_key, next);
  if (i == next) {
    chunks_.emplace_back();
    chunks_.back().key = chunk_key;
  }
  return i;
}

void ScanScratch::add_hit(const VoxelKey& k, double intensity) {
  Chunk& c = chunks_[chunk({k.x >> kChunkShift, k.y >> kChunkShift, k.z >> kChunkShift})];
  const auto bit = static_cast<std::uint32_t>(bit_in_chunk(k));
  c.hit[bit >> 6] |= std::uint64_t{1} << (bit & 63);
  c.hits.push_back({bit, intensity});
}

void ScanScratch::largest_intensities(const Chunk& c, std::vector<double>& best) {
  // Hit bits below each word, then each record's slot by one more popcount.
  std::array<std::uint32_t, kBlocksPerChunk * kWordsPerBlock> below;
  std::uint32_t n = 0;
  for (std::size_t w = 0; w < c.hit.size(); ++w) {
    below[w] = n;
    n += static_cast<std::uint32_t>(popcount64(c.hit[w]));
  }
  best.assign(n, -std::numeric_limits<double>::infinity());
  for (const HitRecord& r : c.hits) {
    const std::size_t w = r.bit >> 6;
    const std::uint64_t lower = c.hit[w] & ((std::uint64_t{1} << (r.bit & 63)) - 1);
    double& b = best[below[w] + static_cast<std::uint32_t>(popcount64(lower))];
    if (r.intensity > b) b = r.intensity;
  }
}

void ScanScratch::clear() {
  chunks_.clear();
  chunk_index_.clear_keep_capacity();
  last_ = -1;
  has_statistics_ = false;
}

// cast_ray()'s walk (the same set-up and the same comparisons, so the same voxels), with the
// bookkeeping of a voxel's bit done incrementally: a step moves one axis's coordinate inside the
// chunk and looks up that axis's part of the bit index; only a step out of the chunk (about one in
// 30) looks the next chunk up. A per-voxel mark that recomputed the chunk key and the bit index
// from the key cost about twice as much per step. \p visit gets each voxel's key (the walk of a
// scan without hit statistics passes a lambda that does nothing, and compiles to the bare walk).
template <class Visit>
void ScanScratch::mark_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& end, double resolution,
                           Visit&& visit) {
  static constexpr AxisBits kAxisBits = axis_bits();
  const RayWalk w = start_ray_walk(origin, end, resolution);
  if (w.total == 0) return;
  constexpr double kInf = std::numeric_limits<double>::infinity();
  constexpr int kMask = (1 << kChunkShift) - 1;
  VoxelKey ck{w.key.x >> kChunkShift, w.key.y >> kChunkShift, w.key.z >> kChunkShift};
  std::uint64_t* words = chunks_[chunk(ck)].free.data();
  int lx = w.key.x & kMask, ly = w.key.y & kMask, lz = w.key.z & kMask;
  unsigned bx = kAxisBits.x[lx], by = kAxisBits.y[ly], bz = kAxisBits.z[lz];
  std::int64_t nx = w.left[0], ny = w.left[1], nz = w.left[2];
  double tx = w.t[0], ty = w.t[1], tz = w.t[2];
  const int sx = w.step[0], sy = w.step[1], sz = w.step[2];
  for (std::int64_t s = 0;;) {
    const unsigned bit = bx | by | bz;
    words[bit >> 6] |= std::uint64_t{1} << (bit & 63);
    visit(VoxelKey{ck.x * (1 << kChunkShift) + lx, ck.y * (1 << kChunkShift) + ly, ck.z * (1 << kChunkShift) + lz});
    if (++s == w.total) break;
    if (tx <= ty && tx <= tz) {
      tx = --nx == 0 ? kInf : tx + w.dt[0];
      lx += sx;
      if (static_cast<unsigned>(lx) > static_cast<unsigned>(kMask)) {
        ck.x += sx;
        lx &= kMask;
        words = chunks_[chunk(ck)].free.data();
      }
      bx = kAxisBits.x[lx];
    } else if (ty <= tz) {
      ty = --ny == 0 ? kInf : ty + w.dt[1];
      ly += sy;
      if (static_cast<unsigned>(ly) > static_cast<unsigned>(kMask)) {
        ck.y += sy;
        ly &= kMask;
        words = chunks_[chunk(ck)].free.data();
      }
      by = kAxisBits.y[ly];
    } else {
      tz = --nz == 0 ? kInf : tz + w.dt[2];
      lz += sz;
      if (static_cast<unsigned>(lz) > static_cast<unsigned>(kMask)) {
        ck.z += sz;
        lz &= kMask;
        words = chunks_[chunk(ck)].free.data();
      }
      bz = kAxisBits.z[lz];
    }
  }
}

// cast_line()'s walk (the same set-up, and line_step()'s arithmetic with the errors in registers,
// so the same voxels) with mark_ray()'s bookkeeping. A step moves up to three axes at once; each
// axis's move is computed without a branch (err > 0 as 0 or 1), because on a line of a dominant
// axis the other axes move at irregular steps and a branch per axis mispredicts often (Ouster
// frame again, fast rays: 121-131 ms with branches, 100 ms without; calling line_step() and
// unpacking its bits: 120 ms). Only a step out of the chunk branches.
template <class Visit>
void ScanScratch::mark_line(const Eigen::Vector3d& origin, const Eigen::Vector3d& end, double resolution,
                            Visit&& visit) {
  static constexpr AxisBits kAxisBits = axis_bits();
  const LineWalk w = start_line_walk(origin, end, resolution);
  if (w.total == 0) return;
  constexpr int kMask = (1 << kChunkShift) - 1;
  VoxelKey ck{w.key.x >> kChunkShift, w.key.y >> kChunkShift, w.key.z >> kChunkShift};
  std::uint64_t* words = chunks_[chunk(ck)].free.data();
  int lx = w.key.x & kMask, ly = w.key.y & kMask, lz = w.key.z & kMask;
  std::int64_t ex = w.err[0], ey = w.err[1], ez = w.err[2];
  for (std::int64_t s = 0;;) {
    const unsigned bit = kAxisBits.x[lx] | kAxisBits.y[ly] | kAxisBits.z[lz];
    words[bit >> 6] |= std::uint64_t{1} << (bit & 63);
    visit(VoxelKey{ck.x * (1 << kChunkShift) + lx, ck.y * (1 << kChunkShift) + ly, ck.z * (1 << kChunkShift) + lz});
    if (++s == w.total) break;
    // line_step(), one axis at a time: move = err > 0; err += grow - move * fall.
    const int mx = ex > 0, my = ey > 0, mz = ez > 0;
    ex += w.grow[0] - mx * w.fall;
    ey += w.grow[1] - my * w.fall;
    ez += w.grow[2] - mz * w.fall;
    lx += mx * w.step[0];
    ly += my * w.step[1];
    lz += mz * w.step[2];
    if (static_cast<unsigned>(lx | ly | lz) > static_cast<unsigned>(kMask)) {  // out of the chunk
      ck.x += (lx > kMask) - (lx < 0);  // -1 or +1 where the axis left it, else 0
      ck.y += (ly > kMask) - (ly < 0);
      ck.z += (lz > kMask) - (lz < 0);
      lx &= kMask;
      ly &= kMask;
      lz &= kMask;
      words = chunks_[chunk(ck)].free.data();
    }
  }
}

std::size_t ScanScratch::collect_range(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                       const Eigen::VectorXd& intensities, double max_range, double resolution,
                                       RayModel rays, Eigen::Index begin, Eigen::Index end,
                                       Eigen::Index* first_bad, bool visits) {
  const double longest = kMaxRayVoxels * resolution;
  std::size_t skipped = 0;
  for (Eigen::Index i = begin; i < end; ++i) {
    const Eigen::Vector3d p = points.row(i).transpose();
    const double intensity = intensities[i];
    if (!p.allFinite() || !std::isfinite(intensity)) {
      ++skipped;
      continue;
    }
    const ScanRayEnd ray = scan_ray_end(origin, p, max_range, longest);
    if (!ray.cast) {
      ++skipped;
      continue;
    }
    if (!is_representable(ray.end, resolution)) {
      if (first_bad == nullptr) throw_out_of_range(i, p, resolution);
      *first_bad = std::min(*first_bad, i);
      continue;
    }
    const auto no_visit = [](const VoxelKey&) {};
    const auto count_visit = [this](const VoxelKey& k) { ray_hits_.add_visit(k); };
    if (rays == RayModel::kFast) {
      if (!visits)
        mark_line(origin, ray.end, resolution, no_visit);
      else
        mark_line(origin, ray.end, resolution, count_visit);
    } else if (!visits) {
      mark_ray(origin, ray.end, resolution, no_visit);
    } else {
      mark_ray(origin, ray.end, resolution, count_visit);
    }
    if (!ray.clipped) add_hit(world_to_key(p, resolution), intensity);
  }
  return skipped;
}

void ScanScratch::merge_helpers(std::size_t count, std::size_t threads) {
  for (std::size_t k = 0; k < count; ++k) {
    const std::vector<Chunk>& from = helpers_[k].chunks_;
    merge_slots_.resize(from.size());
    for (std::size_t i = 0; i < from.size(); ++i) merge_slots_[i] = static_cast<std::uint32_t>(chunk(from[i].key));
    // One helper's chunks are distinct, so the pieces write distinct chunks of this scratch.
    parallel_pieces(from.size(), 16, threads, [&](std::size_t, std::size_t begin, std::size_t end) {
      for (std::size_t i = begin; i < end; ++i) {
        const Chunk& c = from[i];
        Chunk& mine = chunks_[merge_slots_[i]];
        for (std::size_t w = 0; w < c.free.size(); ++w) {
          mine.free[w] |= c.free[w];
          mine.hit[w] |= c.hit[w];
        }
        mine.hits.insert(mine.hits.end(), c.hits.begin(), c.hits.end());
      }
    });
  }
}

std::size_t ScanScratch::collect(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                 const Eigen::VectorXd& intensities, double max_range, double resolution,
                                 RayModel rays, int threads, const ProgressCallback* progress,
                                 const RayStatistics* stats, ScanPhaseTimes* phases) {
  clear();
  if (stats != nullptr) ray_hits_.reset(resolution);
  const std::size_t skipped = cast_rays(origin, points, intensities, max_range, resolution, rays, threads, progress,
                                        stats != nullptr, phases);
  if (stats != nullptr) {
    PhaseClock merging(phases ? &phases->merging : nullptr);
    add_ray_ends(origin, points, intensities, max_range, resolution, *stats);
    has_statistics_ = true;
  }
  return skipped;
}

// The ends of the rays that collect() cast, in ray order: a hit when the intensity is above the
// threshold, a visit otherwise; a ray clipped at max_range or kMaxRayVoxels ends in no voxel.
void ScanScratch::add_ray_ends(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                               const Eigen::VectorXd& intensities, double max_range, double resolution,
                               const RayStatistics& stats) {
  const double longest = kMaxRayVoxels * resolution;
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    const Eigen::Vector3d p = points.row(i).transpose();
    const double intensity = intensities[i];
    if (!p.allFinite() || !std::isfinite(intensity)) continue;
    const ScanRayEnd ray = scan_ray_end(origin, p, max_range, longest);
    if (!ray.cast || ray.clipped) continue;
    const VoxelKey k = world_to_key(p, resolution);
    if (intensity > stats.intensity_threshold)
      ray_hits_.add_hit(k, p);
    else
      ray_hits_.add_visit(k);
  }
}

std::size_t ScanScratch::cast_rays(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                   const Eigen::VectorXd& intensities, double max_range, double resolution,
                                   RayModel rays, int threads, const ProgressCallback* progress, bool visits,
                                   ScanPhaseTimes* phases) {
  PhaseClock casting(phases ? &phases->casting_rays : nullptr);
  const Eigen::Index n = points.rows();
  StageProgress report(progress, ProgressStage::kCastingRays, static_cast<std::size_t>(n));
  // Below a few thousand rays a thread costs more than it saves.
  const Eigen::Index useful = std::max<Eigen::Index>(1, n / 2048);
  const int t = static_cast<int>(std::min<Eigen::Index>(std::max(threads, 1), useful));
  // Rays differ in length by an order of magnitude (a scan's lower rings hit the ground near the
  // sensor), so threads take blocks of rays from a shared counter rather than fixed ranges. Which
  // thread casts which ray does not matter: OR and max do not depend on the order. On several
  // threads an out-of-range point is recorded, not thrown, so the error reported is always the one
  // of the lowest index, as with one thread (which throws at once). One thread casts in blocks
  // between reports (4,096 rays take about a millisecond), or all at once without a callback.
  constexpr Eigen::Index kGrain = 1024;
  constexpr Eigen::Index kReportGrain = 4096;
  const Eigen::Index grain = t > 1 ? kGrain : report.active() ? kReportGrain : std::max<Eigen::Index>(n, 1);
  const auto helpers = static_cast<std::size_t>(t - 1);
  if (t > 1) helpers_.resize(helpers);  // kept between scans, like the rest of the scratch
  std::vector<std::size_t> skipped(static_cast<std::size_t>(t), 0);
  std::vector<Eigen::Index> first_bad(static_cast<std::size_t>(t), n);
  std::vector<char> started(static_cast<std::size_t>(t), 0);  // a helper is cleared by its thread
  std::atomic<Eigen::Index> finished{0};  // rays cast, for the reports of the calling thread
  // A thread that cannot get memory (the map memory limit, std::bad_alloc) stops the others and
  // its exception is rethrown here once all have joined (parallel_pieces()).
  parallel_pieces(static_cast<std::size_t>(n), static_cast<std::size_t>(grain), static_cast<std::size_t>(t),
                  [&](std::size_t k, std::size_t begin, std::size_t end) {
                    ScanScratch& into = k == 0 ? *this : helpers_[k - 1];
                    if (k > 0 && !started[k]) {
                      into.clear();
                      if (visits) into.ray_hits_.reset(resolution);  // each counts its own visits
                      started[k] = 1;
                    }
                    const auto b = static_cast<Eigen::Index>(begin), e = static_cast<Eigen::Index>(end);
                    skipped[k] += into.collect_range(origin, points, intensities, max_range, resolution, rays, b, e,
                                                     t > 1 ? &first_bad[k] : nullptr, visits);
                    const Eigen::Index cast = finished.fetch_add(e - b, std::memory_order_relaxed) + (e - b);
                    if (k == 0) report.report(static_cast<std::size_t>(cast));  // the calling thread only
                  });
  for (std::size_t k = 1; k < started.size(); ++k) {
    if (started[k]) continue;
    helpers_[k - 1].clear();  // a thread that got no rays: its helper holds the last scan's
    if (visits) helpers_[k - 1].ray_hits_.reset(resolution);
  }
  casting.stop();
  PhaseClock merging(phases != nullptr && t > 1 ? &phases->merging : nullptr);  // one thread: nothing to merge
  const Eigen::Index bad = *std::min_element(first_bad.begin(), first_bad.end());
  if (bad < n) throw_out_of_range(bad, points.row(bad).transpose(), resolution);
  std::size_t total = 0;
  for (const std::size_t k : skipped) total += k;
  merge_helpers(helpers, static_cast<std::size_t>(t));
  if (visits)  // counts: the same sums in any order
    for (std::size_t k = 0; k < helpers; ++k) ray_hits_.add_visits(helpers_[k].ray_hits_);
  report.finish();
  return total;
}

std::size_t ScanScratch::bytes() const noexcept {
  std::size_t b = chunks_.capacity() * sizeof(Chunk) + chunk_index_.bytes() + helpers_.capacity() * sizeof(ScanScratch);
  for (const Chunk& c : chunks_) b += c.hits.capacity() * sizeof(HitRecord);
  for (const ScanScratch& h : helpers_) b += h.bytes();
  b += work_.masks.capacity() * sizeof(CellMask) + work_.growths.capacity() * sizeof(work_.growths[0]) +
       merge_slots_.capacity() * sizeof(std::uint32_t);
  return b + ray_hits_.bytes();
}

void ScanScratch::release() {
  free_memory(chunks_);
  chunk_index_.reset();
  last_ = -1;
  free_memory(helpers_);
  ray_hits_ = ScanHits();
  has_statistics_ = false;
  free_memory(work_.masks);
  free_memory(work_.growths);
  free_memory(merge_slots_);
}

}  // namespace iwlomap::detail
