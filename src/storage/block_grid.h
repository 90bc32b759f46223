// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The sparse block grid behind every backend's voxels (the RAM map, the Disk backend's resident
// tiles, the OctoMap backend's exact state). Voxels live in 8^3 blocks found through a FlatKeyMap
// keyed by block coordinate; inside a block they are stored in cells of 2 x 2 x 1 voxels (16
// bytes), allocated on first touch. A block keeps a 128-bit mask of its allocated cells, one
// array holding them in allocation order and a table of their positions in it: finding a voxel is
// one byte of the block header away, and a new cell goes to the end of the array without moving
// the others.
//
// Why cells: a surface (the endpoints of a scan, a sonar footprint) touches about ten voxels of
// each 8^3 block it crosses, so dense blocks would cost 4 KiB a block for a few voxels. Why
// 2 x 2 x 1: the ground and most surfaces lie closer to horizontal than to vertical, and this shape
// fills fewest cells on the synthetic and the Ouster scans of any 4-voxel shape (figures in
// docs/benchmark-log.md, 2026-11-21). A block filled by free space costs 4 bytes a voxel plus its 192-byte header.
//
// A voxel is one 4-byte word in the map's iwlomap::iwlo::VoxelFormat (fixed-point log-odds above a
// saturating count), so an update reads and writes one word. The grid stores words and does not
// know the format: the backend's Updater encodes and decodes them. A word of 0 means "unknown";
// every observed voxel has count >= 1, so its word is not 0.

#include "storage/flat_key_map.h"
#include "iwlomap/voxel_key.h"

#include <array>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <new>
#include <type_traits>
#include <vector>

namespace iwlomap::detail {

inline constexpr int kBlockShift = 3;
inline constexpr int kBlockEdge = 1 << kBlockShift;                 // voxels along a block edge
inline constexpr int kBlockVoxels = kBlockEdge * kBlockEdge * kBlockEdge;  // 512
inline constexpr int kCellShift = 2;
inline constexpr int kCellVoxels = 1 << kCellShift;                 // a cell is 2 x 2 x 1 voxels
inline constexpr int kBlockCells = kBlockVoxels / kCellVoxels;      // 128

// Arithmetic right shift is floor division by 8 for negative keys too (guaranteed by GCC and
// Clang, and by the standard from C++20).
static_assert((-1 >> 1) == -1, "iwlomap needs arithmetic right shift of negative integers");

[[nodiscard]] inline VoxelKey block_of(const VoxelKey& k) noexcept {
  return {k.x >> kBlockShift, k.y >> kBlockShift, k.z >> kBlockShift};
}

// The index of a voxel inside its block is cell-major: bits 2..8 name the cell (x and y of the
// cell 2 bits each, then z 3 bits), bits 0..1 the voxel inside the cell. So the 4 voxels of a
// cell are 4 consecutive indices, and one nibble of a 512-bit block mask (the scan scratch's) is
// one cell.
[[nodiscard]] constexpr int index_in_block(const VoxelKey& k) noexcept {
  const int cell = ((k.x >> 1) & 3) | (((k.y >> 1) & 3) << 2) | ((k.z & 7) << 4);
  return (cell << kCellShift) | (k.x & 1) | ((k.y & 1) << 1);
}
[[nodiscard]] inline VoxelKey voxel_of(const VoxelKey& block, int index) noexcept {
  const int cell = index >> kCellShift;
  return {block.x * kBlockEdge + ((cell & 3) << 1) + (index & 1),
          block.y * kBlockEdge + (((cell >> 2) & 3) << 1) + ((index >> 1) & 1),
          block.z * kBlockEdge + (cell >> 4)};
}

/// Number of set bits. Without a -m flag that enables the popcnt instruction, GCC makes
/// __builtin_popcountll a library call; the bit-parallel sum is a dozen inline instructions.
[[nodiscard]] inline int popcount64(std::uint64_t x) noexcept {
#if defined(__POPCNT__)
  return __builtin_popcountll(x);
#else
  x = x - ((x >> 1) & 0x5555555555555555ull);
  x = (x & 0x3333333333333333ull) + ((x >> 2) & 0x3333333333333333ull);
  x = (x + (x >> 4)) & 0x0f0f0f0f0f0f0f0full;
  return static_cast<int>((x * 0x0101010101010101ull) >> 56);
#endif
}

/// A set of the 128 cells of a block: bit c % 64 of word c / 64 is cell c.
struct CellMask {
  std::array<std::uint64_t, 2> word{};

  [[nodiscard]] static CellMask of(int cell) noexcept {
    CellMask m;
    m.word[static_cast<std::size_t>(cell >> 6)] = std::uint64_t{1} << (cell & 63);
    return m;
  }
  [[nodiscard]] bool any() const noexcept { return (word[0] | word[1]) != 0; }
  [[nodiscard]] bool has(int cell) const noexcept {
    return ((word[static_cast<std::size_t>(cell >> 6)] >> (cell & 63)) & 1u) != 0;
  }
  [[nodiscard]] int count() const noexcept { return popcount64(word[0]) + popcount64(word[1]); }
  [[nodiscard]] CellMask without(const CellMask& o) const noexcept {  // this & ~o
    CellMask m;
    m.word[0] = word[0] & ~o.word[0];
    m.word[1] = word[1] & ~o.word[1];
    return m;
  }
  CellMask& operator|=(const CellMask& o) noexcept {
    word[0] |= o.word[0];
    word[1] |= o.word[1];
    return *this;
  }
  /// Calls fn(cell) for every cell of the set, in increasing order.
  template <class Fn>
  void for_each(Fn&& fn) const {
    for (std::size_t w = 0; w < word.size(); ++w)
      for (std::uint64_t m = word[w]; m != 0; m &= m - 1) fn(static_cast<int>(w * 64) + __builtin_ctzll(m));
  }
};

/// The cells holding any set bit of 64-bit word \p w of a 512-bit block mask in index_in_block()
/// order: the word covers cells 16w .. 16w + 15, one nibble each.
[[nodiscard]] inline CellMask cells_of_mask_word(std::uint64_t word, int w) noexcept {
  std::uint64_t t = word | (word >> 2);
  t |= t >> 1;
  t &= 0x1111111111111111ull;  // bit 0 of each nibble: "this cell has a bit"
  // Gather the 16 bits at 4i into bits i: pairs, then fours, eights, sixteen.
  t = (t | (t >> 3)) & 0x0303030303030303ull;
  t = (t | (t >> 6)) & 0x000f000f000f000full;
  t = (t | (t >> 12)) & 0x000000ff000000ffull;
  t = (t | (t >> 24)) & 0xffffull;
  CellMask m;
  m.word[static_cast<std::size_t>(w >> 2)] = t << (16 * (w & 3));
  return m;
}

struct Voxel {
  std::uint32_t word = 0;  // iwlo::VoxelFormat of the map; 0: unknown
  [[nodiscard]] bool known() const noexcept { return word != 0; }
};
static_assert(sizeof(Voxel) == 4, "a voxel is 4 bytes");

struct alignas(16) Cell {
  std::array<Voxel, kCellVoxels> voxels{};
};
static_assert(sizeof(Cell) == 16, "a cell is a quarter of a cache line");

/// An 8^3 block: a header of 192 bytes whose first cache line holds everything a batch looks at
/// before it reaches a voxel (key, mask, cell array); its cells live in one array owned by the
/// grid's CellPool, in the order they were allocated, and a table gives each cell's position.
struct alignas(64) VoxelBlock {
  explicit VoxelBlock(const VoxelKey& k) : key(k) {}
  VoxelKey key;
  std::uint32_t known = 0;  // voxels with a count (a word other than 0)
  CellMask cell_mask;       // the allocated cells
  Cell* cells = nullptr;    // the allocated cells, cell_mask.count() of them
  CellMask pending;         // cells a batch in progress needs (RAM, Disk); empty between calls
  // Position of cell c in `cells`, when allocated; left uninitialised otherwise (a new block
  // writes only its first cache line).
  std::array<std::uint8_t, kBlockCells> position;

  [[nodiscard]] int num_cells() const noexcept { return cell_mask.count(); }
  [[nodiscard]] bool has_cell(int cell) const noexcept { return cell_mask.has(cell); }
  /// Notes \p cell in `pending`, for a batch that allocates its blocks' missing cells together.
  void note_pending(int cell) noexcept {
    pending.word[static_cast<std::size_t>(cell >> 6)] |= std::uint64_t{1} << (cell & 63);
  }
  /// The voxel at \p index; its cell must be allocated.
  [[nodiscard]] Voxel& existing(int index) noexcept {
    return cells[position[static_cast<std::size_t>(index >> kCellShift)]]
        .voxels[static_cast<std::size_t>(index & (kCellVoxels - 1))];
  }
  [[nodiscard]] const Voxel& existing(int index) const noexcept {
    return cells[position[static_cast<std::size_t>(index >> kCellShift)]]
        .voxels[static_cast<std::size_t>(index & (kCellVoxels - 1))];
  }
  /// The voxel at \p index, or nullptr when its cell is not allocated (so the voxel is unknown).
  [[nodiscard]] const Voxel* find(int index) const noexcept {
    return has_cell(index >> kCellShift) ? &existing(index) : nullptr;
  }
  /// Calls fn(index, voxel) for every voxel of every allocated cell (unknown ones included), in
  /// index order.
  template <class Fn>
  void for_each_slot(Fn&& fn) const {
    cell_mask.for_each([&](int c) {
      const Cell& cell = cells[position[static_cast<std::size_t>(c)]];
      for (int v = 0; v < kCellVoxels; ++v) fn(c * kCellVoxels + v, cell.voxels[static_cast<std::size_t>(v)]);
    });
  }
};
static_assert(sizeof(VoxelBlock) == 192, "a block header is 192 bytes");

/// A block with all 512 voxels in place (index_in_block() order), for reading and writing tile
/// files.
struct DenseBlock {
  VoxelKey key{};
  std::uint32_t known = 0;
  std::array<Voxel, kBlockVoxels> voxels{};
};

static_assert(std::is_trivially_destructible_v<VoxelBlock> && std::is_trivially_destructible_v<Cell>,
              "the pools release slabs without destroying what they hold");

// Block headers and cells are carved out of slabs rather than allocated one by one: a map of
// millions of voxels allocates thousands of blocks per scan, and one heap allocation each cost
// more than updating them. Slabs grow from 64 KiB to 2 MiB, come from mmap and go back to a
// process-wide cache for reuse (see block_grid.cpp and iwlomap/map_memory.h).
/// The largest slab an arena maps at once (they grow from 64 KiB).
inline constexpr std::size_t kLargestSlabBytes = 2 * 1024 * 1024;

class SlabArena {
 public:
  SlabArena();
  SlabArena(const SlabArena&) = delete;
  SlabArena& operator=(const SlabArena&) = delete;
  ~SlabArena();

  /// \p size bytes (at most 4 KiB) aligned to \p align (a power of two, at most 64); zero-filled
  /// when fresh from the kernel, but callers must not rely on it.
  void* allocate(std::size_t size, std::size_t align) {
    const std::size_t at = (used_ + align - 1) & ~(align - 1);
    if (at + size > capacity_) return allocate_in_new_slab(size);
    used_ = at + size;
    return static_cast<char*>(slabs_.back().memory) + at;
  }
  void release() noexcept;
  [[nodiscard]] std::size_t bytes() const noexcept { return bytes_; }

 private:
  struct Slab {
    void* memory;
    std::size_t size;
  };
  void* allocate_in_new_slab(std::size_t size);

  std::vector<Slab> slabs_;
  std::size_t used_ = 0;      // bytes used in the last slab
  std::size_t capacity_ = 0;  // bytes in the last slab
  std::size_t bytes_ = 0;     // all slabs
};

/// Storage of the cell arrays of blocks: arrays of 1, 2, 4, ..., 128 cells (size class k holds 2^k
/// cells). A block's array grows to the next class when a cell is added to a full one (one copy
/// of its cells); the old array goes to a free list of its class and is reused by the next array
/// of that size.
class CellPool {
 public:
  static constexpr int kClasses = 8;
  [[nodiscard]] static int class_of(int cells) noexcept {  // smallest class holding \p cells (>= 1)
    return cells <= 1 ? 0 : 32 - __builtin_clz(static_cast<unsigned>(cells - 1));
  }
  // A free array keeps the link to the next free array of its class in its first bytes, copied in
  // and out with memcpy (the memory held cells before).
  Cell* allocate(int size_class) {
    void*& head = free_[static_cast<std::size_t>(size_class)];
    if (head != nullptr) {
      void* const a = head;
      std::memcpy(&head, a, sizeof head);
      return static_cast<Cell*>(a);
    }
    return static_cast<Cell*>(arena_.allocate(sizeof(Cell) << size_class, alignof(Cell)));
  }
  void free(Cell* cells, int size_class) noexcept {
    void*& head = free_[static_cast<std::size_t>(size_class)];
    std::memcpy(static_cast<void*>(cells), &head, sizeof head);
    head = cells;
  }
  [[nodiscard]] std::size_t bytes() const noexcept { return arena_.bytes(); }

 private:
  SlabArena arena_;
  std::array<void*, kClasses> free_{};  // heads of the lists of free arrays, by class
};

class BlockGrid {
 public:
  BlockGrid() = default;
  BlockGrid(const BlockGrid&) = delete;
  BlockGrid& operator=(const BlockGrid&) = delete;
  // Moving keeps every block and cell where it is (the pools move as pointers).
  BlockGrid(BlockGrid&&) noexcept = default;
  BlockGrid& operator=(BlockGrid&&) noexcept = default;

  [[nodiscard]] VoxelBlock* find(const VoxelKey& block_key) const noexcept {
    const std::uint32_t i = index_.find(block_key);
    return i == FlatKeyMap::kEmpty ? nullptr : blocks_[i];
  }

  VoxelBlock& get_or_create(const VoxelKey& block_key) { return get_or_create(block_key, recent_slot(block_key)); }
  /// get_or_create() for a block whose recent_slot() is known.
  VoxelBlock& get_or_create(const VoxelKey& block_key, std::size_t slot) {
    VoxelBlock* const cached = (*recent_)[slot];
    if (cached != nullptr && cached->key == block_key) return *cached;
    return get_or_create_missed(block_key, slot);
  }
  /// get_or_create() once block_key was not found in the cache of recent blocks. Out of line, so
  /// that the batch loops around the look-up keep their values in registers.
  VoxelBlock& get_or_create_missed(const VoxelKey& block_key, std::size_t slot);

  /// Where block \p k goes in the cache of recent blocks: the top bits of a multiplicative hash
  /// in 32-bit arithmetic (so the batch path computes it vectorised).
  [[nodiscard]] static std::size_t recent_slot(const VoxelKey& k) noexcept {
    const std::uint32_t h = static_cast<std::uint32_t>(k.x) * 0x9E3779B1u + static_cast<std::uint32_t>(k.y) * 0x85EBCA77u +
                            static_cast<std::uint32_t>(k.z) * 0xC2B2AE3Du;
    return static_cast<std::size_t>(h >> (32 - kRecentBits));
  }

  /// Allocates the cells of \p mask that \p b lacks (zero-filled); returns whether there were
  /// any. When b's array grows, its cells move: a Voxel pointer or reference into b taken before
  /// may be invalid afterwards.
  bool ensure_cells(VoxelBlock& b, const CellMask& mask) {
    const CellMask added = mask.without(b.cell_mask);
    if (!added.any()) return false;
    add_cells(b, added);
    return true;
  }

  /// The cells a block gains in one allocation, between reserve_cells() and finish_cells().
  struct CellGrowth {
    VoxelBlock* block;
    Cell* from;              // the block's array before (nullptr: none); b.cells when it did not change
    std::int32_t old_count;  // cells before
    std::uint32_t tag;       // the caller's, unused here
  };
  /// The bookkeeping half of ensure_cells() for \p added (cells that \p b lacks): when b's array
  /// must grow, b.cells becomes a new array of the larger size class. Writes no cell and leaves
  /// b.cell_mask and b.position as they were, so \p b must not be read or written until
  /// finish_cells(). Throws std::bad_alloc or MemoryLimitError with \p b unchanged.
  CellGrowth reserve_cells(VoxelBlock& b, const CellMask& added);
  /// The other half, for the same \p added: moves b's old cells into the new array, zero-fills
  /// the added cells and records their positions and mask. It touches \p g.block and its arrays
  /// only, so different blocks may be finished on different threads at once.
  static void finish_cells(const CellGrowth& g, const CellMask& added) noexcept;
  /// After finish_cells(): the old array, if b's array changed, goes back to this grid's pool. Old
  /// arrays are given back only once every growth of a pass is finished, since another block's
  /// reserve_cells() may take a freed array.
  void release_old_cells(const CellGrowth& g) noexcept;

  /// Voxel \p index of \p b, allocating its cell if needed (which may move b's other cells).
  Voxel& voxel(VoxelBlock& b, int index) {
    ensure_cells(b, CellMask::of(index >> kCellShift));
    return b.existing(index);
  }

  /// A deep copy: the same blocks in the same order, each with the same voxels.
  [[nodiscard]] BlockGrid clone() const;

  /// Stores \p dense (its known voxels; the others stay unknown) as the block \p dense.key, which
  /// must not be in the grid yet.
  void add_dense(const DenseBlock& dense);

  [[nodiscard]] const std::vector<VoxelBlock*>& blocks() const noexcept { return blocks_; }
  [[nodiscard]] std::size_t num_blocks() const noexcept { return blocks_.size(); }
  /// Known voxels in all blocks (a walk over the blocks).
  [[nodiscard]] std::size_t known_voxels() const noexcept {
    std::size_t n = 0;
    for (const VoxelBlock* b : blocks_) n += b->known;
    return n;
  }
  /// Voxel slots allocated (kCellVoxels per cell).
  [[nodiscard]] std::size_t num_slots() const noexcept { return cells_ * kCellVoxels; }

  /// Drops blocks and cells without known voxels (copying the rest into fresh slabs, so the
  /// memory is given back, to the slab cache or the system) and shrinks the index to fit;
  /// returns the voxel slots freed.
  std::size_t prune();

  void clear();

  /// Bytes held: slabs of block headers and cells, the block pointer array, the index and the
  /// cache of recent blocks.
  [[nodiscard]] std::size_t bytes() const noexcept {
    return headers_->bytes() + cells_pool_->bytes() + blocks_.capacity() * sizeof(blocks_[0]) + index_.bytes() +
           sizeof(*recent_);
  }

 private:
  void add_cells(VoxelBlock& b, const CellMask& added);

  // A direct-mapped cache of recently used blocks in front of the index: a scan's points run along
  // rings, and a ring comes back to the blocks of the previous ring about a thousand points later,
  // so most block changes of a batch hit here instead of walking the index (hash, slot, block
  // pointer: three dependent cache misses on a large map). Slots come from a hash of the block
  // coordinate, not from its low bits, which made blocks 16 apart on the ground collide. Only the
  // writing path uses it; find() stays free of side effects for concurrent readers.
  static constexpr int kRecentBits = 11;
  static constexpr std::size_t kRecentSlots = std::size_t{1} << kRecentBits;
  std::unique_ptr<std::array<VoxelBlock*, kRecentSlots>> recent_ =
      std::make_unique<std::array<VoxelBlock*, kRecentSlots>>();

  std::unique_ptr<SlabArena> headers_ = std::make_unique<SlabArena>();
  std::unique_ptr<CellPool> cells_pool_ = std::make_unique<CellPool>();
  std::vector<VoxelBlock*> blocks_;
  FlatKeyMap index_;
  std::size_t cells_ = 0;
};

/// Writing accessor with a last-block cache: consecutive updates in one block skip the hash look-up.
class BlockAccessor {
 public:
  explicit BlockAccessor(BlockGrid& grid) : grid_(&grid) {}
  VoxelBlock& block(const VoxelKey& block_key) {
    if (last_ == nullptr || last_->key != block_key) last_ = &grid_->get_or_create(block_key);
    return *last_;
  }
  /// Voxel \p key (its block and cell allocated if needed); \p b receives its block.
  Voxel& voxel(const VoxelKey& key, VoxelBlock*& b) {
    b = &block(block_of(key));
    return grid_->voxel(*b, index_in_block(key));
  }

 private:
  BlockGrid* grid_;
  VoxelBlock* last_ = nullptr;
};

}  // namespace iwlomap::detail
