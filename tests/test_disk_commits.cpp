// SPDX-License-Identifier: BSD-3-Clause
// The Disk backend's commits: all or nothing under SIGKILL and on failure, rollback(), readers
// beside a committing writer, the manifest (missing, extra and replaced tiles, maps from before
// manifests).

#include "backends/disk/tile_file.h"
#include "disk_test_support.h"
#include "sanitizers.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"

#include "tile_test_inputs.h"
#include "repetitions.h"

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

// ---- crashes ----

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
  const int kRounds = test_support::repetitions(100, 30);
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
    EXPECT_EQ(disk->get_num_known_voxels(), got.size());
    after_rounds += is_after && !is_before ? 1 : 0;
  }
  std::cout << "[          ] " << kRounds << " kills; up to " << max_steps << " steps flushed; " << after_rounds
            << " rounds killed after a commit and before its report" << std::endl;
  EXPECT_GT(max_steps, 0) << "the writer never completed a flush: the kills came too early to test anything";
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
    EXPECT_EQ(map.get_num_known_voxels(), committed.size());
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
    expect_open_refused(dir, StorageError::Kind::kCorrupt, extra, "not part of the map");
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
  expect_open_refused(dir, StorageError::Kind::kCorrupt, replaced, "replaced");
}

// A map as iwlomap wrote it before manifests (format 2: tile_<x>_<y>_<z>.iwt, no manifest) opens
// with the same contents, gets a manifest and format 3 at its first commit, and goes on.
// A manifest whose adaptive flag reads as -0.0 (equal to 0.0 as a number) is refused as damaged:
// the reader accepts each value in exactly the bytes the writer gives it (found by fuzz_manifest).
TEST(OutofcoreTileMapper, RefusesAManifestWhoseFlagIsNegativeZero) {
  const TempDir tmp;
  const std::string dir = tmp.sub("map");
  write_small_map(dir, 2);
  const std::string path = (fs::path(dir) / "iwlomap_map.manifest").string();
  std::vector<std::uint8_t> bytes = read_bytes(path);
  const double negative_zero = -0.0;
  std::memcpy(bytes.data() + 32 + 8 * 9, &negative_zero, sizeof negative_zero);
  const std::uint32_t crc = iwlomap::detail::crc32(bytes.data(), bytes.size() - 4);
  std::memcpy(bytes.data() + bytes.size() - 4, &crc, sizeof crc);  // little-endian hosts, as the format
  {
    std::ofstream out(path, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(bytes.data()), static_cast<std::streamsize>(bytes.size()));
  }
  expect_open_refused(dir, StorageError::Kind::kCorrupt, path, "adaptive_enabled");
}

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
