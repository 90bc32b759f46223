// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// OctoMap's .bt and .ot files: checked reading (OctoMap's own readers trust their input), writing
// through a temporary file, and moving voxels between an octree and any backend.

#include "octomap_keys.h"
#include "iwlomap/mapper_backend.h"

#include <octomap/OcTree.h>

#include <functional>
#include <memory>
#include <ostream>
#include <string>
#include <utility>

namespace iwlomap::detail {

enum class FileFormat { kBinary, kFull };  // .bt, .ot

/// The format named by the extension of \p path; std::invalid_argument naming \p caller otherwise.
[[nodiscard]] FileFormat format_of(const std::string& path, const char* caller);

struct LoadedTree {
  FileFormat format;
  double resolution;
  std::unique_ptr<octomap::OcTree> tree;
};

/// Reads and fully checks an OctoMap file. \p clamping holds the clamping thresholds (min, max
/// probability) of the reading tree, which are the log-odds of .bt leaves; nullptr keeps those of
/// a fresh OcTree, as OctoMap's own tools read the file. Throws std::runtime_error naming the path.
[[nodiscard]] LoadedTree read_octomap_file(const std::string& path, const char* caller,
                                           const std::pair<double, double>* clamping);

/// Feeds every voxel of \p tree to map.set_log_odds() in batches.
void set_tree_voxels(const octomap::OcTree& tree, IMapperBackend& map);

/// Calls write(stream) on a temporary file next to \p path and renames it over \p path; the
/// temporary file is removed when write() returns false or throws, or the stream fails.
/// \p octomap_output holds what OctoMap printed meanwhile, for the error message.
void write_file(const std::string& path, const char* caller, const std::function<bool(std::ostream&)>& write,
                const std::string* octomap_output = nullptr);

/// Writes \p tree to a temporary file next to \p path and renames it over \p path.
void write_tree(const octomap::OcTree& tree, FileFormat f, const std::string& path, const char* caller);

// Calls visit(key, log_odds) for every voxel of \p tree, expanding pruned leaves.
template <class Visit>
void for_each_tree_voxel(const octomap::OcTree& tree, Visit&& visit) {
  for (auto it = tree.begin_leafs(), end = tree.end_leafs(); it != end; ++it) {
    const float value = it->getLogOdds();
    const VoxelKey lo = from_octomap(it.getIndexKey());
    const std::int32_t side = std::int32_t{1} << (kTreeDepth - it.getDepth());
    for (std::int32_t dz = 0; dz < side; ++dz)
      for (std::int32_t dy = 0; dy < side; ++dy)
        for (std::int32_t dx = 0; dx < side; ++dx) visit(VoxelKey{lo.x + dx, lo.y + dy, lo.z + dz}, value);
  }
}

}  // namespace iwlomap::detail
