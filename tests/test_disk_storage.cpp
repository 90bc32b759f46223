// SPDX-License-Identifier: BSD-3-Clause
// The Disk backend's storage contract: another process's map, damaged files and newer formats,
// failed writes, staging. Commits, rollback, crashes and readers: test_disk_commits.cpp.

#include "disk_test_support.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"

#include "tile_test_inputs.h"

#include <gtest/gtest.h>

#include <fcntl.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <iterator>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#ifndef IWLOMAP_TILE_WRITER_HELPER
#error "IWLOMAP_TILE_WRITER_HELPER must name the tile_writer_helper executable"
#endif

namespace iwlomap {
namespace {

using namespace disk_test;

// ---- another process, crashes ----

TEST(OutofcoreTileMapper, OpensMapWrittenByAnotherProcessWithSameContents) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  const int steps = 12;
  const pid_t pid = ::fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    ::execl(IWLOMAP_TILE_WRITER_HELPER, IWLOMAP_TILE_WRITER_HELPER, "write", dir.c_str(), std::to_string(steps).c_str(),
            "3", static_cast<char*>(nullptr));
    ::_exit(127);
  }
  int status = 0;
  ASSERT_EQ(::waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status)) << "helper did not exit normally";
  ASSERT_EQ(WEXITSTATUS(status), 0) << "helper failed (127: could not run " << IWLOMAP_TILE_WRITER_HELPER << ")";

  ProbabilityUpdater ram = ram_after_steps(steps);
  OutofcoreTileMapper disk(dir, tile_test::kResolution, tile_test::kTileSize, 4);
  EXPECT_GT(disk.get_num_tiles(), 4u);
  expect_same_map(disk, ram);
  EXPECT_EQ(count_scratch_files(dir), 0u);
}

// ---- damaged and foreign files ----

class DamagedTile : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = tmp_.sub("map");
    write_small_map(dir_, 4);
    tiles_ = tile_files(dir_);
    ASSERT_GE(tiles_.size(), 3u);
    victim_ = (fs::path(dir_) / tiles_[tiles_.size() / 2]).string();
  }
  // Applies \p damage to the victim tile and returns the image of the directory after it.
  std::map<std::string, std::vector<std::uint8_t>> damage(const std::function<void(std::vector<std::uint8_t>&)>& f) {
    std::vector<std::uint8_t> bytes = read_bytes(victim_);
    f(bytes);
    write_bytes(victim_, bytes);
    return directory_image(dir_);
  }
  void expect_open_fails(StorageError::Kind kind, const std::string& text) {
    expect_open_refused(dir_, kind, victim_, text);
  }

  TempDir tmp_;
  std::string dir_;
  std::vector<std::string> tiles_;
  std::string victim_;
};

TEST_F(DamagedTile, ThrowsNamingFileAndNeverReplacesItWhenPayloadByteFlipped) {
  const auto image = damage([](std::vector<std::uint8_t>& b) { b[b.size() - 3] ^= 0x10; });
  const ProbabilityUpdater ram = ram_after_steps(4);
  {
    OutofcoreTileMapper map(dir_, tile_test::kResolution, tile_test::kTileSize, 4);  // headers are fine
    EXPECT_EQ(map.get_num_known_voxels(), ram.get_num_known_voxels());
    const StorageError e = expect_storage_error([&] { (void)snapshot(map); }, StorageError::Kind::kCorrupt);
    EXPECT_EQ(e.path(), victim_);
    EXPECT_NE(std::string(e.what()).find("checksum"), std::string::npos) << e.what();
    (void)expect_storage_error([&] { (void)map.get_occupied_voxels(); }, StorageError::Kind::kCorrupt);

    // A voxel of the damaged tile and one of a healthy tile.
    VoxelKey in_victim{}, healthy{};
    bool have_victim = false, have_healthy = false;
    const std::string victim_name = fs::path(victim_).filename().string();
    ram.for_each_voxel([&](const VoxelKey& k, const VoxelState&) {
      const bool in_victim_tile = tile_name_prefix(k) == tile_name_prefix(victim_name);
      if (in_victim_tile && !have_victim) {
        in_victim = k;
        have_victim = true;
      } else if (!in_victim_tile && !have_healthy) {
        healthy = k;
        have_healthy = true;
      }
    });
    ASSERT_TRUE(have_victim && have_healthy);
    const Eigen::Vector3d pv = key_to_center(in_victim, tile_test::kResolution);
    const Eigen::Vector3d ph = key_to_center(healthy, tile_test::kResolution);
    (void)expect_storage_error([&] { (void)map.query(pv); }, StorageError::Kind::kCorrupt);
    const auto healthy_before = map.query(ph);
    ASSERT_TRUE(healthy_before.has_value());
    // An update touching both tiles fails before it changes anything.
    Eigen::MatrixXd points(2, 3);
    points.row(0) = ph.transpose();
    points.row(1) = pv.transpose();
    EXPECT_THROW(map.batch_update_iwlo(points, Eigen::Vector2d(200, 200), {true, true}), StorageError);
    EXPECT_EQ(map.query(ph)->count, healthy_before->count);
    EXPECT_EQ(map.query(ph)->log_odds, healthy_before->log_odds);
    EXPECT_EQ(map.get_num_known_voxels(), ram.get_num_known_voxels());
    // The healthy part still takes updates, and is written by flush.
    map.batch_update_iwlo(points.topRows(1), Eigen::VectorXd::Constant(1, 200.0), {true});
    map.flush();
  }  // destruction flushes too
  EXPECT_EQ(read_bytes(victim_), image.at(fs::path(victim_).filename().string())) << "the damaged tile was replaced";
  // Moved away, it is missed: the manifest names it.
  fs::rename(victim_, victim_ + ".bad");
  expect_open_refused(dir_, StorageError::Kind::kCorrupt, victim_, "missing");
}

// repair() sets a damaged tile (or forgets a missing one) aside and commits the map of the others:
// every other voxel as it was.
TEST_F(DamagedTile, RepairSetsTheDamagedTileAsideAndKeepsEveryOtherVoxel) {
  (void)damage([](std::vector<std::uint8_t>& b) { b[b.size() - 3] ^= 0x10; });
  const std::string victim_name = fs::path(victim_).filename().string();
  Snapshot kept;
  for (const auto& [k, v] : snapshot(ram_after_steps(4)))
    if (tile_name_prefix(k) != tile_name_prefix(victim_name)) kept.emplace(k, v);
  {
    OutofcoreTileMapper locked(dir_, tile_test::kResolution, tile_test::kTileSize, 4);
    (void)expect_storage_error([&] { (void)OutofcoreTileMapper::repair(dir_); }, StorageError::Kind::kLocked);
  }
  const DiskMapRepair r = OutofcoreTileMapper::repair(dir_);
  ASSERT_EQ(r.set_aside.size(), 1u);
  EXPECT_NE(r.set_aside[0].find(victim_name), std::string::npos) << r.set_aside[0];
  EXPECT_NE(r.set_aside[0].find("checksum"), std::string::npos) << r.set_aside[0];
  EXPECT_EQ(r.tiles_kept, tiles_.size() - 1);
  EXPECT_TRUE(fs::exists(fs::path(dir_) / "damaged" / victim_name));
  {
    OutofcoreTileMapper map(dir_, tile_test::kResolution, tile_test::kTileSize, 4);
    EXPECT_EQ(snapshot(map), kept);
    EXPECT_EQ(map.get_num_known_voxels(), kept.size());
  }
  EXPECT_TRUE(OutofcoreTileMapper::repair(dir_).set_aside.empty()) << "a sound map is left as it is";
  // A missing tile is forgotten, a foreign one moved aside.
  const std::string other = (fs::path(dir_) / tile_files(dir_).front()).string();
  fs::remove(other);
  write_bytes((fs::path(dir_) / "tile_50_50_50.iwt").string(), {'x'});
  const DiskMapRepair again = OutofcoreTileMapper::repair(dir_);
  ASSERT_EQ(again.set_aside.size(), 2u);
  EXPECT_EQ(again.set_aside[0].rfind("forgotten (missing)", 0), 0u) << again.set_aside[0];
  EXPECT_NE(again.set_aside[1].find("not part of the map"), std::string::npos) << again.set_aside[1];
  EXPECT_NO_THROW(OutofcoreTileMapper(dir_, tile_test::kResolution, tile_test::kTileSize, 4));
}

TEST_F(DamagedTile, ThrowsAtOpenNamingFileWhenHeaderByteFlipped) {
  (void)damage([](std::vector<std::uint8_t>& b) { b[30] ^= 0x01; });  // inside the resolution field
  expect_open_fails(StorageError::Kind::kCorrupt, "header checksum");
}

TEST_F(DamagedTile, ThrowsAtOpenNamingFileWhenTruncated) {
  (void)damage([](std::vector<std::uint8_t>& b) { b.resize(b.size() - 7); });
  expect_open_fails(StorageError::Kind::kCorrupt, "truncated");
  (void)damage([](std::vector<std::uint8_t>& b) { b.resize(12); });
  expect_open_fails(StorageError::Kind::kCorrupt, "truncated");
  (void)damage([](std::vector<std::uint8_t>& b) { b.clear(); });
  expect_open_fails(StorageError::Kind::kCorrupt, "truncated");
}

TEST_F(DamagedTile, ThrowsAtOpenNamingFileWhenMagicWrong) {
  (void)damage([](std::vector<std::uint8_t>& b) { b[0] = 'X'; });
  expect_open_fails(StorageError::Kind::kCorrupt, "wrong magic");
}

TEST_F(DamagedTile, ThrowsNewerVersionAtOpenWhenTileFormatIsNewer) {
  (void)damage([](std::vector<std::uint8_t>& b) { b[8] = 4; });  // version 4, header checksum left stale
  expect_open_fails(StorageError::Kind::kNewerVersion, "format version 4");
}

TEST_F(DamagedTile, ThrowsNewerVersionAtOpenWhenMetadataFormatIsNewer) {
  const std::string meta = (fs::path(dir_) / "iwlomap_map.meta").string();
  std::vector<std::uint8_t> bytes = read_bytes(meta);
  std::string text(bytes.begin(), bytes.end());
  const auto at = text.find("format_version 3");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 16, "format_version 7");
  write_bytes(meta, {text.begin(), text.end()});
  const auto image = directory_image(dir_);
  const StorageError e = expect_storage_error(
      [&] { OutofcoreTileMapper map(dir_, tile_test::kResolution, tile_test::kTileSize, 4); },
      StorageError::Kind::kNewerVersion);
  EXPECT_EQ(e.path(), meta);
  EXPECT_EQ(directory_image(dir_), image);
}

// ---- failed writes ----

// Root ignores directory permissions, so "the directory cannot be written" is made real another
// way: the map directory is moved aside and a regular file takes its path. Every open() under the
// path then fails with ENOTDIR, for root too, while the tiles themselves sit untouched in the moved
// directory; moving it back is "the administrator fixed the disk".
TEST(OutofcoreTileMapper, KeepsPreviousTilesAndDirtyStateWhenDirectoryUnwritable) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map"), aside = tmp.sub("map.aside");
  auto map = std::make_unique<OutofcoreTileMapper>(dir, tile_test::kResolution, tile_test::kTileSize, 16);
  for (int k = 1; k <= 3; ++k) tile_test::apply_step(*map, k);
  map->flush();
  const auto flushed = directory_image(dir);
  tile_test::apply_step(*map, 4);  // dirty tiles in RAM

  fs::rename(dir, aside);
  write_bytes(dir, {'x'});
  const StorageError e = expect_storage_error([&] { map->flush(); }, StorageError::Kind::kIo);
  EXPECT_EQ(e.path().rfind(dir + "/tile_", 0), 0u) << e.path();
  EXPECT_NE(std::string(e.what()).find("Not a directory"), std::string::npos) << e.what();
  EXPECT_NE(std::string(e.what()).find("previous file is unchanged"), std::string::npos) << e.what();
  fs::remove(dir);
  fs::rename(aside, dir);
  EXPECT_EQ(directory_image(dir), flushed) << "the previous tiles must be intact";

  ProbabilityUpdater ram = ram_after_steps(4);
  expect_same_map(*map, ram);  // the failed flush lost nothing in RAM
  map->flush();                // and a later flush succeeds
  map.reset();
  OutofcoreTileMapper reopened(dir, tile_test::kResolution, tile_test::kTileSize, 4);
  expect_same_map(reopened, ram);
}


TEST(OutofcoreTileMapper, KeepsPreviousTilesAndDirtyStateWhenDiskFull) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 16);
  for (int k = 1; k <= 3; ++k) tile_test::apply_step(map, k);
  map.flush();
  const auto flushed = directory_image(dir);
  tile_test::apply_step(map, 4);
  {
    const FileSizeLimit full(100);  // smaller than any tile
    const StorageError e = expect_storage_error([&] { map.flush(); }, StorageError::Kind::kIo);
    EXPECT_NE(std::string(e.what()).find("File too large"), std::string::npos) << e.what();
  }
  EXPECT_EQ(directory_image(dir), flushed) << "the previous tiles must be intact, and no temporary file left";
  ProbabilityUpdater ram = ram_after_steps(4);
  expect_same_map(map, ram);
  map.flush();
  EXPECT_EQ(count_scratch_files(dir), 0u);
}

// An evicted dirty tile is appended to the staging file, not fsync'ed; the tile file changes only
// at flush(), so a crash between flushes leaves the last flushed state.
TEST(OutofcoreTileMapper, StagesEvictedTilesAndCommitsThemOnlyAtFlush) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, 0.1, 0.8, 1);
  const Eigen::MatrixXd a = (Eigen::MatrixXd(1, 3) << 0.15, 0.15, 0.15).finished();  // tile (0, 0, 0)
  const Eigen::MatrixXd b = (Eigen::MatrixXd(1, 3) << 2.05, 0.15, 0.15).finished();  // tile (2, 0, 0)
  const Eigen::VectorXd intensity = Eigen::VectorXd::Constant(1, 200.0);
  map.batch_update_iwlo(a, intensity, {true});
  map.flush();
  const std::string tile_a = tile_file(dir, 0, 0, 0);
  const std::string staging = (fs::path(dir) / "iwlomap_map.staging").string();
  const std::vector<std::uint8_t> flushed = read_bytes(tile_a);
  EXPECT_FALSE(fs::exists(staging));
  map.batch_update_iwlo(a, intensity, {true});  // count 2, in RAM
  map.batch_update_iwlo(b, intensity, {true});  // evicts tile (0, 0, 0): staged
  EXPECT_TRUE(fs::exists(staging));
  EXPECT_EQ(read_bytes(tile_a), flushed);
  EXPECT_EQ(tile_file(dir, 2, 0, 0), "");
  EXPECT_EQ(map.query(a.row(0).transpose())->count, 2u);  // read back from the staging file
  std::size_t files = 0;  // tile (0, 0, 0), the staging file (now also with (2, 0, 0)), metadata
  for (const auto& [name, bytes] : directory_image(dir)) files += bytes.size();
  EXPECT_EQ(map.get_disk_usage(), files);
  map.flush();
  EXPECT_EQ(count_scratch_files(dir), 0u);
  EXPECT_FALSE(fs::exists(tile_a)) << "the commit retired it";
  EXPECT_NE(read_bytes(tile_file(dir, 0, 0, 0)), flushed);
  EXPECT_EQ(tile_files(dir).size(), 2u);
}

// The record layout is part of the file format (src/backends/disk/tile_file.h), whatever the in-memory
// layout of a block: a mask bit x + 8 y + 64 z inside the block, the voxels in that order.
TEST(OutofcoreTileMapper, WritesBlockRecordsInTheDocumentedVoxelOrder) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  {
    OutofcoreTileMapper map(dir, 1.0, 8.0, 4);  // one 8^3 block per tile
    // Voxels (1, 2, 3) twice and (7, 0, 5) once, given in the opposite order of the file.
    const Eigen::MatrixXd pts = (Eigen::MatrixXd(3, 3) << 7.5, 0.5, 5.5, 1.5, 2.5, 3.5, 1.5, 2.5, 3.5).finished();
    map.batch_update_iwlo(pts, Eigen::VectorXd::Constant(3, 200.0), {true, true, true});
    map.flush();
  }
  const std::vector<std::uint8_t> f = read_bytes(tile_file(dir, 0, 0, 0));
  const auto u32 = [&f](std::size_t at) {
    return static_cast<std::uint32_t>(f[at]) | static_cast<std::uint32_t>(f[at + 1]) << 8 |
           static_cast<std::uint32_t>(f[at + 2]) << 16 | static_cast<std::uint32_t>(f[at + 3]) << 24;
  };
  const auto u64 = [&u32](std::size_t at) { return static_cast<std::uint64_t>(u32(at)) | static_cast<std::uint64_t>(u32(at + 4)) << 32; };
  const std::size_t rec = 80;  // header bytes
  const iwlo::VoxelFormat format;  // the defaults'
  EXPECT_EQ(u32(rec), 8u);         // the format block: 8 count bits, 19 fraction bits
  EXPECT_EQ(u32(rec + 4), 19u);
  const std::size_t r = rec + 8;  // the block record
  ASSERT_EQ(f.size(), r + 12 + 4 + 64 + 2 * 4);
  EXPECT_EQ(u32(r), 0u);       // block (0, 0, 0)
  EXPECT_EQ(u32(r + 12), 2u);  // known voxels
  const std::size_t a = 1 + 8 * 2 + 64 * 3, b = 7 + 8 * 0 + 64 * 5;  // 209, 327
  for (std::size_t w = 0; w < 8; ++w) {
    std::uint64_t want = 0;
    if (a / 64 == w) want |= std::uint64_t{1} << (a % 64);
    if (b / 64 == w) want |= std::uint64_t{1} << (b % 64);
    EXPECT_EQ(u64(r + 16 + 8 * w), want) << "mask word " << w;
  }
  const std::size_t v = r + 80;  // voxel words
  EXPECT_EQ(format.count(u32(v)), 2u);      // (1, 2, 3): seen twice
  EXPECT_EQ(format.count(u32(v + 4)), 1u);  // (7, 0, 5): once
  EXPECT_GT(format.log_odds(u32(v)), format.log_odds(u32(v + 4)));
}

// Tiles evicted again and again leave dead images in the staging file; it is rewritten with the
// live ones when it is mostly dead, and the map stays equal to the RAM map throughout.
TEST(OutofcoreTileMapper, CompactsStagingFileWhenTilesEvictedRepeatedly) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, 0.1, 3.2, 1);  // 32-voxel tiles, one resident
  ProbabilityUpdater ram(0.1);
  std::mt19937 rng(12u);
  const std::string staging = (fs::path(dir) / "iwlomap_map.staging").string();
  std::uintmax_t largest = 0;
  for (int round = 0; round < 12; ++round) {
    for (const double x : {1.6, 4.8}) {  // tiles (0, 0, 0) and (1, 0, 0) take turns
      const Batch batch = random_batch(rng, 20000, 1.5, Eigen::Vector3d(x, 1.6, 1.6));
      map.batch_update_iwlo(batch.points, batch.intensities, batch.flags);
      ram.batch_update_iwlo(batch.points, batch.intensities, batch.flags);
    }
    if (fs::exists(staging)) largest = std::max(largest, fs::file_size(staging));
  }
  // Each image is about 150 kB and 23 were appended: about 3.4 MB without compaction.
  EXPECT_GT(largest, 400000u);
  EXPECT_LT(largest, 1600000u);
  expect_same_map(map, ram);
  map.flush();
  EXPECT_EQ(count_scratch_files(dir), 0u);
  expect_same_map(map, ram);
}

TEST(OutofcoreTileMapper, ChangesNothingWhenEvictionWriteFails) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, 0.1, 0.8, 1);  // one resident tile: every other tile evicts it
  ProbabilityUpdater ram(0.1);
  std::mt19937 rng(4u);
  const Batch a = random_batch(rng, 500, 0.3, Eigen::Vector3d(0.4, 0.4, 0.4));  // tile (0, 0, 0)
  const Batch b = random_batch(rng, 500, 0.3, Eigen::Vector3d(2.0, 0.4, 0.4));  // tile (2, 0, 0)
  map.batch_update_iwlo(a.points, a.intensities, a.flags);
  ram.batch_update_iwlo(a.points, a.intensities, a.flags);
  {
    const FileSizeLimit full(100);
    (void)expect_storage_error([&] { map.batch_update_iwlo(b.points, b.intensities, b.flags); }, StorageError::Kind::kIo);
  }
  expect_same_map(map, ram);  // b was not applied, a is still there (dirty, in RAM)
  EXPECT_EQ(map.get_num_resident_tiles(), 1u);
  map.batch_update_iwlo(b.points, b.intensities, b.flags);
  ram.batch_update_iwlo(b.points, b.intensities, b.flags);
  expect_same_map(map, ram);
}

TEST(OutofcoreTileMapper, DestructorSwallowsWriteErrorsAndKeepsLastFlushedState) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map"), aside = tmp.sub("map.aside");
  {
    OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 16);
    for (int k = 1; k <= 3; ++k) tile_test::apply_step(map, k);
    map.flush();
    tile_test::apply_step(map, 4);
    fs::rename(dir, aside);
    write_bytes(dir, {'x'});
  }  // the flush of the destructor fails: no exception escapes
  fs::remove(dir);
  fs::rename(aside, dir);
  expect_reopened_after_steps(dir, 3);
}

TEST(OutofcoreTileMapper, ThrowsIoErrorWhenDirectoryReadOnlyForNonRoot) {
  if (::geteuid() == 0)
    GTEST_SKIP() << "running as root, which ignores directory permissions; the unwritable-directory and full-disk "
                    "tests above cover failed writes for root";
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 16);
  tile_test::apply_step(map, 1);
  map.flush();
  const auto flushed = directory_image(dir);
  tile_test::apply_step(map, 2);
  fs::permissions(dir, fs::perms::owner_read | fs::perms::owner_exec);
  (void)expect_storage_error([&] { map.flush(); }, StorageError::Kind::kIo);
  fs::permissions(dir, fs::perms::owner_all);
  EXPECT_EQ(directory_image(dir), flushed);
  map.flush();
}

}  // namespace
}  // namespace iwlomap
