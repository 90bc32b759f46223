// SPDX-License-Identifier: BSD-3-Clause
// The RAM backend's batches: random batches against a dense reference array, a scattered batch
// applied whole or in slices (and by the Disk backend), the voxel of a point at the ends of the key
// range, on voxel faces and a hundred kilometres away, and a batch that runs out of memory.

#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/voxel_key.h"

#include "backend_test_support.h"
#include "ram_test_support.h"
#include "sanitizers.h"

#include <gtest/gtest.h>

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <fstream>
#include <map>
#include <new>
#include <optional>
#include <random>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

namespace iwlomap {
namespace {

using ram_test::kNaN;
using ram_test::RefVoxel;
using ram_test::rows;
using ram_test::single_observation;
using ram_test::Snapshot;
using ram_test::snapshot;
using ram_test::state_at;
using ram_test::values;

double prob_of(double L) { return 1.0 / (1.0 + std::exp(-L)); }

// Key of a voxel centre returned by get_occupied_voxels(): centre = (k + 0.5) r.
VoxelKey key_of_centre(double x, double y, double z, double r) {
  return {static_cast<std::int32_t>(std::lround(x / r - 0.5)), static_cast<std::int32_t>(std::lround(y / r - 0.5)),
          static_cast<std::int32_t>(std::lround(z / r - 0.5))};
}

// ---- dense reference -------------------------------------------------------------------------

// Voxels with keys in [-20, 20)^3: 40^3 voxels, 5^3 blocks of 8^3, across negative keys.
class DenseReference {
 public:
  static constexpr int kLo = -20;
  static constexpr int kEdge = 40;

  static std::size_t index(int x, int y, int z) {
    return (static_cast<std::size_t>(x - kLo) * kEdge + static_cast<std::size_t>(y - kLo)) * kEdge +
           static_cast<std::size_t>(z - kLo);
  }
  RefVoxel& at(int x, int y, int z) { return cells_[index(x, y, z)]; }
  const RefVoxel& at(int x, int y, int z) const { return cells_[index(x, y, z)]; }
  std::size_t known() const {
    std::size_t n = 0;
    for (const RefVoxel& v : cells_) n += v.count > 0 ? 1 : 0;
    return n;
  }

 private:
  std::vector<RefVoxel> cells_ = std::vector<RefVoxel>(static_cast<std::size_t>(kEdge) * kEdge * kEdge);
};

void expect_map_matches_reference(const ProbabilityUpdater& map, const DenseReference& ref, double r) {
  const int lo = DenseReference::kLo;
  const int hi = DenseReference::kLo + DenseReference::kEdge;
  std::size_t mismatches = 0;
  for (int x = lo; x < hi; ++x) {
    for (int y = lo; y < hi; ++y) {
      for (int z = lo; z < hi; ++z) {
        const RefVoxel& want = ref.at(x, y, z);
        const auto got = map.query(key_to_center(VoxelKey{x, y, z}, r));
        bool ok;
        if (want.count == 0) {
          ok = !got.has_value();
        } else {
          ok = got.has_value() && got->log_odds == static_cast<double>(want.L) && got->count == want.count &&
               got->probability == prob_of(static_cast<double>(want.L));
        }
        if (!ok && ++mismatches <= 10) {
          ADD_FAILURE() << "query mismatch at (" << x << ", " << y << ", " << z << "): reference L = " << want.L
                        << " n = " << want.count << ", map "
                        << (got ? std::to_string(got->log_odds) + " n = " + std::to_string(got->count) : "unknown");
        }
      }
    }
  }
  EXPECT_EQ(mismatches, 0u);

  const Snapshot s = snapshot(map);
  EXPECT_EQ(s.size(), ref.known());
  EXPECT_EQ(map.get_num_known_voxels(), ref.known());
  mismatches = 0;
  for (const auto& [k, v] : s) {
    const bool in_box = k.x >= lo && k.x < hi && k.y >= lo && k.y < hi && k.z >= lo && k.z < hi;
    const bool ok = in_box && ref.at(k.x, k.y, k.z).count == v.second &&
                    static_cast<double>(ref.at(k.x, k.y, k.z).L) == v.first;
    if (!ok && ++mismatches <= 10) ADD_FAILURE() << "visitor mismatch at (" << k.x << ", " << k.y << ", " << k.z << ")";
  }
  EXPECT_EQ(mismatches, 0u);
}

void expect_occupied_matches_reference(ProbabilityUpdater& map, const DenseReference& ref, double r,
                                       double min_probability) {
  SCOPED_TRACE("min_probability = " + std::to_string(min_probability));
  std::map<VoxelKey, double> want;
  const int lo = DenseReference::kLo;
  for (int x = lo; x < lo + DenseReference::kEdge; ++x)
    for (int y = lo; y < lo + DenseReference::kEdge; ++y)
      for (int z = lo; z < lo + DenseReference::kEdge; ++z) {
        const RefVoxel& v = ref.at(x, y, z);
        const double p = prob_of(static_cast<double>(v.L));
        if (v.count > 0 && p > min_probability) want[VoxelKey{x, y, z}] = p;
      }
  const Eigen::MatrixXd occ = map.get_occupied_voxels(min_probability);
  ASSERT_EQ(occ.cols(), 4);
  std::map<VoxelKey, double> got;
  for (Eigen::Index i = 0; i < occ.rows(); ++i) {
    const VoxelKey k = key_of_centre(occ(i, 0), occ(i, 1), occ(i, 2), r);
    const Eigen::Vector3d c = key_to_center(k, r);
    EXPECT_NEAR(occ(i, 0), c.x(), 1e-12);
    EXPECT_NEAR(occ(i, 1), c.y(), 1e-12);
    EXPECT_NEAR(occ(i, 2), c.z(), 1e-12);
    got[k] = occ(i, 3);
  }
  EXPECT_EQ(static_cast<std::size_t>(occ.rows()), got.size()) << "a voxel is reported twice";
  EXPECT_EQ(got, want);
}

TEST(ProbabilityUpdater, MatchesDenseReferenceWhenRandomBatches) {
  const double r = 0.05;
  ProbabilityUpdater map(r);
  DenseReference ref;
  IwloParams params;

  std::mt19937 rng(123456u);
  std::uniform_int_distribution<int> key_all(DenseReference::kLo, DenseReference::kLo + DenseReference::kEdge - 1);
  std::uniform_int_distribution<int> key_hot(-2, 1);  // a 4^3 hot spot straddling 0: high counts, alpha floor
  std::uniform_real_distribution<double> frac(0.05, 0.95);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::uniform_real_distribution<double> real_intensity(0.0, 255.0);
  std::uniform_int_distribution<int> int_intensity(0, 255);  // hits I_th = 35 exactly now and then
  std::uniform_real_distribution<double> weight(0.0, 2.0);

  const int kBatches = 10;
  const int kPerBatch = 10000;  // 100,000 observations in all
  bool saw_zero_log_odds = false;
  for (int b = 0; b < kBatches; ++b) {
    if (b == 5) {
      // Change the parameters half way: the map must use the new ones from here on.
      params.adaptive_enabled = false;
      params.sharpness = 3.0;
      params.decay_rate = 0.5;
      params.min_alpha = 0.2;
      params.L_min = -4.0;
      params.L_max = 6.0;
      params.intensity_threshold = 60.0;
      map.set_params(params);
    } else if (b == 8) {
      params.adaptive_enabled = true;
      params.adaptive_threshold = 0.35;
      params.adaptive_max_ratio = 0.6;
      map.set_adaptive_params(true, 0.35, 0.6);
    }
    const bool with_weights = b % 2 == 1;
    Eigen::MatrixXd points(kPerBatch, 3);
    Eigen::VectorXd intensities(kPerBatch);
    Eigen::VectorXd weights(kPerBatch);
    std::vector<bool> flags(kPerBatch);
    std::vector<VoxelKey> keys(kPerBatch);
    for (int i = 0; i < kPerBatch; ++i) {
      const bool hot = unit(rng) < 0.3;
      const VoxelKey k = hot ? VoxelKey{key_hot(rng), key_hot(rng), key_hot(rng)}
                             : VoxelKey{key_all(rng), key_all(rng), key_all(rng)};
      keys[static_cast<std::size_t>(i)] = k;
      // Strictly inside the voxel (5% margin), so the key is known without computing a floor.
      points(i, 0) = (k.x + frac(rng)) * r;
      points(i, 1) = (k.y + frac(rng)) * r;
      points(i, 2) = (k.z + frac(rng)) * r;
      intensities[i] = unit(rng) < 0.7 ? real_intensity(rng) : static_cast<double>(int_intensity(rng));
      flags[static_cast<std::size_t>(i)] = unit(rng) < 0.6;
      const double u = unit(rng);
      weights[i] = u < 0.1 ? 0.0 : (u < 0.15 ? 0.5 : (u < 0.2 ? 2.0 : weight(rng)));
    }
    if (with_weights)
      map.batch_update_iwlo(points, intensities, flags, weights);
    else
      map.batch_update_iwlo(points, intensities, flags);
    for (int i = 0; i < kPerBatch; ++i) {
      const VoxelKey& k = keys[static_cast<std::size_t>(i)];
      RefVoxel& v = ref.at(k.x, k.y, k.z);
      iwlo::apply_observation(v.L, v.count, intensities[i], flags[static_cast<std::size_t>(i)],
                              with_weights ? weights[i] : 1.0, params);
    }
    if (b == 0 || b == kBatches - 1) expect_map_matches_reference(map, ref, r);
  }
  for (int x = -20; x < 20 && !saw_zero_log_odds; ++x)
    for (int y = -20; y < 20 && !saw_zero_log_odds; ++y)
      for (int z = -20; z < 20; ++z)
        if (ref.at(x, y, z).count > 0 && ref.at(x, y, z).L == 0.0f) saw_zero_log_odds = true;
  // Voxels seen only with weight 0 sit at exactly p = 0.5, which exercises the strict comparison.
  EXPECT_TRUE(saw_zero_log_odds);
  // The hot spot passed the alpha floor (25 and 9 observations with these parameters) and its count
  // saturated: with a floor within 255 observations a voxel stores 8 bits of count.
  EXPECT_EQ(ref.at(0, 0, 0).count, 255);
  EXPECT_EQ(map.get_num_skipped_points(), 0u);
  for (double p : {0.5, 0.0, 0.3, 0.7, 0.95}) expect_occupied_matches_reference(map, ref, r, p);
  // A negative threshold means 0.5; 1 is allowed and reports nothing.
  const Eigen::MatrixXd neg = map.get_occupied_voxels(-1.0);
  const Eigen::MatrixXd half = map.get_occupied_voxels(0.5);
  ASSERT_EQ(neg.rows(), half.rows());
  EXPECT_TRUE(neg == half);
  EXPECT_EQ(map.get_occupied_voxels(1.0).rows(), 0);
}

// A large batch of scattered points is applied block by block (each block found once, its rows
// in call order); one of fewer rows, or slices of it, in call order. Both must give the same map,
// down to the order for_each_voxel() visits it in, and the same as the Disk backend's values.
TEST(ProbabilityUpdater, GivesTheSameMapWhenAScatteredBatchIsAppliedWholeOrInSlices) {
  const double r = 0.05;
  const Eigen::Index n = 120000;
  std::mt19937_64 rng(2711u);
  std::uniform_real_distribution<double> xy(-6.0, 6.0), z(-1.5, 1.5), unit(0.0, 1.0);
  Eigen::MatrixXd points(n, 3);
  Eigen::VectorXd intensities(n), weights(n);
  std::vector<bool> flags(static_cast<std::size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) {
    // Every 5th row observes the voxel of one of the 20 rows before it again: per-voxel order counts.
    if (i > 20 && i % 5 == 0)
      points.row(i) = points.row(i - 1 - static_cast<Eigen::Index>(rng() % 20));
    else
      points.row(i) << xy(rng), xy(rng), z(rng);
    intensities[i] = unit(rng) < 0.5 ? 255.0 * unit(rng) : static_cast<double>(rng() % 256);
    flags[static_cast<std::size_t>(i)] = unit(rng) < 0.6;
    weights[i] = unit(rng) < 0.1 ? 0.0 : 2.0 * unit(rng);
  }
  for (Eigen::Index i = 3; i < n; i += 1001) points(i, 2) = kNaN;  // skipped rows
  IwloParams params;
  params.intensity_threshold = 35.0;

  using Visit = std::tuple<VoxelKey, double, std::uint32_t>;
  const auto visits = [](const IMapperBackend& m) {
    std::vector<Visit> v;
    m.for_each_voxel([&v](const VoxelKey& k, const VoxelState& s) { v.emplace_back(k, s.log_odds, s.count); });
    return v;
  };
  for (const bool weighted : {false, true}) {
    SCOPED_TRACE(weighted ? "weighted" : "unweighted");
    ProbabilityUpdater whole(r), sliced(r);
    whole.set_params(params);
    sliced.set_params(params);
    const test_support::TempDir dir;
    OutofcoreTileMapper disk(dir.sub("map"), r);
    disk.set_params(params);
    const auto apply = [&](IMapperBackend& m, Eigen::Index from, Eigen::Index rows) {
      const Eigen::MatrixXd p = points.middleRows(from, rows);
      const Eigen::VectorXd in = intensities.segment(from, rows);
      const std::vector<bool> f(flags.begin() + from, flags.begin() + from + rows);
      if (weighted)
        m.batch_update_iwlo(p, in, f, Eigen::VectorXd(weights.segment(from, rows)));
      else
        m.batch_update_iwlo(p, in, f);
    };
    // Twice over: into new voxels, then into known ones.
    for (int pass = 0; pass < 2; ++pass) {
      apply(whole, 0, n);
      apply(disk, 0, n);
      for (Eigen::Index from = 0; from < n; from += 15000) apply(sliced, from, std::min<Eigen::Index>(15000, n - from));
    }
    EXPECT_EQ(whole.get_num_skipped_points(), sliced.get_num_skipped_points());
    EXPECT_EQ(whole.get_num_known_voxels(), sliced.get_num_known_voxels());
    EXPECT_EQ(whole.get_num_known_voxels(), disk.get_num_known_voxels());
    const std::vector<Visit> a = visits(whole), b = visits(sliced);
    ASSERT_EQ(a.size(), whole.get_num_known_voxels());
    EXPECT_TRUE(a == b) << "the maps differ in values or in the order they are visited in";
    std::vector<Visit> c = visits(disk), sorted_a = a;
    std::sort(c.begin(), c.end());
    std::sort(sorted_a.begin(), sorted_a.end());
    EXPECT_TRUE(sorted_a == c) << "the RAM and Disk backends differ";
  }
}

// ---- voxel keys ------------------------------------------------------------------------------

// Keys at the ends of the int32 range and at a resolution whose inverse is not a normal number
// take the exact division path of the key computation; they must agree with world_to_key().
TEST(ProbabilityUpdater, PutsPointsInVoxelOfWorldToKeyAtKeyRangeEndsAndExtremeResolutions) {
  const double lo = -2147483648.0, hi = 2147483647.0;
  for (const double r : {0.05, 1e-310, 1e290}) {
    const std::vector<double> keys = {lo, lo + 0.5, lo + 1.0, hi, hi + 0.5, hi - 1.0, -0.5, 0.0, 0.25, 3.0, -7.75};
    Eigen::MatrixXd pts(static_cast<Eigen::Index>(keys.size()), 3);
    std::map<VoxelKey, std::uint32_t> expected;
    for (std::size_t i = 0; i < keys.size(); ++i) {
      const auto row = static_cast<Eigen::Index>(i);
      pts.row(row) << keys[i] * r, keys[(i + 3) % keys.size()] * r, keys[(i + 5) % keys.size()] * r;
      ASSERT_TRUE(is_representable(pts.row(row).transpose(), r)) << "row " << i;
      ++expected[world_to_key(pts.row(row).transpose(), r)];
    }
    ProbabilityUpdater map(r);
    map.batch_update_iwlo(pts, Eigen::VectorXd::Constant(pts.rows(), 200.0), std::vector<bool>(keys.size(), true));
    std::map<VoxelKey, std::uint32_t> got;
    for (const auto& [k, v] : snapshot(map)) got[k] = v.second;
    EXPECT_EQ(got, expected) << "resolution " << r;
  }
}

// The batch path derives blocks from the coordinates in one pass per chunk of 512 rows and sends a
// chunk holding a value on (or within rounding of) a voxel face through the exact division; both
// kinds of chunk, side by side, must give world_to_key()'s voxels.
TEST(ProbabilityUpdater, PutsPointsOnAndBetweenVoxelFacesInVoxelOfWorldToKey) {
  const double r = 0.1;
  std::mt19937 rng(23u);
  std::uniform_real_distribution<double> pos(-30.0, 30.0);
  std::uniform_int_distribution<int> face(-300, 300);
  const Eigen::Index n = 5 * 512 + 37;
  Eigen::MatrixXd pts(n, 3);
  std::map<VoxelKey, std::uint32_t> expected;
  for (Eigen::Index i = 0; i < n; ++i) {
    const Eigen::Index chunk = i / 512;
    // Chunks 1 and 3 hold faces (k * 0.1, whose quotient lies within rounding of k) every 7th row.
    if ((chunk == 1 || chunk == 3) && i % 7 == 0)
      pts.row(i) << face(rng) * r, face(rng) * r, face(rng) * r;
    else
      pts.row(i) << pos(rng), pos(rng), pos(rng);
    ++expected[world_to_key(pts.row(i).transpose(), r)];
  }
  ProbabilityUpdater map(r);
  map.batch_update_iwlo(pts, Eigen::VectorXd::Constant(n, 200.0), std::vector<bool>(static_cast<std::size_t>(n), true));
  std::map<VoxelKey, std::uint32_t> got;
  for (const auto& [k, v] : snapshot(map)) got[k] = v.second;
  EXPECT_EQ(got, expected);
}

// ---- far coordinates -------------------------------------------------------------------------

TEST(ProbabilityUpdater, StoresAndQueriesWhenHundredKilometresAway) {
  const double r = 0.05;
  ProbabilityUpdater map(r);
  const Eigen::MatrixXd pts = rows({{100000.0123, -100000.0123, 100000.0},
                                    {-100000.0, 100000.0, -99999.951},
                                    {100000.049, 100000.001, -100000.02}});
  map.batch_update_iwlo(pts, values({255, 255, 255}), {true, true, true});
  ASSERT_EQ(map.get_num_known_voxels(), 3u);
  const IwloParams p;
  const double l255 = static_cast<double>(single_observation(255.0, true, p));
  for (Eigen::Index i = 0; i < pts.rows(); ++i) {
    const auto s = map.query(pts.row(i).transpose());
    ASSERT_TRUE(s.has_value()) << "point " << i;
    EXPECT_EQ(s->count, 1u);
    EXPECT_EQ(s->log_odds, l255);
  }
  // 2,000,000 voxels away the keys are still exact: the neighbours are unknown.
  EXPECT_FALSE(map.query(Eigen::Vector3d(100000.0123 + r, -100000.0123, 100000.0)).has_value());
  const Eigen::MatrixXd occ = map.get_occupied_voxels(0.5);
  ASSERT_EQ(occ.rows(), 3);
  for (Eigen::Index i = 0; i < pts.rows(); ++i) {
    bool found = false;
    for (Eigen::Index j = 0; j < occ.rows(); ++j)
      found = found || (occ.row(j).head<3>() - pts.row(i)).cwiseAbs().maxCoeff() <= 0.5 * r + 1e-9;
    EXPECT_TRUE(found) << "no occupied centre within half a voxel of point " << i;
  }
  // A scan far away: origin at a voxel centre, a hit 1 m along +y (20 voxels).
  const Eigen::Vector3d origin = key_to_center(VoxelKey{-2000000, 2000000, 1000}, r);
  map.insert_scan(origin, rows({{origin.x(), origin.y() + 1.0, origin.z()}}), values({200}));
  EXPECT_EQ(map.get_num_known_voxels(), 3u + 21u);
  EXPECT_EQ(state_at(map, -2000000, 2000010, 1000), std::make_pair(-3.0, 1u));
  EXPECT_GT(state_at(map, -2000000, 2000020, 1000).first, 0.0);
}

// ---- out of memory ---------------------------------------------------------------------------

// Runs \p scenario in a child process whose address space is limited, so that the map's
// allocations fail (std::bad_alloc) part-way through a batch; returns the child's exit code.
// Sanitizers reserve far more address space than any limit leaves, so they cannot run it.
#if IWLOMAP_TEST_UNDER_SANITIZER
constexpr bool kCanLimitAddressSpace = false;
#else
constexpr bool kCanLimitAddressSpace = true;
#endif

std::size_t address_space_bytes() {
  std::ifstream statm("/proc/self/statm");
  std::size_t pages = 0;
  statm >> pages;
  return pages * static_cast<std::size_t>(::sysconf(_SC_PAGESIZE));
}

// The child's checks, as exit codes (no gtest in the child).
enum OutOfMemoryResult : int { kOk = 0, kNeverFailed = 10, kWrongException, kSecondCallFailed, kMapInconsistent };

int run_out_of_memory_scenario(std::size_t margin) {
  // One point per 8^3 block, so that every row needs a new block and a new cell.
  constexpr int kSide = 550;
  const Eigen::Index n = Eigen::Index{kSide} * kSide;
  Eigen::MatrixXd points(n, 3);
  for (int i = 0; i < kSide; ++i)
    for (int j = 0; j < kSide; ++j) points.row(Eigen::Index{i} * kSide + j) << 0.8 * i + 0.05, 0.8 * j + 0.05, 0.05;
  const Eigen::VectorXd intensities = Eigen::VectorXd::Constant(n, 200.0);
  const std::vector<bool> occupied(static_cast<std::size_t>(n), true);

  ProbabilityUpdater map(0.1);
  rlimit old{};
  ::getrlimit(RLIMIT_AS, &old);
  rlimit low = old;
  low.rlim_cur = static_cast<rlim_t>(address_space_bytes() + margin);
  ::setrlimit(RLIMIT_AS, &low);
  bool failed = false;
  try {
    map.batch_update_iwlo(points, intensities, occupied);
  } catch (const std::bad_alloc&) {
    failed = true;
  } catch (...) {
    ::setrlimit(RLIMIT_AS, &old);
    return kWrongException;
  }
  ::setrlimit(RLIMIT_AS, &old);
  if (!failed) return kNeverFailed;
  try {
    map.batch_update_iwlo(points, intensities, occupied);
  } catch (...) {
    return kSecondCallFailed;
  }
  // The groups of rows applied before the failure hold count 2, every other row's voxel count 1,
  // and the applied rows are a prefix of the batch.
  std::size_t visited = 0;
  map.for_each_voxel([&visited](const VoxelKey&, const VoxelState&) { ++visited; });
  if (visited != static_cast<std::size_t>(n) || map.get_num_known_voxels() != static_cast<std::size_t>(n))
    return kMapInconsistent;
  bool in_prefix = true;
  for (Eigen::Index i = 0; i < n; ++i) {
    const std::optional<VoxelState> v = map.query(points.row(i).transpose());
    if (!v || v->count < 1 || v->count > 2 || (v->count == 2 && !in_prefix)) return kMapInconsistent;
    in_prefix = v->count == 2;
  }
  return kOk;
}

TEST(ProbabilityUpdater, StaysConsistentWhenMemoryRunsOutDuringABatch) {
  if (!kCanLimitAddressSpace) GTEST_SKIP() << "sanitizers reserve address space beyond any limit";
  // Margins from tight to loose make the allocation fail at different points of the batch.
  for (const std::size_t margin_mib : {1, 4, 12, 24}) {
    SCOPED_TRACE("address-space margin " + std::to_string(margin_mib) + " MiB");
    const pid_t pid = ::fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) ::_exit(run_out_of_memory_scenario(margin_mib << 20));
    int status = 0;
    ASSERT_EQ(::waitpid(pid, &status, 0), pid);
    ASSERT_TRUE(WIFEXITED(status)) << "the child did not exit normally";
    EXPECT_EQ(WEXITSTATUS(status), kOk) << "10: never ran out of memory, 11: not std::bad_alloc, 12: the second "
                                           "call failed, 13: map inconsistent";
  }
}

}  // namespace
}  // namespace iwlomap
