// SPDX-License-Identifier: BSD-3-Clause
#include "backends/disk/map_directory.h"

#include "backends/disk/file_io.h"
#include "backends/disk/map_manifest.h"
#include "backends/disk/tile_file.h"
#include "model/checks.h"
#include "storage/block_grid.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <limits>
#include <sstream>
#include <stdexcept>

namespace iwlomap::detail {

namespace {

namespace fs = std::filesystem;

constexpr const char* kMetaName = "iwlomap_map.meta";
constexpr const char* kLockName = "iwlomap_map.lock";
constexpr const char* kReadersName = "iwlomap_map.readers";
constexpr const char* kMetaFirstLine = "iwlomap tile map";
constexpr const char* kTilePrefix = "tile_";
constexpr const char* kTileSuffix = ".iwt";
// Tiles above 8192 voxels (1024 blocks) per edge could hold more than 2^32 block records.
constexpr std::uint32_t kMaxTileVoxels = 8192;

bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

std::string hexfloat(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%a", v);
  return buf;
}

std::vector<std::uint8_t> encode_meta(const MapMeta& m) {
  std::ostringstream s;
  s << kMetaFirstLine << "\n"
    << "format_version " << m.version << "\n"
    << "resolution " << hexfloat(m.resolution) << "\n"
    << "tile_size " << hexfloat(m.tile_size) << "\n"
    << "tile_voxels " << m.tile_voxels << "\n"
    << "iwlo_params";
  double values[13];
  params_to_array(m.params, values);
  for (const double v : values) s << " " << hexfloat(v);
  s << "\n"
    << "hit_statistics " << (m.hit_statistics ? 1 : 0) << "\n"
    << "hit_epoch " << m.hit_epoch << "\n"
    << "# resolution " << shortest(m.resolution) << " m, tiles of " << shortest(m.tile_size) << " m (" << m.tile_voxels
    << " voxels); tiles are tile_<x>_<y>_<z>.iwt, see src/backends/disk/tile_file.h\n"
    << "# iwlo_params: sharpness decay_rate min_alpha L_min L_max log_odds_occupied log_odds_free"
       " intensity_threshold intensity_max adaptive_enabled adaptive_threshold adaptive_max_ratio"
       " occupied_threshold\n";
  const std::string text = s.str();
  return {text.begin(), text.end()};
}

[[noreturn]] void throw_bad_meta(const std::string& path, const std::string& what) {
  throw StorageError(StorageError::Kind::kCorrupt, path, "iwlomap: map metadata " + path + " is corrupt: " + what);
}

}  // namespace

std::string tile_file_name(const VoxelKey& t, std::uint64_t generation) {
  return kTilePrefix + std::to_string(t.x) + "_" + std::to_string(t.y) + "_" + std::to_string(t.z) +
         (generation == 0 ? std::string() : ".g" + std::to_string(generation)) + kTileSuffix;
}

// Strict: only the exact names tile_file_name() produces, so no other file is ever taken for a
// tile (or removed as a retired one).
bool holds_map(const std::string& directory) {
  std::error_code ec;
  return fs::exists(fs::path(directory) / kMetaName, ec);
}

bool parse_tile_file_name(const std::string& name, VoxelKey& t, std::uint64_t& generation) {
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
  std::uint64_t g = 0;
  if (p[0] == '.' && p[1] == 'g') {
    char* end = nullptr;
    errno = 0;
    const unsigned long long parsed = std::strtoull(p + 2, &end, 10);
    if (end == p + 2 || errno != 0 || parsed == 0) return false;
    g = parsed;
    p = end;
  }
  if (*p != '\0') return false;
  t = {static_cast<std::int32_t>(v[0]), static_cast<std::int32_t>(v[1]), static_cast<std::int32_t>(v[2])};
  generation = g;
  return tile_file_name(t, g) == name;
}

void params_to_array(const IwloParams& p, double (&v)[13]) {
  const double values[13] = {p.sharpness,         p.decay_rate,        p.min_alpha,
                             p.L_min,             p.L_max,             p.log_odds_occupied,
                             p.log_odds_free,     p.intensity_threshold, p.intensity_max,
                             p.adaptive_enabled ? 1.0 : 0.0, p.adaptive_threshold, p.adaptive_max_ratio,
                             p.occupied_threshold};
  std::copy(std::begin(values), std::end(values), std::begin(v));
}

IwloParams params_from_array(const double (&v)[13]) {
  IwloParams p;
  p.sharpness = v[0];
  p.decay_rate = v[1];
  p.min_alpha = v[2];
  p.L_min = v[3];
  p.L_max = v[4];
  p.log_odds_occupied = v[5];
  p.log_odds_free = v[6];
  p.intensity_threshold = v[7];
  p.intensity_max = v[8];
  p.adaptive_enabled = v[9] != 0.0;
  p.adaptive_threshold = v[10];
  p.adaptive_max_ratio = v[11];
  p.occupied_threshold = v[12];
  return p;
}

std::uint32_t tile_voxels_for(double resolution, double tile_size) {
  if (!(std::isfinite(tile_size) && tile_size > 0.0))
    throw std::invalid_argument("iwlomap: tile_size must be finite and > 0, got " + describe("tile_size", tile_size));
  // The nearest whole number of blocks, at least one and at most kMaxTileVoxels / 8 (clamp first:
  // the quotient may be beyond any integer type).
  const double blocks = std::clamp(std::round(tile_size / resolution / kBlockEdge), 1.0,
                                   static_cast<double>(kMaxTileVoxels / kBlockEdge));
  return static_cast<std::uint32_t>(blocks) * static_cast<std::uint32_t>(kBlockEdge);
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
    } else if (key == "hit_statistics" || key == "hit_epoch") {
      const unsigned long v = std::strtoul(value.c_str(), &end, 10);
      if (end == value.c_str() || *end != '\0' || errno != 0 || v > std::numeric_limits<std::uint32_t>::max() ||
          (key == "hit_statistics" && v > 1))
        throw_bad_meta(path, "bad " + key + " '" + value + "'");
      if (key == "hit_statistics")
        m.hit_statistics = v == 1;
      else
        m.hit_epoch = static_cast<std::uint32_t>(v);
    } else if (key == "iwlo_params") {
      double v[13];
      const char* q = value.c_str();
      for (double& x : v) {
        x = std::strtod(q, &end);
        if (end == q) throw_bad_meta(path, "iwlo_params '" + value + "' has fewer than 13 numbers");
        q = end;
      }
      if (*q != '\0') throw_bad_meta(path, "iwlo_params '" + value + "' has more than 13 numbers");
      const IwloParams p = params_from_array(v);
      try {
        p.validate();
      } catch (const std::invalid_argument& e) {
        throw_bad_meta(path, e.what());
      }
      m.params = p;
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
  if (m.version > kMapFormatVersion)
    throw StorageError(StorageError::Kind::kNewerVersion, path,
                       "iwlomap: map metadata " + path + " has format version " + std::to_string(m.version) +
                           ", newer than the version " + std::to_string(kMapFormatVersion) +
                           " this build reads; open the map with a newer iwlomap");
  if (m.version == 0) throw_bad_meta(path, "format_version 0");
  if (!have_res || !have_size || !have_voxels) throw_bad_meta(path, "resolution, tile_size or tile_voxels is missing");
  // The three must agree: a tile edge of whole blocks within the limit, and a tile size that is
  // that many voxels (to the rounding of the size requested when the map was made).
  if (m.tile_voxels < kBlockEdge || m.tile_voxels > kMaxTileVoxels || m.tile_voxels % kBlockEdge != 0)
    throw_bad_meta(path, "tile_voxels " + std::to_string(m.tile_voxels) + " is not a whole number of 8-voxel blocks in [8, " +
                             std::to_string(kMaxTileVoxels) + "]");
  if (tile_voxels_for(m.resolution, m.tile_size) != m.tile_voxels)
    throw_bad_meta(path, "tile_size " + shortest(m.tile_size) + " m at resolution " + shortest(m.resolution) +
                             " m is not tiles of " + std::to_string(m.tile_voxels) + " voxels");
  return m;
}

MapDirectory::MapDirectory(std::string directory, double resolution, double tile_size, std::uint32_t tile_voxels,
                           bool read_only)
    : dir_(std::move(directory)), read_only_(read_only) {
  std::error_code ec;
  if (!read_only) fs::create_directories(dir_, ec);
  if (ec || !fs::is_directory(dir_))
    throw StorageError(StorageError::Kind::kIo, dir_,
                       "iwlomap: cannot use " + dir_ + " as a map directory: " +
                           (ec ? ec.message() : std::string(read_only ? "it is not a directory" : "it exists and is not a directory")));
  if (!read_only) lock();
  try {
    // Before the listing and the manifest: the files of the commit a reader reads stay.
    open_readers_lock();
    for (fs::directory_iterator it(dir_, ec), end; !ec && it != end; it.increment(ec)) {
      std::error_code type_ec;
      if (!it->is_regular_file(type_ec)) continue;  // a directory named like a tile is not ours
      const std::string name = it->path().filename().string();
      VoxelKey t;
      std::uint64_t g = 0;
      if (parse_tile_file_name(name, t, g))
        tile_files_.push_back({name, t, g});
      else if ((ends_with(name, kTempSuffix) &&
                (name == std::string(kMetaName) + kTempSuffix || name == std::string(kManifestName) + kTempSuffix ||
                 parse_tile_file_name(name.substr(0, name.size() - 4), t, g))) ||
               name == kStagingName || name == std::string(kStagingName) + ".new")
        leftovers_.push_back(name);
    }
    if (ec) throw StorageError(StorageError::Kind::kIo, dir_, "iwlomap: cannot list map directory " + dir_ + ": " + ec.message());
    std::sort(tile_files_.begin(), tile_files_.end(),
              [](const ListedTile& a, const ListedTile& b) { return a.name < b.name; });

    const std::string meta_path = path_of(kMetaName);
    if (fs::exists(meta_path, ec)) {
      std::uint64_t size = 0;
      const MapMeta m = parse_meta(read_file_prefix(meta_path, 1 << 16, size), meta_path);
      meta_bytes_ = size;
      meta_ = m;
      // The stored tile edge in voxels decides: any requested size that rounds to it is accepted.
      if (m.resolution != resolution || m.tile_voxels != tile_voxels)
        throw std::invalid_argument("iwlomap: the map in " + dir_ + " was created with " +
                                    describe("resolution", m.resolution) + " and tiles of " +
                                    std::to_string(m.tile_voxels) + " voxels (" + describe("tile_size", m.tile_size) +
                                    "), not " + describe("resolution", resolution) + " and tiles of " +
                                    std::to_string(tile_voxels) + " voxels (" + describe("tile_size", tile_size) +
                                    "); open it with the stored values");
    } else if (read_only) {
      throw StorageError(StorageError::Kind::kIo, meta_path,
                         "iwlomap: " + dir_ + " holds no iwlomap map (" + meta_path + " is missing)");
    } else {
      if (!tile_files_.empty())
        throw StorageError(StorageError::Kind::kCorrupt, meta_path,
                           "iwlomap: " + dir_ + " holds tile files (" + tile_files_.front().name +
                               ", ...) but no map metadata " + meta_path + "; its resolution and tile size are unknown");
      MapMeta m;
      m.resolution = resolution;
      m.tile_size = static_cast<double>(tile_voxels) * resolution;  // the effective size
      m.tile_voxels = tile_voxels;
      write_meta(m);
    }
  } catch (...) {
    if (lock_fd_ >= 0) ::close(lock_fd_);
    if (readers_fd_ >= 0) ::close(readers_fd_);
    throw;
  }
}

void MapDirectory::write_meta(const MapMeta& meta) {
  if (read_only_) throw std::logic_error("iwlomap: the map directory " + dir_ + " is open read-only");
  write_meta_file(dir_, meta);
  meta_ = meta;
  meta_.version = kMapFormatVersion;
  meta_bytes_ = encode_meta(meta_).size();
}

void MapDirectory::write_meta_file(const std::string& directory, const MapMeta& meta) {
  MapMeta m = meta;
  m.version = kMapFormatVersion;
  const std::string meta_path = (fs::path(directory) / kMetaName).string();
  write_file_durably(meta_path + kTempSuffix, meta_path, encode_meta(m));
  sync_directory(directory);
}

MapDirectory::~MapDirectory() {
  if (lock_fd_ >= 0) ::close(lock_fd_);
  if (readers_fd_ >= 0) ::close(readers_fd_);
}

// A reader holds the lock shared for its lifetime, waiting while a writer removes retired files
// (a moment). A writer keeps the descriptor to test for readers. A read-only open of a directory
// where the file cannot be created (a read-only file system) goes without: no writer can run there.
void MapDirectory::open_readers_lock() {
  const std::string path = path_of(kReadersName);
  readers_fd_ = ::open(path.c_str(), (read_only_ ? O_RDONLY : O_RDWR) | O_CREAT | O_CLOEXEC, 0644);
  if (readers_fd_ < 0 && read_only_) readers_fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (readers_fd_ < 0) {
    if (read_only_) return;
    throw StorageError(StorageError::Kind::kIo, path, "iwlomap: cannot create lock file " + path + ": " + std::strerror(errno));
  }
  if (!read_only_) return;
  int r;
  do r = ::flock(readers_fd_, LOCK_SH);
  while (r != 0 && errno == EINTR);
  if (r != 0) throw StorageError(StorageError::Kind::kIo, path, "iwlomap: cannot lock " + path + ": " + std::strerror(errno));
}

bool MapDirectory::exclude_readers() noexcept {
  if (read_only_ || readers_fd_ < 0) return false;
  int r;
  do r = ::flock(readers_fd_, LOCK_EX | LOCK_NB);
  while (r != 0 && errno == EINTR);
  return r == 0;
}

void MapDirectory::release_readers() noexcept {
  if (readers_fd_ >= 0) (void)::flock(readers_fd_, LOCK_UN);
}

std::string MapDirectory::path_of(const std::string& name) const { return (fs::path(dir_) / name).string(); }

void MapDirectory::remove_leftovers() {
  if (read_only_) return;  // a writer may have them open
  for (const std::string& name : leftovers_) remove_file(path_of(name));
  leftovers_.clear();
}

void MapDirectory::lock() {
  const std::string path = path_of(kLockName);
  lock_fd_ = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (lock_fd_ < 0)
    throw StorageError(StorageError::Kind::kIo, path, "iwlomap: cannot create lock file " + path + ": " + std::strerror(errno));
  int r;
  do r = ::flock(lock_fd_, LOCK_EX | LOCK_NB);
  while (r != 0 && errno == EINTR);
  if (r != 0) {
    const int err = errno;
    ::close(lock_fd_);
    lock_fd_ = -1;
    if (err == EWOULDBLOCK)
      throw StorageError(StorageError::Kind::kLocked, dir_,
                         "iwlomap: the map directory " + dir_ + " is already open in another mapper (this process or another)");
    throw StorageError(StorageError::Kind::kIo, path, "iwlomap: cannot lock " + path + ": " + std::strerror(err));
  }
}

MapMeta MapDirectory::read_meta(const std::string& directory) {
  const std::string meta_path = (fs::path(directory) / kMetaName).string();
  std::error_code ec;
  if (!fs::exists(meta_path, ec))
    throw StorageError(StorageError::Kind::kIo, meta_path,
                       "iwlomap: " + directory + " holds no iwlomap map (" + meta_path + " is missing)");
  std::uint64_t size = 0;
  return parse_meta(read_file_prefix(meta_path, 1 << 16, size), meta_path);
}

}  // namespace iwlomap::detail
