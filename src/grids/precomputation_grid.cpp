// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/precomputation_grid.h"

#include "iwlomap/mapper_backend.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <string>
#include <utility>

namespace iwlomap {

std::uint8_t probability_to_value(double probability) {
  if (std::isnan(probability)) throw std::invalid_argument("iwlomap: probability_to_value: probability is NaN");
  const double p = std::clamp(probability, kMinValueProbability, kMaxValueProbability);
  const long v = std::lround((p - kMinValueProbability) / (kMaxValueProbability - kMinValueProbability) * 255.0);
  // The clamp keeps v in [0, 255]; the second clamp only guards against a rounding surprise.
  return static_cast<std::uint8_t>(std::clamp(v, 0L, 255L));
}

double value_to_probability(std::uint8_t value) noexcept {
  return kMinValueProbability + static_cast<double>(value) / 255.0 * (kMaxValueProbability - kMinValueProbability);
}

namespace {

template <int D>
std::string cell_text(const Eigen::Matrix<int, D, 1>& c) {
  std::string s = "(";
  for (int a = 0; a < D; ++a) s += (a ? ", " : "") + std::to_string(c[a]);
  return s + ")";
}

// Checks sizes and returns the cell count; the limit keeps a mistyped box from allocating
// gigabytes, and the int64 product cannot overflow for sizes that pass the per-axis check.
template <int D>
std::size_t checked_cells(const Eigen::Matrix<std::int64_t, D, 1>& size, const char* what) {
  std::uint64_t cells = 1;
  for (int a = 0; a < D; ++a) {
    if (size[a] < 1)
      throw std::invalid_argument(std::string("iwlomap: ") + what + " size must be >= 1 on every axis, got " +
                                  std::to_string(size[a]) + " on axis " + std::to_string(a));
    if (size[a] > std::numeric_limits<int>::max() || cells * static_cast<std::uint64_t>(size[a]) > DiscreteGrid<D>::kMaxCells)
      throw std::length_error(std::string("iwlomap: ") + what + " would exceed " +
                              std::to_string(DiscreteGrid<D>::kMaxCells) + " cells (axis " + std::to_string(a) +
                              " has " + std::to_string(size[a]) + ")");
    cells *= static_cast<std::uint64_t>(size[a]);
  }
  return static_cast<std::size_t>(cells);
}

// Sliding-window maximum of one line of n values for windows of width w, written to the n + w - 1
// positions out[0 ..]: position s gets the maximum of in[s - w + 1 .. s] within the line. The
// deque (q: indices, qv: their values, kept side by side to avoid an indirect load) holds the
// candidates, whose values strictly decrease from front to back; an index leaves from the back
// when a value at least as large arrives (it can never be a maximum again) and from the front
// when it leaves the window, so every index moves at most twice: O(n + w) whatever w.
void sliding_max(const std::uint8_t* in, int n, int w, int* q, std::uint8_t* qv, std::uint8_t* out) {
  if (w == 1) {  // the window is the cell itself
    std::memcpy(out, in, static_cast<std::size_t>(n));
    return;
  }
  int head = 0, tail = 0;
  for (int s = 0; s < n; ++s) {
    const std::uint8_t v = in[s];
    while (tail > head && qv[tail - 1] <= v) --tail;
    q[tail] = s;
    qv[tail] = v;
    ++tail;
    // Only index s - w can have left the window since the previous step (branch-free: the test
    // is data-dependent and mispredicts often).
    head += static_cast<int>(q[head] <= s - w);
    out[s] = qv[head];
  }
  // The grown border past the line's end: nothing enters any more, the oldest leave.
  for (int s = n; s < n + w - 1; ++s) {
    head += static_cast<int>(q[head] <= s - w);
    out[s] = qv[head];
  }
}

// One separable pass: the sliding maximum along axis 0 of `in` (n0 x n1 x n2, axis 0 contiguous),
// written with the axes rotated, so that `out` is n1 x n2 x (n0 + w - 1) with axis 1 contiguous.
// Rotating makes the next axis contiguous for the next pass (D passes restore the layout), so
// every pass reads whole lines. kTile lines at a time are filtered into contiguous rows and then
// transposed into `out` in kTile x kTile blocks, which stay in L1 cache: writing the rotated
// output directly would touch one cache line per byte.
struct PassScratch {
  std::vector<int> queue;
  std::vector<std::uint8_t> queue_values;
  std::vector<std::uint8_t> rows;
};

void max_pass(const std::uint8_t* in, int n0, int n1, int n2, int w, std::uint8_t* out, PassScratch& scratch) {
  constexpr int kTile = 64;
  const int m0 = n0 + w - 1;
  const auto m0s = static_cast<std::size_t>(m0);
  scratch.queue.resize(static_cast<std::size_t>(n0));
  scratch.queue_values.resize(static_cast<std::size_t>(n0));
  scratch.rows.resize(static_cast<std::size_t>(kTile) * m0s);
  const auto n1s = static_cast<std::size_t>(n1), n2s = static_cast<std::size_t>(n2);
  std::uint8_t* rows = scratch.rows.data();
  for (int c = 0; c < n2; ++c) {
    for (int b0 = 0; b0 < n1; b0 += kTile) {
      const int nb = std::min(kTile, n1 - b0);
      for (int bi = 0; bi < nb; ++bi) {
        const std::uint8_t* line =
            in + static_cast<std::size_t>(n0) * (static_cast<std::size_t>(b0 + bi) + n1s * static_cast<std::size_t>(c));
        sliding_max(line, n0, w, scratch.queue.data(), scratch.queue_values.data(), rows + static_cast<std::size_t>(bi) * m0s);
      }
      for (int s0 = 0; s0 < m0; s0 += kTile) {
        const int ns = std::min(kTile, m0 - s0);
        for (int s = s0; s < s0 + ns; ++s) {
          std::uint8_t* dst = out + static_cast<std::size_t>(b0) + n1s * (static_cast<std::size_t>(c) + n2s * static_cast<std::size_t>(s));
          const std::uint8_t* src = rows + static_cast<std::size_t>(s);
          for (int bi = 0; bi < nb; ++bi) dst[bi] = src[static_cast<std::size_t>(bi) * m0s];
        }
      }
    }
  }
}

template <int D>
DiscreteGrid<D> make_grid(const VoxelBox& box, const GridFrame& frame, const char* what) {
  box.validate();
  const auto e = box.extent();
  Eigen::Matrix<std::int64_t, D, 1> size;
  for (int a = 0; a < D; ++a) size[a] = e[a];
  (void)checked_cells<D>(size, what);
  return DiscreteGrid<D>(size.template cast<int>(), kUnknownValue, frame);
}

}  // namespace

// ---- DiscreteGrid ----

template <int D>
DiscreteGrid<D>::DiscreteGrid(const Index& size, std::uint8_t fill, const GridFrame& frame)
    : size_(size), frame_(frame) {
  values_.assign(checked_cells<D>(size.template cast<std::int64_t>(), "grid"), fill);
}

template <int D>
DiscreteGrid<D>::DiscreteGrid(const Index& size, std::vector<std::uint8_t> values, const GridFrame& frame)
    : size_(size), frame_(frame), values_(std::move(values)) {
  const std::size_t cells = checked_cells<D>(size.template cast<std::int64_t>(), "grid");
  if (values_.size() != cells)
    throw std::invalid_argument("iwlomap: grid of size " + cell_text<D>(size) + " needs " + std::to_string(cells) +
                                " values, got " + std::to_string(values_.size()));
}

template <int D>
std::uint8_t DiscreteGrid<D>::at(const Index& cell) const {
  if (!contains(cell))
    throw std::out_of_range("iwlomap: cell " + cell_text<D>(cell) + " outside a grid of size " + cell_text<D>(size_));
  return values_[offset(cell)];
}

template <int D>
void DiscreteGrid<D>::set(const Index& cell, std::uint8_t value) {
  if (!contains(cell))
    throw std::out_of_range("iwlomap: cell " + cell_text<D>(cell) + " outside a grid of size " + cell_text<D>(size_));
  values_[offset(cell)] = value;
}

template <int D>
VoxelKey DiscreteGrid<D>::key_of(const Index& cell) const noexcept {
  VoxelKey k = frame_.origin;
  k.x += cell[0];
  k.y += cell[1];
  if constexpr (D == 3) k.z += cell[2];
  return k;
}

// ---- extraction from a map ----

DiscreteGrid3D discretize_volume(const IMapperBackend& map, const VoxelBox& box) {
  DiscreteGrid3D grid = make_grid<3>(box, GridFrame{box.min, map.get_resolution()}, "volume grid");
  const auto sx = static_cast<std::size_t>(grid.size().x()), sy = static_cast<std::size_t>(grid.size().y());
  std::vector<std::uint8_t>& v = grid.values();
  map.for_each_voxel([&](const VoxelKey& k, const VoxelState& state) {
    if (!box.contains(k)) return;
    const std::size_t o = static_cast<std::size_t>(k.x - box.min.x) +
                          sx * (static_cast<std::size_t>(k.y - box.min.y) + sy * static_cast<std::size_t>(k.z - box.min.z));
    v[o] = probability_to_value(state.probability);
  });
  return grid;
}

DiscreteGrid2D discretize_column_max(const IMapperBackend& map, const VoxelBox& box) {
  DiscreteGrid2D grid = make_grid<2>(box, GridFrame{box.min, map.get_resolution()}, "column grid");
  const auto sx = static_cast<std::size_t>(grid.size().x());
  std::vector<std::uint8_t>& v = grid.values();
  map.for_each_voxel([&](const VoxelKey& k, const VoxelState& state) {
    if (!box.contains(k)) return;
    std::uint8_t& cell = v[static_cast<std::size_t>(k.x - box.min.x) + sx * static_cast<std::size_t>(k.y - box.min.y)];
    cell = std::max(cell, probability_to_value(state.probability));
  });
  return grid;
}

DiscreteGrid2D discretize_slice(const IMapperBackend& map, const VoxelBox& box, double z) {
  if (!std::isfinite(z)) throw std::invalid_argument("iwlomap: discretize_slice: z = " + std::to_string(z) + " is not finite");
  VoxelBox slice = box;
  slice.min.z = slice.max.z = world_to_key_checked(Eigen::Vector3d(0.0, 0.0, z), map.get_resolution()).z;
  return discretize_column_max(map, slice);
}

// ---- PrecomputationGrid ----

template <int D>
PrecomputationGrid<D>::PrecomputationGrid(const DiscreteGrid<D>& base, int width)
    : width_(width), base_size_(base.size()), frame_(base.frame()) {
  if (width < 1) throw std::invalid_argument("iwlomap: precomputation width must be >= 1, got " + std::to_string(width));
  const Eigen::Matrix<std::int64_t, D, 1> grown =
      base.size().template cast<std::int64_t>().array() + static_cast<std::int64_t>(width - 1);
  values_.resize(checked_cells<D>(grown, "precomputation grid"));
  size_ = grown.template cast<int>();

  // D passes, one per axis, alternating between values_ and a buffer of the final size (every
  // intermediate is smaller); after each pass the axes are rotated by one (see max_pass()).
  PassScratch scratch;
  std::vector<std::uint8_t> buffer(values_.size());
  std::array<int, 3> dims{1, 1, 1};
  for (int a = 0; a < D; ++a) dims[static_cast<std::size_t>(a)] = base.size()[a];
  const std::uint8_t* in = base.values().data();
  // Choose the first target so that the last pass writes into values_.
  std::uint8_t* targets[2] = {D % 2 == 1 ? values_.data() : buffer.data(), D % 2 == 1 ? buffer.data() : values_.data()};
  for (int pass = 0; pass < D; ++pass) {
    std::uint8_t* out = targets[pass % 2];
    if constexpr (D == 2) {
      max_pass(in, dims[0], dims[1], 1, width, out, scratch);
      dims = {dims[1], dims[0] + width - 1, 1};
    } else {
      max_pass(in, dims[0], dims[1], dims[2], width, out, scratch);
      dims = {dims[1], dims[2], dims[0] + width - 1};
    }
    in = out;
  }
}

template <int D>
std::uint8_t PrecomputationGrid<D>::value(const Index& cell) const {
  if ((cell.array() < 0).any() || (cell.array() >= size_.array()).any())
    throw std::out_of_range("iwlomap: cell " + cell_text<D>(cell) + " outside a precomputation grid of size " +
                            cell_text<D>(size_) + " (width " + std::to_string(width_) + ")");
  std::size_t o = static_cast<std::size_t>(cell[D - 1]);
  for (int a = D - 2; a >= 0; --a) o = o * static_cast<std::size_t>(size_[a]) + static_cast<std::size_t>(cell[a]);
  return values_[o];
}

template <int D>
std::uint8_t PrecomputationGrid<D>::window_max(const Index& corner) const noexcept {
  std::size_t o = 0;
  for (int a = D - 1; a >= 0; --a) {
    // In int64: corner + width - 1 may overflow int for corners near INT_MAX.
    const std::int64_t s = static_cast<std::int64_t>(corner[a]) + width_ - 1;
    if (s < 0 || s >= size_[a]) return kUnknownValue;
    o = o * static_cast<std::size_t>(size_[a]) + static_cast<std::size_t>(s);
  }
  return values_[o];
}

template <int D>
VoxelKey PrecomputationGrid<D>::window_min_key(const Index& cell) const noexcept {
  VoxelKey k = frame_.origin;
  k.x += cell[0] - width_ + 1;
  k.y += cell[1] - width_ + 1;
  if constexpr (D == 3) k.z += cell[2] - width_ + 1;
  return k;
}

template class DiscreteGrid<2>;
template class DiscreteGrid<3>;
template class PrecomputationGrid<2>;
template class PrecomputationGrid<3>;

}  // namespace iwlomap
