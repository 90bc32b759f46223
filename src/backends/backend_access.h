// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// What the library's own layers may do to a backend beyond its public API.

#include "integrate/scan_scratch.h"
#include "storage/block_grid.h"
#include "iwlomap/mapper_backend.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"

#include <cstddef>
#include <cstdint>
#include <functional>

namespace iwlomap::detail {

/// Applies a collected scan (at most one observation per voxel) to any backend the way
/// IMapperBackend's default insert_scan() does: every voxel's observation at its centre through
/// the unweighted batch_update_iwlo() (free voxels with intensity 0, not occupied), in batches.
void apply_scratch_by_batches(IMapperBackend& map, const ScanScratch& scratch);

/// Gathers voxels visited one by one into the calls of BackendAccess::for_each_known_block(): one
/// call per run of voxels of one block (at most 512 voxels).
class KnownBlockGrouper {
 public:
  explicit KnownBlockGrouper(const std::function<void(const VoxelKey&, const std::uint16_t*, const float*,
                                                      std::size_t)>& visit)
      : visit_(visit) {}
  void add(const VoxelKey& key, float log_odds) {
    const VoxelKey block = block_of(key);
    if (n_ == kBlockVoxels || (n_ > 0 && !(block == block_))) finish();
    block_ = block;
    index_[n_] = static_cast<std::uint16_t>(index_in_block(key));
    log_odds_[n_++] = log_odds;
  }
  void finish() {
    if (n_ > 0) visit_(block_, index_, log_odds_, n_);
    n_ = 0;
  }

 private:
  const std::function<void(const VoxelKey&, const std::uint16_t*, const float*, std::size_t)>& visit_;
  VoxelKey block_{};
  std::size_t n_ = 0;
  std::uint16_t index_[kBlockVoxels];
  float log_odds_[kBlockVoxels];
};

struct BackendAccess {
  /// Applies a scan already collected into \p scratch (at most one observation per voxel) to
  /// \p map, so that its voxels come out bit-identical to \p map's own insert_scan() of that scan;
  /// the skipped-point count is the caller's. The RAM and Disk backends apply it through their own
  /// scan path (throwing std::logic_error, before changing the map, when they gather hit
  /// statistics and the scratch holds none; RAM also MemoryLimitError as insert_scan() does); any
  /// other backend gets apply_scratch_by_batches().
  static void apply_collected_scan(IMapperBackend& map, const ScanScratch& scratch);

  /// Some known voxels of one 8^3 block: block_of() key, then n voxels by index_in_block() with
  /// their stored log-odds.
  using KnownBlockVisit = std::function<void(const VoxelKey& block, const std::uint16_t* index,
                                             const float* log_odds, std::size_t n)>;

  /// Calls \p visit for the known voxels of \p map block by block, in for_each_voxel()'s order
  /// (a block may come in several calls when for_each_voxel() does not visit it at once), with the
  /// stored float log-odds. The RAM and Disk backends read their storage directly and skip the
  /// probability for_each_voxel() computes (an exp() a voxel, the largest cost of a file writer)
  /// and the call per voxel; any other backend goes through for_each_voxel().
  static void for_each_known_block(const IMapperBackend& map, const KnownBlockVisit& visit);

 private:
  static void apply_to_ram(ProbabilityUpdater& map, const ScanScratch& scratch);
  static void apply_to_disk(OutofcoreTileMapper& map, const ScanScratch& scratch);
  static void for_each_known_block_ram(const ProbabilityUpdater& map, const KnownBlockVisit& visit);
  static void for_each_known_block_disk(const OutofcoreTileMapper& map, const KnownBlockVisit& visit);
};

}  // namespace iwlomap::detail
