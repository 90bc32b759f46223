// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Map entropy for exploration: how uncertain a map (or a box of it, e.g. what a candidate view
/// would see) still is.
///
/// Units: bits. A voxel with occupancy probability p has the Shannon entropy
/// H(p) = -p log2 p - (1 - p) log2(1 - p) bits, 0 for a certain voxel and 1 bit for p = 0.5. An
/// unknown voxel (never observed) counts 1 bit when a total includes it. (GMapping's cell entropy
/// of hit_statistics.h is a different quantity, of hit rates, in nats.)

#include "iwlomap/voxel_box.h"

#include <cstdint>

namespace iwlomap {

class IMapperBackend;

/// H(p) in bits; 0 at p = 0 and p = 1. Throws std::invalid_argument for p outside [0, 1] or NaN.
[[nodiscard]] double occupancy_entropy_bits(double probability);

/// The sum of occupancy_entropy_bits() over every known voxel of \p map (unknown voxels are not
/// included: a map has no bounds of its own). One pass over for_each_voxel().
[[nodiscard]] double map_entropy_bits(const IMapperBackend& map);

/// Entropy of the voxels of one box.
struct BoxEntropy {
  double known_bits = 0.0;             ///< sum of H(p) over the known voxels of the box
  std::uint64_t known_voxels = 0;      ///< known voxels in the box
  std::uint64_t unknown_voxels = 0;    ///< box voxels never observed
  /// known_bits plus 1 bit per unknown voxel: the score a view that resolves the box would gain.
  [[nodiscard]] double total_bits() const noexcept { return known_bits + static_cast<double>(unknown_voxels); }
};

/// Entropy and unknown count of \p box in \p map, in one pass over for_each_voxel() (the cost is
/// that of the map's known voxels, whatever the box's size). Throws std::invalid_argument for an
/// invalid box.
[[nodiscard]] BoxEntropy box_entropy(const IMapperBackend& map, const VoxelBox& box);

/// Voxels of \p box that are unknown in \p map (box_entropy().unknown_voxels).
[[nodiscard]] std::uint64_t count_unknown_voxels(const IMapperBackend& map, const VoxelBox& box);

}  // namespace iwlomap
