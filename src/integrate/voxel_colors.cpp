// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/voxel_colors.h"

#include "integrate/scan_ray.h"
#include "model/checks.h"
#include "storage/flat_key_map.h"

#include "iwlomap/ray_caster.h"
#include "iwlomap/voxel_key.h"

#include <cmath>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap {

struct VoxelColorMeans::Impl {
  struct Sum {
    std::uint64_t r = 0, g = 0, b = 0, n = 0;
  };
  detail::FlatKeyMap index;  // voxel -> position in sums
  std::vector<Sum> sums;

  void add(const VoxelKey& key, Rgb8 c) {
    if (sums.size() >= detail::FlatKeyMap::kEmpty)
      throw std::length_error("VoxelColorMeans: more than 2^32 - 2 coloured voxels");
    const auto at = index.insert(key, static_cast<std::uint32_t>(sums.size()));
    if (at == sums.size()) sums.emplace_back();
    Sum& s = sums[at];
    s.r += c.r;
    s.g += c.g;
    s.b += c.b;
    ++s.n;
  }

  [[nodiscard]] const Sum* find(const VoxelKey& key) const {
    const auto at = index.find(key);
    return at == detail::FlatKeyMap::kEmpty ? nullptr : &sums[at];
  }
};

namespace {

// Round half up of sum / n, n > 0; the quotient of byte values is at most 255.
std::uint8_t mean_channel(std::uint64_t sum, std::uint64_t n) { return static_cast<std::uint8_t>((2 * sum + n) / (2 * n)); }

void check_colors(const ColorMatrix& colors, Eigen::Index n) {
  if (colors.rows() != n)
    throw std::invalid_argument("VoxelColorMeans: " + std::to_string(colors.rows()) + " colours for " +
                                std::to_string(n) + " points; give one (r, g, b) row per point");
}

Rgb8 row_color(const ColorMatrix& colors, Eigen::Index i) { return {colors(i, 0), colors(i, 1), colors(i, 2)}; }

}  // namespace

VoxelColorMeans::VoxelColorMeans(double resolution) : resolution_(resolution), impl_(std::make_unique<Impl>()) {
  detail::check_resolution(resolution);
}

VoxelColorMeans::~VoxelColorMeans() = default;
VoxelColorMeans::VoxelColorMeans(VoxelColorMeans&&) noexcept = default;
VoxelColorMeans& VoxelColorMeans::operator=(VoxelColorMeans&&) noexcept = default;

bool VoxelColorMeans::add(const Eigen::Vector3d& point, Rgb8 color) {
  if (!point.allFinite()) return false;
  if (!is_representable(point, resolution_)) detail::throw_out_of_range(-2, point, resolution_);
  impl_->add(world_to_key(point, resolution_), color);
  return true;
}

void VoxelColorMeans::add_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                               const Eigen::VectorXd& intensities, const ColorMatrix& colors, const IwloParams& params,
                               double max_range) {
  detail::check_points_shape(points, intensities.size(), "intensities");
  check_colors(colors, points.rows());
  if (!origin.allFinite()) throw std::invalid_argument("VoxelColorMeans::add_scan: the origin is not finite");
  const double longest = kMaxRayVoxels * resolution_;
  // The hits first, then the sums: a point out of the key range throws before anything is added.
  std::vector<std::pair<VoxelKey, Eigen::Index>> hits;
  hits.reserve(static_cast<std::size_t>(points.rows()));
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    const Eigen::Vector3d p = points.row(i).transpose();
    if (!p.allFinite() || !std::isfinite(intensities[i]) || !(intensities[i] > params.intensity_threshold)) continue;
    const detail::ScanRayEnd ray = detail::scan_ray_end(origin, p, max_range, longest);
    if (!ray.cast || ray.clipped) continue;
    if (!is_representable(p, resolution_)) detail::throw_out_of_range(i, p, resolution_);
    hits.emplace_back(world_to_key(p, resolution_), i);
  }
  for (const auto& [key, i] : hits) impl_->add(key, row_color(colors, i));
}

void VoxelColorMeans::add_observations(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                       const std::vector<bool>& is_occupied, const ColorMatrix& colors,
                                       const IwloParams& params) {
  detail::check_points_shape(points, intensities.size(), "intensities");
  detail::check_points_shape(points, static_cast<Eigen::Index>(is_occupied.size()), "is_occupied");
  check_colors(colors, points.rows());
  std::vector<std::pair<VoxelKey, Eigen::Index>> hits;
  hits.reserve(static_cast<std::size_t>(points.rows()));
  for (Eigen::Index i = 0; i < points.rows(); ++i) {
    const Eigen::Vector3d p = points.row(i).transpose();
    if (!is_occupied[static_cast<std::size_t>(i)] || !p.allFinite() || !std::isfinite(intensities[i]) ||
        !(intensities[i] > params.intensity_threshold))
      continue;
    if (!is_representable(p, resolution_)) detail::throw_out_of_range(i, p, resolution_);
    hits.emplace_back(world_to_key(p, resolution_), i);
  }
  for (const auto& [key, i] : hits) impl_->add(key, row_color(colors, i));
}

std::optional<Rgb8> VoxelColorMeans::mean(const Eigen::Vector3d& point) const {
  if (!is_representable(point, resolution_)) return std::nullopt;
  const Impl::Sum* s = impl_->find(world_to_key(point, resolution_));
  if (s == nullptr) return std::nullopt;
  return Rgb8{mean_channel(s->r, s->n), mean_channel(s->g, s->n), mean_channel(s->b, s->n)};
}

std::uint64_t VoxelColorMeans::hits(const Eigen::Vector3d& point) const {
  if (!is_representable(point, resolution_)) return 0;
  const Impl::Sum* s = impl_->find(world_to_key(point, resolution_));
  return s == nullptr ? 0 : s->n;
}

ColorMatrix VoxelColorMeans::colors_at(const Eigen::MatrixXd& positions, Rgb8 missing) const {
  if (positions.cols() < 3 && positions.rows() > 0)
    throw std::invalid_argument("VoxelColorMeans::colors_at: " + std::to_string(positions.cols()) +
                                " columns, expected at least 3 (x, y, z)");
  ColorMatrix out(positions.rows(), 3);
  for (Eigen::Index i = 0; i < positions.rows(); ++i) {
    const Rgb8 c = mean(positions.row(i).head<3>().transpose()).value_or(missing);
    out(i, 0) = c.r;
    out(i, 1) = c.g;
    out(i, 2) = c.b;
  }
  return out;
}

std::size_t VoxelColorMeans::size() const noexcept { return impl_->sums.size(); }

std::size_t VoxelColorMeans::memory_bytes() const noexcept {
  return impl_->index.bytes() + impl_->sums.capacity() * sizeof(Impl::Sum);
}

void VoxelColorMeans::clear() {
  impl_->index.reset();
  impl_->sums.clear();
  impl_->sums.shrink_to_fit();
}

}  // namespace iwlomap
