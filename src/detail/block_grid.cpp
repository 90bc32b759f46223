// SPDX-License-Identifier: BSD-3-Clause
#include "detail/block_grid.h"

#include <sys/mman.h>

#include <algorithm>
#include <new>

namespace iwlomap::detail {

namespace {

constexpr std::size_t kFirstSlab = 64 * 1024;
constexpr std::size_t kLargestSlab = 2 * 1024 * 1024;

// Slabs come straight from mmap: fresh zero pages every time, and none of malloc's heuristics
// (glibc raises its mmap threshold after large frees and then serves big blocks from a reused
// heap, which made every map after the first one in a process markedly slower to fill).
// Transparent huge pages were tried (madvise): they halved the cost of filling an empty map with
// a surface batch, but with the kernel's default defrag policy a large map then stalled in page
// compaction at random, doubling some scans; predictable times won.
void* map_slab(std::size_t size) {
  void* p = mmap(nullptr, size, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (p == MAP_FAILED) throw std::bad_alloc();
  return p;
}

}  // namespace

VoxelBlock* BlockPool::allocate(const VoxelKey& key) {
  if (used_ + sizeof(VoxelBlock) > capacity_) {
    const std::size_t size = slabs_.empty() ? kFirstSlab : std::min(kLargestSlab, slabs_.back().size * 2);
    slabs_.push_back({map_slab(size), size});
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
  for (const Slab& s : slabs_) munmap(s.memory, s.size);
  slabs_.clear();
  used_ = capacity_ = bytes_ = 0;
}

}  // namespace iwlomap::detail
