// SPDX-License-Identifier: BSD-3-Clause
#include "storage/block_grid.h"

#include "iwlomap/map_memory.h"
#include "storage/memory_limit.h"

#include <sys/mman.h>

#include <algorithm>
#include <cstring>
#include <mutex>
#include <new>
#include <utility>
#include <vector>

namespace iwlomap::detail {

namespace {

constexpr std::size_t kFirstSlab = 64 * 1024;
constexpr std::size_t kLargestSlab = kLargestSlabBytes;

// Slabs come from mmap, not malloc: glibc raises its mmap threshold after large frees and then
// serves big blocks from a reused heap, which made every map after the first one in a process
// markedly slower to fill. No transparent huge pages: with the kernel's default defrag policy a
// large map stalled in page compaction at random.
//
// Slabs that arenas give back are cached, up to kCachedBytes, while any arena is alive: the
// kernel's first touch of a fresh page (fault, zeroing) costs more than filling it with voxels,
// so a map built after another one, or a Disk tile loaded after an eviction, takes them instead.
// When the last arena goes, the cache keeps only what set_retained_map_memory() asks for. Users
// of a slab never rely on its contents.
constexpr std::size_t kCachedBytes = 64 * 1024 * 1024;

class SlabCache {
 public:
  SlabCache() { slabs_.reserve(kCachedBytes / kFirstSlab); }

  void* take(std::size_t size) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (std::size_t i = 0; i < slabs_.size(); ++i) {
      if (slabs_[i].second != size) continue;
      void* p = slabs_[i].first;
      slabs_[i] = slabs_.back();
      slabs_.pop_back();
      bytes_ -= size;
      return p;
    }
    return nullptr;
  }
  bool give(void* p, std::size_t size) noexcept {
    std::lock_guard<std::mutex> lock(mutex_);
    if (bytes_ + size > kCachedBytes || slabs_.size() == slabs_.capacity()) return false;
    slabs_.emplace_back(p, size);  // no allocation: capacity reserved up front
    bytes_ += size;
    return true;
  }
  void attach() noexcept {
    std::lock_guard<std::mutex> lock(mutex_);
    ++arenas_;
  }
  void detach() noexcept {
    std::lock_guard<std::mutex> lock(mutex_);
    if (--arenas_ == 0) trim(retained_);
  }
  void set_retained(std::size_t bytes) noexcept {
    std::lock_guard<std::mutex> lock(mutex_);
    retained_ = std::min(bytes, kCachedBytes);
    if (arenas_ == 0) trim(retained_);
  }
  std::size_t retained() noexcept {
    std::lock_guard<std::mutex> lock(mutex_);
    return retained_;
  }
  std::size_t bytes() noexcept {
    std::lock_guard<std::mutex> lock(mutex_);
    return bytes_;
  }

 private:
  // Unmaps cached slabs, largest first, until at most \p limit bytes are left. Holds the lock.
  void trim(std::size_t limit) noexcept {
    std::sort(slabs_.begin(), slabs_.end(), [](const auto& a, const auto& b) { return a.second < b.second; });
    while (bytes_ > limit) {
      munmap(slabs_.back().first, slabs_.back().second);
      bytes_ -= slabs_.back().second;
      slabs_.pop_back();
    }
  }

  std::mutex mutex_;
  std::vector<std::pair<void*, std::size_t>> slabs_;
  std::size_t bytes_ = 0;
  std::size_t arenas_ = 0;
  std::size_t retained_ = 0;
};

SlabCache& slab_cache() {
  static SlabCache* cache = new SlabCache;  // never destroyed: maps may outlive static destructors
  return *cache;
}

void* map_slab(std::size_t size) {
  if (void* p = slab_cache().take(size)) return p;
  void* p = mmap(nullptr, size, PROT_READ | PROT_WRITE, MAP_PRIVATE | MAP_ANONYMOUS, -1, 0);
  if (p == MAP_FAILED) throw std::bad_alloc();
  return p;
}

void unmap_slab(void* p, std::size_t size) noexcept {
  if (!slab_cache().give(p, size)) munmap(p, size);
}

}  // namespace

SlabArena::SlabArena() { slab_cache().attach(); }

SlabArena::~SlabArena() {
  release();
  slab_cache().detach();
}

void* SlabArena::allocate_in_new_slab(std::size_t size) {
  const std::size_t slab = slabs_.empty() ? kFirstSlab : std::min(kLargestSlab, slabs_.back().size * 2);
  if (slabs_.size() == slabs_.capacity()) slabs_.reserve(2 * slabs_.size() + 8);  // a failing push_back would lose the slab
  charge_map_memory(slab);
  void* memory = nullptr;
  try {
    memory = map_slab(slab);
  } catch (...) {
    uncharge_map_memory(slab);
    throw;
  }
  slabs_.push_back({memory, slab});
  bytes_ += slab;
  capacity_ = slab;
  used_ = size;
  return slabs_.back().memory;
}

void SlabArena::release() noexcept {
  for (const Slab& s : slabs_) unmap_slab(s.memory, s.size);
  uncharge_map_memory(bytes_);
  slabs_.clear();
  used_ = capacity_ = bytes_ = 0;
}

VoxelBlock& BlockGrid::get_or_create_missed(const VoxelKey& block_key, std::size_t slot) {
  const auto next = static_cast<std::uint32_t>(blocks_.size());
  const std::uint32_t i = index_.insert(block_key, next);
  if (i == next) blocks_.push_back(new (headers_->allocate(sizeof(VoxelBlock), alignof(VoxelBlock))) VoxelBlock(block_key));
  VoxelBlock* const b = blocks_[i];
  (*recent_)[slot] = b;
  return *b;
}

void BlockGrid::add_cells(VoxelBlock& b, const CellMask& added) {
  const CellGrowth g = reserve_cells(b, added);
  finish_cells(g, added);
  release_old_cells(g);
}

// New cells go to the end of the block's array, so no cell ever moves within it; the array
// doubles when full (one copy of the cells, amortised below one per added cell).
BlockGrid::CellGrowth BlockGrid::reserve_cells(VoxelBlock& b, const CellMask& added) {
  const int old_count = b.num_cells();
  const int count = old_count + added.count();
  const CellGrowth g{&b, b.cells, old_count, 0};
  const int new_class = CellPool::class_of(count);
  if (b.cells == nullptr || new_class != CellPool::class_of(old_count)) b.cells = cells_pool_->allocate(new_class);
  cells_ += static_cast<std::size_t>(count - old_count);
  return g;
}

void BlockGrid::finish_cells(const CellGrowth& g, const CellMask& added) noexcept {
  VoxelBlock& b = *g.block;
  if (g.from != nullptr && g.from != b.cells)
    std::memcpy(static_cast<void*>(b.cells), g.from, sizeof(Cell) * static_cast<std::size_t>(g.old_count));
  int at = g.old_count;
  added.for_each([&](int c) {
    new (&b.cells[at]) Cell{};
    b.position[static_cast<std::size_t>(c)] = static_cast<std::uint8_t>(at);
    ++at;
  });
  b.cell_mask |= added;
}

void BlockGrid::release_old_cells(const CellGrowth& g) noexcept {
  if (g.from != nullptr && g.from != g.block->cells) cells_pool_->free(g.from, CellPool::class_of(g.old_count));
}

BlockGrid BlockGrid::clone() const {
  BlockGrid copy;
  for (const VoxelBlock* b : blocks_) {
    VoxelBlock& c = copy.get_or_create(b->key);
    copy.ensure_cells(c, b->cell_mask);
    b->for_each_slot([&c](int i, const Voxel& v) { c.existing(i) = v; });
    c.known = b->known;
  }
  return copy;
}

void BlockGrid::add_dense(const DenseBlock& dense) {
  VoxelBlock& b = get_or_create(dense.key);
  CellMask mask;
  for (int i = 0; i < kBlockVoxels; ++i)
    if (dense.voxels[static_cast<std::size_t>(i)].known()) mask |= CellMask::of(i >> kCellShift);
  ensure_cells(b, mask);
  b.for_each_slot([&](int i, const Voxel&) { b.existing(i) = dense.voxels[static_cast<std::size_t>(i)]; });
  b.known = dense.known;
}

std::size_t BlockGrid::prune() {
  auto headers = std::make_unique<SlabArena>();
  auto pool = std::make_unique<CellPool>();
  std::vector<VoxelBlock*> kept;
  const std::size_t slots_before = num_slots();
  std::size_t cells = 0;
  for (VoxelBlock* b : blocks_) {
    if (b->known == 0) continue;
    // Keep the cells holding a known voxel.
    CellMask mask;
    b->for_each_slot([&](int i, const Voxel& v) {
      if (v.known()) mask |= CellMask::of(i >> kCellShift);
    });
    auto* copy = new (headers->allocate(sizeof(VoxelBlock), alignof(VoxelBlock))) VoxelBlock(b->key);
    copy->known = b->known;
    copy->cell_mask = mask;
    const int n = mask.count();
    copy->cells = pool->allocate(CellPool::class_of(n));
    int r = 0;
    mask.for_each([&](int cell) {
      const auto c = static_cast<std::size_t>(cell);
      new (&copy->cells[r]) Cell(b->cells[b->position[c]]);
      copy->position[c] = static_cast<std::uint8_t>(r);
      ++r;
    });
    cells += static_cast<std::size_t>(n);
    kept.push_back(copy);
  }
  kept.shrink_to_fit();
  blocks_.swap(kept);
  recent_->fill(nullptr);
  headers_ = std::move(headers);
  cells_pool_ = std::move(pool);
  cells_ = cells;
  index_.reset(blocks_.size());
  for (std::uint32_t i = 0; i < blocks_.size(); ++i) index_.insert(blocks_[i]->key, i);
  return slots_before - num_slots();
}

void BlockGrid::clear() {
  blocks_.clear();
  blocks_.shrink_to_fit();
  headers_ = std::make_unique<SlabArena>();
  cells_pool_ = std::make_unique<CellPool>();
  index_.reset();
  cells_ = 0;
  recent_ = std::make_unique<std::array<VoxelBlock*, kRecentSlots>>();  // also after a move
}

}  // namespace iwlomap::detail

namespace iwlomap {

void set_retained_map_memory(std::size_t bytes) { detail::slab_cache().set_retained(bytes); }
std::size_t get_retained_map_memory() { return detail::slab_cache().retained(); }
std::size_t get_cached_map_memory() { return detail::slab_cache().bytes(); }

}  // namespace iwlomap
