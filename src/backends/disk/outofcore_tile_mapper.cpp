// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/outofcore_tile_mapper.h"

#include "integrate/absolute_log_odds.h"
#include "integrate/batch_input.h"
#include "integrate/voxel_update.h"
#include "storage/block_grid.h"
#include "storage/free_memory.h"
#include "storage/grid_reads.h"
#include "storage/flat_key_map.h"
#include "integrate/scan_scratch.h"
#include "backends/disk/tile_file.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <filesystem>
#include <limits>
#include <mutex>
#include <sstream>
#include <unordered_map>
#include <utility>

namespace iwlomap {

StorageError::StorageError(Kind kind, std::string path, const std::string& message)
    : std::runtime_error(message), kind_(kind), path_(std::move(path)) {}

namespace {

namespace fs = std::filesystem;

constexpr const char* kMetaName = "iwlomap_map.meta";
constexpr const char* kLockName = "iwlomap_map.lock";
constexpr const char* kStagingName = "iwlomap_map.staging";
// The staging file is rewritten without its dead images once it is this large and more than half
// of it is dead.
constexpr std::uint64_t kCompactMinBytes = std::uint64_t{1} << 20;
constexpr const char* kMetaFirstLine = "iwlomap tile map";
constexpr const char* kTilePrefix = "tile_";
constexpr const char* kTileSuffix = ".iwt";
constexpr const char* kTempSuffix = ".tmp";
// Tiles above 8192 voxels (1024 blocks) per edge could hold more than 2^32 block records.
constexpr std::uint32_t kMaxTileVoxels = 8192;

std::string tile_file_name(const VoxelKey& t) {
  return kTilePrefix + std::to_string(t.x) + "_" + std::to_string(t.y) + "_" + std::to_string(t.z) + kTileSuffix;
}

bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

// Strict: only the exact names tile_file_name() produces, so no other file is ever taken for a
// tile (or deleted by clear()).
bool parse_tile_file_name(const std::string& name, VoxelKey& t) {
  if (name.rfind(kTilePrefix, 0) != 0 || !ends_with(name, kTileSuffix)) return false;
  const std::string body = name.substr(5, name.size() - 5 - 4);
  long v[3];
  const char* p = body.c_str();
  for (int i = 0; i < 3; ++i) {
    char* end = nullptr;
    errno = 0;
    v[i] = std::strtol(p, &end, 10);
    if (end == p || errno != 0 || v[i] < std::numeric_limits<std::int32_t>::min() ||
        v[i] > std::numeric_limits<std::int32_t>::max())
      return false;
    p = end;
    if (i < 2) {
      if (*p != '_') return false;
      ++p;
    }
  }
  if (*p != '\0') return false;
  t = {static_cast<std::int32_t>(v[0]), static_cast<std::int32_t>(v[1]), static_cast<std::int32_t>(v[2])};
  return tile_file_name(t) == name;
}

std::uint32_t tile_voxels_for(double resolution, double tile_size) {
  if (!(std::isfinite(tile_size) && tile_size > 0.0))
    throw std::invalid_argument("iwlomap: tile_size must be finite and > 0, got " + detail::describe("tile_size", tile_size));
  const double voxels = tile_size / resolution;
  const double whole = std::round(voxels);
  const bool integral = std::abs(voxels - whole) <= 1e-9 * std::max(1.0, whole);
  const auto blocks = static_cast<long long>(whole) / detail::kBlockEdge;
  if (!integral || whole < detail::kBlockEdge || whole > kMaxTileVoxels ||
      static_cast<long long>(whole) % detail::kBlockEdge != 0) {
    std::ostringstream s;
    s.precision(17);
    s << "iwlomap: tile_size / resolution must be a whole multiple of 8 voxels (one 8^3 block) between 8 and "
      << kMaxTileVoxels << ", got tile_size = " << tile_size << " and resolution = " << resolution << " ("
      << voxels << " voxels)";
    if (blocks >= 1) s << "; e.g. tile_size = " << static_cast<double>(blocks * detail::kBlockEdge) * resolution;
    throw std::invalid_argument(s.str());
  }
  return static_cast<std::uint32_t>(whole);
}

std::string hexfloat(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%a", v);
  return buf;
}

struct MapMeta {
  std::uint32_t version = detail::kTileFormatVersion;
  double resolution = 0.0;
  double tile_size = 0.0;
  std::uint32_t tile_voxels = 0;
};

std::vector<std::uint8_t> encode_meta(const MapMeta& m) {
  std::ostringstream s;
  s.precision(17);
  s << kMetaFirstLine << "\n"
    << "format_version " << m.version << "\n"
    << "resolution " << hexfloat(m.resolution) << "\n"
    << "tile_size " << hexfloat(m.tile_size) << "\n"
    << "tile_voxels " << m.tile_voxels << "\n"
    << "# resolution " << m.resolution << " m, tiles of " << m.tile_size << " m (" << m.tile_voxels
    << " voxels); tiles are tile_<x>_<y>_<z>.iwt, see src/detail/tile_file.h\n";
  const std::string text = s.str();
  return {text.begin(), text.end()};
}

[[noreturn]] void throw_bad_meta(const std::string& path, const std::string& what) {
  throw StorageError(StorageError::Kind::kCorrupt, path, "iwlomap: map metadata " + path + " is corrupt: " + what);
}

MapMeta parse_meta(const std::vector<std::uint8_t>& bytes, const std::string& path) {
  std::istringstream in(std::string(bytes.begin(), bytes.end()));
  std::string line;
  if (!std::getline(in, line) || line != kMetaFirstLine) throw_bad_meta(path, "it does not start with '" + std::string(kMetaFirstLine) + "'");
  MapMeta m;
  bool have_version = false, have_res = false, have_size = false, have_voxels = false;
  while (std::getline(in, line)) {
    if (line.empty() || line[0] == '#') continue;
    const auto space = line.find(' ');
    if (space == std::string::npos) throw_bad_meta(path, "line '" + line + "' has no value");
    const std::string key = line.substr(0, space);
    const std::string value = line.substr(space + 1);
    char* end = nullptr;
    errno = 0;
    if (key == "format_version" || key == "tile_voxels") {
      const unsigned long v = std::strtoul(value.c_str(), &end, 10);
      if (end == value.c_str() || *end != '\0' || errno != 0 || v > std::numeric_limits<std::uint32_t>::max())
        throw_bad_meta(path, "bad " + key + " '" + value + "'");
      (key == "format_version" ? m.version : m.tile_voxels) = static_cast<std::uint32_t>(v);
      (key == "format_version" ? have_version : have_voxels) = true;
    } else if (key == "resolution" || key == "tile_size") {
      const double v = std::strtod(value.c_str(), &end);
      if (end == value.c_str() || *end != '\0' || !std::isfinite(v) || v <= 0.0)
        throw_bad_meta(path, "bad " + key + " '" + value + "'");
      (key == "resolution" ? m.resolution : m.tile_size) = v;
      (key == "resolution" ? have_res : have_size) = true;
    }
    // Other keys are ignored: a later minor version may add informative ones.
  }
  if (!have_version) throw_bad_meta(path, "format_version is missing");
  if (m.version > detail::kTileFormatVersion)
    throw StorageError(StorageError::Kind::kNewerVersion, path,
                       "iwlomap: map metadata " + path + " has format version " + std::to_string(m.version) +
                           ", newer than the version " + std::to_string(detail::kTileFormatVersion) +
                           " this build reads; open the map with a newer iwlomap");
  if (m.version == 0) throw_bad_meta(path, "format_version 0");
  if (!have_res || !have_size || !have_voxels) throw_bad_meta(path, "resolution, tile_size or tile_voxels is missing");
  return m;
}

// Tiles are resident (with their grid) or only on disk; the index below knows both.
struct Tile {
  explicit Tile(const VoxelKey& k) : key(k) {}
  VoxelKey key;
  detail::BlockGrid grid;
  std::size_t known = 0;
  bool dirty = false;
  bool pinned = false;  // needed by the call in progress: never evicted
  std::uint64_t last_used = 0;
};

// A tile on disk: its committed file tile_<x>_<y>_<z>.iwt, and possibly a staged image, a newer
// complete state that an eviction appended to the staging file (one file for all evicted tiles,
// not fsync'ed: appending costs no file creation, which dominates on many file systems). flush()
// writes staged images to their tile files; a crash discards the staging file (the next open
// deletes it), so tile files only ever change at a flush.
struct TileInfo {
  Tile* resident = nullptr;
  bool committed = false;
  bool staged = false;
  std::uint64_t committed_bytes = 0;
  std::uint64_t staged_offset = 0;  // in the staging file
  std::uint64_t staged_bytes = 0;
  std::size_t file_known = 0;  // known voxels of the newest image (staged, else committed)
  [[nodiscard]] bool on_disk() const noexcept { return committed || staged; }
};

// Items (observations, voxels) of one call sorted by tile, stable, so that each tile is loaded
// once per call and every voxel sees its observations in call order.
struct Routing {
  std::vector<VoxelKey> slot_tiles;  // tile coordinate of each slot
  detail::FlatKeyMap slot_index;     // tile coordinate -> slot
  std::vector<std::uint32_t> slot_of;
  std::vector<std::uint32_t> order;
  std::vector<std::size_t> begin;  // slot s owns order[begin[s], begin[s + 1])

  void reset() {
    slot_tiles.clear();
    slot_index.clear_keep_capacity();
  }
  std::uint32_t slot(const VoxelKey& tile) {
    const auto next = static_cast<std::uint32_t>(slot_tiles.size());
    const std::uint32_t s = slot_index.insert(tile, next);
    if (s == next) slot_tiles.push_back(tile);
    return s;
  }
  [[nodiscard]] std::size_t bytes() const noexcept {
    return slot_tiles.capacity() * sizeof(VoxelKey) + slot_index.bytes() +
           (slot_of.capacity() + order.capacity()) * sizeof(std::uint32_t) + begin.capacity() * sizeof(std::size_t);
  }
};

}  // namespace

struct OutofcoreTileMapper::Impl {
  Impl(const std::string& directory, double res, double tile, std::size_t cache)
      : dir(directory), resolution(res), tile_size(tile), cache_tiles(cache) {}

  ~Impl() {
    // The destructor's contract: flush, never throw. Every file keeps its last complete state.
    try {
      flush();
    } catch (...) {
    }
    if (staging_fd >= 0) ::close(staging_fd);
    if (lock_fd >= 0) ::close(lock_fd);
  }
  Impl(const Impl&) = delete;
  Impl& operator=(const Impl&) = delete;

  // ---- paths and geometry ----

  [[nodiscard]] std::string path_of(const std::string& name) const { return (fs::path(dir) / name).string(); }
  [[nodiscard]] std::string tile_path(const VoxelKey& t) const { return path_of(tile_file_name(t)); }

  [[nodiscard]] VoxelKey tile_of_voxel(const VoxelKey& k) const noexcept {
    const auto e = static_cast<std::int32_t>(tile_voxels);
    return {detail::floor_div(k.x, e), detail::floor_div(k.y, e), detail::floor_div(k.z, e)};
  }
  [[nodiscard]] VoxelKey tile_of_block(const VoxelKey& b) const noexcept {
    return {detail::floor_div(b.x, tile_blocks), detail::floor_div(b.y, tile_blocks), detail::floor_div(b.z, tile_blocks)};
  }

  // ---- opening ----

  void open() {
    tile_voxels = tile_voxels_for(resolution, tile_size);
    tile_blocks = static_cast<std::int32_t>(tile_voxels / detail::kBlockEdge);
    std::error_code ec;
    fs::create_directories(dir, ec);
    if (ec || !fs::is_directory(dir))
      throw StorageError(StorageError::Kind::kIo, dir,
                         "iwlomap: cannot use " + dir + " as a map directory: " +
                             (ec ? ec.message() : std::string("it exists and is not a directory")));
    lock_directory();
    const std::string meta_path = path_of(kMetaName);
    std::vector<std::string> tile_names, temp_names;
    for (fs::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
      std::error_code type_ec;
      if (!it->is_regular_file(type_ec)) continue;  // a directory named like a tile is not ours
      const std::string name = it->path().filename().string();
      VoxelKey t;
      if (parse_tile_file_name(name, t))
        tile_names.push_back(name);
      else if ((ends_with(name, kTempSuffix) && (name == std::string(kMetaName) + kTempSuffix ||
                                                   parse_tile_file_name(name.substr(0, name.size() - 4), t))) ||
               name == kStagingName || name == std::string(kStagingName) + ".new")
        temp_names.push_back(name);
    }
    if (ec) throw StorageError(StorageError::Kind::kIo, dir, "iwlomap: cannot list map directory " + dir + ": " + ec.message());
    std::sort(tile_names.begin(), tile_names.end());

    if (fs::exists(meta_path, ec)) {
      std::uint64_t size = 0;
      const MapMeta m = parse_meta(detail::read_file_prefix(meta_path, 1 << 16, size), meta_path);
      meta_bytes = size;
      if (m.resolution != resolution || m.tile_size != tile_size || m.tile_voxels != tile_voxels) {
        std::ostringstream s;
        s.precision(17);
        s << "iwlomap: the map in " << dir << " was created with resolution = " << m.resolution
          << " and tile_size = " << m.tile_size << ", not resolution = " << resolution
          << " and tile_size = " << tile_size << "; open it with the stored values";
        throw std::invalid_argument(s.str());
      }
    } else {
      if (!tile_names.empty())
        throw StorageError(StorageError::Kind::kCorrupt, meta_path,
                           "iwlomap: " + dir + " holds tile files (" + tile_names.front() + ", ...) but no map metadata " +
                               meta_path + "; its resolution and tile size are unknown");
      MapMeta m;
      m.resolution = resolution;
      m.tile_size = tile_size;
      m.tile_voxels = tile_voxels;
      const std::vector<std::uint8_t> bytes = encode_meta(m);
      detail::write_file_durably(meta_path + kTempSuffix, meta_path, bytes);
      detail::sync_directory(dir);
      meta_bytes = bytes.size();
    }
    for (const std::string& name : tile_names) {
      VoxelKey t;
      (void)parse_tile_file_name(name, t);
      const std::string path = path_of(name);
      std::uint64_t size = 0;
      const std::vector<std::uint8_t> head = detail::read_file_prefix(path, detail::kTileHeaderBytes, size);
      const detail::TileHeader h =
          detail::parse_tile_header(head.data(), head.size(), size, resolution, tile_voxels, t, path);
      TileInfo& info = tiles[t];
      info.committed = true;
      info.committed_bytes = size;
      info.file_known = static_cast<std::size_t>(h.known_voxels);
      total_known += info.file_known;
      committed_bytes_total += size;
    }
    // The staging file and writes interrupted by a crash: never committed, not necessarily complete
    // on disk (no fsync), and always ours. Removed only once every tile checked out, so that an open
    // that fails changes no file.
    for (const std::string& name : temp_names) detail::remove_file(path_of(name));
  }

  void lock_directory() {
    const std::string path = path_of(kLockName);
    lock_fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (lock_fd < 0)
      throw StorageError(StorageError::Kind::kIo, path, "iwlomap: cannot create lock file " + path + ": " + std::strerror(errno));
    int r;
    do r = ::flock(lock_fd, LOCK_EX | LOCK_NB);
    while (r != 0 && errno == EINTR);
    if (r != 0) {
      const int err = errno;
      ::close(lock_fd);
      lock_fd = -1;
      if (err == EWOULDBLOCK)
        throw StorageError(StorageError::Kind::kLocked, dir,
                           "iwlomap: the map directory " + dir + " is already open in another mapper (this process or another)");
      throw StorageError(StorageError::Kind::kIo, path, "iwlomap: cannot lock " + path + ": " + std::strerror(err));
    }
  }

  // ---- the cache ----

  void touch(Tile& t) { t.last_used = ++tick; }

  [[nodiscard]] std::string staging_path() const { return path_of(kStagingName); }

  // The newest image of a tile (staged, else committed) into \p bytes; returns the path that
  // names it in messages.
  std::string read_image(const VoxelKey& key, const TileInfo& info, std::vector<std::uint8_t>& bytes) {
    if (info.staged) {
      const std::string where = staging_path() + " (staged image of " + tile_file_name(key) + ")";
      detail::read_at(staging_fd, info.staged_offset, static_cast<std::size_t>(info.staged_bytes), where, bytes);
      return where;
    }
    const std::string path = tile_path(key);
    bytes = detail::read_file(path);
    return path;
  }

  // Reads and fully checks the newest image of a tile. Nothing changes when it throws.
  std::unique_ptr<Tile> read_tile(const VoxelKey& key, const TileInfo& info) {
    std::vector<std::uint8_t> bytes;
    const std::string path = read_image(key, info, bytes);
    const detail::TileHeader h =
        detail::parse_tile_header(bytes.data(), bytes.size(), bytes.size(), resolution, tile_voxels, key, path);
    auto tile = std::make_unique<Tile>(key);
    auto scratch = std::make_unique<detail::DenseBlock>();
    detail::decode_tile(bytes, h, tile_voxels, path, *scratch,
                        [&](const detail::DenseBlock& b) { tile->grid.add_dense(b); });
    tile->known = static_cast<std::size_t>(h.known_voxels);
    return tile;
  }

  void unstage(TileInfo& info) {
    if (!info.staged) return;
    staging_live -= info.staged_bytes;
    info.staged = false;
  }

  // Appends a dirty tile's image to the staging file (eviction). On failure nothing changes: the
  // tile stays dirty, and a previous staged image of it stays valid.
  void stage_tile(Tile& t, TileInfo& info) {
    (void)detail::encode_tile(t.grid, resolution, tile_voxels, t.key, io_buffer);
    if (staging_fd < 0) {
      staging_fd = detail::create_scratch_file(staging_path());
      staging_size = 0;
      staging_live = 0;
    } else if (staging_size >= kCompactMinBytes && staging_size > 2 * staging_live) {
      compact_staging();
    }
    detail::write_at(staging_fd, io_buffer, staging_size, staging_path());
    unstage(info);
    info.staged = true;
    info.staged_offset = staging_size;
    info.staged_bytes = io_buffer.size();
    info.file_known = t.known;
    staging_size += io_buffer.size();
    staging_live += io_buffer.size();
    t.dirty = false;
  }

  // Rewrites the staging file with the live images only (a new file renamed over the old one: if
  // anything fails, the old file and its offsets stay valid).
  void compact_staging() {
    const std::string fresh_path = staging_path() + ".new";
    const int fresh = detail::create_scratch_file(fresh_path);
    std::vector<std::pair<TileInfo*, std::uint64_t>> moved;  // new offsets, applied on success
    std::uint64_t size = 0;
    try {
      std::vector<VoxelKey> keys;
      for (const auto& [k, info] : tiles)
        if (info.staged) keys.push_back(k);
      std::sort(keys.begin(), keys.end());
      std::vector<std::uint8_t> bytes;
      for (const VoxelKey& k : keys) {
        TileInfo& info = tiles.at(k);
        detail::read_at(staging_fd, info.staged_offset, static_cast<std::size_t>(info.staged_bytes), staging_path(), bytes);
        detail::write_at(fresh, bytes, size, fresh_path);
        moved.emplace_back(&info, size);
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
    ::close(staging_fd);
    staging_fd = fresh;
    for (const auto& [info, offset] : moved) info->staged_offset = offset;
    staging_size = size;
    staging_live = size;
  }

  // Closes and removes the staging file once no image in it is needed.
  void drop_staging_if_unused() {
    if (staging_fd < 0 || staging_live > 0) return;
    ::close(staging_fd);
    staging_fd = -1;
    staging_size = 0;
    ::unlink(staging_path().c_str());  // a leftover is deleted by the next open anyway
  }

  // Evicts least recently used unpinned tiles until one more fits. A dirty tile that cannot be
  // written stays resident and dirty, and the error propagates.
  void make_room() {
    while (resident.size() >= cache_tiles) {
      std::size_t victim = resident.size();
      for (std::size_t i = 0; i < resident.size(); ++i)
        if (!resident[i]->pinned && (victim == resident.size() || resident[i]->last_used < resident[victim]->last_used))
          victim = i;
      if (victim == resident.size()) throw std::logic_error("iwlomap: every resident tile is pinned");
      Tile& t = *resident[victim];
      TileInfo& info = tiles.at(t.key);
      if (t.dirty) stage_tile(t, info);  // flush() makes it durable
      info.resident = nullptr;
      if (!info.on_disk()) tiles.erase(t.key);  // an empty tile that was never written
      resident.erase(resident.begin() + static_cast<std::ptrdiff_t>(victim));
    }
  }

  Tile& insert_resident(std::unique_ptr<Tile> tile, TileInfo& info) {
    tile->pinned = true;
    touch(*tile);
    info.resident = tile.get();
    resident.push_back(std::move(tile));
    peak_resident = std::max(peak_resident, resident.size());
    return *resident.back();
  }

  // Makes the tiles \p keys (at most cache_tiles, distinct) resident and pinned; out[i] is keys[i]'s
  // tile. Tiles on disk are read (and checked) before any new tile is created, so a corrupt tile
  // makes the call fail before a voxel changes.
  void make_resident(const std::vector<VoxelKey>& keys, std::vector<Tile*>& out) {
    out.assign(keys.size(), nullptr);
    for (std::size_t i = 0; i < keys.size(); ++i) {
      const auto it = tiles.find(keys[i]);
      if (it != tiles.end() && it->second.resident != nullptr) {
        out[i] = it->second.resident;
        out[i]->pinned = true;
        touch(*out[i]);
      }
    }
    for (std::size_t i = 0; i < keys.size(); ++i) {
      if (out[i] != nullptr) continue;
      const auto it = tiles.find(keys[i]);
      if (it == tiles.end()) continue;
      std::unique_ptr<Tile> tile = read_tile(keys[i], it->second);
      // The file may have changed since the header was read at open: keep the count exact.
      total_known = total_known - it->second.file_known + tile->known;
      it->second.file_known = tile->known;
      make_room();
      out[i] = &insert_resident(std::move(tile), tiles.at(keys[i]));
    }
    for (std::size_t i = 0; i < keys.size(); ++i) {
      if (out[i] != nullptr) continue;
      make_room();
      out[i] = &insert_resident(std::make_unique<Tile>(keys[i]), tiles[keys[i]]);
    }
  }

  void unpin_all() noexcept {
    for (auto& t : resident) t->pinned = false;
  }

  // Unpins on every exit path of a call.
  struct PinScope {
    explicit PinScope(Impl& m) : m_(m) {}
    ~PinScope() { m_.unpin_all(); }
    PinScope(const PinScope&) = delete;
    PinScope& operator=(const PinScope&) = delete;
    Impl& m_;
  };

  // Splits the slots of routing into groups of at most cache_tiles, resident tiles first so that a
  // call never evicts a tile it needs later. Calls fn(group slots, their tiles) per group.
  template <class Fn>
  void for_each_group(Fn&& fn) {
    const std::size_t n = routing.slot_tiles.size();
    std::vector<std::uint32_t> slots(n);
    for (std::uint32_t s = 0; s < n; ++s) slots[s] = s;
    std::stable_partition(slots.begin(), slots.end(), [&](std::uint32_t s) {
      const auto it = tiles.find(routing.slot_tiles[s]);
      return it != tiles.end() && it->second.resident != nullptr;
    });
    std::vector<VoxelKey> keys;
    std::vector<Tile*> group_tiles;
    for (std::size_t first = 0; first < n; first += cache_tiles) {
      const std::size_t last = std::min(n, first + cache_tiles);
      keys.clear();
      for (std::size_t i = first; i < last; ++i) keys.push_back(routing.slot_tiles[slots[i]]);
      PinScope pins(*this);
      make_resident(keys, group_tiles);
      fn(slots.data() + first, group_tiles.data(), last - first);
    }
  }

  // Sorts items 0..n-1 by tile (stable). voxel_key(i) gives item i's voxel key.
  template <class KeyOf>
  void route(std::size_t n, KeyOf&& voxel_key) {
    assign_slots(n, voxel_key);
    sort_by_slot(n);
  }

  // The slot (tile) of every item, in routing.slot_of.
  template <class KeyOf>
  void assign_slots(std::size_t n, KeyOf&& voxel_key) {
    routing.reset();
    routing.slot_of.resize(n);
    const std::int64_t e = tile_voxels;
    std::int64_t lo[3] = {0, 0, 0};
    std::uint32_t last = detail::FlatKeyMap::kEmpty;
    for (std::size_t i = 0; i < n; ++i) {
      const VoxelKey k = voxel_key(i);
      if (last == detail::FlatKeyMap::kEmpty || k.x < lo[0] || k.x >= lo[0] + e || k.y < lo[1] || k.y >= lo[1] + e ||
          k.z < lo[2] || k.z >= lo[2] + e) {
        const VoxelKey t = tile_of_voxel(k);
        last = routing.slot(t);
        lo[0] = t.x * e;
        lo[1] = t.y * e;
        lo[2] = t.z * e;
      }
      routing.slot_of[i] = last;
    }
  }

  void sort_by_slot(std::size_t n) {
    const std::size_t slots = routing.slot_tiles.size();
    routing.begin.assign(slots + 1, 0);
    for (std::size_t i = 0; i < n; ++i) ++routing.begin[routing.slot_of[i] + 1];
    for (std::size_t s = 0; s < slots; ++s) routing.begin[s + 1] += routing.begin[s];
    routing.order.resize(n);
    std::vector<std::size_t> next(routing.begin.begin(), routing.begin.end() - 1);
    for (std::size_t i = 0; i < n; ++i) routing.order[next[routing.slot_of[i]]++] = static_cast<std::uint32_t>(i);
  }

  // ---- updates ----

  // Counts a voxel that became known in tile \p t (the block counted it already).
  void count_new(Tile& t) {
    ++t.known;
    ++total_known;
  }

  // Applies n observations of the batch, the j-th being batch[index_of(j)] in tile tile_of(j),
  // reached through accessor_of(j). Passes as in the RAM backend: resolve every voxel (allocating
  // blocks, and noting in each block the cells it lacks), allocate those cells once per block,
  // then update with the voxel of a later observation prefetched (addresses are taken only then,
  // as adding cells may move a block's cells). With a cell allocated as its row came, bench_disk's
  // survey batches ran at 0.57x the RAM backend's speed instead of 0.67x with the whole map
  // resident, 0.47x instead of 0.51x with the working set cached (one run each).
  // Its two halves are always inlined, so that apply_resident_in_call_order()'s copies for each
  // CPU level hold them.
  template <class IndexOf, class TileOf, class AccessorOf>
  void apply_observations(const detail::BatchValues& in, std::size_t n, IndexOf index_of, TileOf tile_of,
                          AccessorOf accessor_of) {
    resolve_observations(n, index_of, tile_of, accessor_of);
    update_observations(in, n, index_of, tile_of);
  }

  // The first half of apply_observations(): blocks, cells and targets. It may throw
  // (std::bad_alloc), leaving no note behind; nothing is updated yet.
  template <class IndexOf, class TileOf, class AccessorOf>
  __attribute__((always_inline)) inline void resolve_observations(std::size_t n, IndexOf index_of, TileOf tile_of,
                                                                  AccessorOf accessor_of) {
    targets.resize(n);
    pending_blocks.clear();
    try {
      for (std::size_t j = 0; j < n; ++j) {
        const VoxelKey& key = batch[index_of(j)].key;
        detail::VoxelBlock& b = accessor_of(j).block(detail::block_of(key));
        const int index = detail::index_in_block(key);
        const int cell = index >> detail::kCellShift;
        if (!b.has_cell(cell)) {
          // Listed before the note is made: emplace_back may throw.
          if (!b.pending.any()) pending_blocks.emplace_back(&b, &tile_of(j).grid);
          b.note_pending(cell);
        }
        targets[j] = {&b, index};
      }
      for (const auto& [b, grid] : pending_blocks) {
        grid->ensure_cells(*b, b->pending);
        b->pending = {};
      }
    } catch (...) {
      // Out of memory: no note may outlive the call.
      for (const auto& [b, grid] : pending_blocks) b->pending = {};
      throw;
    }
  }

  // The second half of apply_observations(): the updates, which cannot fail.
  template <class IndexOf, class TileOf>
  __attribute__((always_inline)) inline void update_observations(const detail::BatchValues& in, std::size_t n,
                                                                 IndexOf index_of, TileOf tile_of) {
    const auto voxel = [this](std::size_t j) -> detail::Voxel& { return targets[j].first->existing(targets[j].second); };
    constexpr std::size_t kAhead = 16;
    for (std::size_t j = 0; j < n; ++j) {
      if (j + kAhead < n) __builtin_prefetch(&voxel(j + kAhead), 1);
      const std::uint32_t row = batch[index_of(j)].row;
      if (detail::observe_voxel(*targets[j].first, voxel(j), in.intensity(row), in.occupied_flag(row), in.weight(row),
                                updater))
        count_new(tile_of(j));
    }
  }

  void apply_batch(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                   const std::vector<bool>& is_occupied, const Eigen::VectorXd* weights) {
    const std::size_t skip = detail::prepare_batch(points, intensities, is_occupied, weights, resolution, batch);
    const detail::BatchValues in{intensities, is_occupied, weights};
    assign_slots(batch.size(), [&](std::size_t i) { return batch[i].key; });
    if (routing.slot_tiles.size() <= cache_tiles) {
      apply_in_call_order(in);
    } else {
      sort_by_slot(batch.size());
      for_each_group([&](const std::uint32_t* slots, Tile* const* group, std::size_t count) {
        for (std::size_t g = 0; g < count; ++g) {
          Tile& t = *group[g];
          detail::BlockAccessor acc(t.grid);
          const std::size_t from = routing.begin[slots[g]];
          apply_observations(
              in, routing.begin[slots[g] + 1] - from, [&](std::size_t j) { return routing.order[from + j]; },
              [&](std::size_t) -> Tile& { return t; }, [&](std::size_t) -> detail::BlockAccessor& { return acc; });
          t.dirty = true;
        }
      });
    }
    skipped += skip;
  }

  // The common case: every tile of the batch fits in the cache at once. They are loaded first
  // (so an I/O error changes nothing), then the batch is applied in call order exactly as the RAM
  // backend does, without sorting it by tile.
  void apply_in_call_order(const detail::BatchValues& in) {
    PinScope pins(*this);
    make_resident(routing.slot_tiles, slot_tile);
    accessors.clear();
    for (Tile* t : slot_tile) accessors.emplace_back(t->grid);
    if (const std::exception_ptr e = apply_resident_in_call_order(in)) std::rethrow_exception(e);
    for (Tile* t : slot_tile) t->dirty = true;
  }

  // The updates of apply_in_call_order(), its tiles resident. Compiled per CPU level, as the RAM
  // backend's batch (with the copies bench_disk's survey batches ran at 0.52-0.55x the RAM
  // backend's speed with the working set cached, two runs, against 0.48x without); it returns what
  // it throws (see IWLOMAP_CPU_CLONES).
  // Only the first half runs inside the try: a try around the update loop made the RAM backend's
  // copy spill its values (the same batch again 17% slower).
  IWLOMAP_CPU_CLONES std::exception_ptr apply_resident_in_call_order(const detail::BatchValues& in) noexcept {
    const auto index_of = [](std::size_t i) { return i; };
    const auto tile_of = [&](std::size_t i) -> Tile& { return *slot_tile[routing.slot_of[i]]; };
    try {
      resolve_observations(batch.size(), index_of, tile_of,
                           [&](std::size_t i) -> detail::BlockAccessor& { return accessors[routing.slot_of[i]]; });
    } catch (...) {
      return std::current_exception();
    }
    update_observations(in, batch.size(), index_of, tile_of);
    return nullptr;
  }

  void insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                   double max_range, int threads) {
    detail::check_scan_input(origin, points, intensities, max_range, resolution);
    const std::size_t skip = scratch.collect(origin, points, intensities, max_range, resolution, threads);

    // Which tiles the scan touches, and which scratch chunks hold each tile's free voxels (a
    // 32^3 chunk may straddle tiles). Hits are routed like batch observations.
    const std::size_t chunks = scratch.num_chunks();
    const std::vector<detail::ScanScratch::Hit>& hits = scratch.hits();
    route(hits.size(), [&](std::size_t i) { return hits[i].key; });
    const auto grow_lists = [&] {
      const std::size_t slots = routing.slot_tiles.size();
      if (slot_chunks.size() < slots) slot_chunks.resize(slots);
      if (slot_last_chunk.size() < slots) slot_last_chunk.resize(slots);
    };
    grow_lists();
    for (std::size_t s = 0; s < routing.slot_tiles.size(); ++s) {
      slot_chunks[s].clear();
      slot_last_chunk[s] = kNoChunk;
    }
    for (std::size_t ci = 0; ci < chunks; ++ci) {
      VoxelKey last_block{};
      bool first = true;
      scratch.for_each_free(ci, ci + 1, [&](const VoxelKey& block_key, int) {
        if (!first && block_key == last_block) return;
        first = false;
        last_block = block_key;
        const std::size_t before = routing.slot_tiles.size();
        const std::uint32_t s = routing.slot(tile_of_block(block_key));
        if (routing.slot_tiles.size() != before) {
          grow_lists();
          slot_chunks[s].clear();
          slot_last_chunk[s] = kNoChunk;
        }
        if (slot_last_chunk[s] != ci) {
          slot_chunks[s].push_back(ci);
          slot_last_chunk[s] = ci;
        }
      });
    }
    // Slots added by free voxels own no hits.
    routing.begin.resize(routing.slot_tiles.size() + 1, routing.begin.back());

    const std::size_t slots = routing.slot_tiles.size();
    slot_group.assign(slots, kNoGroup);
    slot_tile.assign(slots, nullptr);
    std::size_t group_id = 0;
    for_each_group([&](const std::uint32_t* group_slots, Tile* const* group, std::size_t count) {
      ++group_id;
      for (std::size_t g = 0; g < count; ++g) {
        slot_group[group_slots[g]] = group_id;
        slot_tile[group_slots[g]] = group[g];
      }
      Tile* tile = nullptr;
      detail::VoxelBlock* block = nullptr;
      VoxelKey block_key_cached{};
      bool have_block = false;
      const auto apply_free = [&](const VoxelKey& block_key, int index) {
        if (!have_block || block_key != block_key_cached) {
          have_block = true;
          block_key_cached = block_key;
          const std::uint32_t s = routing.slot_index.find(tile_of_block(block_key));
          tile = slot_group[s] == group_id ? slot_tile[s] : nullptr;
          block = tile != nullptr ? &tile->grid.get_or_create(block_key) : nullptr;
        }
        if (block == nullptr) return;
        if (detail::observe_voxel(*block, tile->grid.voxel(*block, index), 0.0, false, 1.0, updater))
          count_new(*tile);
      };
      if (count == slots) {
        scratch.for_each_free(0, chunks, apply_free);
      } else {
        group_chunks.clear();
        for (std::size_t g = 0; g < count; ++g)
          group_chunks.insert(group_chunks.end(), slot_chunks[group_slots[g]].begin(), slot_chunks[group_slots[g]].end());
        std::sort(group_chunks.begin(), group_chunks.end());
        group_chunks.erase(std::unique(group_chunks.begin(), group_chunks.end()), group_chunks.end());
        for (const std::size_t ci : group_chunks) scratch.for_each_free(ci, ci + 1, apply_free);
      }
      for (std::size_t g = 0; g < count; ++g) {
        Tile& t = *group[g];
        detail::BlockAccessor acc(t.grid);
        const std::uint32_t s = group_slots[g];
        for (std::size_t j = routing.begin[s]; j < routing.begin[s + 1]; ++j) {
          const detail::ScanScratch::Hit& h = hits[routing.order[j]];
          detail::VoxelBlock* b = nullptr;
          detail::Voxel& v = acc.voxel(h.key, b);
          if (detail::observe_voxel(*b, v, h.intensity, true, 1.0, updater))
            count_new(t);
        }
        t.dirty = true;
      }
    });
    skipped += skip;
  }

  void set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) {
    std::vector<detail::AbsoluteLogOdds> values;
    const std::size_t skip = detail::prepare_log_odds(points, log_odds, updater.params(), resolution, values);
    route(values.size(), [&](std::size_t i) { return values[i].key; });
    for_each_group([&](const std::uint32_t* slots, Tile* const* group, std::size_t count) {
      for (std::size_t g = 0; g < count; ++g) {
        Tile& t = *group[g];
        detail::BlockAccessor acc(t.grid);
        for (std::size_t j = routing.begin[slots[g]]; j < routing.begin[slots[g] + 1]; ++j) {
          const detail::AbsoluteLogOdds& a = values[routing.order[j]];
          detail::VoxelBlock* b = nullptr;
          detail::Voxel& v = acc.voxel(a.key, b);
          if (detail::set_voxel_log_odds(*b, v, a.log_odds))
            count_new(t);
        }
        t.dirty = true;
      }
    });
    skipped += skip;
  }

  // ---- reading the whole map ----

  // Calls fn(key, const Voxel&) for every known voxel of every tile, tiles in key order: resident
  // ones from RAM, the others read one at a time and dropped (the cache is left as it is).
  template <class Fn>
  void for_each_known(Fn&& fn) {
    std::vector<VoxelKey> keys;
    keys.reserve(tiles.size());
    for (const auto& [k, info] : tiles) keys.push_back(k);
    std::sort(keys.begin(), keys.end());
    std::unique_ptr<detail::DenseBlock> scratch_block;
    for (const VoxelKey& k : keys) {
      const TileInfo& info = tiles.at(k);
      if (info.resident != nullptr) {
        detail::for_each_known(info.resident->grid, fn);
        continue;
      }
      std::vector<std::uint8_t> bytes;
      const std::string path = read_image(k, info, bytes);
      const detail::TileHeader h =
          detail::parse_tile_header(bytes.data(), bytes.size(), bytes.size(), resolution, tile_voxels, k, path);
      if (h.known_voxels != info.file_known)
        detail::throw_corrupt(path, "it holds " + std::to_string(h.known_voxels) + " voxels, " +
                                        std::to_string(info.file_known) + " when last written or read (changed by another program?)");
      if (!scratch_block) scratch_block = std::make_unique<detail::DenseBlock>();
      detail::decode_tile(bytes, h, tile_voxels, path, *scratch_block, [&fn](const detail::DenseBlock& b) {
        for (int i = 0; i < detail::kBlockVoxels; ++i) {
          const detail::Voxel& v = b.voxels[static_cast<std::size_t>(i)];
          if (v.count != 0) fn(detail::voxel_of(b.key, i), v);
        }
      });
    }
  }

  // ---- flush and clear ----

  // Writes every tile whose newest state is not in its tile file: dirty resident tiles from RAM,
  // staged tiles from the staging file. Each goes to a temporary file that is fsync'ed and renamed
  // over the tile file; the directory is fsync'ed once at the end. Every tile is attempted; the
  // first error is rethrown at the end, and a tile that failed keeps its newest state (dirty in
  // RAM, or staged) for a later flush.
  void flush() {
    std::exception_ptr first_error;
    std::vector<VoxelKey> keys;
    for (const auto& [k, info] : tiles)
      if (info.staged || (info.resident != nullptr && info.resident->dirty)) keys.push_back(k);
    std::sort(keys.begin(), keys.end());
    std::vector<std::uint8_t> staged_image;
    std::unique_ptr<detail::DenseBlock> check_block_owner;
    if (!keys.empty()) check_block_owner = std::make_unique<detail::DenseBlock>();
    detail::DenseBlock* const check_block_ptr = check_block_owner.get();
    for (const VoxelKey& k : keys) {
      detail::DenseBlock& check_block = *check_block_ptr;
      TileInfo& info = tiles.at(k);
      try {
        Tile* t = info.resident;
        const bool from_ram = t != nullptr && t->dirty;
        if (from_ram) {
          (void)detail::encode_tile(t->grid, resolution, tile_voxels, k, io_buffer);
        } else {
          // Checked before it replaces a tile file: a damaged staging file must never spoil one.
          const std::string where = read_image(k, info, staged_image);
          const detail::TileHeader h = detail::parse_tile_header(staged_image.data(), staged_image.size(),
                                                                 staged_image.size(), resolution, tile_voxels, k, where);
          detail::decode_tile(staged_image, h, tile_voxels, where, check_block, [](const detail::DenseBlock&) {});
          io_buffer.swap(staged_image);
        }
        const std::string path = tile_path(k);
        detail::write_file_durably(path + kTempSuffix, path, io_buffer);
        dir_sync_pending = true;
        committed_bytes_total -= info.committed ? info.committed_bytes : 0;
        info.committed = true;
        info.committed_bytes = io_buffer.size();
        committed_bytes_total += info.committed_bytes;
        if (from_ram) {
          info.file_known = t->known;
          t->dirty = false;
        }
        unstage(info);
      } catch (...) {
        if (!first_error) first_error = std::current_exception();
      }
    }
    if (dir_sync_pending) {
      detail::sync_directory(dir);
      dir_sync_pending = false;
    }
    drop_staging_if_unused();
    if (first_error) std::rethrow_exception(first_error);
  }

  void clear() {
    for (auto& t : resident) tiles.at(t->key).resident = nullptr;
    resident.clear();
    std::exception_ptr first_error;
    for (auto it = tiles.begin(); it != tiles.end();) {
      TileInfo& info = it->second;
      unstage(info);  // the staging file goes as a whole below
      if (info.committed) {
        try {
          detail::remove_file(tile_path(it->first));
        } catch (...) {
          if (!first_error) first_error = std::current_exception();
          info.file_known = committed_known(it->first);
          ++it;
          continue;  // still on disk: it stays in the index with its file's contents
        }
      }
      it = tiles.erase(it);
    }
    drop_staging_if_unused();
    total_known = 0;
    committed_bytes_total = 0;
    for (const auto& [k, info] : tiles) {
      total_known += info.file_known;
      committed_bytes_total += info.committed_bytes;
    }
    skipped = 0;
    peak_resident = 0;
    scratch.release();
    detail::free_memory(batch);
    detail::free_memory(targets);
    detail::free_memory(io_buffer);
    detail::sync_directory(dir);
    dir_sync_pending = false;
    if (first_error) std::rethrow_exception(first_error);
  }

  // Known voxels of a committed file, from its header (0 when it cannot be read: the next read of
  // the tile reports the problem).
  std::size_t committed_known(const VoxelKey& key) {
    try {
      const std::string path = tile_path(key);
      std::uint64_t size = 0;
      const std::vector<std::uint8_t> head = detail::read_file_prefix(path, detail::kTileHeaderBytes, size);
      return static_cast<std::size_t>(
          detail::parse_tile_header(head.data(), head.size(), size, resolution, tile_voxels, key, path).known_voxels);
    } catch (const std::exception&) {
      return 0;
    }
  }

  static constexpr std::size_t kNoChunk = static_cast<std::size_t>(-1);
  static constexpr std::size_t kNoGroup = 0;

  std::string dir;
  double resolution;
  double tile_size;
  std::size_t cache_tiles;
  std::uint32_t tile_voxels = 0;
  std::int32_t tile_blocks = 0;
  int lock_fd = -1;

  detail::Updater updater;
  std::unordered_map<VoxelKey, TileInfo, VoxelKeyHash> tiles;  // every tile of the map
  std::vector<std::unique_ptr<Tile>> resident;                 // the cache
  std::uint64_t tick = 0;
  std::size_t total_known = 0;
  std::size_t skipped = 0;
  std::uint64_t committed_bytes_total = 0;  // tile files
  int staging_fd = -1;
  std::uint64_t staging_size = 0;  // bytes of the staging file
  std::uint64_t staging_live = 0;  // bytes of its images still needed
  std::uint64_t meta_bytes = 0;
  std::size_t peak_resident = 0;
  bool dir_sync_pending = false;  // renames since the last directory fsync

  // Buffers reused between calls.
  detail::ScanScratch scratch;
  std::vector<detail::Observation> batch;
  std::vector<std::pair<detail::VoxelBlock*, int>> targets;  // block and index_in_block
  // Blocks with cells to add during a batch, and their tile's grid.
  std::vector<std::pair<detail::VoxelBlock*, detail::BlockGrid*>> pending_blocks;
  Routing routing;
  std::vector<std::vector<std::size_t>> slot_chunks;
  std::vector<std::size_t> slot_last_chunk;
  std::vector<std::size_t> slot_group;
  std::vector<Tile*> slot_tile;
  std::vector<detail::BlockAccessor> accessors;
  std::vector<std::size_t> group_chunks;
  std::vector<std::uint8_t> io_buffer;

  mutable std::mutex mutex;
};

// ---- public methods: each takes the lock once ----

OutofcoreTileMapper::OutofcoreTileMapper(const std::string& directory, double resolution, double tile_size,
                                         size_t cache_tiles) {
  if (directory.empty()) throw std::invalid_argument("iwlomap: OutofcoreTileMapper needs a map directory, got an empty path");
  detail::check_resolution(resolution);
  if (cache_tiles < 1) throw std::invalid_argument("iwlomap: cache_tiles must be >= 1, got cache_tiles = 0");
  auto m = std::make_unique<Impl>(directory, resolution, tile_size, cache_tiles);
  m->open();
  impl_ = std::move(m);
}

OutofcoreTileMapper::~OutofcoreTileMapper() = default;
OutofcoreTileMapper::OutofcoreTileMapper(OutofcoreTileMapper&&) noexcept = default;
OutofcoreTileMapper& OutofcoreTileMapper::operator=(OutofcoreTileMapper&&) noexcept = default;

OutofcoreTileMapper::Impl& OutofcoreTileMapper::impl() {
  if (!impl_) throw std::logic_error("iwlomap: OutofcoreTileMapper used after it was moved from");
  return *impl_;
}
const OutofcoreTileMapper::Impl& OutofcoreTileMapper::impl() const {
  if (!impl_) throw std::logic_error("iwlomap: OutofcoreTileMapper used after it was moved from");
  return *impl_;
}

void OutofcoreTileMapper::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                            const std::vector<bool>& is_occupied) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.apply_batch(points, intensities, is_occupied, nullptr);
}

void OutofcoreTileMapper::batch_update_iwlo(const Eigen::MatrixXd& points, const Eigen::VectorXd& intensities,
                                            const std::vector<bool>& is_occupied, const Eigen::VectorXd& weights) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.apply_batch(points, intensities, is_occupied, &weights);
}

void OutofcoreTileMapper::insert_scan(const Eigen::Vector3d& origin, const Eigen::MatrixXd& points,
                                      const Eigen::VectorXd& intensities, double max_range) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.insert_scan(origin, points, intensities, max_range, get_num_threads());
}

void OutofcoreTileMapper::set_params(const IwloParams& params) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.updater = detail::Updater(params);
}
void OutofcoreTileMapper::modify_params(const std::function<void(IwloParams&)>& change) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  IwloParams p = m.updater.params();
  change(p);
  m.updater = detail::Updater(p);
}

IwloParams OutofcoreTileMapper::get_params() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.updater.params();
}

void OutofcoreTileMapper::set_log_odds(const Eigen::MatrixXd& points, const Eigen::VectorXd& log_odds) {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.set_log_odds(points, log_odds);
}

Eigen::MatrixXd OutofcoreTileMapper::get_occupied_voxels(double min_probability) {
  const double threshold = detail::resolve_min_probability(min_probability);
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  std::vector<double> rows;
  m.for_each_known([&](const VoxelKey& key, const detail::Voxel& v) {
    const double p = iwlo::probability(v.log_odds);
    if (!(p > threshold)) return;
    const Eigen::Vector3d c = key_to_center(key, m.resolution);
    rows.insert(rows.end(), {c.x(), c.y(), c.z(), p});
  });
  return detail::rows_to_matrix(rows);
}

std::optional<VoxelState> OutofcoreTileMapper::query(const Eigen::Vector3d& point) const {
  // The cache is not part of the observable state: a query may load a tile into it, so it works
  // on the non-const Impl (impl() only checks for a moved-from object).
  (void)impl();
  Impl& m = *impl_;
  const VoxelKey key = world_to_key_checked(point, m.resolution);
  std::lock_guard<std::mutex> lock(m.mutex);
  const VoxelKey tile_key = m.tile_of_voxel(key);
  const auto it = m.tiles.find(tile_key);
  if (it == m.tiles.end()) return std::nullopt;
  Tile* tile = it->second.resident;
  if (tile == nullptr) {
    std::vector<Tile*> out;
    Impl::PinScope pins(m);
    m.make_resident({tile_key}, out);
    tile = out[0];
  } else {
    m.touch(*tile);
  }
  return detail::query_voxel(tile->grid, key);
}

void OutofcoreTileMapper::for_each_voxel(const std::function<void(const VoxelKey&, const VoxelState&)>& visit) const {
  (void)impl();
  Impl& m = *impl_;
  std::lock_guard<std::mutex> lock(m.mutex);
  m.for_each_known([&](const VoxelKey& key, const detail::Voxel& v) { visit(key, detail::state_of(v)); });
}

MemoryStats OutofcoreTileMapper::get_memory_usage() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  std::size_t bytes = sizeof(Impl) + m.scratch.bytes() + m.batch.capacity() * sizeof(detail::Observation) +
                      m.targets.capacity() * sizeof(m.targets[0]) + m.routing.bytes() + m.io_buffer.capacity() +
                      m.resident.capacity() * sizeof(m.resident[0]);
  // The index: a node per tile (key, info, next pointer, cached hash) and the bucket array.
  bytes += m.tiles.size() * (sizeof(std::pair<const VoxelKey, TileInfo>) + 2 * sizeof(void*)) +
           m.tiles.bucket_count() * sizeof(void*);
  std::size_t slots = 0, resident_known = 0;
  for (const auto& t : m.resident) {
    bytes += sizeof(Tile) + t->grid.bytes();
    slots += t->grid.num_slots();
    resident_known += t->known;
  }
  return MemoryStats{m.total_known, m.total_known, static_cast<double>(bytes) / (1024.0 * 1024.0),
                     slots == 0 ? 0.0 : static_cast<double>(resident_known) / static_cast<double>(slots)};
}

double OutofcoreTileMapper::get_resolution() const { return impl().resolution; }

size_t OutofcoreTileMapper::get_num_nodes() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.total_known;
}

size_t OutofcoreTileMapper::get_num_skipped_points() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.skipped;
}

void OutofcoreTileMapper::clear() {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.clear();
}

void OutofcoreTileMapper::flush() {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.flush();
}

void OutofcoreTileMapper::preload_region(const Eigen::Vector3d& min_bound, const Eigen::Vector3d& max_bound) {
  if (!min_bound.allFinite() || !max_bound.allFinite())
    throw std::invalid_argument("iwlomap: preload_region needs finite bounds, got min (" + std::to_string(min_bound.x()) +
                                ", " + std::to_string(min_bound.y()) + ", " + std::to_string(min_bound.z()) + ") max (" +
                                std::to_string(max_bound.x()) + ", " + std::to_string(max_bound.y()) + ", " +
                                std::to_string(max_bound.z()) + ")");
  for (int a = 0; a < 3; ++a)
    if (min_bound[a] > max_bound[a])
      throw std::invalid_argument("iwlomap: preload_region needs min <= max on every axis, got " +
                                  detail::describe("min", min_bound[a]) + " > " + detail::describe("max", max_bound[a]) +
                                  " on axis " + std::to_string(a));
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  // Tile range in doubles: floor(floor(x / r) / edge) is exact for any key, and never overflows.
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::floor(std::floor(min_bound[a] / m.resolution) / m.tile_voxels);
    hi[a] = std::floor(std::floor(max_bound[a] / m.resolution) / m.tile_voxels);
  }
  std::vector<VoxelKey> keys;
  for (const auto& [k, info] : m.tiles) {
    const double t[3] = {static_cast<double>(k.x), static_cast<double>(k.y), static_cast<double>(k.z)};
    if (t[0] >= lo[0] && t[0] <= hi[0] && t[1] >= lo[1] && t[1] <= hi[1] && t[2] >= lo[2] && t[2] <= hi[2])
      keys.push_back(k);
  }
  std::sort(keys.begin(), keys.end());
  if (keys.size() > m.cache_tiles) keys.resize(m.cache_tiles);
  std::vector<Tile*> out;
  Impl::PinScope pins(m);
  m.make_resident(keys, out);
}

size_t OutofcoreTileMapper::get_disk_usage() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return static_cast<size_t>(m.committed_bytes_total + m.staging_size + m.meta_bytes);
}

size_t OutofcoreTileMapper::prune() {
  Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  m.scratch.release();
  detail::free_memory(m.batch);
  detail::free_memory(m.targets);
  m.routing = Routing{};
  detail::free_memory(m.slot_chunks);
  detail::free_memory(m.slot_last_chunk);
  detail::free_memory(m.slot_group);
  detail::free_memory(m.slot_tile);
  detail::free_memory(m.group_chunks);
  detail::free_memory(m.io_buffer);
  std::size_t freed = 0;
  for (auto& t : m.resident) freed += t->grid.prune();
  return freed;
}

std::string OutofcoreTileMapper::get_directory() const { return impl().dir; }
double OutofcoreTileMapper::get_tile_size() const { return impl().tile_size; }
size_t OutofcoreTileMapper::get_tile_voxels() const { return impl().tile_voxels; }
size_t OutofcoreTileMapper::get_cache_tiles() const { return impl().cache_tiles; }

size_t OutofcoreTileMapper::get_num_resident_tiles() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.resident.size();
}
size_t OutofcoreTileMapper::get_num_tiles() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.tiles.size();
}
size_t OutofcoreTileMapper::get_peak_resident_tiles() const {
  const Impl& m = impl();
  std::lock_guard<std::mutex> lock(m.mutex);
  return m.peak_resident;
}

DiskMapInfo OutofcoreTileMapper::read_map_info(const std::string& directory) {
  const std::string meta_path = (std::filesystem::path(directory) / kMetaName).string();
  std::error_code ec;
  if (!std::filesystem::exists(meta_path, ec))
    throw StorageError(StorageError::Kind::kIo, meta_path,
                       "iwlomap: " + directory + " holds no iwlomap map (" + meta_path + " is missing)");
  std::uint64_t size = 0;
  const MapMeta m = parse_meta(detail::read_file_prefix(meta_path, 1 << 16, size), meta_path);
  return DiskMapInfo{m.resolution, m.tile_size, m.tile_voxels, m.version};
}

}  // namespace iwlomap
