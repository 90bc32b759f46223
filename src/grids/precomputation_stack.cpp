// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/precomputation_stack.h"

#include <algorithm>
#include <cstdint>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap {

template <int D>
PrecomputationStack<D>::PrecomputationStack(const DiscreteGrid<D>& base, int num_levels) {
  if (num_levels < 1 || num_levels > kMaxLevels)
    throw std::invalid_argument("iwlomap: PrecomputationStack needs 1 to " + std::to_string(kMaxLevels) +
                                " levels, got " + std::to_string(num_levels));
  levels_.reserve(static_cast<std::size_t>(num_levels));
  // Every level is built from the base grid, not from the previous level: each costs O(cells)
  // anyway, and levels stay independent of one another's rounding of the border.
  for (int k = 0; k < num_levels; ++k) levels_.emplace_back(base, 1 << k);
}

template <int D>
const PrecomputationGrid<D>& PrecomputationStack<D>::level(int k) const {
  if (k < 0 || k >= num_levels())
    throw std::out_of_range("iwlomap: precomputation level " + std::to_string(k) + " outside [0, " +
                            std::to_string(num_levels()) + ")");
  return levels_[static_cast<std::size_t>(k)];
}

template <int D>
std::uint8_t PrecomputationStack<D>::max_in_box(int k, const Index& lo, const Index& hi) const {
  const PrecomputationGrid<D>& grid = level(k);
  for (int a = 0; a < D; ++a)
    if (lo[a] > hi[a])
      throw std::invalid_argument("iwlomap: max_in_box: lo exceeds hi on axis " + std::to_string(a) + " (" +
                                  std::to_string(lo[a]) + " > " + std::to_string(hi[a]) + ")");
  const int w = grid.width();
  // Window corners along each axis. Cells outside the base grid are unknown (0), so the box is
  // clipped to the grid (less work), and a window may reach outside the grid without changing the
  // answer: only reaching past the box into the grid can.
  std::vector<int> corners[D];
  for (int a = 0; a < D; ++a) {
    const int n = base_size()[a];
    const int a_lo = std::max(lo[a], 0), a_hi = std::min(hi[a], n - 1);
    if (a_lo > a_hi) return kUnknownValue;
    if (a_hi - a_lo + 1 >= w) {
      // lo, lo + w, ... and a last window ending exactly at hi: they tile the box, never leave it.
      const int last = a_hi - w + 1;
      for (int c = a_lo; c < last; c += w) corners[a].push_back(c);
      corners[a].push_back(last);
    } else {
      // One window covers the box; it stays inside the box extended by the cells outside the grid
      // when there is room, else it overhangs (an upper bound).
      const std::int64_t allowed_lo = lo[a] < 0 ? std::numeric_limits<std::int64_t>::min() : lo[a];
      const std::int64_t allowed_hi = hi[a] > n - 1 ? std::numeric_limits<std::int64_t>::max() : hi[a];
      const std::int64_t c_min = std::max<std::int64_t>(allowed_lo, a_hi - w + 1);
      const std::int64_t c_max = std::min<std::int64_t>(a_lo, allowed_hi == std::numeric_limits<std::int64_t>::max()
                                                                  ? allowed_hi
                                                                  : allowed_hi - w + 1);
      corners[a].push_back(c_min <= c_max ? static_cast<int>(c_min) : a_lo);
    }
  }
  std::uint8_t best = kUnknownValue;
  Index corner;
  if constexpr (D == 2) {
    for (const int y : corners[1])
      for (const int x : corners[0]) {
        corner << x, y;
        best = std::max(best, grid.window_max(corner));
      }
  } else {
    for (const int z : corners[2])
      for (const int y : corners[1])
        for (const int x : corners[0]) {
          corner << x, y, z;
          best = std::max(best, grid.window_max(corner));
        }
  }
  return best;
}

template <int D>
std::uint8_t PrecomputationStack<D>::max_in_box(const Index& lo, const Index& hi) const {
  for (int a = 0; a < D; ++a)
    if (lo[a] > hi[a])
      throw std::invalid_argument("iwlomap: max_in_box: lo exceeds hi on axis " + std::to_string(a) + " (" +
                                  std::to_string(lo[a]) + " > " + std::to_string(hi[a]) + ")");
  // The smallest extent after clipping decides: a wider window would overhang the box.
  std::int64_t smallest = std::numeric_limits<std::int64_t>::max();
  for (int a = 0; a < D; ++a) {
    const std::int64_t l = std::max(lo[a], 0), h = std::min(hi[a], base_size()[a] - 1);
    if (l > h) return kUnknownValue;
    smallest = std::min(smallest, h - l + 1);
  }
  int k = 0;
  while (k + 1 < num_levels() && (std::int64_t{1} << (k + 1)) <= smallest) ++k;
  return max_in_box(k, lo, hi);
}

template class PrecomputationStack<2>;
template class PrecomputationStack<3>;

}  // namespace iwlomap
