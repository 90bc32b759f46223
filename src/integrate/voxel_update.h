// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The two ways a stored voxel changes, shared by every backend. Each returns true when the voxel
// was unknown before, so the caller can count it in its own totals (the block's count is kept here).

#include "integrate/updater.h"
#include "iwlomap/iwlo.h"
#include "storage/block_grid.h"

#include <cstdint>

namespace iwlomap::detail {

/// iwlo::apply_observation() with the precomputed Updater (the same stored state). An unknown
/// voxel's first observation with weight 1 and an integer intensity (or a free one) is a table
/// look-up: most observations of a batch into new space are such.
inline void update_voxel_state(float& log_odds_value, std::uint16_t& count, double intensity, bool occupied_flag,
                               double weight, const Updater& u) {
  if (count == 0 && log_odds_value == 0.0f && weight == 1.0 &&
      u.first_observation(intensity, occupied_flag, log_odds_value)) {
    count = 1;
    return;
  }
  const std::uint32_t n = iwlo::increment_count(count);
  log_odds_value =
      static_cast<float>(u.step(static_cast<double>(log_odds_value), n, intensity, occupied_flag, weight));
  count = static_cast<std::uint16_t>(n);
}

/// One IWLO observation of voxel \p v of block \p b.
inline bool observe_voxel(VoxelBlock& b, Voxel& v, double intensity, bool occupied_flag, double weight,
                          const Updater& updater) {
  const bool was_unknown = v.count == 0;
  if (was_unknown) ++b.known;
  update_voxel_state(v.log_odds, v.count, intensity, occupied_flag, weight, updater);
  return was_unknown;
}

/// Absolute log-odds (IMapperBackend::set_log_odds()): an unknown voxel becomes known with count 1.
inline bool set_voxel_log_odds(VoxelBlock& b, Voxel& v, float log_odds) {
  const bool was_unknown = v.count == 0;
  if (was_unknown) {
    ++b.known;
    v.count = 1;
  }
  v.log_odds = log_odds;
  return was_unknown;
}

}  // namespace iwlomap::detail
