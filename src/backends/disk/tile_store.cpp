// SPDX-License-Identifier: BSD-3-Clause
#include "backends/disk/tile_store.h"

#include "backends/disk/file_io.h"

#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <exception>
#include <utility>

namespace iwlomap::detail {

namespace {
// The staging file is rewritten without its dead images once it is this large and more than half
// of it is dead.
constexpr std::uint64_t kCompactMinBytes = std::uint64_t{1} << 20;
}  // namespace

TileStore::TileStore(MapDirectory& dir, double resolution, std::uint32_t tile_voxels)
    : dir_(dir), resolution_(resolution), tile_voxels_(tile_voxels) {
  for (const std::string& name : dir_.tile_names()) {
    VoxelKey t;
    (void)parse_tile_file_name(name, t);
    const std::string path = dir_.path_of(name);
    std::uint64_t size = 0;
    const std::vector<std::uint8_t> head = read_file_prefix(path, kTileHeaderBytes, size);
    const TileHeader h = parse_tile_header(head.data(), head.size(), size, resolution_, tile_voxels_, t, path);
    TileImage& image = images_[t];
    image.committed = true;
    image.committed_bytes = size;
    image.known = static_cast<std::size_t>(h.known_voxels);
    committed_bytes_ += size;
  }
}

TileStore::~TileStore() {
  if (staging_fd_ >= 0) ::close(staging_fd_);
}

TileImage* TileStore::find(const VoxelKey& key) {
  const auto it = images_.find(key);
  return it == images_.end() ? nullptr : &it->second;
}

std::size_t TileStore::known() const noexcept {
  std::size_t n = 0;
  for (const auto& [k, image] : images_) n += image.known;
  return n;
}

TileHeader TileStore::read(const VoxelKey& key, std::vector<std::uint8_t>& bytes, std::string& where) {
  const TileImage& image = images_.at(key);
  if (image.staged) {
    where = staging_path() + " (staged image of " + tile_file_name(key) + ")";
    read_at(staging_fd_, image.staged_offset, static_cast<std::size_t>(image.staged_bytes), where, bytes);
  } else {
    where = dir_.tile_path(key);
    bytes = read_file(where);
  }
  return parse_tile_header(bytes.data(), bytes.size(), bytes.size(), resolution_, tile_voxels_, key, where);
}

void TileStore::unstage(TileImage& image) noexcept {
  if (!image.staged) return;
  staging_live_ -= image.staged_bytes;
  image.staged = false;
}

void TileStore::stage(const VoxelKey& key, const std::vector<std::uint8_t>& encoded, std::size_t known) {
  if (staging_fd_ < 0) {
    staging_fd_ = create_scratch_file(staging_path());
    staging_size_ = 0;
    staging_live_ = 0;
  } else if (staging_size_ >= kCompactMinBytes && staging_size_ > 2 * staging_live_) {
    compact_staging();
  }
  write_at(staging_fd_, encoded, staging_size_, staging_path());
  TileImage& image = images_[key];
  unstage(image);
  image.staged = true;
  image.staged_offset = staging_size_;
  image.staged_bytes = encoded.size();
  image.known = known;
  staging_size_ += encoded.size();
  staging_live_ += encoded.size();
}

// Rewrites the staging file with the live images only (a new file renamed over the old one: if
// anything fails, the old file and its offsets stay valid).
void TileStore::compact_staging() {
  const std::string fresh_path = staging_path() + ".new";
  const int fresh = create_scratch_file(fresh_path);
  std::vector<std::pair<TileImage*, std::uint64_t>> moved;  // new offsets, applied on success
  std::uint64_t size = 0;
  try {
    std::vector<VoxelKey> keys;
    for (const auto& [k, image] : images_)
      if (image.staged) keys.push_back(k);
    std::sort(keys.begin(), keys.end());
    std::vector<std::uint8_t> bytes;
    for (const VoxelKey& k : keys) {
      TileImage& image = images_.at(k);
      read_at(staging_fd_, image.staged_offset, static_cast<std::size_t>(image.staged_bytes), staging_path(), bytes);
      write_at(fresh, bytes, size, fresh_path);
      moved.emplace_back(&image, size);
      size += bytes.size();
    }
    if (::rename(fresh_path.c_str(), staging_path().c_str()) != 0)
      throw StorageError(StorageError::Kind::kIo, staging_path(),
                         "iwlomap: cannot rename " + fresh_path + " to " + staging_path() + ": " + std::strerror(errno));
  } catch (...) {
    ::close(fresh);
    ::unlink(fresh_path.c_str());
    throw;
  }
  ::close(staging_fd_);
  staging_fd_ = fresh;
  for (const auto& [image, offset] : moved) image->staged_offset = offset;
  staging_size_ = size;
  staging_live_ = size;
}

void TileStore::commit(const VoxelKey& key, const std::vector<std::uint8_t>& encoded, std::size_t known) {
  const std::string path = dir_.tile_path(key);
  write_file_durably(path + kTempSuffix, path, encoded);
  dir_sync_pending_ = true;
  TileImage& image = images_[key];
  committed_bytes_ -= image.committed ? image.committed_bytes : 0;
  image.committed = true;
  image.committed_bytes = encoded.size();
  committed_bytes_ += image.committed_bytes;
  image.known = known;
  unstage(image);
}

void TileStore::commit_staged(const VoxelKey& key, std::vector<std::uint8_t>& image_buffer, DenseBlock& check_block) {
  std::string where;
  const TileHeader h = read(key, image_buffer, where);
  decode_tile(image_buffer, h, tile_voxels_, where, check_block, [](const DenseBlock&) {});
  commit(key, image_buffer, static_cast<std::size_t>(h.known_voxels));
}

void TileStore::finish_commits() {
  if (dir_sync_pending_) {
    sync_directory(dir_.path());
    dir_sync_pending_ = false;
  }
  drop_staging_if_unused();
}

// Closes and removes the staging file once no image in it is needed.
void TileStore::drop_staging_if_unused() noexcept {
  if (staging_fd_ < 0 || staging_live_ > 0) return;
  ::close(staging_fd_);
  staging_fd_ = -1;
  staging_size_ = 0;
  ::unlink(staging_path().c_str());  // a leftover is deleted by the next open anyway
}

void TileStore::clear() {
  std::exception_ptr first_error;
  for (auto it = images_.begin(); it != images_.end();) {
    TileImage& image = it->second;
    unstage(image);  // the staging file goes as a whole below
    if (image.committed) {
      try {
        remove_file(dir_.tile_path(it->first));
      } catch (...) {
        if (!first_error) first_error = std::current_exception();
        image.known = committed_known(it->first);
        ++it;
        continue;  // still on disk: it stays with its file's contents
      }
    }
    it = images_.erase(it);
  }
  drop_staging_if_unused();
  committed_bytes_ = 0;
  for (const auto& [k, image] : images_) committed_bytes_ += image.committed_bytes;
  sync_directory(dir_.path());
  dir_sync_pending_ = false;
  if (first_error) std::rethrow_exception(first_error);
}

// Known voxels of a committed file, from its header (0 when it cannot be read: the next read of
// the tile reports the problem).
std::size_t TileStore::committed_known(const VoxelKey& key) const {
  try {
    const std::string path = dir_.tile_path(key);
    std::uint64_t size = 0;
    const std::vector<std::uint8_t> head = read_file_prefix(path, kTileHeaderBytes, size);
    return static_cast<std::size_t>(
        parse_tile_header(head.data(), head.size(), size, resolution_, tile_voxels_, key, path).known_voxels);
  } catch (const std::exception&) {
    return 0;
  }
}

}  // namespace iwlomap::detail
