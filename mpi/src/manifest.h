// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The manifest of a distributed map directory and the tile files of a shard.
//
//   iwlomap_distributed.manifest   text, written durably by rank 0 at each flush():
//     iwlomap distributed map 1
//     ranks N
//     resolution <hex float>
//     tile_size <hex float>        (the effective shard edge, tile_voxels * resolution)
//     tile_voxels T
//     rank K M                     then M lines, each a tile file name of rank K's shard
//   rank-K/                        rank K's shard: a Disk map directory

#include "iwlomap/mpi/distributed_mapper.h"

#include <string>
#include <vector>

namespace iwlomap::mpi {

/// Writes \p m as the manifest of \p directory: temporary file, fsync, rename, directory fsync.
/// Throws StorageError (kIo) naming the file.
void write_manifest(const std::string& directory, const DistributedManifest& m);

/// The tile files of the last commit of the Disk map in \p directory (no writer may be changing
/// it), sorted by tile.
[[nodiscard]] std::vector<std::string> committed_tile_files(const std::string& directory);

}  // namespace iwlomap::mpi
