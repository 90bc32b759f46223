// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Max-pooled copies of an occupancy grid, as Cartographer's fast correlative scan matcher builds
/// them for its branch-and-bound loop closure: a precomputation grid of width w holds, in each
/// cell, the largest 8-bit occupancy value of a w x w (x w) window of the base grid, so one
/// look-up bounds the best score of w^d candidate translations.
///
/// ## 8-bit values (Cartographer's discretization)
///
///     value = RoundToInt((p - 0.1) / (0.9 - 0.1) * 255),  p clamped to [0.1, 0.9]
///
/// RoundToInt rounds half away from zero (std::lround). An unknown voxel takes p = 0.1, i.e.
/// value 0, the same as any free voxel with p <= 0.1: a bound may only ever be optimistic about
/// occupancy, and unknown space must not promise a match. p = 0.5 gives 128 (127.5 rounded away
/// from zero), p >= 0.9 gives 255. Cartographer evaluates the formula in float; here it is
/// evaluated in double, which can differ only for a p within about 1e-7 of a rounding boundary.
///
/// ## Base grids, indices and frames
///
/// A DiscreteGrid holds one value per voxel of a VoxelBox, x fastest: cell (i, j[, k]) is the
/// voxel with key frame().origin + (i, j[, k]) and covers
/// [(origin.x + i) * r, (origin.x + i + 1) * r) along x (likewise y, z), r = frame().resolution.
/// A 2D grid's cells are columns of the box (or one slice of it); frame().origin.z is then the
/// lowest z key the column covers.
///
/// ## Precomputation grids
///
/// PrecomputationGrid<D> of width w over a base grid of size n (per axis) has n + w - 1 cells per
/// axis. Its cell s (per axis) holds the maximum of the base cells s - w + 1 .. s that lie in the
/// base grid: the window whose corner of largest indices (the "lower-right" corner of an image
/// with rows and columns counted from the top left) is at s. Cells 0 .. w - 2 and n .. n + w - 2
/// are the grown border, where the window overhangs the base grid; base cells outside count as
/// unknown (0), which is why the grid grows rather than clips. Equivalently, window_max(c) is the
/// maximum over base cells c .. c + w - 1 for any base index c, and equals value(c + w - 1):
/// this is the look-up of a branch-and-bound search, which at width w scores the w^d translations
/// c .. c + w - 1 at once.
///
/// In the world: precomputation cell s covers base cells s - w + 1 .. s, i.e. voxel keys
/// origin + s - w + 1 .. origin + s. Cell 0 is the window whose highest voxel is the box's lowest
/// voxel `origin` (world [origin * r, (origin + 1) * r)); its other w - 1 voxels lie below the box.
/// Width 1 is the base grid itself.
///
/// Construction is O(cells) whatever w: a sliding-window maximum (a monotonic deque of
/// candidate indices, each pushed and popped once) along one axis after the other, since the
/// maximum over a box is the maximum along x of maxima along y (and z).

#include "iwlomap/voxel_box.h"
#include "iwlomap/voxel_key.h"

#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <vector>

namespace iwlomap {

class IMapperBackend;

/// Lowest and highest probability Cartographer's 8-bit grid distinguishes.
inline constexpr double kMinValueProbability = 0.1;
inline constexpr double kMaxValueProbability = 0.9;
/// The value of an unknown voxel (p taken as kMinValueProbability).
inline constexpr std::uint8_t kUnknownValue = 0;

/// The 8-bit value of an occupancy probability (see the file comment). Throws
/// std::invalid_argument for NaN; values outside [0, 1] are clamped like any other.
[[nodiscard]] std::uint8_t probability_to_value(double probability);
/// The probability at the centre of a value's bin: 0.1 + value / 255 * 0.8 (inverse of
/// probability_to_value() on [0.1, 0.9] up to rounding).
[[nodiscard]] double value_to_probability(std::uint8_t value) noexcept;

/// Where a grid lies in the map: the voxel key of cell 0 and the voxel edge in metres.
struct GridFrame {
  VoxelKey origin{};
  double resolution = 1.0;
};

/// A dense grid of 8-bit occupancy values (2D or 3D), x fastest. Cheap to move, copyable.
template <int D>
class DiscreteGrid {
  static_assert(D == 2 || D == 3, "grids are 2D or 3D");

 public:
  using Index = Eigen::Matrix<int, D, 1>;

  /// A grid of \p size cells (each >= 1) all holding \p fill. Throws std::invalid_argument for a
  /// size < 1 and std::length_error when the grid would hold more than kMaxCells cells.
  explicit DiscreteGrid(const Index& size, std::uint8_t fill = kUnknownValue, const GridFrame& frame = {});
  /// A grid over existing values (x fastest, size.prod() entries). Throws like the constructor
  /// above, and std::invalid_argument when the value count does not match.
  DiscreteGrid(const Index& size, std::vector<std::uint8_t> values, const GridFrame& frame = {});

  /// Largest number of cells a grid or a precomputation level may hold (2^31: 2 GiB per level),
  /// so that a mistyped box fails with a message instead of exhausting memory.
  static constexpr std::size_t kMaxCells = std::size_t{1} << 31;

  [[nodiscard]] const Index& size() const noexcept { return size_; }
  [[nodiscard]] const GridFrame& frame() const noexcept { return frame_; }
  [[nodiscard]] const std::vector<std::uint8_t>& values() const noexcept { return values_; }
  [[nodiscard]] std::vector<std::uint8_t>& values() noexcept { return values_; }
  [[nodiscard]] bool contains(const Index& cell) const noexcept {
    return (cell.array() >= 0).all() && (cell.array() < size_.array()).all();
  }
  /// Position of \p cell in values() (unchecked).
  [[nodiscard]] std::size_t offset(const Index& cell) const noexcept {
    std::size_t o = static_cast<std::size_t>(cell[D - 1]);
    for (int a = D - 2; a >= 0; --a) o = o * static_cast<std::size_t>(size_[a]) + static_cast<std::size_t>(cell[a]);
    return o;
  }
  /// The value of \p cell; throws std::out_of_range naming the cell outside the grid.
  [[nodiscard]] std::uint8_t at(const Index& cell) const;
  /// Sets the value of \p cell; throws std::out_of_range naming the cell outside the grid.
  void set(const Index& cell, std::uint8_t value);
  /// Voxel key of \p cell (its z is frame().origin.z for a 2D grid).
  [[nodiscard]] VoxelKey key_of(const Index& cell) const noexcept;

 private:
  Index size_;
  GridFrame frame_;
  std::vector<std::uint8_t> values_;
};

using DiscreteGrid2D = DiscreteGrid<2>;
using DiscreteGrid3D = DiscreteGrid<3>;

/// The values of \p map in \p box, one cell per voxel (frame origin = box.min); unknown voxels
/// are 0. One pass over IMapperBackend::for_each_voxel() (one virtual call), skipping voxels
/// outside the box, so the cost is that of the map's known voxels plus the box's cells.
/// Throws std::invalid_argument for an invalid box, std::length_error for a box too large.
[[nodiscard]] DiscreteGrid3D discretize_volume(const IMapperBackend& map, const VoxelBox& box);
/// The maximum value of every (x, y) column of \p box over its z range (frame origin = box.min).
[[nodiscard]] DiscreteGrid2D discretize_column_max(const IMapperBackend& map, const VoxelBox& box);
/// The horizontal slice of \p box at height \p z (metres): its voxels with z key
/// floor(z / resolution), whatever the box's own z range (frame origin.z = that key).
[[nodiscard]] DiscreteGrid2D discretize_slice(const IMapperBackend& map, const VoxelBox& box, double z);

/// A max-pooled copy of a base grid for windows of width w (see the file comment for indices and
/// frames). Copyable and movable.
template <int D>
class PrecomputationGrid {
 public:
  using Index = Eigen::Matrix<int, D, 1>;

  /// Builds the grid of width \p width (>= 1) over \p base in O(cells). Throws
  /// std::invalid_argument for a width < 1 and std::length_error when the grown grid would hold
  /// more than DiscreteGrid<D>::kMaxCells cells.
  PrecomputationGrid(const DiscreteGrid<D>& base, int width);

  [[nodiscard]] int width() const noexcept { return width_; }
  /// Cells per axis: base_size() + width() - 1.
  [[nodiscard]] const Index& size() const noexcept { return size_; }
  [[nodiscard]] const Index& base_size() const noexcept { return base_size_; }
  /// The base grid's frame (cell 0 of the base grid is voxel frame().origin).
  [[nodiscard]] const GridFrame& frame() const noexcept { return frame_; }
  /// All values, x fastest, size().prod() entries.
  [[nodiscard]] const std::vector<std::uint8_t>& values() const noexcept { return values_; }

  /// Value of cell \p cell in 0 .. size() - 1: the maximum over base cells cell - width() + 1 ..
  /// cell. Throws std::out_of_range naming the cell outside the grid.
  [[nodiscard]] std::uint8_t value(const Index& cell) const;
  template <int E = D, std::enable_if_t<E == 2, int> = 0>
  [[nodiscard]] std::uint8_t value(int i, int j) const {
    return value(Index(i, j));
  }
  template <int E = D, std::enable_if_t<E == 3, int> = 0>
  [[nodiscard]] std::uint8_t value(int i, int j, int k) const {
    return value(Index(i, j, k));
  }

  /// Maximum over base cells corner .. corner + width() - 1 for any base index \p corner
  /// (Cartographer's GetValue()); 0 when the window misses the base grid. Never throws.
  [[nodiscard]] std::uint8_t window_max(const Index& corner) const noexcept;

  /// Voxel key of the lowest voxel of cell \p cell's window: frame().origin + cell - width() + 1
  /// (z unchanged for 2D grids).
  [[nodiscard]] VoxelKey window_min_key(const Index& cell) const noexcept;

 private:
  int width_;
  Index size_;
  Index base_size_;
  GridFrame frame_;
  std::vector<std::uint8_t> values_;
};

using PrecomputationGrid2D = PrecomputationGrid<2>;
using PrecomputationGrid3D = PrecomputationGrid<3>;

extern template class DiscreteGrid<2>;
extern template class DiscreteGrid<3>;
extern template class PrecomputationGrid<2>;
extern template class PrecomputationGrid<3>;

}  // namespace iwlomap
