// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// The two ray models of insert_scan(), in the keys of voxel_key.h: the exact Amanatides-Woo
/// traversal of a segment (cast_ray(), the default) and a 26-connected digital line between voxel
/// centres (cast_line(), RayModel::kFast).

#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <optional>
#include <string_view>
#include <cstdlib>
#include <limits>
#include <utility>
#include <vector>

namespace iwlomap {

/// The longest ray insert_scan() casts, in voxel edges: 131,072, i.e. 13.1 km at 0.1 m, 1.3 km
/// at 1 cm. A point farther from the origin (after max_range clipping) is skipped and counted.
inline constexpr double kMaxRayVoxels = 131072.0;

/// Which voxels a ray of insert_scan() marks free (IMapperBackend::set_ray_model()).
///
/// - kExact (the default): every voxel the segment from the origin to the point crosses, as
///   cast_ray() walks it: a face-connected path of |dx| + |dy| + |dz| voxels (dx, dy, dz: the key
///   differences between the two ends), the path of OctoMap's computeRayKeys.
/// - kFast: the 26-connected line of cast_line() between the centres of the two end voxels: one
///   voxel per step along the axis of largest key difference, max(|dx|, |dy|, |dz|) voxels, so a
///   diagonal ray takes up to three times fewer steps. What it misses: a voxel that the segment
///   only crosses near an edge or a corner of it (where the exact walk steps along one axis
///   and then another, the line steps along both at once), so each ray gives fewer free
///   observations, and thin free space seen only at grazing angles is cleared more slowly. It also
///   ignores where inside its voxel the origin and the point lie. Hits are the same in both models.
enum class RayModel : std::uint8_t {
  kExact,
  kFast,
};

/// The model's name as the tool and the configuration files spell it: "exact" or "fast".
[[nodiscard]] constexpr const char* ray_model_name(RayModel model) noexcept {
  return model == RayModel::kFast ? "fast" : "exact";
}

/// The model named \p name ("exact", "fast"), or nothing.
[[nodiscard]] inline std::optional<RayModel> parse_ray_model(std::string_view name) noexcept {
  if (name == "exact") return RayModel::kExact;
  if (name == "fast") return RayModel::kFast;
  return std::nullopt;
}

/// Visits, in order from \p origin, the voxels that the segment origin -> end crosses, starting
/// with the voxel that contains \p origin and stopping before the voxel that contains \p end (the
/// endpoint voxel is never visited; a segment inside one voxel visits nothing).
///
/// The path is 6-connected and always arrives exactly at the endpoint's key: each axis takes
/// exactly |key(end) - key(origin)| steps, so rounding can never make the walk overshoot or stop
/// early. Where the segment passes exactly through a voxel edge or corner, the walk steps along x
/// before y before z and so also visits a voxel the segment only touches.
///
/// \param origin, end  metres, map frame; both must be finite and representable as keys at
///                     \p resolution (see is_representable()): this function does not check.
/// \param resolution   voxel edge in metres (> 0).
/// \param visit        callable as visit(const VoxelKey&).
namespace detail {

/// The state of cast_ray()'s walk after its set-up: the one definition of the arithmetic that
/// decides each step, shared by cast_ray() and the scan scratch's own walk so that both take
/// exactly the same steps.
struct RayWalk {
  VoxelKey key;               ///< the voxel holding the origin, where the walk starts
  std::int64_t total = 0;     ///< voxels to visit: the origin's and every one before the end's
  std::int64_t left[3]{};     ///< steps still to take along x, y, z
  double t[3]{};              ///< ray parameter in [0, 1] of the next boundary along each axis
  double dt[3]{};             ///< ray parameter span of one voxel along each axis
  std::int32_t step[3]{};     ///< +1 or -1 along each axis
};

/// Sets up the walk of the segment \p origin -> \p end (see cast_ray()). An axis with no step
/// gets t = dt = infinity, so the comparisons of a step never choose it.
[[nodiscard]] inline RayWalk start_ray_walk(const Eigen::Vector3d& origin, const Eigen::Vector3d& end,
                                            double resolution) noexcept {
  RayWalk w;
  w.key = world_to_key(origin, resolution);
  const VoxelKey end_key = world_to_key(end, resolution);
  const std::int32_t start[3] = {w.key.x, w.key.y, w.key.z};
  const std::int32_t stop[3] = {end_key.x, end_key.y, end_key.z};
  constexpr double kInf = std::numeric_limits<double>::infinity();
  for (int a = 0; a < 3; ++a) {
    const std::int64_t diff = static_cast<std::int64_t>(stop[a]) - start[a];
    w.left[a] = std::llabs(diff);
    w.total += w.left[a];
    w.step[a] = diff > 0 ? 1 : -1;
    if (diff == 0) {
      w.t[a] = kInf;
      w.dt[a] = kInf;
      continue;
    }
    const double o = origin[a];
    const double d = end[a] - o;
    const double boundary = (static_cast<double>(start[a]) + (diff > 0 ? 1.0 : 0.0)) * resolution;
    w.t[a] = (boundary - o) / d;
    w.dt[a] = resolution / std::abs(d);
  }
  return w;
}

}  // namespace detail

template <class Visitor>
void cast_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& end, double resolution, Visitor&& visit) {
  const detail::RayWalk w = detail::start_ray_walk(origin, end, resolution);
  if (w.total == 0) return;
  constexpr double kInf = std::numeric_limits<double>::infinity();
  std::int64_t nx = w.left[0], ny = w.left[1], nz = w.left[2];
  double tx = w.t[0], ty = w.t[1], tz = w.t[2];
  VoxelKey key = w.key;
  visit(static_cast<const VoxelKey&>(key));
  for (std::int64_t s = 1; s < w.total; ++s) {
    // Ties go to x, then y, then z (documented above). An axis whose steps are all taken gets
    // t = infinity, so rounding can never make it step again.
    if (tx <= ty && tx <= tz) {
      key.x += w.step[0];
      tx = --nx == 0 ? kInf : tx + w.dt[0];
    } else if (ty <= tz) {
      key.y += w.step[1];
      ty = --ny == 0 ? kInf : ty + w.dt[1];
    } else {
      key.z += w.step[2];
      tz = --nz == 0 ? kInf : tz + w.dt[2];
    }
    visit(static_cast<const VoxelKey&>(key));
  }
}

/// The keys cast_ray() visits, as a vector (convenient; the template is the fast path).
[[nodiscard]] inline std::vector<VoxelKey> compute_ray_keys(const Eigen::Vector3d& origin,
                                                            const Eigen::Vector3d& end, double resolution) {
  std::vector<VoxelKey> keys;
  cast_ray(origin, end, resolution, [&keys](const VoxelKey& k) { keys.push_back(k); });
  return keys;
}

namespace detail {

/// The state of cast_line()'s walk after its set-up, shared by cast_line() and the scan scratch's
/// own walk. A 3D Bresenham line in integers: every step moves the axis of largest key difference
/// (the driving axis, whose error stays positive) and each other axis a whose error is > 0; an
/// axis's error starts at 2|d_a| - total, grows by 2|d_a| per step and falls by 2 total when the
/// axis moves. Over `total` steps axis a moves exactly |d_a| times, so the line always arrives at
/// the end's key; where the line passes exactly halfway between two voxels it takes the one nearer
/// the origin.
struct LineWalk {
  VoxelKey key;               ///< the voxel holding the origin, where the walk starts
  std::int64_t total = 0;     ///< voxels to visit: max over the axes of |key(end) - key(origin)|
  std::int64_t err[3]{};      ///< each axis's error (see above)
  std::int64_t grow[3]{};     ///< 2 |d_a|
  std::int64_t fall = 0;      ///< 2 total
  std::int32_t step[3]{};     ///< +1 or -1 along each axis
};

/// Sets up the walk of the line from the voxel of \p origin to the voxel of \p end (cast_line()).
[[nodiscard]] inline LineWalk start_line_walk(const Eigen::Vector3d& origin, const Eigen::Vector3d& end,
                                              double resolution) noexcept {
  LineWalk w;
  w.key = world_to_key(origin, resolution);
  const VoxelKey end_key = world_to_key(end, resolution);
  const std::int32_t start[3] = {w.key.x, w.key.y, w.key.z};
  const std::int32_t stop[3] = {end_key.x, end_key.y, end_key.z};
  for (int a = 0; a < 3; ++a) {
    const std::int64_t diff = static_cast<std::int64_t>(stop[a]) - start[a];
    const std::int64_t length = diff < 0 ? -diff : diff;
    w.grow[a] = 2 * length;
    w.step[a] = diff > 0 ? 1 : -1;
    w.total = std::max(w.total, length);
  }
  w.fall = 2 * w.total;
  for (int a = 0; a < 3; ++a) w.err[a] = w.grow[a] - w.total;
  return w;
}

/// One step of the line: the axes that move (bit a set: axis a), with the errors updated. The scan
/// scratch's walk does the same arithmetic on errors kept in registers (scan_scratch.cpp).
[[nodiscard]] inline unsigned line_step(LineWalk& w) noexcept {
  unsigned moved = 0;
  for (int a = 0; a < 3; ++a) {
    const unsigned m = w.err[a] > 0;
    w.err[a] += w.grow[a] - static_cast<std::int64_t>(m) * w.fall;
    moved |= m << a;
  }
  return moved;
}

}  // namespace detail

/// Visits, in order from \p origin, the voxels of the 26-connected line from the voxel that
/// contains \p origin to the voxel that contains \p end (RayModel::kFast), starting with the
/// origin's voxel and stopping before the end's (never visited; a segment inside one voxel visits
/// nothing): max(|dx|, |dy|, |dz|) voxels, each a face, edge or corner neighbour of the one before,
/// and the last a neighbour of the end's voxel. Arguments as for cast_ray().
template <class Visitor>
void cast_line(const Eigen::Vector3d& origin, const Eigen::Vector3d& end, double resolution, Visitor&& visit) {
  detail::LineWalk w = detail::start_line_walk(origin, end, resolution);
  VoxelKey key = w.key;
  for (std::int64_t s = 0; s < w.total; ++s) {
    visit(static_cast<const VoxelKey&>(key));
    const unsigned moved = detail::line_step(w);
    if (moved & 1u) key.x += w.step[0];
    if (moved & 2u) key.y += w.step[1];
    if (moved & 4u) key.z += w.step[2];
  }
}

/// The voxels a ray of insert_scan() marks free under \p model: cast_ray() or cast_line().
template <class Visitor>
void cast_ray(const Eigen::Vector3d& origin, const Eigen::Vector3d& end, double resolution, RayModel model,
              Visitor&& visit) {
  if (model == RayModel::kFast)
    cast_line(origin, end, resolution, std::forward<Visitor>(visit));
  else
    cast_ray(origin, end, resolution, std::forward<Visitor>(visit));
}

}  // namespace iwlomap
