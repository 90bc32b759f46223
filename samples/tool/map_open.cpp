// SPDX-License-Identifier: BSD-3-Clause
#include "map_open.h"

#include "args.h"

#include <iwlomap/outofcore_tile_mapper.h>

#ifdef IWLOMAP_HAVE_OCTOMAP
#include <iwlomap/octomap/octree_mapper.h>
#endif

#include <filesystem>
#include <stdexcept>

namespace iwlomap::tool {

bool is_map_path(const std::string& path) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) return true;
  const std::string ext = extension(path);
  return ext == ".bt" || ext == ".ot";
}

std::unique_ptr<IMapperBackend> open_map(const std::string& path, std::size_t cache_tiles) {
  std::error_code ec;
  if (std::filesystem::is_directory(path, ec)) {
    // Read-only: no lock, nothing written, so a map can be read while a mapper writes it.
    return std::make_unique<OutofcoreTileMapper>(OutofcoreTileMapper::open_read_only(path, cache_tiles));
  }
  if (!std::filesystem::exists(path, ec)) throw std::runtime_error("cannot open '" + path + "'");
#ifdef IWLOMAP_HAVE_OCTOMAP
  auto map = std::make_unique<OctreeMapper>();
  map->load_from_file(path);  // takes the file's resolution
  return map;
#else
  throw std::runtime_error("'" + path + "': reading OctoMap files needs the OctoMap layer (build with -DIWLOMAP_WITH_OCTOMAP=ON)");
#endif
}

}  // namespace iwlomap::tool
