// SPDX-License-Identifier: BSD-3-Clause
#include "voxel_cloud.h"

#include "args.h"

#include <iwlomap/iwlo.h>
#include <iwlomap/probability_updater.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace iwlomap::tool {

/// The voxel edge of a grid of voxel centres: the smallest gap between distinct centre coordinates
/// along any axis (centres of neighbouring voxels differ by exactly one edge). The tolerance
/// absorbs the float rounding of PCD files.
std::optional<double> infer_resolution(const Eigen::MatrixXd& v) {
  std::optional<double> best;
  for (int axis = 0; axis < 3; ++axis) {
    std::vector<double> c;
    c.reserve(static_cast<std::size_t>(v.rows()));
    for (Eigen::Index i = 0; i < v.rows(); ++i)
      if (std::isfinite(v(i, axis))) c.push_back(v(i, axis));
    std::sort(c.begin(), c.end());
    for (std::size_t i = 1; i < c.size(); ++i) {
      const double gap = c[i] - c[i - 1];
      const double tol = 1e-5 * std::max({1.0, std::abs(c[i]), std::abs(c[i - 1])});
      if (gap > tol && (!best || gap < *best)) best = gap;
    }
  }
  // Round away the float noise (to 4 significant digits): 0.0999999 -> 0.1.
  if (best) {
    const double scale = std::pow(10.0, 3 - std::floor(std::log10(*best)));
    best = std::round(*best * scale) / scale;
  }
  return best;
}

// True when (nearly) every coordinate lies at a voxel centre, (k + 0.5) * resolution, on every
// axis: the cloud is a voxel cloud as 'iwlomap map' writes it, not a raw scan whose smallest
// coordinate gap says nothing about a voxel size.
bool on_voxel_lattice(const Eigen::MatrixXd& v, double resolution) {
  if (!(resolution >= 1e-3)) return false;
  std::size_t on = 0, all = 0;
  for (Eigen::Index i = 0; i < v.rows(); ++i)
    for (int axis = 0; axis < 3; ++axis) {
      if (!std::isfinite(v(i, axis))) continue;
      const double k = v(i, axis) / resolution - 0.5;
      ++all;
      if (std::abs(k - std::round(k)) < 1e-3) ++on;
    }
  return all > 0 && static_cast<double>(on) >= 0.99 * static_cast<double>(all);
}

std::unique_ptr<IMapperBackend> map_from_voxel_cloud(const LoadedCloud& cloud, const std::string& path,
                                                     std::optional<double> resolution) {
  const auto& c = *cloud.cloud;
  Eigen::MatrixXd v(static_cast<Eigen::Index>(c.size()), 3);
  Eigen::VectorXd log_odds(static_cast<Eigen::Index>(c.size()));
  for (std::size_t i = 0; i < c.size(); ++i) {
    const auto r = static_cast<Eigen::Index>(i);
    v.row(r) << c[i].x, c[i].y, c[i].z;
    const double p = c[i].intensity > 0.0f && c[i].intensity < 1.0f ? c[i].intensity : 0.9;
    log_odds[r] = iwlo::log_odds(p);
  }
  if (cloud.map_info) {
    if (resolution && *resolution != cloud.map_info->resolution) {
      throw UsageError("'" + path + "' records a resolution of " + shortest(cloud.map_info->resolution) +
                       " m; --resolution " + shortest(*resolution) + " differs");
    }
    resolution = cloud.map_info->resolution;
  }
  if (!resolution) {
    resolution = infer_resolution(v);
    if (!resolution || !on_voxel_lattice(v, *resolution))
      throw UsageError("'" + path + "' is not a cloud of voxel centres of one size: give --resolution");
  }
  auto map = std::make_unique<ProbabilityUpdater>(*resolution);
  map->set_log_odds(v, log_odds);
  return map;
}

}  // namespace iwlomap::tool
