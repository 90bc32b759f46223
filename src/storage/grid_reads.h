// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Reading a BlockGrid as the backend interface reports it, shared by the backends that keep their
// exact IWLO state in one (RAM, OctoMap), so that their answers cannot drift apart.

#include "model/checks.h"
#include "model/probability_above.h"
#include "storage/block_grid.h"
#include "iwlomap/iwlo.h"
#include "iwlomap/voxel_state.h"

#include <Eigen/Core>

#include <functional>
#include <optional>
#include <vector>

namespace iwlomap::detail {

/// The reported state of a stored voxel of format \p f.
[[nodiscard]] inline VoxelState state_of(const Voxel& v, const iwlo::VoxelFormat& f) {
  const double L = f.log_odds(v.word);
  return VoxelState{L, iwlo::probability(L), f.count(v.word)};
}

/// Calls fn(key, voxel) for every known voxel, block by block in grid order.
template <class Fn>
void for_each_known(const BlockGrid& grid, Fn&& fn) {
  for (const VoxelBlock* b : grid.blocks()) {
    if (b->known == 0) continue;
    b->for_each_slot([&](int i, const Voxel& v) {
      if (v.known()) fn(voxel_of(b->key, i), v);
    });
  }
}

/// The known voxels (of format \p f) with probability > \p threshold as flattened rows (x, y, z in
/// metres, p), in the order for_each_known(fn) visits them (it calls fn(key, const Voxel&));
/// position(key) gives a row's point: the voxel centre, or a mean hit position.
template <class ForEachKnown, class Position>
[[nodiscard]] std::vector<double> occupied_rows(ForEachKnown&& for_each_known, const iwlo::VoxelFormat& f,
                                                double threshold, Position&& position) {
  std::vector<double> rows;
  const ProbabilityAbove above(threshold);
  for_each_known([&](const VoxelKey& key, const Voxel& v) {
    const float L = f.log_odds(v.word);
    if (!above(L)) return;
    const double p = iwlo::probability(L);
    const Eigen::Vector3d x = position(key);
    rows.insert(rows.end(), {x.x(), x.y(), x.z(), p});
  });
  return rows;
}

/// occupied_rows() of a grid, at the voxel centres.
[[nodiscard]] inline std::vector<double> occupied_rows(const BlockGrid& grid, const iwlo::VoxelFormat& f,
                                                       double resolution, double threshold) {
  return occupied_rows([&grid](auto&& fn) { for_each_known(grid, fn); }, f, threshold,
                       [resolution](const VoxelKey& k) { return key_to_center(k, resolution); });
}

/// Builds the N x 4 (x, y, z, p) matrix of occupied voxels from \p rows (flattened quadruples).
[[nodiscard]] inline Eigen::MatrixXd rows_to_matrix(const std::vector<double>& rows) {
  const auto n = static_cast<Eigen::Index>(rows.size() / 4);
  Eigen::MatrixXd m(n, 4);
  for (Eigen::Index i = 0; i < n; ++i)
    for (Eigen::Index c = 0; c < 4; ++c) m(i, c) = rows[static_cast<std::size_t>(i * 4 + c)];
  return m;
}

/// The state of voxel \p key, or nullopt when it is unknown.
[[nodiscard]] inline std::optional<VoxelState> query_voxel(const BlockGrid& grid, const iwlo::VoxelFormat& f,
                                                           const VoxelKey& key) {
  const VoxelBlock* b = grid.find(block_of(key));
  if (b == nullptr) return std::nullopt;
  const Voxel* v = b->find(index_in_block(key));
  if (v == nullptr || !v->known()) return std::nullopt;
  return state_of(*v, f);
}

/// get_occupied_voxels() of a backend whose map is one grid.
[[nodiscard]] inline Eigen::MatrixXd occupied_matrix(const BlockGrid& grid, const iwlo::VoxelFormat& f,
                                                     double resolution, double min_probability) {
  return rows_to_matrix(occupied_rows(grid, f, resolution, resolve_min_probability(min_probability)));
}

/// query() of a backend whose map is one grid.
[[nodiscard]] inline std::optional<VoxelState> query_point(const BlockGrid& grid, const iwlo::VoxelFormat& f,
                                                           double resolution, const Eigen::Vector3d& point) {
  return query_voxel(grid, f, world_to_key_checked(point, resolution));
}

/// for_each_voxel() of a backend whose map is one grid.
inline void for_each_state(const BlockGrid& grid, const iwlo::VoxelFormat& f,
                           const std::function<void(const VoxelKey&, const VoxelState&)>& visit) {
  for_each_known(grid, [&visit, &f](const VoxelKey& k, const Voxel& v) { visit(k, state_of(v, f)); });
}

}  // namespace iwlomap::detail
