// SPDX-License-Identifier: BSD-3-Clause
// The Disk backend's storage contract: another process's map, commits that are all or nothing
// under SIGKILL, failed writes and rollback(), readers beside a writer, the manifest (missing,
// extra and replaced tiles, maps from before manifests), damaged files and newer formats.

#include "disk_test_support.h"
#include "sanitizers.h"
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
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();

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

// The child integrates step k (two calls: a scan, then a batch) and flushes, for k = 1, 2, ...,
// and reports each completed flush; it is killed at a random moment. If c is the last step
// reported, the child was between the report of c and that of c + 1: integrating step c + 1,
// committing it, or about to report it. A commit is atomic, so after reopening the whole map must
// be exactly its state after step c or after step c + 1, voxel for voxel (log-odds bits and
// counts): never a mix of the two, a torn tile, or the state between the two calls of a step.
// Odd rounds give the child 3 resident tiles, so evictions write staged tiles between flushes:
// they must never show through.
TEST(OutofcoreTileMapper, ReopensAsOneCommittedStateWhenWriterKilledAtRandomMoments) {
  const TempDir tmp;
  const int kRounds = 100;
  std::mt19937 rng(20261121u);
  std::uniform_int_distribution<int> delay_ms(2, 200);
  int after_rounds = 0, max_steps = 0;
  for (int round = 0; round < kRounds; ++round) {
    SCOPED_TRACE("round " + std::to_string(round));
    const bool evicting = round % 2 == 1;
    const std::string dir = tmp.sub("crash" + std::to_string(round));
    int fds[2];
    ASSERT_EQ(::pipe(fds), 0);
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      ::dup2(fds[1], STDOUT_FILENO);
      ::close(fds[0]);
      ::close(fds[1]);
      ::execl(IWLOMAP_TILE_WRITER_HELPER, IWLOMAP_TILE_WRITER_HELPER, "loop", dir.c_str(), "100000",
              evicting ? "3" : "1000", static_cast<char*>(nullptr));
      ::_exit(127);
    }
    ::close(fds[1]);
    // The kill's moment is what is random here; nothing waits on the child's progress.
    std::this_thread::sleep_for(std::chrono::milliseconds(delay_ms(rng)));
    ::kill(pid, SIGKILL);
    int status = 0;
    ASSERT_EQ(::waitpid(pid, &status, 0), pid);
    ASSERT_TRUE(WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL)
        << "the helper ended on its own (exit " << (WIFEXITED(status) ? WEXITSTATUS(status) : -1) << ")";
    std::int32_t last = 0, value = 0;
    while (::read(fds[0], &value, sizeof value) == static_cast<ssize_t>(sizeof value)) last = value;
    ::close(fds[0]);
    max_steps = std::max(max_steps, static_cast<int>(last));

    std::unique_ptr<OutofcoreTileMapper> disk;
    ASSERT_NO_THROW(disk = std::make_unique<OutofcoreTileMapper>(dir, tile_test::kResolution, tile_test::kTileSize, 4));
    EXPECT_EQ(count_scratch_files(dir), 0u) << "leftover temporary files are removed when the map is opened";
    const Snapshot got = snapshot(*disk);
    ProbabilityUpdater ram(tile_test::kResolution);
    for (int k = 1; k <= last; ++k) tile_test::apply_step(ram, k);
    const Snapshot before = snapshot(ram);
    tile_test::apply_step(ram, last + 1);
    const Snapshot after = snapshot(ram);
    const bool is_before = got == before, is_after = got == after;
    EXPECT_TRUE(is_before || is_after) << "the map holds " << got.size() << " voxels, neither its state after step "
                                       << last << " (" << before.size() << " voxels) nor after step " << last + 1
                                       << " (" << after.size() << ")";
    EXPECT_EQ(disk->get_num_nodes(), got.size());
    after_rounds += is_after && !is_before ? 1 : 0;
  }
  std::cout << "[          ] " << kRounds << " kills; up to " << max_steps << " steps flushed; " << after_rounds
            << " rounds killed after a commit and before its report" << std::endl;
  EXPECT_GT(max_steps, 0) << "the writer never completed a flush: the kills came too early to test anything";
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
    const auto image = directory_image(dir_);
    const StorageError e = expect_storage_error(
        [&] { OutofcoreTileMapper map(dir_, tile_test::kResolution, tile_test::kTileSize, 4); }, kind);
    EXPECT_EQ(e.path(), victim_);
    EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    EXPECT_EQ(directory_image(dir_), image) << "a failed open must not change any file";
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
    EXPECT_EQ(map.get_num_nodes(), ram.get_num_nodes());
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
    EXPECT_EQ(map.get_num_nodes(), ram.get_num_nodes());
    // The healthy part still takes updates, and is written by flush.
    map.batch_update_iwlo(points.topRows(1), Eigen::VectorXd::Constant(1, 200.0), {true});
    map.flush();
  }  // destruction flushes too
  EXPECT_EQ(read_bytes(victim_), image.at(fs::path(victim_).filename().string())) << "the damaged tile was replaced";
  // Moved away, it is missed: the manifest names it.
  fs::rename(victim_, victim_ + ".bad");
  const StorageError e = expect_storage_error(
      [&] { OutofcoreTileMapper map(dir_, tile_test::kResolution, tile_test::kTileSize, 4); },
      StorageError::Kind::kCorrupt);
  EXPECT_EQ(e.path(), victim_);
  EXPECT_NE(std::string(e.what()).find("missing"), std::string::npos) << e.what();
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
    EXPECT_EQ(map.get_num_nodes(), kept.size());
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
  (void)damage([](std::vector<std::uint8_t>& b) { b[8] = 3; });  // version 3, header checksum left stale
  expect_open_fails(StorageError::Kind::kNewerVersion, "format version 3");
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
  ASSERT_EQ(f.size(), rec + 12 + 4 + 64 + 2 * 6);
  EXPECT_EQ(u32(rec), 0u);       // block (0, 0, 0)
  EXPECT_EQ(u32(rec + 12), 2u);  // known voxels
  const std::size_t a = 1 + 8 * 2 + 64 * 3, b = 7 + 8 * 0 + 64 * 5;  // 209, 327
  for (std::size_t w = 0; w < 8; ++w) {
    std::uint64_t want = 0;
    if (a / 64 == w) want |= std::uint64_t{1} << (a % 64);
    if (b / 64 == w) want |= std::uint64_t{1} << (b % 64);
    EXPECT_EQ(u64(rec + 16 + 8 * w), want) << "mask word " << w;
  }
  const auto u16 = [&f](std::size_t at) { return static_cast<unsigned>(f[at]) | static_cast<unsigned>(f[at + 1]) << 8; };
  const std::size_t v = rec + 80;  // voxels: f32 log-odds, u16 count
  EXPECT_EQ(u16(v + 4), 2u);       // (1, 2, 3): seen twice
  EXPECT_EQ(u16(v + 6 + 4), 1u);   // (7, 0, 5): once
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


// ---- commits: all or nothing, rollback, readers beside a writer, the manifest ----

// A flush that fails part-way (the first tiles written, then a full disk) leaves every file as it
// was: the files it wrote are removed, the manifest is the previous one.
TEST(OutofcoreTileMapper, LeavesEveryFileAsItWasWhenAFlushFailsPartWay) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 16);
  for (int k = 1; k <= 3; ++k) tile_test::apply_step(map, k);
  map.flush();
  const auto flushed = directory_image(dir);
  for (int k = 4; k <= 6; ++k) tile_test::apply_step(map, k);
  map.flush();
  std::vector<std::uintmax_t> sizes;
  for (const std::string& t : tile_files(dir)) sizes.push_back(fs::file_size(fs::path(dir) / t));
  std::sort(sizes.begin(), sizes.end());
  ASSERT_GE(sizes.size(), 4u);
  ASSERT_LT(sizes.front(), sizes.back());
  // Steps 7..9 touch the same tiles: with the limit between the smallest and the largest tile
  // file, the smaller ones are written and a larger one fails.
  const auto committed = directory_image(dir);
  for (int k = 7; k <= 9; ++k) tile_test::apply_step(map, k);
  {
    const FileSizeLimit full(static_cast<rlim_t>(sizes[sizes.size() / 2]));
    (void)expect_storage_error([&] { map.flush(); }, StorageError::Kind::kIo);
  }
  EXPECT_EQ(directory_image(dir), committed) << "a failed commit must leave no trace";
  EXPECT_NE(committed, flushed);
  ProbabilityUpdater ram = ram_after_steps(9);
  expect_same_map(map, ram);  // nothing lost in the mapper either
  map.flush();  // and the next commit writes it all
  EXPECT_EQ(count_scratch_files(dir), 0u);
}

// rollback() forgets what came after the last commit (resident, staged, parameters, statistics
// setting) and writes nothing; the map goes on from the committed state.
TEST(OutofcoreTileMapper, RollbackReturnsToTheLastCommitAndChangesNoFile) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  write_small_map(dir, 2);
  const auto image = directory_image(dir);
  {
    OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 2);  // evictions: staged
    const Snapshot committed = snapshot(map);
    const double threshold = map.get_params().occupied_threshold;
    for (int k = 3; k <= 6; ++k) tile_test::apply_step(map, k);
    map.set_occupied_threshold(0.9);
    map.set_hit_accumulation(true);
    EXPECT_TRUE(fs::exists(fs::path(dir) / "iwlomap_map.staging"));
    map.rollback();
    EXPECT_EQ(snapshot(map), committed);
    EXPECT_EQ(map.get_num_nodes(), committed.size());
    EXPECT_EQ(map.get_params().occupied_threshold, threshold);
    EXPECT_FALSE(map.get_hit_accumulation());
    EXPECT_EQ(directory_image(dir), image);
    map.flush();  // nothing to commit
    EXPECT_EQ(directory_image(dir), image);
    tile_test::apply_step(map, 3);
  }  // the destructor commits step 3
  expect_reopened_after_steps(dir, 3);
}

// What the tool does when a run fails on a damaged tile: the calls before it succeeded, the run
// rolls back, and every file of the map is as it was.
TEST(OutofcoreTileMapper, LeavesEveryFileAsItWasWhenARunOnADamagedMapRollsBack) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  write_small_map(dir, 6);
  // A tile the first step does not touch, so that the run applies something before it fails.
  std::set<std::string> first_step_tiles;
  for (const auto& entry : snapshot(ram_after_steps(1))) first_step_tiles.insert(tile_name_prefix(entry.first));
  std::string victim;
  for (const std::string& name : tile_files(dir))
    if (first_step_tiles.count(tile_name_prefix(name)) == 0) victim = (fs::path(dir) / name).string();
  ASSERT_FALSE(victim.empty());
  std::vector<std::uint8_t> bytes = read_bytes(victim);
  bytes[bytes.size() - 3] ^= 0x10;  // payload: the header still checks out at open
  write_bytes(victim, bytes);
  const auto image = directory_image(dir);
  {
    OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 2);
    int k = 1;
    try {
      for (; k <= 12; ++k) tile_test::apply_step(map, k);
      ADD_FAILURE() << "no step touched the damaged tile";
    } catch (const StorageError& e) {
      EXPECT_EQ(e.path(), victim) << e.what();
    }
    EXPECT_GT(k, 1) << "the first step already failed: nothing was applied before the failure";
    map.rollback();
  }
  EXPECT_EQ(directory_image(dir), image);
}

// A digest of a map's contents in key order: key, log-odds bits, count.
std::uint64_t digest(const Snapshot& s) {
  std::uint64_t h = 1469598103934665603ull;
  const auto mix = [&h](std::uint64_t v) {
    for (int i = 0; i < 8; ++i) h = (h ^ ((v >> (8 * i)) & 0xff)) * 1099511628211ull;
  };
  for (const auto& [k, v] : s) {
    mix(static_cast<std::uint32_t>(k.x));
    mix(static_cast<std::uint32_t>(k.y));
    mix(static_cast<std::uint32_t>(k.z));
    std::uint64_t bits;
    std::memcpy(&bits, &v.first, sizeof bits);
    mix(bits);
    mix(v.second);
  }
  return h;
}

// Two reader threads open the map read-only 1,000 times in all (250 under a sanitizer) while a writer (a small cache, so
// tiles are staged between commits) commits new states without pause. Every read must succeed
// (no tile called corrupt, none missing) and see exactly one committed state.
TEST(OutofcoreTileMapper, ReadersInThreadsBesideACommittingWriterSeeOnlyCommittedStates) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  OutofcoreTileMapper writer(dir, tile_test::kResolution, tile_test::kTileSize, 2);
  tile_test::apply_step(writer, 1);
  writer.flush();
  std::mutex mutex;
  std::set<std::uint64_t> committed{digest(snapshot(writer))};
  std::atomic<bool> stop{false};
  std::atomic<int> commits{1};
  std::thread writing([&] {
    for (int k = 2; !stop.load(); ++k) {
      tile_test::apply_step(writer, 1 + k % 6);  // a map of bounded size whose voxels keep changing
      writer.flush();
      const std::uint64_t d = digest(snapshot(writer));
      std::lock_guard<std::mutex> lock(mutex);
      committed.insert(d);
      commits.fetch_add(1);
    }
  });
  // Per reader. Under a sanitizer, where a read costs 10x or more, a quarter: the races are the
  // same, the figure in docs/reliability.md is the Release build's.
  constexpr int kReads = IWLOMAP_TEST_UNDER_SANITIZER ? 125 : 500;
  std::vector<std::uint64_t> seen[2];
  std::vector<std::string> errors[2];
  std::vector<std::thread> readers;
  for (int r = 0; r < 2; ++r)
    readers.emplace_back([&, r] {
      for (int i = 0; i < kReads; ++i) {
        try {
          const OutofcoreTileMapper map = OutofcoreTileMapper::open_read_only(dir, 4);
          seen[r].push_back(digest(snapshot(map)));
        } catch (const std::exception& e) {
          errors[r].push_back(e.what());
        }
      }
    });
  for (std::thread& t : readers) t.join();
  stop = true;
  writing.join();
  tile_test::apply_step(writer, 1);
  writer.flush();  // no reader now: the files retired while they read go
  std::set<std::uint64_t> distinct;
  std::size_t unknown = 0;
  for (int r = 0; r < 2; ++r) {
    EXPECT_TRUE(errors[r].empty()) << errors[r].size() << " failed reads, the first: " << errors[r].front();
    for (const std::uint64_t d : seen[r]) {
      distinct.insert(d);
      unknown += committed.count(d) == 0 ? 1 : 0;
    }
  }
  EXPECT_EQ(unknown, 0u) << "reads that saw no committed state";
  EXPECT_GT(distinct.size(), 1u) << "the readers saw one state only: the writer did not run beside them";
  std::cout << "[          ] " << 2 * kReads << " reads beside " << commits.load() << " commits; " << distinct.size()
            << " distinct states read" << std::endl;
  EXPECT_TRUE(fs::exists(fs::path(dir) / "iwlomap_map.manifest"));
  EXPECT_EQ(tile_files(dir).size(), writer.get_num_tiles()) << "retired files are removed once no reader holds the map";
}

TEST(OutofcoreTileMapper, ThrowsAtOpenNamingATileFileTheManifestDoesNotName) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  write_small_map(dir, 2);
  const std::string some_tile = (fs::path(dir) / tile_files(dir).front()).string();
  for (const std::string name : {"tile_99_99_99.iwt", "tile_99_99_99.g1.iwt"}) {
    const std::string extra = (fs::path(dir) / name).string();
    fs::copy_file(some_tile, extra);
    const auto image = directory_image(dir);
    const StorageError e = expect_storage_error(
        [&] { OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 4); },
        StorageError::Kind::kCorrupt);
    EXPECT_EQ(e.path(), extra);
    EXPECT_NE(std::string(e.what()).find("not part of the map"), std::string::npos) << e.what();
    (void)expect_storage_error([&] { (void)OutofcoreTileMapper::open_read_only(dir); }, StorageError::Kind::kCorrupt);
    EXPECT_EQ(directory_image(dir), image) << "a failed open must not change any file";
    fs::remove(extra);
  }
  expect_reopened_after_steps(dir, 2);
}

// A sound tile file of the same tile, but not the one the last commit wrote (an older copy put
// back): refused at open, naming it.
TEST(OutofcoreTileMapper, ThrowsAtOpenWhenATileFileIsReplacedByAnOlderOne) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  write_small_map(dir, 3);
  const auto old_image = directory_image(dir);
  {
    OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 16);
    tile_test::apply_step(map, 3);
  }
  // A tile the fourth commit rewrote: its old bytes under its new name.
  std::string replaced;
  for (const std::string& name : tile_files(dir)) {
    const std::string stem = name.substr(0, name.find('.') + 1);
    for (const auto& [old_name, bytes] : old_image)
      if (old_name.rfind(stem, 0) == 0 && old_name != name && replaced.empty()) {
        replaced = (fs::path(dir) / name).string();
        write_bytes(replaced, bytes);
      }
  }
  ASSERT_FALSE(replaced.empty());
  const StorageError e = expect_storage_error(
      [&] { OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 4); },
      StorageError::Kind::kCorrupt);
  EXPECT_EQ(e.path(), replaced);
  EXPECT_NE(std::string(e.what()).find("replaced"), std::string::npos) << e.what();
}

// A map as iwlomap wrote it before manifests (format 2: tile_<x>_<y>_<z>.iwt, no manifest) opens
// with the same contents, gets a manifest and format 3 at its first commit, and goes on.
TEST(OutofcoreTileMapper, OpensAMapWrittenBeforeManifestsAndConvertsItAtItsFirstCommit) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  write_small_map(dir, 3);
  for (const std::string& name : tile_files(dir)) {
    const std::string legacy = name.substr(0, name.find('.')) + ".iwt";
    fs::rename(fs::path(dir) / name, fs::path(dir) / legacy);
  }
  fs::remove(fs::path(dir) / "iwlomap_map.manifest");
  const std::string meta = (fs::path(dir) / "iwlomap_map.meta").string();
  std::vector<std::uint8_t> bytes = read_bytes(meta);
  std::string text(bytes.begin(), bytes.end());
  const auto at = text.find("format_version 3");
  ASSERT_NE(at, std::string::npos);
  text.replace(at, 16, "format_version 2");
  write_bytes(meta, {text.begin(), text.end()});
  ASSERT_EQ(OutofcoreTileMapper::read_map_info(dir).format_version, 2u);
  {
    const OutofcoreTileMapper reader = OutofcoreTileMapper::open_read_only(dir);
    ProbabilityUpdater ram = ram_after_steps(3);
    EXPECT_EQ(snapshot(reader), snapshot(ram));
  }
  {
    OutofcoreTileMapper map(dir, tile_test::kResolution, tile_test::kTileSize, 2);
    ProbabilityUpdater ram = ram_after_steps(3);
    expect_same_map(map, ram);
    EXPECT_EQ(OutofcoreTileMapper::read_map_info(dir).format_version, 2u) << "opening changes nothing";
    tile_test::apply_step(map, 4);
    map.flush();
  }
  EXPECT_EQ(OutofcoreTileMapper::read_map_info(dir).format_version, 3u);
  EXPECT_TRUE(fs::exists(fs::path(dir) / "iwlomap_map.manifest"));
  expect_reopened_after_steps(dir, 4);
}

}  // namespace
}  // namespace iwlomap
