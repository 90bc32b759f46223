// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The Disk backend's state and operations (OutofcoreTileMapper::Impl): the map directory
// (map_directory), the tiles on disk (tile_store), the resident tiles (tile_cache) and the routing
// of a call's items to tiles (tile_routing) put together; updates run the core's batch kernel on
// resident tiles. Callers hold `mutex`; the public methods (outofcore_tile_mapper.cpp) take it once
// per call.

#include "iwlomap/outofcore_tile_mapper.h"

#include "backends/disk/file_io.h"
#include "backends/disk/map_directory.h"
#include "backends/disk/tile_cache.h"
#include "backends/disk/tile_file.h"
#include "backends/disk/tile_routing.h"
#include "backends/disk/tile_store.h"
#include "integrate/absolute_log_odds.h"
#include "integrate/batch_apply.h"
#include "integrate/batch_input.h"
#include "integrate/phase_clock.h"
#include "integrate/block_sorted_batch.h"
#include "integrate/progress_report.h"
#include "integrate/scan_apply.h"
#include "integrate/scan_scratch.h"
#include "integrate/updater.h"
#include "integrate/voxel_update.h"
#include "model/checks.h"
#include "storage/block_grid.h"
#include "storage/free_memory.h"
#include "storage/grid_reads.h"

#include <algorithm>
#include <cmath>
#include <exception>
#include <filesystem>
#include <limits>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

namespace iwlomap {

struct OutofcoreTileMapper::Impl {
  // Opening: the directory (lock, metadata, tile list), then the manifest and the tile files it
  // names; what interrupted writes left behind is removed only once every tile checked out, so an
  // open that fails changes no file.
  Impl(const std::string& directory, double res, double tile, std::size_t cache_tiles, bool read_only = false)
      : resolution(res),
        tile_voxels(detail::tile_voxels_for(res, tile)),
        tile_size(static_cast<double>(tile_voxels) * res),
        dir(directory, res, tile, tile_voxels, read_only),
        store(dir, res, tile_voxels, detail::state_of(dir.meta())),
        updater(store.committed_state().params),
        cache(store, cache_tiles, res, tile_voxels, total_known, hit_settings, updater.format()),
        routing(tile_voxels) {
    total_known = store.known();
    hit_settings = {store.committed_state().hit_statistics, store.committed_state().hit_epoch};
    dir.remove_leftovers();
    store.remove_retired();
  }

  // ---- what the manifest records besides the tiles ----

  // The parameters belong to the map: validated, used at once, recorded by the next commit.
  //
  // A new voxel layout converts every tile now, each once from the values it holds, as the RAM
  // backend converts its grid: the resident tiles in memory first (the cache writes a tile in the
  // map's current format, so none may be evicted before), then the others as they are read (a
  // file names its own format). All are marked dirty, so a second change converts what the first
  // produced and not the older files. This reads and later writes the whole map, but only when
  // decay_rate, min_alpha or a clamp beyond +-15 change the layout of a map that holds voxels.
  void set_params(const IwloParams& p) {
    detail::Updater next(p);
    const bool convert = !next.format().same_layout(updater.format());
    if (convert)
      for (const auto& t : cache.resident()) {
        detail::convert_voxels(t->grid, updater.format(), next.format());
        t->dirty = true;
      }
    updater = std::move(next);
    if (!convert) return;
    const std::vector<VoxelKey> keys = all_tiles();
    std::vector<VoxelKey> group;
    std::vector<detail::Tile*> tiles;
    for (std::size_t first = 0; first < keys.size(); first += cache.capacity()) {
      group.assign(keys.begin() + static_cast<std::ptrdiff_t>(first),
                   keys.begin() + static_cast<std::ptrdiff_t>(std::min(keys.size(), first + cache.capacity())));
      detail::TileCache::PinScope pins(cache);
      cache.make_resident(group, tiles);
      for (detail::Tile* t : tiles) t->dirty = true;
    }
  }

  void set_hit_accumulation(bool enabled) {
    if (enabled == hit_settings.enabled) return;
    // A new epoch each time it is turned on: statistics still in tiles from before are void.
    hit_settings = {enabled, enabled ? hit_settings.epoch + 1 : hit_settings.epoch};
    for (const auto& t : cache.resident())
      t->hits = enabled ? std::make_unique<detail::HitAccumulator>(resolution) : nullptr;
  }

  [[nodiscard]] detail::MapState current_state() const {
    return {updater.params(), hit_settings.enabled, hit_settings.epoch};
  }

  // Read-only maps refuse every change (open_read_only()): \p what names the call.
  void check_writable(const char* what) const {
    if (dir.read_only())
      throw std::logic_error(std::string("iwlomap: OutofcoreTileMapper::") + what + ": the map in " + dir.path() +
                             " is open read-only");
  }

  ~Impl() {
    // The destructor's contract: flush, never throw. Every file keeps its last complete state.
    try {
      flush();
    } catch (...) {
    }
  }
  Impl(const Impl&) = delete;
  Impl& operator=(const Impl&) = delete;

  // Tile \p key, made resident when it is on disk (which may evict and write another); null when
  // the map has no such tile.
  const detail::Tile* resident_tile(const VoxelKey& key) {
    if (detail::Tile* t = cache.find(key)) {
      cache.touch(*t);
      return t;
    }
    if (store.find(key) == nullptr) return nullptr;
    std::vector<detail::Tile*> out;
    detail::TileCache::PinScope pins(cache);
    cache.make_resident({key}, out);
    return out[0];
  }

  // Every tile of the map, resident or on disk, in key order.
  [[nodiscard]] std::vector<VoxelKey> all_tiles() const {
    std::vector<VoxelKey> keys;
    keys.reserve(store.images().size() + cache.resident().size());
    for (const auto& [k, image] : store.images()) keys.push_back(k);
    for (const auto& t : cache.resident())
      if (store.images().count(t->key) == 0) keys.push_back(t->key);
    std::sort(keys.begin(), keys.end());
    return keys;
  }

  // Splits the tiles of `routing` into groups of at most the cache's capacity, resident tiles
  // first so that a call never evicts a tile it needs later. Calls fn(group slots, their tiles,
  // count) per group, the group's tiles resident and pinned.
  template <class Fn>
  void for_each_group(Fn&& fn) {
    const std::size_t n = routing.tiles().size();
    std::vector<std::uint32_t> slots(n);
    for (std::uint32_t s = 0; s < n; ++s) slots[s] = s;
    std::stable_partition(slots.begin(), slots.end(),
                          [&](std::uint32_t s) { return cache.find(routing.tiles()[s]) != nullptr; });
    std::vector<VoxelKey> keys;
    std::vector<detail::Tile*> group_tiles;
    for (std::size_t first = 0; first < n; first += cache.capacity()) {
      const std::size_t last = std::min(n, first + cache.capacity());
      keys.clear();
      for (std::size_t i = first; i < last; ++i) keys.push_back(routing.tiles()[slots[i]]);
      detail::TileCache::PinScope pins(cache);
      cache.make_resident(keys, group_tiles);
      fn(slots.data() + first, group_tiles.data(), last - first);
    }
  }

  // ---- updates ----

  // When every tile of the batch fits in the cache, the tiles are loaded first (so an I/O error
  // changes nothing) and the batch is applied in call order, exactly as the RAM backend applies
  // it; otherwise tile group by tile group, each tile's observations in call order.
  void apply_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                   const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights) {
    const std::size_t skip = detail::prepare_batch(points, intensities, is_occupied, weights, resolution, batch);
    const detail::BatchValues in{intensities, is_occupied, weights};
    routing.assign(batch.size(), [&](std::size_t i) { return batch[i].key; });
    std::size_t none_skipped = 0;  // prepared observations are all finite
    if (routing.tiles().size() <= cache.capacity()) {
      detail::TileCache::PinScope pins(cache);
      cache.make_resident(routing.tiles(), slot_tile);
      accessors.clear();
      for (detail::Tile* t : slot_tile) {
        accessors.emplace_back(t->grid);
        t->dirty = true;
      }
      const detail::FloorDivider divide(resolution);
      detail::BlockSortedBatch sorted;  // scattered points, as the RAM backend takes them
      if (detail::BlockSortedBatch::suits(points, intensities, skip, divide) &&
          sorted.build(points, intensities, is_occupied, skip, divide)) {
        struct ByBlock {
          Impl& m;
          std::uint32_t slot(const VoxelKey& block_key) const { return m.routing.find(m.routing.tile_of_block(block_key)); }
          detail::VoxelBlock& block(const VoxelKey& block_key) { return m.accessors[slot(block_key)].block(block_key); }
          detail::BlockGrid& grid(const VoxelKey& block_key) { return m.slot_tile[slot(block_key)]->grid; }
        };
        detail::apply_block_sorted(sorted, ByBlock{*this}, in, updater, total_known);
      } else {
        struct ByRow {
          Impl& m;
          detail::VoxelBlock& block(std::size_t j, const VoxelKey& block_key, std::size_t) {
            return m.accessors[m.routing.slot_of(j)].block(block_key);
          }
          detail::BlockGrid& grid(std::size_t j) { return m.slot_tile[m.routing.slot_of(j)]->grid; }
        };
        detail::apply_batch(detail::ObservationRows(batch.data(), nullptr), batch.size(), ByRow{*this}, in, updater,
                            {total_known, none_skipped});
      }
      if (hit_settings.enabled)
        for (std::size_t j = 0; j < batch.size(); ++j)
          slot_tile[routing.slot_of(j)]->hits->add_row(points, intensities, is_occupied, batch[j].row,
                                                        updater.params().intensity_threshold);
    } else {
      routing.sort(batch.size());
      for_each_group([&](const std::uint32_t* slots, detail::Tile* const* group, std::size_t count) {
        for (std::size_t g = 0; g < count; ++g) {
          detail::Tile& t = *group[g];
          t.dirty = true;
          struct Locate {
            detail::BlockAccessor acc;
            detail::BlockGrid& grid_;
            detail::VoxelBlock& block(std::size_t, const VoxelKey& block_key, std::size_t) {
              return acc.block(block_key);
            }
            detail::BlockGrid& grid(std::size_t) { return grid_; }
          };
          const std::size_t from = routing.begin(slots[g]);
          const std::size_t n = routing.begin(slots[g] + 1) - from;
          detail::apply_batch(detail::ObservationRows(batch.data(), routing.order() + from), n,
                              Locate{detail::BlockAccessor(t.grid), t.grid}, in, updater, {total_known, none_skipped});
          if (t.hits)
            for (std::size_t j = 0; j < n; ++j)
              t.hits->add_row(points, intensities, is_occupied, batch[routing.order()[from + j]].row,
                              updater.params().intensity_threshold);
        }
      });
    }
    skipped += skip;
  }

  // The Locate of scan_apply.h for tile group \p group: a block is applied when its tile's slot is
  // in the group; the group's tiles are resident and pinned.
  struct TileGroupLocate {
    Impl& m;
    std::size_t group;
    [[nodiscard]] detail::Tile* tile_of(const VoxelKey& block_key) const noexcept {
      const std::uint32_t s = m.routing.find(m.routing.tile_of_block(block_key));
      return s != detail::FlatKeyMap::kEmpty && m.slot_group[s] == group ? m.slot_tile[s] : nullptr;
    }
    [[nodiscard]] detail::BlockGrid* grid_of(const VoxelKey& block_key) const noexcept {
      detail::Tile* t = tile_of(block_key);
      return t != nullptr ? &t->grid : nullptr;
    }
    [[nodiscard]] detail::VoxelBlock* find(const VoxelKey& block_key) const noexcept {
      const detail::Tile* t = tile_of(block_key);
      return t != nullptr ? t->grid.find(block_key) : nullptr;
    }
  };

  // Gives every tile the scan touches a slot in `routing`, and each slot the list of scratch
  // chunks that hold its observations (32^3 chunks may straddle tiles).
  void route_scan(const detail::ScanScratch& scan) {
    routing.reset();
    for (std::size_t ci = 0; ci < scan.num_chunks(); ++ci) {
      scan.for_each_block_in(ci, [&](const VoxelKey& block_key) {
        const std::size_t before = routing.tiles().size();
        const std::uint32_t s = routing.slot(routing.tile_of_block(block_key));
        if (routing.tiles().size() != before) {
          if (slot_chunks.size() <= s) slot_chunks.resize(s + 1);
          if (slot_last_chunk.size() <= s) slot_last_chunk.resize(s + 1);
          slot_chunks[s].clear();
          slot_last_chunk[s] = kNoChunk;
        }
        if (slot_last_chunk[s] != ci) {
          slot_chunks[s].push_back(ci);
          slot_last_chunk[s] = ci;
        }
      });
    }
  }

  // The scan is collected (its hit statistics in the same walk), then applied (apply_collected()).
  // Reports kCastingRays, then kUpdatingVoxels (an exception of the callback there is rethrown once
  // the scan is applied in full).
  void insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                   double max_range, RayModel rays, int threads, const ProgressCallback* progress,
                   ScanPhaseTimes& phases) {
    detail::PhaseClock total = detail::start_scan_phases(phases, threads);
    detail::check_scan_input(origin, points, intensities, max_range, resolution);
    const detail::RayStatistics ray_stats{updater.params().intensity_threshold};
    const detail::RayStatistics* stats = hit_settings.enabled ? &ray_stats : nullptr;
    const std::size_t skip =
        scratch.collect(origin, points, intensities, max_range, resolution, rays, threads, progress, stats, &phases);
    std::exception_ptr deferred;
    apply_collected(scratch, threads, progress, deferred, &phases);
    skipped += skip;
    total.stop();
    if (deferred) std::rethrow_exception(deferred);
  }

  // A collected scan, routed to tiles and applied tile group by tile group through scan_apply.h,
  // each group's free voxels on up to \p threads threads, with the scan's hit statistics when the
  // map keeps them. Reports kUpdatingVoxels by scratch chunks; an exception of the callback is
  // kept in \p deferred.
  void apply_collected(const detail::ScanScratch& scan, int threads, const ProgressCallback* progress,
                       std::exception_ptr& deferred, ScanPhaseTimes* phases = nullptr) {
    route_scan(scan);
    const std::size_t slots = routing.tiles().size();
    slot_group.assign(slots, kNoGroup);
    slot_tile.assign(slots, nullptr);
    // Reported units: each group's chunks and one at its end; with one group, every chunk.
    std::size_t units = scan.num_chunks() + 1;
    if (slots > cache.capacity()) {
      units = 0;
      for (std::size_t s = 0; s < slots; ++s) units += slot_chunks[s].size() + 1;
    }
    detail::StageProgress report(progress, ProgressStage::kUpdatingVoxels, units, &deferred);
    std::size_t reported = 0;
    std::size_t group_id = 0;
    for_each_group([&](const std::uint32_t* group_slots, detail::Tile* const* group, std::size_t count) {
      ++group_id;
      for (std::size_t g = 0; g < count; ++g) {
        slot_group[group_slots[g]] = group_id;
        slot_tile[group_slots[g]] = group[g];
        group[g]->dirty = true;
      }
      TileGroupLocate locate{*this, group_id};
      detail::allocate_scan(scan, locate, threads, phases);
      detail::ChunkSelection chunks;
      if (count != slots) {
        group_chunks.clear();
        for (std::size_t g = 0; g < count; ++g)
          group_chunks.insert(group_chunks.end(), slot_chunks[group_slots[g]].begin(), slot_chunks[group_slots[g]].end());
        std::sort(group_chunks.begin(), group_chunks.end());
        group_chunks.erase(std::unique(group_chunks.begin(), group_chunks.end()), group_chunks.end());
        chunks.list = &group_chunks;
      }
      const detail::Updater& u = updater;
      total_known += detail::apply_scan(
          scan, chunks, threads, locate,
          [&u](detail::VoxelBlock& b, int index, const VoxelKey&, double intensity, bool occupied) {
            return detail::observe_voxel(b, b.existing(index), intensity, occupied, 1.0, u);
          },
          report, reported, phases ? &phases->updating : nullptr);
      reported += chunks.size(scan) + 1;
      const detail::ScanHits* h = hit_settings.enabled ? scan.statistics() : nullptr;
      if (h != nullptr) {  // each tile takes its own blocks' statistics
        h->for_each_block([&](const VoxelKey& b, const detail::ScanHits::Counts& c) {
          if (detail::Tile* t = locate.tile_of(b)) t->hits->merge_visits(b, c);
        });
        h->for_each_hit([&](const VoxelKey& k, const detail::ScanHits::HitSum& sum) {
          if (detail::Tile* t = locate.tile_of(detail::block_of(k))) t->hits->merge_hits(k, sum);
        });
      }
    });
    report.finish();
  }

  void set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) {
    std::vector<detail::AbsoluteLogOdds> values;
    const std::size_t skip = detail::prepare_log_odds(points, log_odds, updater.params(), resolution, values);
    routing.assign(values.size(), [&](std::size_t i) { return values[i].key; });
    routing.sort(values.size());
    for_each_group([&](const std::uint32_t* slots, detail::Tile* const* group, std::size_t count) {
      for (std::size_t g = 0; g < count; ++g) {
        detail::Tile& t = *group[g];
        t.dirty = true;
        detail::BlockAccessor acc(t.grid);
        for (std::size_t j = routing.begin(slots[g]); j < routing.begin(slots[g] + 1); ++j) {
          const detail::AbsoluteLogOdds& a = values[routing.order()[j]];
          detail::VoxelBlock* b = nullptr;
          detail::Voxel& v = acc.voxel(a.key, b);
          if (detail::set_voxel_log_odds(*b, v, a.log_odds, updater.format())) ++total_known;
        }
      }
    });
    skipped += skip;
  }

  // ---- reading the whole map ----

  // Calls fn(key, const Voxel&) for every known voxel of every tile, tiles in key order: resident
  // ones from RAM, the others read one at a time and dropped (the cache is left as it is).
  template <class Fn>
  void for_each_known(Fn&& fn) {
    std::unique_ptr<detail::DenseBlock> scratch_block;
    std::vector<std::uint8_t> bytes;
    for (const VoxelKey& k : all_tiles()) {
      if (const detail::Tile* t = cache.find(k)) {
        detail::for_each_known(t->grid, fn);
        continue;
      }
      std::string where;
      const detail::TileHeader h = store.read(k, bytes, where);
      const std::size_t expected = store.find(k)->known;
      if (h.known_voxels != expected)
        detail::throw_corrupt(where, "it holds " + std::to_string(h.known_voxels) + " voxels, " +
                                         std::to_string(expected) +
                                         " when last written or read (changed by another program?)");
      if (!scratch_block) scratch_block = std::make_unique<detail::DenseBlock>();
      detail::decode_tile(bytes, h, tile_voxels, where, updater.format(), *scratch_block, [&fn](const detail::DenseBlock& b) {
        for (int i = 0; i < detail::kBlockVoxels; ++i) {
          const detail::Voxel& v = b.voxels[static_cast<std::size_t>(i)];
          if (v.known()) fn(detail::voxel_of(b.key, i), v);
        }
      });
    }
  }

  // ---- commits ----

  // One commit (tile_store.h): every tile whose newest state is not in its committed file (dirty
  // resident tiles from RAM, staged tiles from the staging file) and the parameters. All or
  // nothing: on failure the map stays as the last commit left it, and every tile keeps its newest
  // state (dirty in RAM, or staged) for a later flush. Reports kWritingTiles (an exception of the
  // callback is rethrown after the commit).
  void flush(const ProgressCallback* progress = nullptr) {
    if (dir.read_only()) return;  // nothing can be dirty
    std::vector<VoxelKey> keys;
    for (const auto& [k, image] : store.images())
      if (image.staged) keys.push_back(k);
    for (const auto& t : cache.resident())
      if (t->dirty && std::find(keys.begin(), keys.end(), t->key) == keys.end()) keys.push_back(t->key);
    const detail::MapState state = current_state();
    if (keys.empty() && detail::same_state(state, store.committed_state())) return;
    std::sort(keys.begin(), keys.end());
    std::vector<detail::Tile*> written;
    std::unique_ptr<detail::DenseBlock> check_block;
    std::exception_ptr deferred;
    detail::StageProgress report(progress, ProgressStage::kWritingTiles, keys.size(), &deferred);
    try {
      for (std::size_t i = 0; i < keys.size(); ++i) {
        const VoxelKey& k = keys[i];
        report.report(i);
        detail::Tile* t = cache.find(k);
        if (t != nullptr && t->dirty) {
          const std::uint64_t known = cache.encode(*t, io_buffer);
          store.write(k, io_buffer, static_cast<std::size_t>(known));
          written.push_back(t);
        } else {
          if (!check_block) check_block = std::make_unique<detail::DenseBlock>();
          store.write_staged(k, io_buffer, *check_block);
        }
      }
      store.commit(state);
    } catch (...) {
      store.abort();
      throw;
    }
    for (detail::Tile* t : written) t->dirty = false;
    report.finish();
    if (deferred) std::rethrow_exception(deferred);
  }

  // Back to the last commit: resident tiles, staged images and parameters as it left them.
  void rollback() {
    cache.clear();
    store.discard_staged();
    total_known = store.known();
    const detail::MapState& committed = store.committed_state();
    updater = detail::Updater(committed.params);
    hit_settings = {committed.hit_statistics, committed.hit_epoch};
  }

  // A commit of an empty map (the parameters stay); unflushed changes go either way.
  void clear() {
    cache.clear();
    skipped = 0;
    scratch.release();
    detail::free_memory(batch);
    detail::free_memory(io_buffer);
    store.discard_staged();
    try {
      store.commit(current_state(), true);
    } catch (...) {
      store.abort();
      total_known = store.known();
      throw;
    }
    total_known = store.known();
  }

  void release_buffers() {
    scratch.release();
    detail::free_memory(batch);
    routing = detail::TileRouting(tile_voxels);
    detail::free_memory(slot_chunks);
    detail::free_memory(slot_last_chunk);
    detail::free_memory(slot_group);
    detail::free_memory(slot_tile);
    detail::free_memory(accessors);
    detail::free_memory(group_chunks);
    detail::free_memory(io_buffer);
  }

  static constexpr std::size_t kNoChunk = static_cast<std::size_t>(-1);
  static constexpr std::size_t kNoGroup = 0;

  double resolution;
  std::uint32_t tile_voxels;
  double tile_size;  // effective: tile_voxels * resolution
  std::size_t total_known = 0;  // of the whole map (before `cache`, which keeps it exact)
  detail::HitSettings hit_settings;  // (before `cache`, which reads it)
  detail::MapDirectory dir;
  detail::TileStore store;
  detail::Updater updater;  // (before `cache`, which reads its voxel format)
  detail::TileCache cache;
  detail::TileRouting routing;
  std::size_t skipped = 0;

  // Buffers reused between calls.
  detail::ScanScratch scratch;
  std::vector<detail::Observation> batch;
  std::vector<std::vector<std::size_t>> slot_chunks;
  std::vector<std::size_t> slot_last_chunk;
  std::vector<std::size_t> slot_group;
  std::vector<detail::Tile*> slot_tile;
  std::vector<detail::BlockAccessor> accessors;
  std::vector<std::size_t> group_chunks;
  std::vector<std::uint8_t> io_buffer;

  mutable std::mutex mutex;
};

}  // namespace iwlomap
