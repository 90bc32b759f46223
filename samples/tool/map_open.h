// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Opening a stored map for the tool: a disk-backend tile directory, or an OctoMap .bt/.ot file.

#include <iwlomap/mapper_backend.h>

#include <cstddef>
#include <memory>
#include <string>

namespace iwlomap::tool {

/// True for a directory or a .bt/.ot file: something open_map() takes rather than a cloud.
[[nodiscard]] bool is_map_path(const std::string& path);

/// Opens the map at \p path with its stored resolution: a tile directory as the Disk backend
/// opened read-only (\p cache_tiles resident tiles; nothing in it is locked or written), a .bt/.ot
/// file as the OctoMap backend (needs that layer).
/// Throws std::runtime_error (or StorageError) naming the path.
[[nodiscard]] std::unique_ptr<IMapperBackend> open_map(const std::string& path, std::size_t cache_tiles = 4);

}  // namespace iwlomap::tool
