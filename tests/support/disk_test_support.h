// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// Helpers of the Disk backend's tests (test_outofcore_tile_mapper.cpp, test_disk_storage.cpp):
// comparing a Disk map with the RAM backend, files of a map directory, the small map of
// tile_test_inputs.h, expecting a StorageError.

#include "backend_test_support.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"

#include "tile_test_inputs.h"

#include <gtest/gtest.h>

#include <signal.h>
#include <sys/resource.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <random>
#include <string>
#include <vector>

namespace iwlomap::disk_test {

using test_support::Batch;
using test_support::Snapshot;
using test_support::TempDir;
using test_support::snapshot;
using test_support::sorted_rows;

namespace fs = std::filesystem;

// Per-voxel log-odds and counts, occupied voxels and point queries: all exactly equal.
inline void expect_same_map(IMapperBackend& got, IMapperBackend& want) {
  const Snapshot g = snapshot(got), w = snapshot(want);
  ASSERT_FALSE(w.empty());
  EXPECT_EQ(g.size(), w.size());
  std::size_t mismatches = 0;
  for (const auto& [k, v] : w) {
    const auto it = g.find(k);
    if ((it == g.end() || it->second != v) && ++mismatches <= 5)
      ADD_FAILURE() << "voxel (" << k.x << ", " << k.y << ", " << k.z << "): RAM L = " << v.first << " n = " << v.second
                    << (it == g.end() ? ", Disk does not know it"
                                      : ", Disk L = " + std::to_string(it->second.first) + " n = " +
                                            std::to_string(it->second.second));
  }
  EXPECT_EQ(mismatches, 0u);
  EXPECT_EQ(got.get_num_known_voxels(), want.get_num_known_voxels());
  for (double p : {0.0, 0.5, 0.7, 0.95})
    EXPECT_EQ(sorted_rows(got.get_occupied_voxels(p)), sorted_rows(want.get_occupied_voxels(p))) << "min_probability " << p;
  const double r = want.get_resolution();
  int n = 0;
  for (const auto& [k, v] : w) {
    if (++n % 7 != 0) continue;  // a sample, spread over the map
    const auto s = got.query(key_to_center(k, r));
    ASSERT_TRUE(s.has_value());
    EXPECT_EQ(s->log_odds, v.first);
    EXPECT_EQ(s->count, v.second);
  }
}

inline Batch random_batch(std::mt19937& rng, int n, double half_extent, const Eigen::Vector3d& centre = Eigen::Vector3d::Zero()) {
  return test_support::random_batch(rng, n, half_extent, centre, test_support::BadRows::kNaNPoints);
}

inline std::vector<std::uint8_t> read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}
inline void write_bytes(const std::string& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
}

// Every file of a directory with its bytes: "nothing on disk is lost" means this stays equal.
inline std::map<std::string, std::vector<std::uint8_t>> directory_image(const std::string& dir) {
  std::map<std::string, std::vector<std::uint8_t>> image;
  for (const auto& e : fs::directory_iterator(dir))
    if (e.is_regular_file()) image[e.path().filename().string()] = read_bytes(e.path().string());
  return image;
}

inline std::vector<std::string> tile_files(const std::string& dir) {
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name.rfind("tile_", 0) == 0 && name.size() > 4 && name.compare(name.size() - 4, 4, ".iwt") == 0)
      names.push_back(name);
  }
  std::sort(names.begin(), names.end());
  return names;
}

// The path of the file that holds tile (x, y, z) (tile_x_y_z.g<commit>.iwt), "" when there is none.
// Between commits, with no reader holding the map, a tile has one file.
inline std::string tile_file(const std::string& dir, int x, int y, int z) {
  const std::string prefix = "tile_" + std::to_string(x) + "_" + std::to_string(y) + "_" + std::to_string(z) + ".";
  std::string found;
  for (const std::string& name : tile_files(dir))
    if (name.rfind(prefix, 0) == 0) {
      EXPECT_TRUE(found.empty()) << "two files of one tile: " << found << ", " << name;
      found = (fs::path(dir) / name).string();
    }
  return found;
}

// Files that hold no committed state: temporary tiles and the staging file of evicted tiles.
inline std::size_t count_scratch_files(const std::string& dir) {
  std::size_t n = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    n += (name.size() > 4 && name.compare(name.size() - 4, 4, ".tmp") == 0) || name.rfind("iwlomap_map.staging", 0) == 0
             ? 1
             : 0;
  }
  return n;
}

// Runs \p call and returns the StorageError it throws (fails the test when it throws nothing or
// something else).
template <class Call>
inline StorageError expect_storage_error(Call&& call, StorageError::Kind kind) {
  try {
    call();
  } catch (const StorageError& e) {
    EXPECT_EQ(static_cast<int>(e.kind()), static_cast<int>(kind)) << e.what();
    EXPECT_NE(std::string(e.what()).find(e.path()), std::string::npos) << "the message must name the file: " << e.what();
    return e;
  } catch (const std::exception& e) {
    ADD_FAILURE() << "expected StorageError, got " << e.what();
    return StorageError(StorageError::Kind::kIo, "", "");
  }
  ADD_FAILURE() << "expected StorageError, nothing was thrown";
  return StorageError(StorageError::Kind::kIo, "", "");
}

// Expects opening the map in \p dir, for writing and read-only, to throw StorageError of \p kind
// naming \p file with \p text in its message, and no file of the directory to change.
inline void expect_open_refused(const std::string& dir, StorageError::Kind kind, const std::string& file,
                                const std::string& text) {
  const auto image = directory_image(dir);
  const StorageError e = expect_storage_error(
      [&] { OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 4); }, kind);
  EXPECT_EQ(e.path(), file);
  EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
  const StorageError r = expect_storage_error([&] { (void)OutofcoreTileMapper::open_read_only(dir); }, kind);
  EXPECT_EQ(r.path(), file);
  EXPECT_EQ(directory_image(dir), image) << "a failed open must not change any file";
}

// A map of a few tiles, flushed and closed: the starting point of the storage error tests.
inline void write_small_map(const std::string& dir, int steps) {
  OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 16);
  for (int k = 1; k <= steps; ++k) tile_test::apply_step(map, k);
  map.flush();
}

inline ProbabilityUpdater ram_after_steps(int steps) {
  ProbabilityUpdater ram(tile_test::kResolution);
  for (int k = 1; k <= steps; ++k) tile_test::apply_step(ram, k);
  return ram;
}

// Reopens the map in \p dir and expects it to equal the RAM map after steps 1..\p steps.
inline void expect_reopened_after_steps(const std::string& dir, int steps) {
  OutofcoreTileMapper reopened(dir, tile_test::kResolution, tile_test::kTileSize, 4);
  ProbabilityUpdater ram = ram_after_steps(steps);
  expect_same_map(reopened, ram);
}

// "tile_<x>_<y>_<z>.": the start of every file name of the tile holding voxel \p k in the maps of
// tile_test_inputs.h, whatever the commit that wrote it.
inline std::string tile_name_prefix(const VoxelKey& k) {
  const auto edge = static_cast<std::int32_t>(std::lround(tile_test::kTileSize / tile_test::kResolution));
  const auto tile_of = [edge](std::int32_t a) { return a >= 0 ? a / edge : -((-a + edge - 1) / edge); };
  return "tile_" + std::to_string(tile_of(k.x)) + "_" + std::to_string(tile_of(k.y)) + "_" +
         std::to_string(tile_of(k.z)) + ".";
}

// The same start of a tile file's name \p name.
inline std::string tile_name_prefix(const std::string& name) { return name.substr(0, name.find('.') + 1); }

// A full disk, made real with RLIMIT_FSIZE (root is bound by it too): writes beyond the limit fail
// with EFBIG. SIGXFSZ is ignored while the limit is set, so the write returns the error instead.
class FileSizeLimit {
 public:
  explicit FileSizeLimit(rlim_t bytes) {
    ::getrlimit(RLIMIT_FSIZE, &saved_);
    old_handler_ = ::signal(SIGXFSZ, SIG_IGN);
    rlimit l = saved_;
    l.rlim_cur = bytes;
    ::setrlimit(RLIMIT_FSIZE, &l);
  }
  ~FileSizeLimit() {
    ::setrlimit(RLIMIT_FSIZE, &saved_);
    ::signal(SIGXFSZ, old_handler_);
  }
  FileSizeLimit(const FileSizeLimit&) = delete;
  FileSizeLimit& operator=(const FileSizeLimit&) = delete;

 private:
  rlimit saved_{};
  sighandler_t old_handler_;
};

}  // namespace iwlomap::disk_test
