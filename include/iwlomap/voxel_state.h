// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// VoxelState: what a backend reports of one known voxel (IMapperBackend::query(),
/// for_each_voxel()). Included by mapper_backend.h.

#include <cstdint>

namespace iwlomap {

/// State of one known voxel.
struct VoxelState {
  double log_odds = 0.0;     ///< current log-odds L (natural logarithm)
  double probability = 0.5;  ///< 1 / (1 + exp(-L))
  std::uint32_t count = 0;   ///< observations so far (saturates at the map's iwlo::VoxelFormat::max_count(): 255 with the defaults)
};

}  // namespace iwlomap
