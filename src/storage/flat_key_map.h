// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// An open-addressing hash map from VoxelKey to a 32-bit index, with linear probing and a
// power-of-two table. It is the index of the block grids: std::unordered_map allocates a node per
// entry and chases a pointer per look-up, which dominated insertion time. There is no erase:
// owners rebuild the map when they drop entries (prune, clear), which keeps probing simple.

#include "iwlomap/voxel_key.h"

#include <cstddef>
#include <cstdint>
#include <limits>
#include <vector>

namespace iwlomap::detail {

class FlatKeyMap {
 public:
  static constexpr std::uint32_t kEmpty = std::numeric_limits<std::uint32_t>::max();

  FlatKeyMap() { slots_.assign(16, Slot{}); }

  /// Index stored for \p key, or kEmpty.
  [[nodiscard]] std::uint32_t find(const VoxelKey& key) const noexcept {
    const std::size_t mask = slots_.size() - 1;
    for (std::size_t i = VoxelKeyHash{}(key) & mask;; i = (i + 1) & mask) {
      const Slot& s = slots_[i];
      if (s.value == kEmpty) return kEmpty;
      if (s.key == key) return s.value;
    }
  }

  /// Inserts key -> value unless the key is present; returns the stored value either way.
  std::uint32_t insert(const VoxelKey& key, std::uint32_t value) {
    if ((size_ + 1) * 4 > slots_.size()) grow();
    const std::size_t mask = slots_.size() - 1;
    for (std::size_t i = VoxelKeyHash{}(key) & mask;; i = (i + 1) & mask) {
      Slot& s = slots_[i];
      if (s.value == kEmpty) {
        s.key = key;
        s.value = value;
        ++size_;
        return value;
      }
      if (s.key == key) return s.value;
    }
  }

  /// Removes everything and shrinks the table to hold \p expected entries.
  void reset(std::size_t expected = 0) {
    std::size_t cap = 16;
    while (cap < expected * 2) cap *= 2;
    slots_.assign(cap, Slot{});
    slots_.shrink_to_fit();
    size_ = 0;
  }

  /// Removes everything but keeps the table's capacity (for per-scan scratch reuse).
  void clear_keep_capacity() {
    if (size_ == 0) return;
    for (Slot& s : slots_) s.value = kEmpty;
    size_ = 0;
  }

  [[nodiscard]] std::size_t size() const noexcept { return size_; }
  [[nodiscard]] std::size_t bytes() const noexcept { return slots_.capacity() * sizeof(Slot); }

 private:
  struct Slot {
    VoxelKey key{};
    std::uint32_t value = kEmpty;
  };

  // The table is kept at most a quarter full (insert() grows it beyond): short probe runs are worth
  // 64-128 bytes of index a block instead of 32-64 (docs/benchmark-log.md, 2026-11-24). Small
  // tables grow fourfold (fewer rehashes while a map fills); from kFourfoldUpTo slots (1 MiB) on,
  // twofold, which keeps a large map's index at the quarter-full bound.
  static constexpr std::size_t kFourfoldUpTo = std::size_t{1} << 16;
  void grow() {
    std::vector<Slot> old(slots_.size() * (slots_.size() < kFourfoldUpTo ? 4 : 2), Slot{});
    old.swap(slots_);
    size_ = 0;
    for (const Slot& s : old)
      if (s.value != kEmpty) insert(s.key, s.value);
  }

  std::vector<Slot> slots_;
  std::size_t size_ = 0;
};

}  // namespace iwlomap::detail
