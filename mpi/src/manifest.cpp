// SPDX-License-Identifier: BSD-3-Clause
// The distributed map directory: its manifest, and the conversions to and from one Disk map.

#include "manifest.h"

#include "backends/disk/file_io.h"
#include "backends/disk/map_directory.h"
#include "backends/disk/map_manifest.h"
#include "iwlomap/outofcore_tile_mapper.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <sstream>
#include <system_error>

namespace iwlomap::mpi {

namespace fs = std::filesystem;

namespace {

constexpr const char* kFirstLine = "iwlomap distributed map 1";

std::string hex(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%a", v);
  return buf;
}

[[noreturn]] void bad_manifest(const std::string& path, const std::string& what) {
  throw StorageError(StorageError::Kind::kCorrupt, path, "distributed map manifest " + path + " is damaged: " + what);
}

// A hard link where the file system allows one (the same bytes, no copy), else a copy.
void link_or_copy(const fs::path& from, const fs::path& to) {
  std::error_code ec;
  fs::create_hard_link(from, to, ec);
  if (!ec) return;
  fs::copy_file(from, to, ec);
  if (ec)
    throw StorageError(StorageError::Kind::kIo, to.string(),
                       "cannot link or copy " + from.string() + " to " + to.string() + ": " + ec.message());
}

// An empty directory \p target for a new map: created, or existing and empty.
void prepare_target(const fs::path& target) {
  std::error_code ec;
  if (fs::exists(target, ec) && !fs::is_empty(target, ec))
    throw StorageError(StorageError::Kind::kIo, target.string(),
                       target.string() + " is not empty: the converted map goes into a new directory");
  fs::create_directories(target, ec);
  if (ec) throw StorageError(StorageError::Kind::kIo, target.string(), "cannot create " + target.string() + ": " + ec.message());
}

// Makes \p target a Disk map of the tiles \p tiles of the commit \p from, whose files are in
// \p source (hard links where possible), durably, with the metadata \p meta. Tiles first, then
// their manifest, the metadata last: a directory without metadata is not a map, so an interrupted
// conversion is never mistaken for a complete one.
void assemble_map(const detail::MapManifest& from, const std::vector<detail::ManifestTile>& tiles,
                  const std::vector<fs::path>& source, const detail::MapMeta& meta, const fs::path& target) {
  for (std::size_t i = 0; i < tiles.size(); ++i) {
    const std::string name = detail::tile_file_name(tiles[i].key, tiles[i].generation);
    link_or_copy(source[i] / name, target / name);
  }
  detail::MapManifest m;
  m.commit = from.commit;
  m.state = from.state;
  m.tiles = tiles;
  detail::sort_by_tile(m.tiles);
  for (const detail::ManifestTile& t : m.tiles) m.commit = std::max(m.commit, t.generation);
  detail::sync_directory(target.string());
  detail::write_manifest_file(target.string(), m);
  detail::MapDirectory::write_meta_file(target.string(), meta);
}

}  // namespace

std::vector<std::string> committed_tile_files(const std::string& directory) {
  std::vector<std::string> names;
  for (const detail::ManifestTile& t : detail::read_committed_manifest(directory).tiles)
    names.push_back(detail::tile_file_name(t.key, t.generation));
  return names;
}

void write_manifest(const std::string& directory, const DistributedManifest& m) {
  std::ostringstream out;
  out << kFirstLine << "\nranks " << m.ranks << "\nresolution " << hex(m.resolution) << "\ntile_size "
      << hex(m.tile_size) << "\ntile_voxels " << m.tile_voxels << "\n";
  for (std::size_t r = 0; r < m.tiles.size(); ++r) {
    out << "rank " << r << " " << m.tiles[r].size() << "\n";
    for (const std::string& t : m.tiles[r]) out << t << "\n";
  }
  const std::string text = out.str();
  const std::string path = (fs::path(directory) / kManifestName).string();
  detail::write_file_durably(path + ".tmp", path, std::vector<std::uint8_t>(text.begin(), text.end()));
  detail::sync_directory(directory);
}

DistributedManifest read_manifest(const std::string& directory) {
  const std::string path = (fs::path(directory) / kManifestName).string();
  std::error_code ec;
  if (!fs::exists(path, ec))
    throw StorageError(StorageError::Kind::kIo, path, "no distributed map in " + directory + " (" + path + " is missing)");
  const std::vector<std::uint8_t> bytes = detail::read_file(path);
  std::istringstream in(std::string(bytes.begin(), bytes.end()));
  std::string line;
  if (!std::getline(in, line) || line != kFirstLine) bad_manifest(path, "it does not start with '" + std::string(kFirstLine) + "'");
  DistributedManifest m;
  const auto field = [&](const char* name) {
    std::string key, value;
    if (!std::getline(in, line)) bad_manifest(path, std::string("no '") + name + "' line");
    std::istringstream ls(line);
    if (!(ls >> key >> value) || key != name) bad_manifest(path, std::string("expected '") + name + "', got '" + line + "'");
    return value;
  };
  const auto number = [&](const std::string& text, const char* name) {
    char* end = nullptr;
    const double v = std::strtod(text.c_str(), &end);
    if (end == text.c_str() || *end != '\0' || !(v > 0.0)) bad_manifest(path, std::string("bad ") + name + " '" + text + "'");
    return v;
  };
  m.ranks = static_cast<int>(number(field("ranks"), "ranks"));
  m.resolution = number(field("resolution"), "resolution");
  m.tile_size = number(field("tile_size"), "tile_size");
  m.tile_voxels = static_cast<std::uint32_t>(number(field("tile_voxels"), "tile_voxels"));
  if (m.ranks < 1 || m.ranks > (1 << 20)) bad_manifest(path, "bad number of ranks");
  for (int r = 0; r < m.ranks; ++r) {
    std::string word;
    long rank = -1, count = -1;
    if (!std::getline(in, line)) bad_manifest(path, "rank " + std::to_string(r) + " is missing");
    std::istringstream ls(line);
    if (!(ls >> word >> rank >> count) || word != "rank" || rank != r || count < 0)
      bad_manifest(path, "expected 'rank " + std::to_string(r) + " <tiles>', got '" + line + "'");
    std::vector<std::string> tiles;
    for (long i = 0; i < count; ++i) {
      VoxelKey t;
      std::uint64_t generation = 0;
      if (!std::getline(in, line) || !detail::parse_tile_file_name(line, t, generation))
        bad_manifest(path, "rank " + std::to_string(r) + " lists " + std::to_string(count) + " tiles, tile " +
                               std::to_string(i) + " is missing or not a tile file name");
      tiles.push_back(line);
    }
    m.tiles.push_back(std::move(tiles));
  }
  return m;
}

void merge_distributed_map(const std::string& directory, const std::string& target) {
  const DistributedManifest dm = read_manifest(directory);
  prepare_target(target);
  // Each shard's own last commit decides which files hold its tiles (the distributed manifest
  // lists them as of its last flush). The ranks own disjoint tiles.
  detail::MapManifest first;
  std::vector<detail::ManifestTile> tiles;
  std::vector<fs::path> sources;
  for (int r = 0; r < dm.ranks; ++r) {
    const fs::path shard = fs::path(directory) / ("rank-" + std::to_string(r));
    const detail::MapManifest m = detail::read_committed_manifest(shard.string());
    if (r == 0) first = m;
    first.commit = std::max(first.commit, m.commit);
    for (const detail::ManifestTile& t : m.tiles) {
      tiles.push_back(t);
      sources.push_back(shard);
    }
  }
  const fs::path shard0 = fs::path(directory) / "rank-0";
  assemble_map(first, tiles, sources, detail::MapDirectory::read_meta(shard0.string()), target);
}

void split_map(const std::string& directory, const std::string& target, int ranks) {
  if (ranks < 1) throw std::invalid_argument("iwlomap::mpi: split_map: ranks must be >= 1, got " + std::to_string(ranks));
  const DiskMapInfo info = OutofcoreTileMapper::read_map_info(directory);
  const detail::MapMeta meta = detail::MapDirectory::read_meta(directory);
  const detail::MapManifest source = detail::read_committed_manifest(directory);
  prepare_target(target);
  DistributedManifest m;
  m.ranks = ranks;
  m.resolution = info.resolution;
  m.tile_size = info.tile_size;
  m.tile_voxels = static_cast<std::uint32_t>(info.tile_voxels);
  m.tiles.resize(static_cast<std::size_t>(ranks));
  std::vector<std::vector<detail::ManifestTile>> owned(static_cast<std::size_t>(ranks));
  for (const detail::ManifestTile& t : source.tiles) {
    const std::size_t r = static_cast<std::size_t>(owner_of_tile(t.key, ranks));
    owned[r].push_back(t);
    m.tiles[r].push_back(detail::tile_file_name(t.key, t.generation));
  }
  for (int r = 0; r < ranks; ++r) {
    const fs::path shard = fs::path(target) / ("rank-" + std::to_string(r));
    prepare_target(shard);
    const std::vector<detail::ManifestTile>& mine = owned[static_cast<std::size_t>(r)];
    assemble_map(source, mine, std::vector<fs::path>(mine.size(), fs::path(directory)), meta, shard);
  }
  write_manifest(target, m);
}

}  // namespace iwlomap::mpi
