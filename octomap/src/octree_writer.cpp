// SPDX-License-Identifier: BSD-3-Clause
#include "octree_writer.h"

#include "octomap_keys.h"
#include "backends/backend_access.h"
#include "model/probability_above.h"

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <ostream>
#include <sstream>
#include <stdexcept>

namespace iwlomap::detail {

namespace {

// The 16 bits of v spread to bits 0, 3, 6, ... 45.
constexpr std::uint64_t spread3(std::uint64_t v) noexcept {
  v &= 0xffff;
  v = (v | (v << 32)) & 0x001f00000000ffffull;
  v = (v | (v << 16)) & 0x001f0000ff0000ffull;
  v = (v | (v << 8)) & 0x100f00f00f00f00full;
  v = (v | (v << 4)) & 0x10c30c30c30c30c3ull;
  v = (v | (v << 2)) & 0x1249249249249249ull;
  return v;
}

// The position of a voxel in OctoMap's depth-first order is its OctoMap key's bits interleaved, x
// lowest, as OcTreeKey's computeChildIdx() numbers the 8 children of a node (x = 1, y = 2, z = 4):
// bits 45..47 pick the child of the root, bits 0..2 the voxel among its 7 siblings. The bits
// from 9 up are the block's code (its key's bits interleaved), the 9 below the voxel's in it.
std::uint64_t block_code(const VoxelKey& block) noexcept {
  constexpr std::int32_t kBlockOffset = kKeyOffset >> kBlockShift;
  return spread3(static_cast<std::uint64_t>(block.x + kBlockOffset)) |
         (spread3(static_cast<std::uint64_t>(block.y + kBlockOffset)) << 1) |
         (spread3(static_cast<std::uint64_t>(block.z + kBlockOffset)) << 2);
}
// The Morton code inside its block of the voxel at index_in_block() i.
struct LocalCodes {
  std::uint16_t of_index[kBlockVoxels];
  LocalCodes() noexcept {
    for (int i = 0; i < kBlockVoxels; ++i) {
      const VoxelKey k = voxel_of(VoxelKey{0, 0, 0}, i);
      of_index[i] = static_cast<std::uint16_t>(spread3(static_cast<std::uint64_t>(k.x)) |
                                               (spread3(static_cast<std::uint64_t>(k.y)) << 1) |
                                               (spread3(static_cast<std::uint64_t>(k.z)) << 2));
    }
  }
};
const LocalCodes kLocalCodes;

constexpr unsigned kBlockDepth = kTreeDepth - kBlockShift;  // depth of an 8^3 block's node: 13

// The 8 bits of v spread to bits 0, 2, ... 14.
constexpr unsigned spread2(unsigned v) noexcept {
  v &= 0xffu;
  v = (v | (v << 4)) & 0x0f0fu;
  v = (v | (v << 2)) & 0x3333u;
  v = (v | (v << 1)) & 0x5555u;
  return v;
}

}  // namespace

OctreeStream::OctreeStream(const IMapperBackend& map, FileFormat format, double occupied_threshold,
                           const std::string& path)
    : format_(format) {
  const ProbabilityAbove occupied(occupied_threshold);
  if (format_ == FileFormat::kFull) {
    local_.reserve(std::min<std::size_t>(map.get_num_known_voxels(), std::size_t{1} << 32));
    values_.reserve(local_.capacity());
  }
  BackendAccess::for_each_known_block(map, [&](const VoxelKey& block, const std::uint16_t* index,
                                               const float* log_odds, std::size_t n) {
    if (!block_in_octomap_range(block)) {
      for (std::size_t i = 0; i < n; ++i) {
        const VoxelKey k = voxel_of(block, index[i]);
        if (!in_octomap_range(k))
          throw std::out_of_range("iwlomap: export_octomap('" + path + "'): voxel " + describe_key(k) +
                                  " lies outside OctoMap's key range [" + std::to_string(kMinKey) + ", " +
                                  std::to_string(kMaxKey) + "] per axis; an OctoMap file cannot hold it");
      }
    }
    if (format_ == FileFormat::kBinary) {  // the run's voxels as two 512-bit masks, known and occupied
      runs_.push_back(Run{block_code(block), masks_.size(), 1});
      masks_.resize(masks_.size() + 1);
      BlockMasks& m = masks_.back();
      for (std::size_t i = 0; i < n; ++i) {
        const unsigned code = kLocalCodes.of_index[index[i]];
        const std::uint64_t bit = std::uint64_t{1} << (code & 63);
        m.known[code >> 6] |= bit;
        m.occupied[code >> 6] = occupied(log_odds[i]) ? (m.occupied[code >> 6] | bit) : (m.occupied[code >> 6] & ~bit);
      }
      return;
    }
    runs_.push_back(Run{block_code(block), local_.size(), static_cast<std::uint32_t>(n)});
    const std::size_t at = local_.size();
    local_.resize(at + n);
    std::uint16_t* local = local_.data() + at;
    for (std::size_t i = 0; i < n; ++i) local[i] = kLocalCodes.of_index[index[i]];
    values_.insert(values_.end(), log_odds, log_odds + n);
  });
  // Blocks in depth-first order; a block the map visited in several runs keeps them in visiting
  // order, so a voxel visited twice ends with its last value, as set_leaf() would leave it.
  std::stable_sort(runs_.begin(), runs_.end(), [](const Run& a, const Run& b) { return a.block < b.block; });
}

void OctreeStream::leaf_record(float value) {
  if (format_ == FileFormat::kBinary) return;  // a .bt leaf is two bits of its parent's record
  char* record = data_.grow(sizeof(float) + 1);
  std::memcpy(record, &value, sizeof(float));
  record[sizeof(float)] = 0;
}

// Emits a node whose children child(i, node) reports (false: no child i), after their records:
// the record goes before them (it is reserved first and filled last). Like OcTree::prune(), a
// node whose 8 children are leaves of one value becomes a leaf of that value, its children's
// records dropped; the root never does.
template <class Child>
OctreeStream::Node OctreeStream::inner_node(bool may_collapse, Child&& child) {
  const std::size_t at = data_.size();
  const std::uint64_t nodes_before = nodes_++;
  data_.grow(format_ == FileFormat::kBinary ? 2 : sizeof(float) + 1);
  Node kids[8];
  bool exists[8];
  bool collapse = may_collapse;
  for (unsigned i = 0; i < 8; ++i) {
    exists[i] = child(i, kids[i]);
    collapse = collapse && exists[i] && kids[i].leaf && kids[i].value == kids[0].value;
  }
  if (collapse) {
    data_.truncate(at);
    nodes_ = nodes_before + 1;
    leaf_record(kids[0].value);
    return Node{true, kids[0].value};
  }
  if (format_ == FileFormat::kBinary) {
    // Two bits a child, child 0 lowest: 01 free leaf, 10 occupied leaf, 11 inner node, 00 none.
    unsigned bits[2] = {0, 0};
    for (unsigned i = 0; i < 8; ++i) {
      if (!exists[i]) continue;
      const unsigned code = !kids[i].leaf ? 3u : (kids[i].value >= 0.0f ? 2u : 1u);
      bits[i / 4] |= code << (2 * (i % 4));
    }
    data_.at(at)[0] = static_cast<char>(bits[0]);
    data_.at(at)[1] = static_cast<char>(bits[1]);
    return Node{false, 0.0f};
  }
  // .ot: the largest child log-odds (updateInnerOccupancy()), then one bit per existing child.
  float largest = -std::numeric_limits<float>::max();
  unsigned mask = 0;
  for (unsigned i = 0; i < 8; ++i) {
    if (!exists[i]) continue;
    mask |= 1u << i;
    if (kids[i].value > largest) largest = kids[i].value;
  }
  std::memcpy(data_.at(at), &largest, sizeof(float));
  data_.at(at)[sizeof(float)] = static_cast<char>(mask);
  return Node{false, largest};
}

// A node above the blocks, at \p depth < 13, holding runs [first_run, end_run) (all non-empty).
OctreeStream::Node OctreeStream::upper_node(unsigned depth, std::size_t first_run, std::size_t end_run) {
  if (depth == kBlockDepth) {
    load_block(first_run, end_run);
    return block_node(kBlockShift, 0);
  }
  const unsigned shift = 3 * (kBlockDepth - 1 - depth);  // bits of the block code naming the child
  std::size_t cursor = first_run;
  return inner_node(depth > 0, [&](unsigned i, Node& node) {
    std::size_t end = cursor;
    while (end < end_run && ((runs_[end].block >> shift) & 7u) == i) ++end;
    if (end == cursor) return false;
    node = upper_node(depth + 1, cursor, end);
    cursor = end;
    return true;
  });
}

void OctreeStream::load_block(std::size_t first_run, std::size_t end_run) {
  // A report every 64 blocks or so: a block takes about a microsecond.
  if ((runs_written_ >> 6) != ((runs_written_ + end_run - first_run) >> 6)) report_->report(runs_written_);
  runs_written_ += end_run - first_run;
  std::fill(std::begin(known_), std::end(known_), 0);
  std::fill(std::begin(occupied_), std::end(occupied_), 0);
  for (std::size_t r = first_run; r < end_run; ++r) {
    if (format_ == FileFormat::kBinary) {
      const BlockMasks& m = masks_[runs_[r].begin];
      for (int w = 0; w < 8; ++w) {  // a voxel visited twice keeps its last state
        occupied_[w] = (occupied_[w] & ~m.known[w]) | m.occupied[w];
        known_[w] |= m.known[w];
      }
      continue;
    }
    for (std::uint64_t i = runs_[r].begin, e = i + runs_[r].count; i < e; ++i) {
      const unsigned code = local_[i];
      known_[code >> 6] |= std::uint64_t{1} << (code & 63);
      block_values_[code] = values_[i];
    }
  }
}

// .bt: the node of 8 voxels from \p base (at least one known) straight from the block's masks.
OctreeStream::Node OctreeStream::binary_voxels(unsigned base) {
  const auto known = static_cast<unsigned>((known_[base >> 6] >> (base & 63)) & 0xffu);
  const auto occupied = static_cast<unsigned>((occupied_[base >> 6] >> (base & 63)) & 0xffu) & known;
  ++nodes_;
  if (known == 0xffu && (occupied == 0 || occupied == 0xffu)) return Node{true, occupied != 0 ? 1.0f : -1.0f};
  nodes_ += static_cast<unsigned>(popcount64(known));
  const unsigned bits = spread2(known & ~occupied) | (spread2(occupied) << 1);  // 01 free, 10 occupied
  char* record = data_.grow(2);
  record[0] = static_cast<char>(bits & 0xffu);
  record[1] = static_cast<char>(bits >> 8);
  return Node{false, 0.0f};
}

// A node inside the loaded block covering the 8^level codes from \p base (level 3: the block).
OctreeStream::Node OctreeStream::block_node(unsigned level, unsigned base) {
  if (format_ == FileFormat::kBinary) {
    if (level == 1) return binary_voxels(base);
    // A node whose voxels are all known and of one state is one leaf (most free space at fine
    // resolutions): decided from the masks without visiting its children.
    const unsigned words = level == 3 ? 8 : 1, first = base >> 6;
    bool full = true, all_occupied = true, all_free = true;
    for (unsigned w = first; w < first + words; ++w) {
      full = full && known_[w] == ~std::uint64_t{0};
      all_occupied = all_occupied && occupied_[w] == ~std::uint64_t{0};
      all_free = all_free && occupied_[w] == 0;
    }
    if (full && (all_occupied || all_free)) {
      ++nodes_;
      return Node{true, all_occupied ? 1.0f : -1.0f};
    }
  }
  const unsigned span = 1u << (3 * (level - 1));  // codes per child
  return inner_node(true, [&](unsigned i, Node& node) {
    const unsigned c = base + i * span;
    const std::uint64_t word = known_[c >> 6];
    if (level == 1) {
      if (((word >> (c & 63)) & 1u) == 0) return false;
      ++nodes_;
      leaf_record(block_values_[c]);
      node = Node{true, block_values_[c]};
      return true;
    }
    const bool any = span == 64 ? word != 0 : ((word >> (c & 63)) & 0xffu) != 0;
    if (!any) return false;
    node = block_node(level - 1, c);
    return true;
  });
}

bool OctreeStream::write(std::ostream& out, double resolution, const ProgressCallback* progress) {
  data_.truncate(0);
  nodes_ = 0;
  StageProgress report(progress, ProgressStage::kWritingFile, runs_.size());
  report_ = &report;
  runs_written_ = 0;
  if (!runs_.empty()) upper_node(0, 0, runs_.size());
  report_ = nullptr;
  // The header as OctoMap writes it (AbstractOcTree::write(), writeBinaryConst()), resolution in
  // the stream's default format.
  std::ostringstream header;
  header << (format_ == FileFormat::kBinary ? "# Octomap OcTree binary file" : "# Octomap OcTree file")
         << "\n# (feel free to add / change comments, but leave the first line as it is!)\n#\n"
         << "id OcTree\nsize " << nodes_ << "\nres " << resolution << "\ndata\n";
  const std::string h = header.str();
  out.write(h.data(), static_cast<std::streamsize>(h.size()));
  out.write(data_.at(0), static_cast<std::streamsize>(data_.size()));
  report.finish();
  return static_cast<bool>(out);
}

}  // namespace iwlomap::detail
