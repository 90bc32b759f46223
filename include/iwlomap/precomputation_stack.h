// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// PrecomputationStack: every level of a multi-resolution max grid, widths 2^0 .. 2^(n-1), as
/// Cartographer keeps them for branch-and-bound (7 levels: windows 1, 2, 4, ..., 64).
///
///     const VoxelBox box = VoxelBox::from_world(lo, hi, map.get_resolution());
///     const PrecomputationStack2D stack(discretize_slice(map, box, 1.0));
///     const std::uint8_t bound = stack.level(3).window_max({i, j});  // max over 8 x 8 cells

#include "iwlomap/precomputation_grid.h"

#include <vector>

namespace iwlomap {

template <int D>
class PrecomputationStack {
 public:
  using Index = typename PrecomputationGrid<D>::Index;
  static constexpr int kDefaultLevels = 7;
  static constexpr int kMaxLevels = 16;

  /// Builds levels 0 .. \p num_levels - 1 (level k has width 2^k) over \p base, each in O(cells).
  /// Throws std::invalid_argument for a level count outside [1, kMaxLevels] and
  /// std::length_error when the widest level would be too large (see PrecomputationGrid).
  explicit PrecomputationStack(const DiscreteGrid<D>& base, int num_levels = kDefaultLevels);

  [[nodiscard]] int num_levels() const noexcept { return static_cast<int>(levels_.size()); }
  /// Level \p k (width 2^k); throws std::out_of_range naming k outside [0, num_levels()).
  [[nodiscard]] const PrecomputationGrid<D>& level(int k) const;
  /// Width of level \p k: 2^k (throws like level()).
  [[nodiscard]] int width(int k) const { return level(k).width(); }
  /// Base grid size (per axis).
  [[nodiscard]] const Index& base_size() const noexcept { return levels_.front().base_size(); }
  [[nodiscard]] const GridFrame& frame() const noexcept { return levels_.front().frame(); }

  /// Maximum value over the base cells lo .. hi (inclusive; cells outside the base grid count 0,
  /// so the box may extend past it) answered from level \p k: the box is covered with windows of
  /// width 2^k starting at lo, the last one along each axis ending at hi, so the answer is exact
  /// when every extent of the box is at least 2^k and otherwise an upper bound (a window then
  /// overhangs the box, unless the overhang falls outside the base grid). Costs
  /// prod(ceil(extent / 2^k)) look-ups, extents taken within the base grid. Throws std::out_of_range for a bad level and
  /// std::invalid_argument when lo > hi on an axis.
  [[nodiscard]] std::uint8_t max_in_box(int k, const Index& lo, const Index& hi) const;
  /// The exact maximum over the base cells lo .. hi, from the coarsest level whose width does not
  /// exceed the box's smallest extent.
  [[nodiscard]] std::uint8_t max_in_box(const Index& lo, const Index& hi) const;

 private:
  std::vector<PrecomputationGrid<D>> levels_;
};

using PrecomputationStack2D = PrecomputationStack<2>;
using PrecomputationStack3D = PrecomputationStack<3>;

extern template class PrecomputationStack<2>;
extern template class PrecomputationStack<3>;

}  // namespace iwlomap
