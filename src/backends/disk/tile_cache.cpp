// SPDX-License-Identifier: BSD-3-Clause
#include "backends/disk/tile_cache.h"

#include <algorithm>
#include <stdexcept>
#include <string>
#include <utility>

namespace iwlomap::detail {

Tile* TileCache::find(const VoxelKey& key) const {
  const auto it = index_.find(key);
  return it == index_.end() ? nullptr : it->second;
}

std::unique_ptr<Tile> TileCache::new_tile(const VoxelKey& key) const {
  auto tile = std::make_unique<Tile>(key);
  if (hits_.enabled) tile->hits = std::make_unique<HitAccumulator>(resolution_);
  return tile;
}

std::unique_ptr<Tile> TileCache::load(const VoxelKey& key) {
  std::string where;
  const TileHeader h = store_.read(key, io_buffer_, where);
  std::unique_ptr<Tile> tile = new_tile(key);
  auto scratch = std::make_unique<DenseBlock>();
  // Statistics of another epoch were gathered before accumulation was last turned off: empty now.
  const bool take_hits = tile->hits != nullptr && h.hit_epoch == hits_.epoch;
  decode_tile(
      io_buffer_, h, tile_voxels_, where, format_, *scratch, [&](const DenseBlock& b) { tile->grid.add_dense(b); },
      [&](const VoxelKey& block_key, const HitAccumulator::Block& cells) {
        if (take_hits) tile->hits->merge(block_key, cells);
      });
  return tile;
}

std::uint64_t TileCache::encode(const Tile& t, std::vector<std::uint8_t>& out) const {
  return encode_tile(t.grid, format_, t.hits.get(), hits_.epoch, resolution_, tile_voxels_, t.key, out);
}

// Evicts least recently used unpinned tiles until one more fits. A dirty tile that cannot be
// written stays resident and dirty, and the error propagates.
void TileCache::make_room() {
  while (resident_.size() >= capacity_) {
    std::size_t victim = resident_.size();
    for (std::size_t i = 0; i < resident_.size(); ++i)
      if (!resident_[i]->pinned && (victim == resident_.size() || resident_[i]->last_used < resident_[victim]->last_used))
        victim = i;
    if (victim == resident_.size()) throw std::logic_error("iwlomap: every resident tile is pinned");
    Tile& t = *resident_[victim];
    if (t.dirty) {  // flush() makes it durable
      const std::uint64_t known = encode(t, io_buffer_);
      store_.stage(t.key, io_buffer_, static_cast<std::size_t>(known));
      t.dirty = false;
    }
    index_.erase(t.key);
    resident_.erase(resident_.begin() + static_cast<std::ptrdiff_t>(victim));
  }
}

Tile& TileCache::insert(std::unique_ptr<Tile> tile) {
  tile->pinned = true;
  touch(*tile);
  index_[tile->key] = tile.get();
  resident_.push_back(std::move(tile));
  peak_ = std::max(peak_, resident_.size());
  return *resident_.back();
}

void TileCache::make_resident(const std::vector<VoxelKey>& keys, std::vector<Tile*>& out) {
  out.assign(keys.size(), nullptr);
  for (std::size_t i = 0; i < keys.size(); ++i) {
    if (Tile* t = find(keys[i])) {
      out[i] = t;
      t->pinned = true;
      touch(*t);
    }
  }
  for (std::size_t i = 0; i < keys.size(); ++i) {
    if (out[i] != nullptr) continue;
    TileImage* image = store_.find(keys[i]);
    if (image == nullptr) continue;
    std::unique_ptr<Tile> tile = load(keys[i]);
    // The file may have changed since its header was read: keep the count exact.
    const std::size_t known = tile->grid.known_voxels();
    known_total_ = known_total_ - image->known + known;
    image->known = known;
    make_room();
    out[i] = &insert(std::move(tile));
  }
  for (std::size_t i = 0; i < keys.size(); ++i) {
    if (out[i] != nullptr) continue;
    make_room();
    out[i] = &insert(new_tile(keys[i]));
  }
}

void TileCache::clear() noexcept {
  resident_.clear();
  index_.clear();
  peak_ = 0;
}

std::size_t TileCache::prune() {
  std::vector<std::uint8_t>().swap(io_buffer_);
  std::size_t freed = 0;
  for (auto& t : resident_) freed += t->grid.prune();
  return freed;
}

}  // namespace iwlomap::detail
