// SPDX-License-Identifier: BSD-3-Clause
#include "detail/scan_scratch.h"

#include "detail/batch_input.h"
#include "iwlomap/ray_caster.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <thread>

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

void ScanScratch::clear() {
  chunks_.clear();
  chunk_index_.clear_keep_capacity();
  hits_.clear();
  hit_index_.clear_keep_capacity();
  last_ = -1;
}

std::size_t ScanScratch::collect_range(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                       const Eigen::VectorXd& intensities, double max_range, double resolution,
                                       Eigen::Index begin, Eigen::Index end) {
  const bool clip = max_range > 0.0;
  std::size_t skipped = 0;
  const auto mark = [this](const VoxelKey& k) { mark_free(k); };
  for (Eigen::Index i = begin; i < end; ++i) {
    const Eigen::Vector3d p = points.row(i).transpose();
    const double intensity = intensities[i];
    if (!p.allFinite() || !std::isfinite(intensity)) {
      ++skipped;
      continue;
    }
    const Eigen::Vector3d d = p - origin;
    const double range = d.norm();
    const bool beyond = clip && range > max_range;
    const Eigen::Vector3d end_point = beyond ? Eigen::Vector3d(origin + d * (max_range / range)) : p;
    if (!is_representable(end_point, resolution)) throw_out_of_range(i, p, resolution);
    cast_ray(origin, end_point, resolution, mark);
    if (!beyond) add_hit(world_to_key(p, resolution), intensity);
  }
  return skipped;
}

void ScanScratch::merge(const ScanScratch& other) {
  for (const Chunk& c : other.chunks_) {
    Chunk& mine = chunks_[chunk(c.key)];
    for (std::size_t w = 0; w < c.free.size(); ++w) {
      mine.free[w] |= c.free[w];
      mine.hit[w] |= c.hit[w];
    }
  }
  for (const Hit& h : other.hits_) add_hit(h.key, h.intensity);
}

std::size_t ScanScratch::collect(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                 const Eigen::VectorXd& intensities, double max_range, double resolution,
                                 int threads) {
  clear();
  const Eigen::Index n = points.rows();
  // Below a few thousand rays a thread costs more than it saves.
  const Eigen::Index useful = std::max<Eigen::Index>(1, n / 2048);
  const int t = static_cast<int>(std::min<Eigen::Index>(std::max(threads, 1), useful));
  if (t == 1) return collect_range(origin, points, intensities, max_range, resolution, 0, n);

  helpers_.resize(static_cast<std::size_t>(t));
  std::vector<std::size_t> skipped(static_cast<std::size_t>(t), 0);
  std::vector<std::exception_ptr> errors(static_cast<std::size_t>(t));
  std::vector<std::thread> workers;
  workers.reserve(static_cast<std::size_t>(t));
  for (int k = 0; k < t; ++k) {
    const Eigen::Index begin = n * k / t, end = n * (k + 1) / t;
    const auto idx = static_cast<std::size_t>(k);
    workers.emplace_back([&, begin, end, idx] {
      try {
        helpers_[idx].clear();
        skipped[idx] = helpers_[idx].collect_range(origin, points, intensities, max_range, resolution, begin, end);
      } catch (...) {
        errors[idx] = std::current_exception();
      }
    });
  }
  for (auto& w : workers) w.join();
  for (const auto& e : errors)
    if (e) std::rethrow_exception(e);
  std::size_t total = 0;
  for (int k = 0; k < t; ++k) {
    merge(helpers_[static_cast<std::size_t>(k)]);
    total += skipped[static_cast<std::size_t>(k)];
  }
  return total;
}

std::size_t ScanScratch::bytes() const noexcept {
  std::size_t b = chunks_.capacity() * sizeof(Chunk) + hits_.capacity() * sizeof(Hit) + chunk_index_.bytes() +
                  hit_index_.bytes() + helpers_.capacity() * sizeof(ScanScratch);
  for (const ScanScratch& h : helpers_) b += h.bytes();
  return b;
}

void ScanScratch::release() {
  chunks_ = {};
  hits_ = {};
  chunk_index_.reset();
  hit_index_.reset();
  last_ = -1;
  helpers_ = {};
}

}  // namespace iwlomap::detail
