// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Accounting behind set_map_memory_limit() (iwlomap/map_memory.h): the bytes of slabs that maps
// hold right now, and the check integration makes before it allocates.

#include <cstddef>

namespace iwlomap::detail {

/// Bytes of slabs held by the block grids of every map in the process (cached slabs excluded).
[[nodiscard]] std::size_t map_memory_in_use() noexcept;
/// The limit of set_map_memory_limit(); 0 when there is none.
[[nodiscard]] std::size_t map_memory_limit() noexcept;

/// Throws MemoryLimitError when a limit is set and map_memory_in_use() + \p extra passes it; a
/// no-op without a limit. \p what names what would need the memory ("the scan's voxels").
void check_map_memory(std::size_t extra, const char* what);

/// Accounts for a slab of \p bytes about to be mapped (check_map_memory() first, then counted),
/// and for one given back.
void charge_map_memory(std::size_t bytes);
void uncharge_map_memory(std::size_t bytes) noexcept;

}  // namespace iwlomap::detail
