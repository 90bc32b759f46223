// SPDX-License-Identifier: BSD-3-Clause
// The map memory limit (iwlomap/map_memory.h): what it counts, the scans it refuses before they
// change the map, and the error it gives instead of std::bad_alloc.

#include "iwlomap/map_memory.h"
#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/synthetic_scan.h"

#include "backend_test_support.h"
#include "sanitizers.h"

#include <gtest/gtest.h>

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <random>
#include <string>

namespace iwlomap {
namespace {

using test_support::snapshot;
using test_support::Snapshot;
using test_support::TempDir;

constexpr std::size_t kMiB = std::size_t{1} << 20;

// Every test starts and ends without a limit (the limit is process-wide).
class MemoryLimit : public ::testing::Test {
 protected:
  void SetUp() override { set_map_memory_limit(0); }
  void TearDown() override { set_map_memory_limit(0); }
};

Eigen::MatrixXd shifted(const Eigen::MatrixXd& pts, const Eigen::Vector3d& by) {
  return pts.rowwise() + by.transpose();
}

TEST_F(MemoryLimit, CountsTheSlabsOfLiveMapsOnly) {
  EXPECT_EQ(get_map_memory_limit(), 0u);
  set_map_memory_limit(512 * kMiB);
  EXPECT_EQ(get_map_memory_limit(), 512 * kMiB);
  const std::size_t before = get_map_memory_in_use();
  const SyntheticScan s = make_synthetic_scan();
  {
    ProbabilityUpdater map(0.1);
    map.insert_scan(s.origin, s.points, s.intensities);
    const std::size_t held = get_map_memory_in_use() - before;
    EXPECT_GT(held, 0u);
    // The slabs are most of what the map reports (the rest: the block index and the scan's
    // scratch, 6.5 MB here).
    const double reported = map.get_memory_usage().memory_mb * double(kMiB);
    EXPECT_LE(double(held), reported);
    EXPECT_GE(double(held), 0.7 * reported);
  }
  EXPECT_EQ(get_map_memory_in_use(), before);
}

TEST_F(MemoryLimit, RefusesAScanThatWouldPassItAndKeepsTheMap) {
  const SyntheticScan s = make_synthetic_scan();
  ProbabilityUpdater map(0.1);
  map.insert_scan(s.origin, s.points, s.intensities);
  const Snapshot before = snapshot(map);
  const std::size_t held = get_map_memory_in_use();
  // Room for a few slabs, not for a second courtyard 1 km away.
  set_map_memory_limit(held + 3 * kMiB);
  const Eigen::Vector3d away(1000.0, 0.0, 0.0);
  try {
    map.insert_scan(s.origin + away, shifted(s.points, away), s.intensities);
    FAIL() << "no MemoryLimitError";
  } catch (const MemoryLimitError& e) {
    const std::string what = e.what();
    EXPECT_NE(what.find("coarser resolution"), std::string::npos) << what;
    EXPECT_NE(what.find("the scan's voxels"), std::string::npos) << what;
    EXPECT_EQ(e.limit(), held + 3 * kMiB);
    EXPECT_GT(e.needed(), 3 * kMiB);
  }
  EXPECT_EQ(snapshot(map), before);
  EXPECT_EQ(get_map_memory_in_use(), held);
  // The same scan again where the map already is needs no new memory: accepted.
  EXPECT_NO_THROW(map.insert_scan(s.origin, s.points, s.intensities));
  // Without the limit the far scan goes in.
  set_map_memory_limit(0);
  EXPECT_NO_THROW(map.insert_scan(s.origin + away, shifted(s.points, away), s.intensities));
}

// A resolution far too fine for the scan: the rays' scratch alone passes the limit, and the
// error comes before any of the map is touched, on one thread or several.
TEST_F(MemoryLimit, RefusesAScanWhoseRayScratchWouldPassIt) {
  const SyntheticScan s = make_synthetic_scan();
  for (const int threads : {1, 2}) {
    SCOPED_TRACE(threads);
    ProbabilityUpdater map(0.002);
    map.set_num_threads(threads);
    set_map_memory_limit(get_map_memory_in_use() + 64 * kMiB);
    try {
      map.insert_scan(s.origin, s.points, s.intensities);
      FAIL() << "no MemoryLimitError";
    } catch (const MemoryLimitError& e) {
      EXPECT_NE(std::string(e.what()).find("ray scratch"), std::string::npos) << e.what();
    }
    EXPECT_EQ(map.get_num_known_voxels(), 0u);
    set_map_memory_limit(0);
  }
}

// While the scratch's chunk array doubles, the old array and the new one are both held: a
// doubling is refused when their sum would pass the limit. Under 90 MiB, 4,096 chunks (32 MiB)
// may not become 8,192 (64 MiB new + 32 MiB old), though the 64 MiB alone would fit.
TEST_F(MemoryLimit, CountsBothChunkArraysWhileTheScratchGrows) {
  const SyntheticScan s = make_synthetic_scan();
  ProbabilityUpdater map(0.002);
  set_map_memory_limit(get_map_memory_in_use() + 90 * kMiB);
  EXPECT_THROW(map.insert_scan(s.origin, s.points, s.intensities), MemoryLimitError);
  set_map_memory_limit(0);
  EXPECT_LT(map.get_memory_usage().memory_mb, 48.0) << "the scratch stopped at 4,096 chunks";
  EXPECT_GT(map.get_memory_usage().memory_mb, 30.0);
}

// Batches and the Disk backend's tiles are checked as slabs are mapped: the error is the same
// MemoryLimitError, and the map stays usable.
TEST_F(MemoryLimit, BatchesAndDiskTilesStopAtTheLimit) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-6.4, 6.4);  // 64 Disk tiles of 3.2 m, all resident
  Eigen::MatrixXd pts(200000, 3);
  for (Eigen::Index i = 0; i < pts.rows(); ++i) pts.row(i) = Eigen::RowVector3d(u(rng), u(rng), u(rng));
  const Eigen::VectorXd ints = Eigen::VectorXd::Constant(pts.rows(), 200.0);
  const std::vector<bool> flags(static_cast<std::size_t>(pts.rows()), true);
  {
    ProbabilityUpdater map(0.05);
    set_map_memory_limit(get_map_memory_in_use() + 8 * kMiB);
    EXPECT_THROW(map.batch_update_iwlo(pts, ints, flags), MemoryLimitError);
    set_map_memory_limit(0);
    EXPECT_NO_THROW(map.batch_update_iwlo(pts.topRows(10), ints.head(10), std::vector<bool>(10, true)));
    EXPECT_TRUE(map.query(pts.row(0).transpose()).has_value());
  }
  TempDir dir;
  {
    OutofcoreTileMapper map(dir.sub("map"), 0.05, 3.2, 64);
    set_map_memory_limit(get_map_memory_in_use() + 8 * kMiB);
    EXPECT_THROW(map.batch_update_iwlo(pts, ints, flags), MemoryLimitError);
    set_map_memory_limit(0);
    EXPECT_NO_THROW(map.flush());
  }
  OutofcoreTileMapper reopened(dir.sub("map"), 0.05, 3.2, 64);
  EXPECT_NO_THROW((void)reopened.get_occupied_voxels());
}

// Under a cap on the address space, a limit below the cap turns what would be std::bad_alloc into
// MemoryLimitError. Sanitizers reserve more address space than any cap leaves, so they cannot
// run it.
#if IWLOMAP_TEST_UNDER_SANITIZER
TEST_F(MemoryLimit, GivesTheErrorInsteadOfBadAllocUnderAnAddressSpaceCap) {
  GTEST_SKIP() << "address-space caps do not work under sanitizers";
}
#else
TEST_F(MemoryLimit, GivesTheErrorInsteadOfBadAllocUnderAnAddressSpaceCap) {
  const SyntheticScan s = make_synthetic_scan();
  // 0: MemoryLimitError; 1: std::bad_alloc; 2: no error; 3: another error.
  const auto run = [&](bool with_limit) {
    const pid_t pid = fork();
    if (pid == 0) {
      rlimit cap{};
      cap.rlim_cur = cap.rlim_max = 1024 * kMiB;
      setrlimit(RLIMIT_AS, &cap);
      if (with_limit) set_map_memory_limit(512 * kMiB);
      try {
        ProbabilityUpdater map(0.002);
        map.insert_scan(s.origin, s.points, s.intensities);
        _exit(2);
      } catch (const MemoryLimitError&) {
        _exit(0);
      } catch (const std::bad_alloc&) {
        _exit(1);
      } catch (...) {
        _exit(3);
      }
    }
    int status = 0;
    waitpid(pid, &status, 0);
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  };
  EXPECT_EQ(run(false), 1);  // the case the limit is for
  EXPECT_EQ(run(true), 0);
}
#endif

}  // namespace
}  // namespace iwlomap
