// SPDX-License-Identifier: BSD-3-Clause
// The scan scratch: its free voxels are exactly those cast_ray() (or, with RayModel::kFast,
// cast_line()) visits; rays cast on several
// threads into scratches of their own and merged give exactly the observations of one thread (OR
// of free bits, max of hit intensities).

#include "integrate/scan_scratch.h"
#include "iwlomap/ray_caster.h"
#include "iwlomap/synthetic_scan.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <random>
#include <set>
#include <tuple>
#include <utility>

namespace iwlomap {
namespace {

struct Observations {
  std::set<std::tuple<int, int, int>> free;
  std::map<std::tuple<int, int, int>, double> hits;
  std::vector<std::pair<std::tuple<int, int, int>, detail::CellMask>> blocks;  // in visiting order
};

Observations observations_of(const detail::ScanScratch& s) {
  Observations o;
  s.for_each_free(0, s.num_chunks(), [&](const VoxelKey& b, int index) {
    const VoxelKey k = detail::voxel_of(b, index);
    EXPECT_TRUE(o.free.emplace(k.x, k.y, k.z).second) << "a free voxel listed twice";
  });
  s.for_each_hit([&](const VoxelKey& k, double intensity) {
    EXPECT_TRUE(o.hits.emplace(std::make_tuple(k.x, k.y, k.z), intensity).second) << "a hit listed twice";
  });
  s.for_each_block([&](const VoxelKey& b, const detail::CellMask& cells) { o.blocks.emplace_back(std::make_tuple(b.x, b.y, b.z), cells); });
  return o;
}

// The scratch walks rays with its own bookkeeping (a bit index kept per axis, chunk changes on
// the way); the voxels must be cast_ray()'s (cast_line()'s for the fast model), ray for ray. The
// rays start on both sides of zero and near chunk corners, run long (across many 32-voxel chunks,
// in every direction, the line's steps leaving a chunk along two or three axes at once), along
// axes and diagonals and through voxel edges, where the walk's tie rule decides.
void expect_free_voxels_equal_the_model(RayModel model) {
  const double res = 0.1;
  std::mt19937 rng(2026);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  const std::vector<Eigen::Vector3d> origins = {{0.05, 0.05, 0.05}, {-3.2, 3.2, -0.0001}, {3.19999, -3.2, 6.4},
                                                {0.0, 0.0, 0.0}, {-12.34, 5.67, -8.9}};
  for (const Eigen::Vector3d& origin : origins) {
    std::vector<Eigen::Vector3d> ends;
    for (int i = 0; i < 300; ++i) ends.push_back(origin + Eigen::Vector3d(u(rng), u(rng), u(rng)) * 15.0);
    for (int a = 0; a < 3; ++a)
      for (const double sign : {-1.0, 1.0}) {
        Eigen::Vector3d d = Eigen::Vector3d::Zero();
        d[a] = sign * 7.0;
        ends.push_back(origin + d);
      }
    for (const Eigen::Vector3d& d : {Eigen::Vector3d(5, 5, 0), Eigen::Vector3d(-5, 5, 5), Eigen::Vector3d(4, -4, -4)})
      ends.push_back(origin + d);  // exact diagonals from the origin pass through edges and corners
    Eigen::MatrixXd points(static_cast<Eigen::Index>(ends.size()), 3);
    for (std::size_t i = 0; i < ends.size(); ++i) points.row(static_cast<Eigen::Index>(i)) = ends[i].transpose();
    const Eigen::VectorXd intensities = Eigen::VectorXd::Constant(points.rows(), 100.0);

    std::set<std::tuple<int, int, int>> walked, hits;
    for (const Eigen::Vector3d& e : ends) {
      cast_ray(origin, e, res, model, [&](const VoxelKey& k) { walked.emplace(k.x, k.y, k.z); });
      const VoxelKey h = world_to_key(e, res);
      hits.emplace(h.x, h.y, h.z);
    }
    for (const auto& h : hits) walked.erase(h);  // occupied wins over free
    detail::ScanScratch s;
    s.collect(origin, points, intensities, -1.0, res, model, 1);
    const Observations o = observations_of(s);
    EXPECT_GT(o.free.size(), 10000u);
    EXPECT_EQ(o.free, walked) << "origin " << origin.transpose();
    EXPECT_EQ(o.hits.size(), hits.size());
  }
}

TEST(ScanScratch, FreeVoxelsEqualCastRayWhenRaysCrossChunksInEveryDirection) {
  expect_free_voxels_equal_the_model(RayModel::kExact);
}

TEST(ScanScratch, FreeVoxelsEqualCastLineWhenFastRaysCrossChunksInEveryDirection) {
  expect_free_voxels_equal_the_model(RayModel::kFast);
}

TEST(ScanScratch, MergedThreadsEqualOneThreadWhenCollectingAScan) {
  SyntheticScanOptions options;
  options.rings = 16;
  options.columns = 512;
  const SyntheticScan scan = make_synthetic_scan(options);
  // Every point twice, the second time darker: the largest intensity must win whichever thread
  // saw which copy.
  const Eigen::Index n = scan.points.rows();
  Eigen::MatrixXd points(2 * n, 3);
  Eigen::VectorXd intensities(2 * n);
  points << scan.points, scan.points;
  intensities << scan.intensities, scan.intensities * 0.5;
  for (const RayModel model : {RayModel::kExact, RayModel::kFast}) {
    detail::ScanScratch one, three;
    one.collect(scan.origin, points, intensities, 20.0, 0.1, model, 1);
    three.collect(scan.origin, points, intensities, 20.0, 0.1, model, 3);
    const Observations a = observations_of(one), b = observations_of(three);
    EXPECT_GT(a.free.size(), 100000u);
    EXPECT_GT(a.hits.size(), 1000u);
    EXPECT_EQ(a.free, b.free);
    EXPECT_EQ(a.hits, b.hits);
    ASSERT_EQ(a.blocks.size(), b.blocks.size());
    for (std::size_t i = 0; i < a.blocks.size(); ++i) {
      EXPECT_EQ(a.blocks[i].first, b.blocks[i].first);  // the same order, whatever the threads
      EXPECT_EQ(a.blocks[i].second.word, b.blocks[i].second.word);
    }
    // A hit voxel is never also listed free (occupied wins).
    for (const auto& [k, intensity] : a.hits) EXPECT_EQ(a.free.count(k), 0u);
  }
}

// Several rays end in most voxels, with random intensities: each hit voxel takes the largest of
// its rays' intensities, for any thread count, the same through for_each_hit() and through the
// chunk-by-chunk for_each_observation_in() that the scan kernel reads.
TEST(ScanScratch, HitsTakeTheLargestIntensityOfTheirVoxel) {
  std::mt19937 rng(77u);
  std::uniform_real_distribution<double> coord(-6.0, 6.0), level(-50.0, 300.0);
  const Eigen::Index n = 20000;
  Eigen::MatrixXd points(n, 3);
  Eigen::VectorXd intensities(n);
  std::map<std::tuple<int, int, int>, double> expected;
  for (Eigen::Index i = 0; i < n; ++i) {
    // Points snapped to a 1 m lattice (13^3 voxels), so about nine share each voxel.
    const Eigen::Vector3d p(std::round(coord(rng)) + 0.01, std::round(coord(rng)) + 0.02, std::round(coord(rng)) + 0.03);
    points.row(i) = p.transpose();
    intensities[i] = level(rng);
    const VoxelKey k = world_to_key(p, 0.1);
    auto [it, fresh] = expected.emplace(std::make_tuple(k.x, k.y, k.z), intensities[i]);
    if (!fresh) it->second = std::max(it->second, intensities[i]);
  }
  ASSERT_LT(expected.size(), static_cast<std::size_t>(n) / 3) << "voxels must hold several points";
  for (const int threads : {1, 2, 5}) {
    detail::ScanScratch s;
    s.collect(Eigen::Vector3d(0.15, 0.25, 0.35), points, intensities, -1.0, 0.1, RayModel::kExact, threads);
    EXPECT_EQ(observations_of(s).hits, expected) << threads << " thread(s)";
    std::map<std::tuple<int, int, int>, double> by_chunks;
    s.for_each_observation_in(
        0, s.num_chunks(), [](const VoxelKey&, int) {},
        [&](const VoxelKey& block, int index, double intensity) {
          const VoxelKey k = detail::voxel_of(block, index);
          EXPECT_TRUE(by_chunks.emplace(std::make_tuple(k.x, k.y, k.z), intensity).second);
        });
    EXPECT_EQ(by_chunks, expected) << threads << " thread(s)";
  }
}

}  // namespace
}  // namespace iwlomap
