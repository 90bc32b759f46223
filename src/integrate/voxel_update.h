// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The two ways a stored voxel changes, shared by every backend. Each returns true when the voxel
// was unknown before, so the caller can count it in its own totals (the block's count is kept here).

#include "integrate/updater.h"
#include "iwlomap/iwlo.h"
#include "storage/block_grid.h"

#include <cstdint>

namespace iwlomap::detail {

/// iwlo::apply_observation() with the precomputed Updater, on a stored word (the same stored
/// state). An unknown voxel's first observation with weight 1 and an integer intensity (or a free
/// one) is a table look-up: most observations of a batch into new space are such.
inline void update_voxel_state(std::uint32_t& word, double intensity, bool occupied_flag, double weight,
                               const Updater& u) {
  if (word == 0 && weight == 1.0 && u.first_observation(intensity, occupied_flag, word)) return;
  // encode(step(L)) computed on the fixed-point value q = L * 2^f, which is the same: 2^f is a
  // power of two, so q + delta * 2^f rounds exactly as (L + delta) * 2^f, and encode's bounds
  // [q_min, q_max] lie within [L_min, L_max] * 2^f, so step()'s clamp before them changes
  // nothing. What a second observation of the voxel waits for is then an add, the bounds and
  // the conversion, not two more multiplications and a clamp.
  // The weight is scaled before it multiplies the increment, (d * w) * 2^f == d * (w * 2^f) for
  // the same reason, and one multiplication leaves that chain.
  const iwlo::VoxelFormat& f = u.format();
  const std::uint32_t n = f.next_count(f.count(word));
  const auto q = static_cast<double>(f.fixed(word));
  word = f.encode_fixed(q + u.weighted_delta(q * f.step(), n, intensity, occupied_flag, weight * f.scale()), n);
}

/// One IWLO observation of voxel \p v of block \p b.
inline bool observe_voxel(VoxelBlock& b, Voxel& v, double intensity, bool occupied_flag, double weight,
                          const Updater& updater) {
  const bool was_unknown = !v.known();
  if (was_unknown) ++b.known;
  update_voxel_state(v.word, intensity, occupied_flag, weight, updater);
  return was_unknown;
}

/// Absolute log-odds (IMapperBackend::set_log_odds()), stored in \p format: an unknown voxel
/// becomes known with count 1; a known one keeps its count.
inline bool set_voxel_log_odds(VoxelBlock& b, Voxel& v, double log_odds, const iwlo::VoxelFormat& format) {
  const bool was_unknown = !v.known();
  if (was_unknown) ++b.known;
  v.word = format.encode(log_odds, was_unknown ? 1 : format.count(v.word));
  return was_unknown;
}

/// Rewrites every known voxel of \p grid from format \p from to format \p to when their layouts
/// differ (a change of parameters): iwlo::VoxelFormat::convert().
inline void convert_voxels(BlockGrid& grid, const iwlo::VoxelFormat& from, const iwlo::VoxelFormat& to) {
  if (to.same_layout(from)) return;
  for (VoxelBlock* b : grid.blocks()) {
    b->cell_mask.for_each([&](int c) {
      Cell& cell = b->cells[b->position[static_cast<std::size_t>(c)]];
      for (Voxel& v : cell.voxels)
        if (v.known()) v.word = to.convert(v.word, from);
    });
  }
}

}  // namespace iwlomap::detail
