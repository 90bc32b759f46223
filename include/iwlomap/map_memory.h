// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Reuse of the memory of destroyed maps.
///
/// The block grids of every backend (RAM maps, the Disk backend's resident tiles, the OctoMap
/// backend's exact state) carve their voxels out of slabs of 64 KiB to 2 MiB mapped from the
/// kernel. Slabs a map gives back (destroyed, clear()ed, prune()d, or a tile evicted) are kept for
/// the next map of the process, up to 64 MiB in all, as long as at least one map is alive: a new
/// map then skips the kernel's cost of handing out and zeroing fresh pages. When the last map is
/// destroyed, the kept slabs go back to the system, except for what set_retained_map_memory()
/// asks to keep.

#include <cstddef>

namespace iwlomap {

/// Keeps up to \p bytes of slabs (capped at 64 MiB) after the last map of the process is
/// destroyed, for programs that build one map after another (a map per frame or per region, a
/// benchmark). Default 0: nothing is kept once no map is alive. Thread-safe.
void set_retained_map_memory(std::size_t bytes);

/// The value set by set_retained_map_memory().
[[nodiscard]] std::size_t get_retained_map_memory();

/// Bytes of slabs kept for reuse right now (not counted by any map's get_memory_usage()).
[[nodiscard]] std::size_t get_cached_map_memory();

}  // namespace iwlomap
