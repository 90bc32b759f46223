// SPDX-License-Identifier: BSD-3-Clause
#include "detail/block_grid.h"

#include <sys/mman.h>

#include <cstdlib>
#include <new>

namespace iwlomap::detail {

namespace {
constexpr std::size_t kFirstSlab = 64 * 1024;
constexpr std::size_t kHugePage = 2 * 1024 * 1024;
}  // namespace

VoxelBlock* BlockPool::allocate(const VoxelKey& key) {
  if (used_ + sizeof(VoxelBlock) > capacity_) {
    const std::size_t size = slabs_.empty() ? kFirstSlab : std::min(kHugePage, slabs_.back().size * 2);
    void* memory = std::aligned_alloc(size == kHugePage ? kHugePage : alignof(VoxelBlock), size);
    if (memory == nullptr) throw std::bad_alloc();
#ifdef MADV_HUGEPAGE
    if (size == kHugePage) (void)madvise(memory, size, MADV_HUGEPAGE);  // advice only; failure is harmless
#endif
    slabs_.push_back({memory, size});
    bytes_ += size;
    used_ = 0;
    capacity_ = size;
  }
  void* at = static_cast<char*>(slabs_.back().memory) + used_;
  used_ += sizeof(VoxelBlock);
  return new (at) VoxelBlock(key);
}

void BlockPool::release() noexcept {
  // VoxelBlock is trivially destructible: the slabs can go without visiting each block.
  for (const Slab& s : slabs_) std::free(s.memory);
  slabs_.clear();
  used_ = capacity_ = bytes_ = 0;
}

}  // namespace iwlomap::detail
