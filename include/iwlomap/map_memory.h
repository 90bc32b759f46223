// SPDX-License-Identifier: BSD-3-Clause
#pragma once

/// \file
/// Reuse of the memory of destroyed maps, and a limit on the memory maps may hold.
///
/// The block grids of every backend (RAM maps, the Disk backend's resident tiles, the OctoMap
/// backend's exact state) carve their voxels out of slabs of 64 KiB to 2 MiB mapped from the
/// kernel. Slabs a map gives back (destroyed, clear()ed, prune()d, or a tile evicted) are kept for
/// the next map of the process, up to 64 MiB in all, as long as at least one map is alive: a new
/// map then skips the kernel's cost of handing out and zeroing fresh pages. When the last map is
/// destroyed, the kept slabs go back to the system, except for what set_retained_map_memory()
/// asks to keep.

#include <cstddef>
#include <stdexcept>
#include <string>

namespace iwlomap {

/// Keeps up to \p bytes of slabs (capped at 64 MiB) after the last map of the process is
/// destroyed, for programs that build one map after another (a map per frame or per region, a
/// benchmark). Default 0: nothing is kept once no map is alive. Thread-safe.
void set_retained_map_memory(std::size_t bytes);

/// The value set by set_retained_map_memory().
[[nodiscard]] std::size_t get_retained_map_memory();

/// Bytes of slabs kept for reuse right now (not counted by any map's get_memory_usage()).
[[nodiscard]] std::size_t get_cached_map_memory();

/// Caps the memory that maps may hold in this process, in bytes: the slabs of voxels of every map
/// (RAM, the Disk backend's resident tiles, the OctoMap backend's exact state; nearly all of what
/// get_memory_usage() reports) plus the scratch of the scan being inserted. 0 (the default): no
/// limit. Thread-safe; a lower limit than the memory already held frees nothing, it only stops
/// growth.
///
/// With a limit, insert_scan() of the RAM and OctoMap backends first collects the scan's rays and
/// works out the most memory the scan can add; when that would pass the limit, it throws
/// MemoryLimitError before changing the map. Other calls (batch updates, the Disk backend's
/// tiles) throw it when the next slab would pass the limit; the map stays consistent, but a batch
/// may be partly applied, as with std::bad_alloc. Under a cap on the address space (RLIMIT_AS,
/// `ulimit -v`), set a limit below it to get this error instead of std::bad_alloc.
void set_map_memory_limit(std::size_t bytes);

/// The value set by set_map_memory_limit() (0: none).
[[nodiscard]] std::size_t get_map_memory_limit();

/// Bytes of slabs that maps hold right now: what set_map_memory_limit() caps (the scan scratch
/// aside, which lives only during insert_scan()).
[[nodiscard]] std::size_t get_map_memory_in_use();

/// Integration that would pass the limit of set_map_memory_limit(). The message says how much
/// more was needed, what is held and what to change (a coarser resolution, a shorter maximum range
/// or a higher limit).
class MemoryLimitError : public std::runtime_error {
 public:
  MemoryLimitError(std::size_t needed, std::size_t in_use, std::size_t limit, const std::string& what);
  /// Bytes the call needed on top of what maps held.
  [[nodiscard]] std::size_t needed() const noexcept { return needed_; }
  /// Bytes maps held when the call was refused.
  [[nodiscard]] std::size_t in_use() const noexcept { return in_use_; }
  /// The limit in effect.
  [[nodiscard]] std::size_t limit() const noexcept { return limit_; }

 private:
  std::size_t needed_;
  std::size_t in_use_;
  std::size_t limit_;
};

}  // namespace iwlomap
