// SPDX-License-Identifier: BSD-3-Clause
// The scan scratch: rays cast on several threads into scratches of their own and merged give
// exactly the observations of one thread (OR of free bits, max of hit intensities).

#include "integrate/scan_scratch.h"
#include "iwlomap/synthetic_scan.h"

#include <gtest/gtest.h>

#include <map>
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
  detail::ScanScratch one, three;
  one.collect(scan.origin, points, intensities, 20.0, 0.1, 1);
  three.collect(scan.origin, points, intensities, 20.0, 0.1, 3);
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

}  // namespace
}  // namespace iwlomap
