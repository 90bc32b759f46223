// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// The Disk backend's file operations (POSIX), each throwing StorageError (kIo) naming the path.
// Writes that replace a file go through a temporary file that is fsync'ed and renamed over it, so
// a crash leaves the old or the new file, never a torn one.

#include "iwlomap/outofcore_tile_mapper.h"

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

namespace iwlomap::detail {

/// The whole file.
[[nodiscard]] std::vector<std::uint8_t> read_file(const std::string& path);
/// Up to \p max_bytes from the start of the file, and the file's size.
[[nodiscard]] std::vector<std::uint8_t> read_file_prefix(const std::string& path, std::size_t max_bytes,
                                                         std::uint64_t& file_size);
/// Writes \p data to \p temp_path (replacing it), fsync'ed when \p sync; the file that will take
/// its place, \p final_path, is untouched and is the path errors name. On failure the temporary
/// file is removed.
void write_temp_file(const std::string& temp_path, const std::string& final_path, const std::vector<std::uint8_t>& data,
                     bool sync);
/// Makes a complete temporary file the real one: fsync (unless \p already_synced), then rename
/// over \p final_path. On failure both files are left as they are. The caller fsyncs the directory.
void commit_temp_file(const std::string& temp_path, const std::string& final_path, bool already_synced);
/// write_temp_file() with fsync, then commit_temp_file().
void write_file_durably(const std::string& temp_path, const std::string& final_path,
                        const std::vector<std::uint8_t>& data);
/// Opens (creating and emptying) a scratch file for reading and writing; returns the descriptor.
[[nodiscard]] int create_scratch_file(const std::string& path);
/// Writes all of \p data at \p offset of \p fd (\p path names the file in errors).
void write_at(int fd, const std::vector<std::uint8_t>& data, std::uint64_t offset, const std::string& path);
/// Reads exactly \p size bytes at \p offset of \p fd into \p out (replaced).
void read_at(int fd, std::uint64_t offset, std::size_t size, const std::string& path, std::vector<std::uint8_t>& out);
/// fsync of a directory, so that renames and unlinks in it are durable.
void sync_directory(const std::string& directory);
/// Removes a file; a missing file is not an error.
void remove_file(const std::string& path);

/// Where throw_corrupt()'s advice to the user starts in its message.
inline constexpr const char* kCorruptAdvice = " (the file is left as it is";
/// Throws StorageError (kCorrupt) "tile file <path> is corrupt: <what>", then the advice.
[[noreturn]] void throw_corrupt(const std::string& path, const std::string& what);

}  // namespace iwlomap::detail
