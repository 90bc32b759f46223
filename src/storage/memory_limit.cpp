// SPDX-License-Identifier: BSD-3-Clause
#include "storage/memory_limit.h"

#include "iwlomap/map_memory.h"

#include <atomic>
#include <cstdio>
#include <string>

namespace iwlomap {

namespace {

std::atomic<std::size_t> g_in_use{0};
std::atomic<std::size_t> g_limit{0};

std::string mib(std::size_t bytes) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.1f MiB", static_cast<double>(bytes) / (1024.0 * 1024.0));
  return buf;
}

}  // namespace

MemoryLimitError::MemoryLimitError(std::size_t needed, std::size_t in_use, std::size_t limit, const std::string& what)
    : std::runtime_error("iwlomap: " + what + " would need " + mib(needed) + " more with " + mib(in_use) +
                         " already held by maps, past the map memory limit of " + mib(limit) +
                         ": use a coarser resolution, a shorter maximum range, or a higher limit"),
      needed_(needed),
      in_use_(in_use),
      limit_(limit) {}

void set_map_memory_limit(std::size_t bytes) { g_limit.store(bytes, std::memory_order_relaxed); }
std::size_t get_map_memory_limit() { return g_limit.load(std::memory_order_relaxed); }
std::size_t get_map_memory_in_use() { return g_in_use.load(std::memory_order_relaxed); }

}  // namespace iwlomap

namespace iwlomap::detail {

std::size_t map_memory_in_use() noexcept { return g_in_use.load(std::memory_order_relaxed); }
std::size_t map_memory_limit() noexcept { return g_limit.load(std::memory_order_relaxed); }

namespace {

// Throws when \p extra bytes on top of \p in_use would pass the limit (none when it is 0).
void refuse_past_limit(std::size_t in_use, std::size_t extra, const char* what) {
  const std::size_t limit = map_memory_limit();
  if (limit != 0 && (extra > limit || in_use > limit - extra)) throw MemoryLimitError(extra, in_use, limit, what);
}

}  // namespace

void check_map_memory(std::size_t extra, const char* what) { refuse_past_limit(map_memory_in_use(), extra, what); }

void charge_map_memory(std::size_t bytes) {
  // Compare and add in one step, so that maps filled on several threads never pass the limit together.
  std::size_t in_use = g_in_use.load(std::memory_order_relaxed);
  do {
    refuse_past_limit(in_use, bytes, "a map's next slab");
  } while (!g_in_use.compare_exchange_weak(in_use, in_use + bytes, std::memory_order_relaxed));
}

void uncharge_map_memory(std::size_t bytes) noexcept { g_in_use.fetch_sub(bytes, std::memory_order_relaxed); }

}  // namespace iwlomap::detail
