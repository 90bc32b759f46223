// SPDX-License-Identifier: BSD-3-Clause
#include "backends/disk/tile_store.h"

#include "backends/disk/file_io.h"

#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <memory>
#include <unordered_set>
#include <utility>

namespace iwlomap::detail {

namespace {
// The staging file is rewritten without its dead images once it is this large and more than half
// of it is dead.
constexpr std::uint64_t kCompactMinBytes = std::uint64_t{1} << 20;
}  // namespace

TileStore::TileStore(MapDirectory& dir, double resolution, std::uint32_t tile_voxels, const MapState& fallback,
                     bool collect_damage)
    : dir_(dir), resolution_(resolution), tile_voxels_(tile_voxels), state_(fallback), collect_damage_(collect_damage) {
  const std::string manifest_path = dir_.path_of(kManifestName);
  std::error_code ec;
  if (std::filesystem::exists(manifest_path, ec))
    open_manifest(manifest_path);
  else
    open_listed();
}

template <class Check>
bool TileStore::checked(const std::string& file, Check&& check) {
  if (!collect_damage_) {
    check();
    return true;
  }
  try {
    check();
    return true;
  } catch (const StorageError& e) {
    if (e.kind() != StorageError::Kind::kCorrupt) throw;
    damage_.push_back({file, e.what()});
    return false;
  }
}

// A map with a manifest: every file it names must be there, with a sound header that matches the
// manifest (the payload is checked when the tile is read); any other tile file must be one the
// map itself left behind.
void TileStore::open_manifest(const std::string& path) {
  const std::vector<std::uint8_t> bytes = read_file(path);
  const MapManifest m = decode_manifest(bytes, path);
  manifest_bytes_ = bytes.size();
  commit_ = m.commit;
  state_ = m.state;
  for (const ManifestTile& t : m.tiles) {
    const std::string tile_path = dir_.tile_path(t.key, t.generation);
    if (checked(tile_path, [&] { check_named_tile(t, tile_path, path); })) adopt(t);
  }
  std::unordered_set<std::string> retired_names;
  for (const RetiredFile& r : m.retired) retired_names.insert(tile_file_name(r.key, r.generation));
  for (const ListedTile& f : dir_.tile_files()) {
    const TileImage* image = find(f.key);
    if (image != nullptr && image->generation == f.generation) continue;
    if (f.generation > commit_ || retired_names.count(f.name) != 0) {
      retired_.push_back({f.key, f.generation});  // retired, or written by a commit that did not finish
      continue;
    }
    const std::string file = dir_.path_of(f.name);
    (void)checked(file, [&] {
      throw StorageError(StorageError::Kind::kCorrupt, file,
                         "iwlomap: tile file " + file + " is not part of the map in " + dir_.path() +
                             ": its manifest does not name it (copied in from another map?); move it out of the "
                             "directory");
    });
  }
}

// Checks that the tile file \p tile_path the manifest \p manifest_path names for \p t is there,
// with a sound header that matches the manifest.
void TileStore::check_named_tile(const ManifestTile& t, const std::string& tile_path,
                                 const std::string& path) const {
  struct stat st {};
  if (::stat(tile_path.c_str(), &st) != 0) {
    const int err = errno;
    if (err != ENOENT)
      throw StorageError(StorageError::Kind::kIo, tile_path, "iwlomap: cannot read " + tile_path + ": " + std::strerror(err));
    throw StorageError(StorageError::Kind::kCorrupt, tile_path,
                       "iwlomap: tile file " + tile_path + " is missing: the map's manifest " + path +
                           " names it (deleted or moved away?); 'iwlomap repair " + dir_.path() +
                           "' makes a map of the other tiles");
  }
  if (!S_ISREG(st.st_mode))
    throw StorageError(StorageError::Kind::kCorrupt, tile_path,
                       "iwlomap: tile file " + tile_path + " is not a regular file (the map's manifest " + path +
                           " names it)");
  // The header too (a small read per tile): a damaged map fails here, before anything changes.
  std::uint64_t size = 0;
  const TileHeader h = read_tile_header(tile_path, resolution_, tile_voxels_, t.key, size);
  if (size != t.bytes || h.header_crc != t.header_crc || h.known_voxels != t.known)
    throw_corrupt(tile_path, "it is not the file the map's manifest " + path + " names (" + std::to_string(size) +
                                 " bytes, header CRC-32 " + hex32(h.header_crc) + "; the manifest says " +
                                 std::to_string(t.bytes) + " bytes, " + hex32(t.header_crc) +
                                 "): replaced by another file?");
}

// A map written before manifests: its tile files are the map; files of a generation were written
// by a first commit that did not finish.
void TileStore::open_listed() {
  for (const ListedTile& f : dir_.tile_files()) {
    if (f.generation != 0) {
      retired_.push_back({f.key, f.generation});
      continue;
    }
    const std::string path = dir_.path_of(f.name);
    std::uint64_t size = 0;
    TileHeader h;
    if (checked(path, [&] { h = read_tile_header(path, resolution_, tile_voxels_, f.key, size); }))
      adopt({f.key, 0, size, h.known_voxels, h.header_crc});
  }
}

// Makes \p t the tile's committed file (its staged image, if any, is dropped).
void TileStore::adopt(const ManifestTile& t) {
  TileImage& image = images_[t.key];
  committed_bytes_ -= image.committed ? image.committed_bytes : 0;
  image.committed = true;
  image.generation = t.generation;
  image.committed_bytes = t.bytes;
  image.committed_known = image.known = static_cast<std::size_t>(t.known);
  image.header_crc = t.header_crc;
  committed_bytes_ += t.bytes;
  unstage(image);
}

ManifestTile TileStore::entry_of(const VoxelKey& key, const TileImage& image) {
  return {key, image.generation, image.committed_bytes, image.committed_known, image.header_crc};
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

MapManifest TileStore::committed_manifest() const {
  MapManifest m;
  m.commit = commit_;
  m.state = state_;
  for (const auto& [k, image] : images_)
    if (image.committed) m.tiles.push_back(entry_of(k, image));
  sort_by_tile(m.tiles);
  return m;
}

TileHeader TileStore::read(const VoxelKey& key, std::vector<std::uint8_t>& bytes, std::string& where) {
  const TileImage& image = images_.at(key);
  if (image.staged) {
    where = staging_path() + " (staged image of " + tile_file_name(key) + ")";
    read_at(staging_fd_, image.staged_offset, static_cast<std::size_t>(image.staged_bytes), where, bytes);
    return parse_tile_header(bytes.data(), bytes.size(), bytes.size(), resolution_, tile_voxels_, key, where);
  }
  where = dir_.tile_path(key, image.generation);
  bytes = read_file(where);
  const TileHeader h = parse_tile_header(bytes.data(), bytes.size(), bytes.size(), resolution_, tile_voxels_, key, where);
  if (h.header_crc != image.header_crc)
    throw_corrupt(where, "it is not the file the map's last commit wrote (header CRC-32 " + hex32(h.header_crc) +
                             ", recorded " + hex32(image.header_crc) + "): replaced by another file?");
  return h;
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

void TileStore::write(const VoxelKey& key, const std::vector<std::uint8_t>& encoded, std::size_t known) {
  const std::uint64_t generation = commit_ + 1;
  const std::string path = dir_.tile_path(key, generation);
  // A leftover of that name (from a commit that did not finish) becomes this commit's file.
  retired_.erase(std::remove_if(retired_.begin(), retired_.end(),
                                [&](const RetiredFile& r) { return r.key == key && r.generation == generation; }),
                 retired_.end());
  write_temp_file(path, path, encoded, true);
  written_.push_back({key, generation, encoded.size(), known, load_u32(encoded.data() + kTileHeaderBytes - 4)});
}

void TileStore::write_staged(const VoxelKey& key, std::vector<std::uint8_t>& image_buffer, DenseBlock& check_block) {
  std::string where;
  const TileHeader h = read(key, image_buffer, where);
  decode_tile(image_buffer, h, tile_voxels_, where, iwlo::voxel_format(state_.params), check_block,
              [](const DenseBlock&) {});
  write(key, image_buffer, static_cast<std::size_t>(h.known_voxels));
}

void TileStore::commit(const MapState& state, bool drop_all) {
  if (!written_.empty()) sync_directory(dir_.path());  // the new files exist before a manifest names them
  if (dir_.meta().version < kMapFormatVersion) {
    // A map from before manifests: its metadata says so first, so that no older build opens it.
    MapMeta meta = dir_.meta();
    meta.params = state.params;
    meta.hit_statistics = state.hit_statistics;
    meta.hit_epoch = state.hit_epoch;
    dir_.write_meta(meta);
  }
  const std::uint64_t generation = commit_ + 1;
  MapManifest m;
  m.commit = generation;
  m.state = state;
  m.retired = retired_;
  std::unordered_set<VoxelKey, VoxelKeyHash> rewritten;
  for (const ManifestTile& w : written_) rewritten.insert(w.key);
  for (const auto& [k, image] : images_) {
    if (!image.committed) continue;
    if (drop_all || rewritten.count(k) != 0)
      m.retired.push_back({k, image.generation});
    else
      m.tiles.push_back(entry_of(k, image));
  }
  m.tiles.insert(m.tiles.end(), written_.begin(), written_.end());
  sort_by_tile(m.tiles);
  const std::vector<std::uint8_t> bytes = encode_manifest(m);
  const std::string path = dir_.path_of(kManifestName);
  write_file_durably(path + kTempSuffix, path, bytes);  // the rename is the commit

  commit_ = generation;
  state_ = state;
  manifest_bytes_ = bytes.size();
  retired_ = std::move(m.retired);
  if (drop_all) {
    for (auto& [k, image] : images_) unstage(image);
    images_.clear();
    committed_bytes_ = 0;
  }
  for (const ManifestTile& w : written_) adopt(w);
  written_.clear();
  drop_staging_if_unused();
  sync_directory(dir_.path());  // on failure the commit stands; the next one makes it durable
  remove_retired();
}

void TileStore::abort() noexcept {
  for (const ManifestTile& w : written_) ::unlink(dir_.tile_path(w.key, w.generation).c_str());
  written_.clear();
}

void TileStore::discard_staged() noexcept {
  for (auto it = images_.begin(); it != images_.end();) {
    TileImage& image = it->second;
    unstage(image);
    if (!image.committed) {
      it = images_.erase(it);
      continue;
    }
    image.known = image.committed_known;
    ++it;
  }
  drop_staging_if_unused();
}

std::vector<std::string> TileStore::set_aside_damaged() {
  std::vector<VoxelKey> keys;
  for (const auto& [k, image] : images_) keys.push_back(k);
  std::sort(keys.begin(), keys.end());
  std::vector<std::uint8_t> bytes;
  auto block = std::make_unique<DenseBlock>();
  for (const VoxelKey& k : keys) {
    const TileImage& image = images_.at(k);
    const std::string path = dir_.tile_path(k, image.generation);
    if (!checked(path, [&] {
          std::string where;
          const TileHeader h = read(k, bytes, where);
          decode_tile(bytes, h, tile_voxels_, where, iwlo::voxel_format(state_.params), *block, [](const DenseBlock&) {});
        })) {
      committed_bytes_ -= image.committed_bytes;
      images_.erase(k);
    }
  }
  std::vector<std::string> lines;
  if (damage_.empty()) return lines;
  namespace fs = std::filesystem;
  const fs::path aside = fs::path(dir_.path()) / "damaged";
  std::error_code ec;
  fs::create_directories(aside, ec);
  if (ec) throw StorageError(StorageError::Kind::kIo, aside.string(), "iwlomap: cannot create " + aside.string() + ": " + ec.message());
  for (Damage& d : damage_) {
    d.what = d.what.substr(0, d.what.find(kCorruptAdvice));  // the advice is being taken
    const fs::path from(d.file);
    if (!fs::exists(fs::symlink_status(from, ec))) {
      lines.push_back("forgotten (missing): " + d.what);
      continue;
    }
    fs::path to = aside / from.filename();
    for (int n = 1; fs::exists(fs::symlink_status(to, ec)); ++n) to = aside / (from.filename().string() + "." + std::to_string(n));
    fs::rename(from, to, ec);
    if (ec) throw StorageError(StorageError::Kind::kIo, d.file, "iwlomap: cannot move " + d.file + " to " + to.string() + ": " + ec.message());
    lines.push_back("set aside as " + to.string() + ": " + d.what);
  }
  sync_directory(dir_.path());
  commit(state_);  // the map without them
  damage_.clear();
  return lines;
}

// Removes the files no commit names, unless a reader holds the map (it may be reading them): then
// they wait for a later commit or open. A file that cannot be removed waits too.
void TileStore::remove_retired() noexcept {
  if (retired_.empty() || !dir_.exclude_readers()) return;
  std::vector<RetiredFile> kept;
  for (const RetiredFile& r : retired_)
    if (::unlink(dir_.tile_path(r.key, r.generation).c_str()) != 0 && errno != ENOENT) kept.push_back(r);
  dir_.release_readers();
  retired_ = std::move(kept);
}

// Closes and removes the staging file once no image in it is needed.
void TileStore::drop_staging_if_unused() noexcept {
  if (staging_fd_ < 0 || staging_live_ > 0) return;
  ::close(staging_fd_);
  staging_fd_ = -1;
  staging_size_ = 0;
  ::unlink(staging_path().c_str());  // a leftover is deleted by the next open anyway
}

}  // namespace iwlomap::detail
