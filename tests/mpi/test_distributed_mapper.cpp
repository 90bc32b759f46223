// SPDX-License-Identifier: BSD-3-Clause
// DistributedMapper under mpirun (-np 1..4): the distributed map equals the one-process map voxel
// for voxel (log-odds and counts), on RAM and Disk shards; the distributed directory converts to
// one Disk map and back; a rank's bad input makes every rank throw, naming it.
//
// Run by CTest as `mpirun -np N test_distributed_mapper`; every rank runs every test, and the
// comparisons are made on rank 0 after the collective calls (a failed check never skips one).

#include <iwlomap/mpi/distributed_mapper.h>
#include <iwlomap/outofcore_tile_mapper.h>
#include <iwlomap/synthetic_scan.h>

#include <gtest/gtest.h>

#ifdef IWLOMAP_TEST_HAVE_PCL
#include <iwlomap/filters/cloud_conversions.h>
#include <pcl/io/pcd_io.h>
#include <pcl/point_types.h>
#endif

#include <algorithm>
#include <cstdio>
#include <cmath>
#include <filesystem>
#include <limits>
#include <random>
#include <string>
#include <vector>

namespace iwlomap::mpi {
namespace {

namespace fs = std::filesystem;

struct Scan {
  Eigen::Vector3d origin;
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
};

int world_rank() {
  int r = 0;
  MPI_Comm_rank(MPI_COMM_WORLD, &r);
  return r;
}
int world_size() {
  int n = 1;
  MPI_Comm_size(MPI_COMM_WORLD, &n);
  return n;
}

// Five synthetic courtyard scans from different places: more scans than ranks, so the last round
// has ranks that pass, and overlapping views, so voxels see several scans in order.
std::vector<Scan> courtyard_scans() {
  std::vector<Scan> scans;
  const double xy[5][2] = {{0, 0}, {4, 2}, {-6, -3}, {8, -5}, {-2, 6}};
  for (int i = 0; i < 5; ++i) {
    SyntheticScanOptions o;
    o.rings = 32;
    o.columns = 512;
    o.sensor_xy = {xy[i][0], xy[i][1]};
    o.seed = static_cast<std::uint32_t>(i + 1);
    const SyntheticScan s = make_synthetic_scan(o);
    scans.push_back({s.origin, s.points, s.intensities});
  }
  return scans;
}

IwloParams lidar_params() {
  IwloParams p;
  p.intensity_threshold = 5.0;  // the synthetic scan's dark asphalt still counts as a hit
  p.intensity_max = 255.0;
  return p;
}

// The one-process map of \p scans (RAM backend, its own insert_scan()), as sorted voxels.
std::vector<std::pair<VoxelKey, VoxelState>> reference(const std::vector<Scan>& scans, double resolution,
                                                       const IwloParams& params, double max_range) {
  auto map = make_backend("RAM", resolution);
  map->set_params(params);
  for (const Scan& s : scans) map->insert_scan(s.origin, s.points, s.intensities, max_range);
  std::vector<std::pair<VoxelKey, VoxelState>> v;
  map->for_each_voxel([&](const VoxelKey& k, const VoxelState& st) { v.emplace_back(k, st); });
  std::sort(v.begin(), v.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  return v;
}

// Scans in rounds, scan i on rank i mod N (the tool's round robin).
void integrate(DistributedMapper& map, const std::vector<Scan>& scans, double max_range, std::size_t first = 0) {
  const std::size_t n = static_cast<std::size_t>(map.ranks());
  for (std::size_t round = 0; round * n < scans.size() - first; ++round) {
    const std::size_t i = first + round * n + static_cast<std::size_t>(map.rank());
    if (i < scans.size())
      map.insert_scan(scans[i].origin, scans[i].points, scans[i].intensities, max_range);
    else
      map.pass();
  }
}

// Equal voxel for voxel: the same keys, bit-identical log-odds, the same counts.
void expect_same(const std::vector<std::pair<VoxelKey, VoxelState>>& got,
                 const std::vector<std::pair<VoxelKey, VoxelState>>& want) {
  ASSERT_EQ(got.size(), want.size());
  std::size_t differ = 0;
  for (std::size_t i = 0; i < got.size(); ++i) {
    const bool same = got[i].first == want[i].first && got[i].second.log_odds == want[i].second.log_odds &&
                      got[i].second.count == want[i].second.count;
    if (!same && ++differ <= 3)
      ADD_FAILURE() << "voxel " << i << " (" << want[i].first.x << ", " << want[i].first.y << ", " << want[i].first.z
                    << "): log-odds " << got[i].second.log_odds << " vs " << want[i].second.log_odds << ", count "
                    << got[i].second.count << " vs " << want[i].second.count;
  }
  EXPECT_EQ(differ, 0u);
}

// A fresh directory, the same path on every rank (made by rank 0).
std::string shared_directory(const std::string& name) {
  const std::string dir = (fs::path(::testing::TempDir()) / ("iwlomap_mpi_" + name + "_np" + std::to_string(world_size()))).string();
  if (world_rank() == 0) fs::remove_all(dir);
  MPI_Barrier(MPI_COMM_WORLD);
  return dir;
}

TEST(DistributedMapper, CourtyardScansOnRamShardsEqualOneProcess) {
  const auto scans = courtyard_scans();
  DistributedOptions o;
  o.tile_size = 1.6;  // many shards, so every rank owns some of each scan
  DistributedMapper map(MPI_COMM_WORLD, 0.1, lidar_params(), o);
  integrate(map, scans, -1.0);
  const auto got = map.gather_voxels();
  const std::size_t nodes = map.num_nodes();
  if (map.rank() != 0) return;
  const auto want = reference(scans, 0.1, lidar_params(), -1.0);
  EXPECT_GT(want.size(), 100000u);
  EXPECT_EQ(nodes, want.size());
  expect_same(got, want);
}

TEST(DistributedMapper, OccupiedVoxelsGatheredOnRootAreTheOneProcessOnes) {
  const auto scans = courtyard_scans();
  DistributedMapper map(MPI_COMM_WORLD, 0.2, lidar_params());
  integrate(map, scans, 12.0);
  const Eigen::MatrixXd got = map.gather_occupied_voxels(0.6);
  if (map.rank() != 0) {
    EXPECT_EQ(got.rows(), 0);
    return;
  }
  auto one = make_backend("RAM", 0.2);
  one->set_params(lidar_params());
  for (const Scan& s : scans) one->insert_scan(s.origin, s.points, s.intensities, 12.0);
  const Eigen::MatrixXd want = one->get_occupied_voxels(0.6);
  ASSERT_EQ(got.rows(), want.rows());
  ASSERT_GT(want.rows(), 1000);
  // The same rows, in key order on the distributed side.
  std::vector<std::vector<double>> a, b;
  for (Eigen::Index i = 0; i < got.rows(); ++i) a.push_back({got(i, 0), got(i, 1), got(i, 2), got(i, 3)});
  for (Eigen::Index i = 0; i < want.rows(); ++i) b.push_back({want(i, 0), want(i, 1), want(i, 2), want(i, 3)});
  std::sort(a.begin(), a.end());
  std::sort(b.begin(), b.end());
  EXPECT_EQ(a, b);
}

TEST(DistributedMapper, BatchesKeepCallOrderPerVoxel) {
  // Each rank's batch holds the same voxels several times with different observations: the order
  // matters, and the map must be that of rank 0's batch, then rank 1's, and so on.
  const int n = world_size();
  std::vector<Eigen::MatrixXd> points(static_cast<std::size_t>(n));
  std::vector<Eigen::VectorXd> values(static_cast<std::size_t>(n));
  std::vector<std::vector<bool>> flags(static_cast<std::size_t>(n));
  for (int r = 0; r < n; ++r) {
    std::mt19937 rng(static_cast<unsigned>(100 + r));
    std::uniform_real_distribution<double> u(-2.0, 2.0), inten(0.0, 255.0);
    const int rows = 3000;
    points[r].resize(rows, 3);
    values[r].resize(rows);
    for (int i = 0; i < rows; ++i) {
      points[r].row(i) << u(rng), u(rng), 0.5 * u(rng);
      values[r][i] = inten(rng);
      flags[r].push_back(i % 3 != 0);
    }
    points[r](7, 1) = std::numeric_limits<double>::quiet_NaN();  // skipped and counted
  }
  DistributedOptions o;
  o.tile_size = 0.8;
  DistributedMapper map(MPI_COMM_WORLD, 0.25, lidar_params(), o);
  const auto me = static_cast<std::size_t>(map.rank());
  map.batch_update_iwlo(points[me], values[me], flags[me]);
  const auto got = map.gather_voxels();
  EXPECT_EQ(map.num_skipped_points(), static_cast<std::size_t>(n));
  if (map.rank() != 0) return;
  auto one = make_backend("RAM", 0.25);
  one->set_params(lidar_params());
  for (int r = 0; r < n; ++r) one->batch_update_iwlo(points[r], values[r], flags[r]);
  std::vector<std::pair<VoxelKey, VoxelState>> want;
  one->for_each_voxel([&](const VoxelKey& k, const VoxelState& s) { want.emplace_back(k, s); });
  std::sort(want.begin(), want.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  expect_same(got, want);
}

TEST(DistributedMapper, DiskShardsEqualOneProcessAndMergeIntoOneDiskMap) {
  const auto scans = courtyard_scans();
  const std::string dir = shared_directory("disk");
  {
    DistributedOptions o;
    o.backend = "Disk";
    o.directory = dir;
    o.tile_size = 3.2;
    o.cache_tiles = 4;  // fewer than the tiles of a scan: evictions and staging are exercised
    DistributedMapper map(MPI_COMM_WORLD, 0.1, lidar_params(), o);
    integrate(map, scans, -1.0);
    map.flush();
    const auto got = map.gather_voxels();
    if (map.rank() == 0) expect_same(got, reference(scans, 0.1, lidar_params(), -1.0));
  }
  MPI_Barrier(MPI_COMM_WORLD);
  if (world_rank() != 0) return;
  const DistributedManifest m = read_manifest(dir);
  EXPECT_EQ(m.ranks, world_size());
  EXPECT_EQ(m.tile_voxels, 32u);
  std::size_t tiles = 0;
  for (const auto& t : m.tiles) tiles += t.size();
  EXPECT_GT(tiles, 10u);
  // One process opens the merged directory as a plain Disk map.
  const std::string merged = dir + "_merged";
  fs::remove_all(merged);
  merge_distributed_map(dir, merged);
  OutofcoreTileMapper one = OutofcoreTileMapper::open_read_only(merged, 8);
  EXPECT_EQ(one.get_num_tiles(), tiles);
  std::vector<std::pair<VoxelKey, VoxelState>> got;
  one.for_each_voxel([&](const VoxelKey& k, const VoxelState& s) { got.emplace_back(k, s); });
  std::sort(got.begin(), got.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  expect_same(got, reference(scans, 0.1, lidar_params(), -1.0));
  EXPECT_EQ(one.get_params().intensity_threshold, lidar_params().intensity_threshold);
}

TEST(DistributedMapper, OneProcessDiskMapSplitsAndContinuesOnTheRanks) {
  // Vice versa, and a restart: one process maps the first two scans into a Disk map; it is split
  // over this job's ranks, which reopen it and add the other three. The result is the map of all
  // five in order; a second job reopening the flushed shards continues from there.
  const auto scans = courtyard_scans();
  const std::string dir = shared_directory("split");
  const std::string single = dir + "_single";
  if (world_rank() == 0) {
    fs::remove_all(single);
    OutofcoreTileMapper one(single, 0.1, 3.2, 8);
    one.set_params(lidar_params());
    for (int i = 0; i < 2; ++i) one.insert_scan(scans[i].origin, scans[i].points, scans[i].intensities);
    one.flush();
  }
  MPI_Barrier(MPI_COMM_WORLD);
  if (world_rank() == 0) split_map(single, dir, world_size());
  MPI_Barrier(MPI_COMM_WORLD);
  DistributedOptions o;
  o.backend = "Disk";
  o.directory = dir;
  o.tile_size = 3.2;
  {
    DistributedMapper map(MPI_COMM_WORLD, 0.1, lidar_params(), o);
    integrate(map, {scans.begin(), scans.begin() + 4}, -1.0, 2);
    map.flush();
  }
  DistributedMapper again(MPI_COMM_WORLD, 0.1, lidar_params(), o);  // the restart
  integrate(again, scans, -1.0, 4);
  const auto got = again.gather_voxels();
  if (again.rank() == 0) expect_same(got, reference(scans, 0.1, lidar_params(), -1.0));
}

// Rank r's share of \p scan: rows [r n / N, (r + 1) n / N).
Scan part_of(const Scan& scan, int rank, int ranks) {
  const Eigen::Index n = scan.points.rows();
  const Eigen::Index begin = n * rank / ranks, end = n * (rank + 1) / ranks;
  return {scan.origin, scan.points.middleRows(begin, end - begin), scan.intensities.segment(begin, end - begin)};
}

TEST(DistributedMapper, OneScanSplitOverTheRanksEqualsItsOneProcessMap) {
  // Each scan's points are split over the ranks (as ranges of one big file would be), in the
  // order the scan has them, so a voxel's free and hit observations, and several hits in one
  // voxel, land on different ranks: the owners must merge them under the per-scan rule.
  auto scans = courtyard_scans();
  scans.resize(3);
  scans[1].points(11, 0) = std::numeric_limits<double>::quiet_NaN();  // skipped and counted once
  for (const char* backend : {"RAM", "Disk"}) {
    DistributedOptions o;
    o.backend = backend;
    if (o.backend == "Disk") o.directory = shared_directory("parts");
    DistributedMapper map(MPI_COMM_WORLD, 0.1, lidar_params(), o);
    for (const Scan& s : scans) {
      const Scan mine = part_of(s, map.rank(), map.ranks());
      map.insert_scan_part(mine.origin, mine.points, mine.intensities, 15.0);
    }
    const auto got = map.gather_voxels();
    EXPECT_EQ(map.num_skipped_points(), 1u);
    if (map.rank() == 0) expect_same(got, reference(scans, 0.1, lidar_params(), 15.0));
  }
}

TEST(DistributedMapper, ARoundMixingScanPartsWithWholeScansIsRefusedEverywhere) {
  if (world_size() < 2) GTEST_SKIP() << "needs two ranks";
  const auto scans = courtyard_scans();
  DistributedMapper map(MPI_COMM_WORLD, 0.2, lidar_params());
  const Scan& s = scans[0];
  try {
    if (map.rank() == 0)
      map.insert_scan_part(s.origin, s.points, s.intensities);
    else
      map.insert_scan(s.origin, s.points, s.intensities);
    ADD_FAILURE() << "no exception";
  } catch (const DistributedError& e) {
    EXPECT_NE(std::string(e.what()).find("insert_scan_part()"), std::string::npos) << e.what();
  }
  EXPECT_EQ(map.num_nodes(), 0u);
  // Parts from different origins are refused before anything is applied.
  Eigen::Vector3d origin = s.origin;
  origin.x() += map.rank();
  try {
    map.insert_scan_part(origin, s.points, s.intensities);
    ADD_FAILURE() << "no exception";
  } catch (const DistributedError& e) {
    EXPECT_NE(std::string(e.what()).find("different origins"), std::string::npos) << e.what();
  }
  EXPECT_EQ(map.num_nodes(), 0u);
}

TEST(DistributedMapper, ABadScanOnOneRankMakesEveryRankThrowNamingIt) {
  const auto scans = courtyard_scans();
  DistributedMapper map(MPI_COMM_WORLD, 0.2, lidar_params());
  integrate(map, {scans.begin(), scans.begin() + 1}, -1.0);
  const std::size_t before = map.num_nodes();
  const int bad = map.ranks() - 1;
  Eigen::Vector3d origin = scans[1].origin;
  if (map.rank() == bad) origin.x() = std::numeric_limits<double>::quiet_NaN();
  try {
    map.insert_scan(origin, scans[1].points, scans[1].intensities);
    ADD_FAILURE() << "no exception";
  } catch (const DistributedError& e) {
    EXPECT_EQ(e.failed_rank(), bad);
    EXPECT_NE(std::string(e.what()).find("rank " + std::to_string(bad) + ": "), std::string::npos) << e.what();
  }
  EXPECT_EQ(map.num_nodes(), before);  // nothing of the failed round was applied anywhere
  // The mapper goes on working.
  map.insert_scan(scans[2].origin, scans[2].points, scans[2].intensities);
  EXPECT_GT(map.num_nodes(), before);
}

TEST(DistributedMapper, AManifestOfAnotherRankCountIsRefused) {
  const std::string dir = shared_directory("ranks");
  if (world_rank() == 0) {
    fs::create_directories(dir);
    DistributedManifest m;
    m.ranks = world_size() + 1;
    m.resolution = 0.1;
    m.tile_voxels = 64;
    m.tile_size = 6.4;
    m.tiles.resize(static_cast<std::size_t>(m.ranks));
    // (written through a one-rank job's flush would need MPI_COMM_SELF; the text is simple)
    std::string text = "iwlomap distributed map 1\nranks " + std::to_string(m.ranks) +
                       "\nresolution 0x1.999999999999ap-4\ntile_size 0x1.999999999999ap+2\ntile_voxels 64\n";
    for (int r = 0; r < m.ranks; ++r) text += "rank " + std::to_string(r) + " 0\n";
    std::FILE* f = std::fopen((fs::path(dir) / kManifestName).c_str(), "w");
    ASSERT_NE(f, nullptr);
    std::fputs(text.c_str(), f);
    std::fclose(f);
    EXPECT_EQ(read_manifest(dir).ranks, world_size() + 1);
  }
  MPI_Barrier(MPI_COMM_WORLD);
  DistributedOptions o;
  o.backend = "Disk";
  o.directory = dir;
  try {
    DistributedMapper map(MPI_COMM_WORLD, 0.1, lidar_params(), o);
    ADD_FAILURE() << "no exception";
  } catch (const DistributedError& e) {
    EXPECT_NE(std::string(e.what()).find("holds a map of " + std::to_string(world_size() + 1) + " ranks"),
              std::string::npos)
        << e.what();
  }
}

#ifdef IWLOMAP_TEST_HAVE_PCL
std::vector<Scan> ouster_frames() {
  const fs::path dir = fs::path(IWLOMAP_SHARED_DATA_DIR) / "ouster_os1_128_3frames";
  std::vector<Scan> scans;
  for (int k = 0; k < 3; ++k) {
    char name[64];
    std::snprintf(name, sizeof name, "frame_%03d_world.pcd", k);
    pcl::PointCloud<pcl::PointXYZI> c;
    if (!fs::exists(dir / name) || pcl::io::loadPCDFile((dir / name).string(), c) < 0) return {};
    Scan s;
    s.origin = c.sensor_origin_.head<3>().cast<double>();
    iwlomap::cloud_to_matrices(c, nullptr, 255.0, s.points, s.intensities);
    scans.push_back(std::move(s));
  }
  return scans;
}

TEST(DistributedMapperData, OusterFramesOnRamAndDiskShardsEqualOneProcess) {
  const auto scans = ouster_frames();
  if (scans.empty()) GTEST_SKIP() << "no Ouster frames in " << IWLOMAP_SHARED_DATA_DIR;
  IwloParams p;  // the lidar preset's intensity range
  p.intensity_threshold = 1.0;
  p.intensity_max = 255.0;
  const auto want = world_rank() == 0 ? reference(scans, 0.1, p, 25.0) : decltype(reference(scans, 0.1, p, 25.0)){};
  {
    DistributedMapper map(MPI_COMM_WORLD, 0.1, p);
    integrate(map, scans, 25.0);
    const auto got = map.gather_voxels();
    if (map.rank() == 0) {
      EXPECT_GT(want.size(), 500000u);
      expect_same(got, want);
    }
  }
  DistributedOptions o;
  o.backend = "Disk";
  o.directory = shared_directory("ouster");
  DistributedMapper map(MPI_COMM_WORLD, 0.1, p, o);
  integrate(map, scans, 25.0);
  map.flush();
  const auto got = map.gather_voxels();
  if (map.rank() == 0) expect_same(got, want);
}
#endif

}  // namespace
}  // namespace iwlomap::mpi

namespace {
// On ranks other than 0: only the failures, each naming its rank.
class RankFailurePrinter : public ::testing::EmptyTestEventListener {
 public:
  explicit RankFailurePrinter(int rank) : rank_(rank) {}
  void OnTestPartResult(const ::testing::TestPartResult& r) override {
    if (r.failed())
      std::fprintf(stderr, "rank %d: %s:%d: failure\n%s\n", rank_, r.file_name() ? r.file_name() : "?", r.line_number(),
                   r.summary());
  }

 private:
  int rank_;
};
}  // namespace

int main(int argc, char** argv) {
  MPI_Init(&argc, &argv);
  ::testing::InitGoogleTest(&argc, argv);
  // Only rank 0 prints the test log; every rank's failures still fail its exit code.
  int rank = 0;
  MPI_Comm_rank(MPI_COMM_WORLD, &rank);
  if (rank != 0) {
    auto& listeners = ::testing::UnitTest::GetInstance()->listeners();
    delete listeners.Release(listeners.default_result_printer());
    listeners.Append(new RankFailurePrinter(rank));
  }
  const int rc = RUN_ALL_TESTS();
  MPI_Finalize();
  return rc;
}
