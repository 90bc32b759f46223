// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// OctoMap's .bt and .ot streams written straight from a map's voxels, without building an
// OcTree. An OcTree costs a node allocation and a 16-level descent per voxel and about 40 bytes a
// node; this writer sorts the map's blocks into the octree's depth-first order and emits the
// pruned tree in one pass. The bytes are those OctoMap writes for the tree that set_leaf() of
// every voxel, updateInnerOccupancy() and prune() build (tests/test_octomap_writer.cpp compares
// them with OctoMap's own output).

#include "octomap_files.h"
#include "integrate/progress_report.h"
#include "iwlomap/mapper_backend.h"

#include <algorithm>
#include <cstdint>
#include <string>
#include <vector>

namespace iwlomap::detail {

/// The known voxels of a map in OctoMap's depth-first order, ready to be written.
/// Memory, per run of voxels of one block as the map visits them (one run per block for the
/// library's backends, which visit block by block): .bt 152 bytes (two 512-bit masks, known and
/// occupied; less than the map's own 192-byte block header), .ot 24 bytes and 6 bytes a voxel
/// (position in the block and float log-odds, less than the map's 8). While writing, the file's
/// data: 2 bytes per inner node for .bt, 5 per node for .ot.
class OctreeStream {
 public:
  /// Collects the voxels of \p map. For .bt a voxel is occupied when its probability exceeds
  /// \p occupied_threshold (maximum likelihood, as OctoMap's writeBinary() stores it); .ot keeps
  /// its log-odds as a float. Throws std::out_of_range naming \p path and the voxel when a voxel
  /// lies outside OctoMap's key range.
  OctreeStream(const IMapperBackend& map, FileFormat format, double occupied_threshold, const std::string& path);

  /// Writes the whole file (header and data) to \p out; false when the stream failed. Reports
  /// ProgressStage::kWritingFile (blocks) to \p progress; an exception of the callback propagates.
  bool write(std::ostream& out, double resolution, const ProgressCallback* progress = nullptr);

  /// The number of octree nodes the file holds (its header's "size"); valid after write().
  [[nodiscard]] std::uint64_t num_nodes() const noexcept { return nodes_; }

 private:
  struct Run {
    std::uint64_t block;  // Morton code of the block's OctoMap key (bits 9 and up of the voxel's)
    std::uint64_t begin;  // first voxel of the run in local_ (and values_)
    std::uint32_t count;  // voxels in the run
  };
  struct Node {
    bool leaf;
    float value;  // .bt: +1 occupied, -1 free; .ot: log-odds (the largest child's for inner nodes)
  };

  Node upper_node(unsigned depth, std::size_t first_run, std::size_t end_run);
  Node block_node(unsigned level, unsigned base);
  Node binary_voxels(unsigned base);
  template <class Child>
  Node inner_node(bool may_collapse, Child&& child);
  void load_block(std::size_t first_run, std::size_t end_run);
  void leaf_record(float value);

  FileFormat format_;
  std::vector<Run> runs_;
  struct BlockMasks {
    std::uint64_t known[8] = {};
    std::uint64_t occupied[8] = {};
  };
  std::vector<BlockMasks> masks_;     // .bt: a run's voxels by Morton code inside the block
  std::vector<std::uint16_t> local_;  // .ot: a run's voxels' Morton codes inside the block
  std::vector<float> values_;         // .ot: and their log-odds
  // The file's data, grown by doubling; a node's record is reserved before its children's and
  // dropped with them when it collapses.
  class Bytes {
   public:
    char* grow(std::size_t n) {
      if (size_ + n > buf_.size()) buf_.resize(std::max({buf_.size() * 2, size_ + n, std::size_t{1} << 16}));
      char* p = buf_.data() + size_;
      size_ += n;
      return p;
    }
    void truncate(std::size_t n) noexcept { size_ = n; }
    [[nodiscard]] std::size_t size() const noexcept { return size_; }
    [[nodiscard]] char* at(std::size_t i) noexcept { return buf_.data() + i; }

   private:
    std::vector<char> buf_;
    std::size_t size_ = 0;
  };
  Bytes data_;
  std::uint64_t nodes_ = 0;
  StageProgress* report_ = nullptr;  // during write()
  std::size_t runs_written_ = 0;
  // The block being written, by Morton code inside it.
  std::uint64_t known_[8] = {};
  std::uint64_t occupied_[8] = {};  // .bt
  float block_values_[512] = {};    // .ot
};

}  // namespace iwlomap::detail
