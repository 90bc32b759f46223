// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/map_entropy.h"

#include "iwlomap/mapper_backend.h"

#include <cmath>
#include <stdexcept>
#include <string>

namespace iwlomap {

namespace {
// p log2 p with the limit 0 at p = 0.
double plog2p(double p) { return p > 0.0 ? p * std::log2(p) : 0.0; }
}  // namespace

double occupancy_entropy_bits(double probability) {
  if (!(probability >= 0.0 && probability <= 1.0))
    throw std::invalid_argument("iwlomap: occupancy_entropy_bits: probability = " + std::to_string(probability) +
                                " is outside [0, 1]");
  return -(plog2p(probability) + plog2p(1.0 - probability));
}

double map_entropy_bits(const IMapperBackend& map) {
  double sum = 0.0;
  map.for_each_voxel([&](const VoxelKey&, const VoxelState& s) { sum += occupancy_entropy_bits(s.probability); });
  return sum;
}

BoxEntropy box_entropy(const IMapperBackend& map, const VoxelBox& box) {
  box.validate();
  BoxEntropy e;
  map.for_each_voxel([&](const VoxelKey& k, const VoxelState& s) {
    if (!box.contains(k)) return;
    e.known_bits += occupancy_entropy_bits(s.probability);
    ++e.known_voxels;
  });
  e.unknown_voxels = box.num_voxels() - e.known_voxels;
  return e;
}

std::uint64_t count_unknown_voxels(const IMapperBackend& map, const VoxelBox& box) {
  return box_entropy(map, box).unknown_voxels;
}

}  // namespace iwlomap
