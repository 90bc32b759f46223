// SPDX-License-Identifier: BSD-3-Clause
// The RAM backend (sparse block grid) against a dense reference array, insert_scan() semantics on
// hand-built scans, and the error contract of IMapperBackend.

#include "iwlomap/outofcore_tile_mapper.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/ray_caster.h"
#include "iwlomap/synthetic_scan.h"

#include "backend_test_support.h"
#include "sanitizers.h"

#include <gtest/gtest.h>

#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <fstream>
#include <initializer_list>
#include <cstdint>
#include <limits>
#include <map>
#include <new>
#include <optional>
#include <random>
#include <set>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

namespace iwlomap {
namespace {

constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

struct RefVoxel {
  float L = 0.0f;
  std::uint16_t count = 0;
};

using Snapshot = std::map<VoxelKey, std::pair<double, std::uint32_t>>;

// Every known voxel of a map, through the visitor; fails the test on a voxel visited twice.
Snapshot snapshot(const IMapperBackend& map) {
  Snapshot s;
  map.for_each_voxel([&s](const VoxelKey& k, const VoxelState& v) {
    const bool inserted = s.emplace(k, std::make_pair(v.log_odds, v.count)).second;
    EXPECT_TRUE(inserted) << "voxel (" << k.x << ", " << k.y << ", " << k.z << ") visited twice";
  });
  return s;
}

void expect_params_eq(const IwloParams& a, const IwloParams& b) {
  EXPECT_EQ(a.sharpness, b.sharpness);
  EXPECT_EQ(a.decay_rate, b.decay_rate);
  EXPECT_EQ(a.min_alpha, b.min_alpha);
  EXPECT_EQ(a.L_min, b.L_min);
  EXPECT_EQ(a.L_max, b.L_max);
  EXPECT_EQ(a.log_odds_occupied, b.log_odds_occupied);
  EXPECT_EQ(a.log_odds_free, b.log_odds_free);
  EXPECT_EQ(a.intensity_threshold, b.intensity_threshold);
  EXPECT_EQ(a.intensity_max, b.intensity_max);
  EXPECT_EQ(a.adaptive_enabled, b.adaptive_enabled);
  EXPECT_EQ(a.adaptive_threshold, b.adaptive_threshold);
  EXPECT_EQ(a.adaptive_max_ratio, b.adaptive_max_ratio);
  EXPECT_EQ(a.occupied_threshold, b.occupied_threshold);
}

double prob_of(double L) { return 1.0 / (1.0 + std::exp(-L)); }

// Key of a voxel centre returned by get_occupied_voxels(): centre = (k + 0.5) r.
VoxelKey key_of_centre(double x, double y, double z, double r) {
  return {static_cast<std::int32_t>(std::lround(x / r - 0.5)), static_cast<std::int32_t>(std::lround(y / r - 0.5)),
          static_cast<std::int32_t>(std::lround(z / r - 0.5))};
}

// A single occupied observation with intensity I on an unknown voxel, through the shared update.
float single_observation(double intensity, bool occupied_flag, const IwloParams& p) {
  float L = 0.0f;
  std::uint16_t n = 0;
  iwlo::apply_observation(L, n, intensity, occupied_flag, 1.0, p);
  return L;
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
  EXPECT_EQ(map.get_num_nodes(), ref.known());
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
  EXPECT_GT(ref.at(0, 0, 0).count, 300);  // the hot spot reached the alpha floor
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
    EXPECT_EQ(whole.get_num_nodes(), sliced.get_num_nodes());
    EXPECT_EQ(whole.get_num_nodes(), disk.get_num_nodes());
    const std::vector<Visit> a = visits(whole), b = visits(sliced);
    ASSERT_EQ(a.size(), whole.get_num_nodes());
    EXPECT_TRUE(a == b) << "the maps differ in values or in the order they are visited in";
    std::vector<Visit> c = visits(disk), sorted_a = a;
    std::sort(c.begin(), c.end());
    std::sort(sorted_a.begin(), sorted_a.end());
    EXPECT_TRUE(sorted_a == c) << "the RAM and Disk backends differ";
  }
}

// ---- insert_scan -----------------------------------------------------------------------------

Eigen::MatrixXd rows(std::initializer_list<std::array<double, 3>> pts) {
  Eigen::MatrixXd m(static_cast<Eigen::Index>(pts.size()), 3);
  Eigen::Index i = 0;
  for (const auto& p : pts) {
    m.row(i++) << p[0], p[1], p[2];
  }
  return m;
}

Eigen::VectorXd values(std::initializer_list<double> v) {
  Eigen::VectorXd out(static_cast<Eigen::Index>(v.size()));
  Eigen::Index i = 0;
  for (double x : v) out[i++] = x;
  return out;
}

std::pair<double, std::uint32_t> state_at(const ProbabilityUpdater& map, int x, int y, int z) {
  const auto s = map.query(key_to_center(VoxelKey{x, y, z}, map.get_resolution()));
  return s ? std::make_pair(s->log_odds, s->count) : std::make_pair(kNaN, 0u);
}

TEST(ProbabilityUpdaterInsertScan, UpdatesEachVoxelOnceWhenRaysShareVoxels) {
  ProbabilityUpdater map(1.0);
  const Eigen::Vector3d origin(0.5, 0.5, 0.5);  // centre of voxel (0, 0, 0)
  // Ray 1 along +x to (5, 0, 0); ray 2 along +x to (3, 0, 0), which ray 1 crosses; ray 3 along -y
  // to (0, -4, 0). The origin voxel is crossed by all three.
  map.insert_scan(origin, rows({{5.5, 0.5, 0.5}, {3.5, 0.5, 0.5}, {0.5, -3.5, 0.5}}), values({200, 200, 100}));

  // Free (one observation, L = 0 -> -3): (0..2, 0, 0), (4, 0, 0), (0, -1..-3, 0).
  const std::vector<VoxelKey> free = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}, {4, 0, 0}, {0, -1, 0}, {0, -2, 0}, {0, -3, 0}};
  for (const VoxelKey& k : free) {
    SCOPED_TRACE(std::to_string(k.x) + " " + std::to_string(k.y) + " " + std::to_string(k.z));
    EXPECT_EQ(state_at(map, k.x, k.y, k.z), std::make_pair(-3.0, 1u));
  }
  // Occupied wins over free at (3, 0, 0). I = 200: u = 165 / 220 = 0.75,
  // w = 1 / (1 + exp(-0.1 * 0.25)) = 0.5062496744995104, L = 3.5 * w = 1.7718738607482865.
  const double l200 = static_cast<double>(static_cast<float>(1.7718738607482865));
  EXPECT_EQ(state_at(map, 5, 0, 0), std::make_pair(l200, 1u));
  EXPECT_EQ(state_at(map, 3, 0, 0), std::make_pair(l200, 1u));
  EXPECT_EQ(state_at(map, 0, -4, 0),
            std::make_pair(static_cast<double>(single_observation(100.0, true, IwloParams{})), 1u));
  EXPECT_EQ(map.get_num_nodes(), 10u);
  EXPECT_FALSE(map.query(Eigen::Vector3d(6.5, 0.5, 0.5)).has_value());
  EXPECT_FALSE(map.query(Eigen::Vector3d(0.5, 0.5, 1.5)).has_value());

  // A second scan is a second observation: n = 2, alpha = 1 / 1.1, P(-3) = 0.047 -> s = 1:
  // L = -3 - 3 / 1.1 = -5.727272727272727 for the free voxels.
  map.insert_scan(origin, rows({{5.5, 0.5, 0.5}}), values({200}));
  EXPECT_EQ(state_at(map, 1, 0, 0), std::make_pair(static_cast<double>(static_cast<float>(-5.727272727272727)), 2u));
  EXPECT_EQ(state_at(map, 0, -1, 0), std::make_pair(-3.0, 1u));  // not on this scan's ray
}

TEST(ProbabilityUpdaterInsertScan, TakesLargestIntensityWhenSeveralHitsInOneVoxel) {
  ProbabilityUpdater map(1.0);
  const IwloParams p;
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{5.2, 0.5, 0.5}, {5.8, 0.6, 0.4}, {5.5, 0.5, 0.5}}),
                  values({80, 220, 150}));
  const auto s = map.query(Eigen::Vector3d(5.5, 0.5, 0.5));
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->count, 1u);
  EXPECT_EQ(s->log_odds, static_cast<double>(single_observation(220.0, true, p)));
  // Neither the first nor the last hit's intensity, and not three observations.
  EXPECT_NE(s->log_odds, static_cast<double>(single_observation(80.0, true, p)));
  EXPECT_NE(s->log_odds, static_cast<double>(single_observation(150.0, true, p)));
  EXPECT_EQ(map.get_num_nodes(), 6u);  // (0..4, 0, 0) free + the hit
}

TEST(ProbabilityUpdaterInsertScan, FreeObservationWhenHitIntensityAtOrBelowThreshold) {
  ProbabilityUpdater map(1.0);
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{0.5, 0.5, 4.5}, {0.5, 2.5, 0.5}}), values({35, 20}));
  for (int z = 0; z <= 4; ++z) EXPECT_EQ(state_at(map, 0, 0, z), std::make_pair(-3.0, 1u)) << "z = " << z;
  for (int y = 1; y <= 2; ++y) EXPECT_EQ(state_at(map, 0, y, 0), std::make_pair(-3.0, 1u)) << "y = " << y;
  EXPECT_EQ(map.get_num_nodes(), 7u);
  EXPECT_EQ(map.get_occupied_voxels(0.0).rows(), 7);
  EXPECT_EQ(map.get_occupied_voxels(0.5).rows(), 0);
}

TEST(ProbabilityUpdaterInsertScan, ClipsFreeRayWithoutHitWhenBeyondMaxRange) {
  ProbabilityUpdater map(1.0);
  // (10.5, 0.5, 0.5) is 10 m away, beyond 4 m: free ray to (4.5, 0.5, 0.5), i.e. voxels 0..3; the
  // clipped end voxel (4, 0, 0) and the point's voxel (10, 0, 0) stay unknown.
  // (0.5, 2.5, 0.5) is 2 m away: a normal ray and hit.
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{10.5, 0.5, 0.5}, {0.5, 2.5, 0.5}}), values({200, 200}), 4.0);
  for (int x = 0; x <= 3; ++x) EXPECT_EQ(state_at(map, x, 0, 0), std::make_pair(-3.0, 1u)) << "x = " << x;
  EXPECT_FALSE(map.query(Eigen::Vector3d(4.5, 0.5, 0.5)).has_value());
  EXPECT_FALSE(map.query(Eigen::Vector3d(10.5, 0.5, 0.5)).has_value());
  EXPECT_EQ(state_at(map, 0, 1, 0), std::make_pair(-3.0, 1u));
  EXPECT_EQ(state_at(map, 0, 2, 0).second, 1u);
  EXPECT_GT(state_at(map, 0, 2, 0).first, 0.0);
  EXPECT_EQ(map.get_num_nodes(), 6u);
  // Without a limit (max_range <= 0) the same far point is a hit.
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{10.5, 0.5, 0.5}}), values({200}), -1.0);
  EXPECT_TRUE(map.query(Eigen::Vector3d(10.5, 0.5, 0.5)).has_value());
}

TEST(ProbabilityUpdaterInsertScan, SkipsAndCountsWhenPointsNotFinite) {
  ProbabilityUpdater map(1.0);
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5),
                  rows({{kNaN, 0.5, 0.5}, {2.5, 0.5, 0.5}, {0.5, kInf, 0.5}, {0.5, 0.5, 2.5}}),
                  values({200, 200, 200, kNaN}));
  EXPECT_EQ(map.get_num_skipped_points(), 3u);  // NaN x, infinite y, NaN intensity
  // Only the second point: (0, 0, 0), (1, 0, 0) free, (2, 0, 0) hit.
  EXPECT_EQ(map.get_num_nodes(), 3u);
  EXPECT_TRUE(map.query(Eigen::Vector3d(2.5, 0.5, 0.5)).has_value());
  EXPECT_FALSE(map.query(Eigen::Vector3d(0.5, 0.5, 1.5)).has_value());
  // Batches count their skipped points into the same total.
  map.batch_update_iwlo(rows({{kNaN, 0, 0}, {0.5, 0.5, 0.5}}), values({10, 10}), {true, true});
  EXPECT_EQ(map.get_num_skipped_points(), 4u);
}

TEST(ProbabilityUpdaterInsertScan, ThrowsInvalidArgumentWhenOriginNotFinite) {
  ProbabilityUpdater map(1.0);
  map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{2.5, 0.5, 0.5}}), values({200}));
  const Snapshot before = snapshot(map);
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d(kNaN, 0, 0), rows({{2.5, 0.5, 0.5}}), values({200})),
               std::invalid_argument);
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d(0, kInf, 0), rows({{2.5, 0.5, 0.5}}), values({200})),
               std::invalid_argument);
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), rows({{2.5, 0.5, 0.5}}), values({200}), kNaN),
               std::invalid_argument);
  EXPECT_EQ(snapshot(map), before);
  EXPECT_EQ(map.get_num_skipped_points(), 0u);
}

TEST(ProbabilityUpdaterInsertScan, ThrowsOutOfRangeAndKeepsMapWhenPointBeyondInt32) {
  ProbabilityUpdater map(0.05);
  map.insert_scan(Eigen::Vector3d(0.01, 0.01, 0.01), rows({{1.0, 0.0, 0.0}}), values({200}));
  const Snapshot before = snapshot(map);
  ASSERT_FALSE(before.empty());
  // The first ray is valid; the second endpoint's key does not fit in int32 (the origin lies 10
  // voxels from the end of the key range, the point 20 voxels beyond it).
  const double edge = 2147483647.0 * 0.05;
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d(edge - 0.5, 0.01, 0.01), rows({{edge - 1.0, 1.0, 0.0}, {edge + 1.0, 0.0, 0.0}}),
                               values({200, 200})),
               std::out_of_range);
  // A point far beyond the range (1e9 / 0.05 = 2e10) is past the longest ray: skipped, counted.
  const std::size_t skipped = map.get_num_skipped_points();
  EXPECT_NO_THROW(map.insert_scan(Eigen::Vector3d(0.01, 0.01, 0.01), rows({{1e9, 0.0, 0.0}}), values({200})));
  EXPECT_EQ(map.get_num_skipped_points(), skipped + 1);
  EXPECT_THROW(map.insert_scan(Eigen::Vector3d(-1e9, 0.0, 0.0), rows({{0.0, 1.0, 0.0}}), values({200})),
               std::out_of_range);
  EXPECT_EQ(snapshot(map), before);
}

// insert_scan against a reference built from compute_ray_keys(): many rays over many blocks.
TEST(ProbabilityUpdaterInsertScan, MatchesRayReferenceWhenRandomScans) {
  const double r = 0.1;
  const double max_range = 1.6;
  ProbabilityUpdater map(r);
  const IwloParams params;
  std::map<VoxelKey, RefVoxel> ref;
  std::mt19937 rng(31337u);
  std::uniform_real_distribution<double> pos(-2.0, 2.0);
  std::uniform_real_distribution<double> intensity(0.0, 255.0);
  for (int scan = 0; scan < 4; ++scan) {
    const Eigen::Vector3d origin(pos(rng) * 0.3, pos(rng) * 0.3, pos(rng) * 0.3);
    const int n = 1500;
    Eigen::MatrixXd points(n, 3);
    Eigen::VectorXd intens(n);
    for (int i = 0; i < n; ++i) {
      points.row(i) << pos(rng), pos(rng), pos(rng);
      intens[i] = intensity(rng);
    }
    // Reference: free = voxels the rays cross; hits keep the largest intensity; occupied wins.
    std::set<VoxelKey> free;
    std::map<VoxelKey, double> hits;
    for (int i = 0; i < n; ++i) {
      const Eigen::Vector3d p = points.row(i).transpose();
      const Eigen::Vector3d d = p - origin;
      const double range = d.norm();
      const bool beyond = range > max_range;
      const Eigen::Vector3d end = beyond ? Eigen::Vector3d(origin + d * (max_range / range)) : p;
      for (const VoxelKey& k : compute_ray_keys(origin, end, r)) free.insert(k);
      if (!beyond) {
        const VoxelKey k = world_to_key(p, r);
        auto it = hits.find(k);
        if (it == hits.end())
          hits.emplace(k, intens[i]);
        else if (intens[i] > it->second)
          it->second = intens[i];
      }
    }
    for (const VoxelKey& k : free) {
      if (hits.count(k) != 0) continue;
      RefVoxel& v = ref[k];
      iwlo::apply_observation(v.L, v.count, 0.0, false, 1.0, params);
    }
    for (const auto& [k, I] : hits) {
      RefVoxel& v = ref[k];
      iwlo::apply_observation(v.L, v.count, I, true, 1.0, params);
    }
    map.insert_scan(origin, points, intens, max_range);

    Snapshot want;
    for (const auto& [k, v] : ref) want.emplace(k, std::make_pair(static_cast<double>(v.L), v.count));
    const Snapshot got = snapshot(map);
    ASSERT_EQ(got.size(), want.size()) << "scan " << scan;
    std::size_t mismatches = 0;
    for (const auto& [k, v] : want) {
      const auto it = got.find(k);
      if ((it == got.end() || it->second != v) && ++mismatches <= 10)
        ADD_FAILURE() << "scan " << scan << ": voxel (" << k.x << ", " << k.y << ", " << k.z << ") differs";
    }
    EXPECT_EQ(mismatches, 0u);
    EXPECT_EQ(map.get_num_nodes(), want.size());
  }
}

// ---- bad input -------------------------------------------------------------------------------

class ProbabilityUpdaterBadInput : public ::testing::Test {
 protected:
  void SetUp() override {
    map_.batch_update_iwlo(rows({{0.01, 0.01, 0.01}, {-0.3, 0.2, 0.1}}), values({200, 10}), {true, false});
    before_ = snapshot(map_);
    ASSERT_EQ(before_.size(), 2u);
  }
  void expect_unchanged() {
    EXPECT_EQ(snapshot(map_), before_);
    EXPECT_EQ(map_.get_num_nodes(), 2u);
    EXPECT_EQ(map_.get_num_skipped_points(), 0u);
  }
  ProbabilityUpdater map_{0.05};
  Snapshot before_;
};

TEST_F(ProbabilityUpdaterBadInput, ThrowsWhenPointsNotNx3) {
  EXPECT_THROW(map_.batch_update_iwlo(Eigen::MatrixXd::Zero(2, 2), values({1, 2}), {true, true}),
               std::invalid_argument);
  EXPECT_THROW(map_.batch_update_iwlo(Eigen::MatrixXd::Zero(2, 4), values({1, 2}), {true, true}),
               std::invalid_argument);
  EXPECT_THROW(map_.insert_scan(Eigen::Vector3d::Zero(), Eigen::MatrixXd::Zero(2, 2), values({1, 2})),
               std::invalid_argument);
  expect_unchanged();
}

TEST_F(ProbabilityUpdaterBadInput, ThrowsWhenSizesMismatch) {
  const Eigen::MatrixXd pts = rows({{0.5, 0.5, 0.5}, {1.5, 0.5, 0.5}});
  EXPECT_THROW(map_.batch_update_iwlo(pts, values({1}), {true, true}), std::invalid_argument);
  EXPECT_THROW(map_.batch_update_iwlo(pts, values({1, 2, 3}), {true, true}), std::invalid_argument);
  EXPECT_THROW(map_.batch_update_iwlo(pts, values({100, 200}), {true}), std::invalid_argument);
  EXPECT_THROW(map_.batch_update_iwlo(pts, values({100, 200}), {true, true, false}), std::invalid_argument);
  EXPECT_THROW(map_.batch_update_iwlo(pts, values({100, 200}), {true, true}, values({1})), std::invalid_argument);
  EXPECT_THROW(map_.batch_update_iwlo(pts, values({100, 200}), {true, true}, values({1, 1, 1})),
               std::invalid_argument);
  EXPECT_THROW(map_.insert_scan(Eigen::Vector3d::Zero(), pts, values({1})), std::invalid_argument);
  expect_unchanged();
}

TEST_F(ProbabilityUpdaterBadInput, ThrowsNamingWeightWhenNegativeOrNaN) {
  const Eigen::MatrixXd pts = rows({{0.5, 0.5, 0.5}, {1.5, 0.5, 0.5}});
  try {
    map_.batch_update_iwlo(pts, values({100, 200}), {true, true}, values({1.0, -0.5}));
    ADD_FAILURE() << "negative weight accepted";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("weights[1] = -0.5"), std::string::npos) << e.what();
  }
  EXPECT_THROW(map_.batch_update_iwlo(pts, values({100, 200}), {true, true}, values({kNaN, 1.0})),
               std::invalid_argument);
  EXPECT_THROW(map_.batch_update_iwlo(pts, values({100, 200}), {true, true}, values({1.0, kInf})),
               std::invalid_argument);
  expect_unchanged();
}

TEST_F(ProbabilityUpdaterBadInput, ThrowsOutOfRangeAndKeepsMapWhenPointBeyondInt32) {
  // The first point is valid and comes first: nothing may be applied.
  EXPECT_THROW(map_.batch_update_iwlo(rows({{0.5, 0.5, 0.5}, {0.0, 0.0, -1e9}}), values({200, 200}), {true, true}),
               std::out_of_range);
  EXPECT_THROW(map_.batch_update_iwlo(rows({{0.5, 0.5, 0.5}, {kNaN, 0, 0}, {2e8, 0.0, 0.0}}), values({200, 1, 200}),
                                      {true, true, true}, values({1, 1, 1})),
               std::out_of_range);
  EXPECT_THROW((void)map_.query(Eigen::Vector3d(1e9, 0, 0)), std::out_of_range);
  expect_unchanged();
}

// Rows the quick whole-batch check cannot vouch for go through the row-by-row check: a weight of
// -0 (which is >= 0), points between 0.999 * 2^31 voxels and the end of the int32 range, and a
// non-finite intensity (skipped). All are valid and applied.
TEST(ProbabilityUpdater, AppliesRowsThatNeedTheDetailedCheck) {
  const double r = 0.05;
  const double far = 2147483000.0 * r;  // key 2147483000: beyond 0.999 * 2^31, inside int32
  ProbabilityUpdater map(r);
  map.batch_update_iwlo(rows({{0.01, 0.01, 0.01}, {far, 0.01, -far}, {0.2, 0.2, 0.2}}), values({200, 200, kNaN}),
                        {true, true, true}, values({-0.0, 1.0, 1.0}));
  EXPECT_EQ(map.get_num_nodes(), 2u);
  EXPECT_EQ(map.get_num_skipped_points(), 1u);
  const auto zero_weight = map.query(Eigen::Vector3d(0.01, 0.01, 0.01));
  ASSERT_TRUE(zero_weight.has_value());
  EXPECT_EQ(zero_weight->log_odds, 0.0);  // dL * (-0) = 0
  EXPECT_EQ(zero_weight->count, 1u);
  const auto far_voxel = map.query(Eigen::Vector3d(far, 0.01, -far));
  ASSERT_TRUE(far_voxel.has_value());
  EXPECT_GT(far_voxel->log_odds, 0.0f);
  std::map<VoxelKey, std::uint32_t> keys;
  for (const auto& [k, v] : snapshot(map)) keys[k] = v.second;
  EXPECT_EQ(keys.count(world_to_key(Eigen::Vector3d(far, 0.01, -far), r)), 1u);
}

TEST_F(ProbabilityUpdaterBadInput, NoOpWhenBatchEmpty) {
  map_.batch_update_iwlo(Eigen::MatrixXd(0, 3), Eigen::VectorXd(0), {});
  map_.batch_update_iwlo(Eigen::MatrixXd(0, 3), Eigen::VectorXd(0), {}, Eigen::VectorXd(0));
  map_.insert_scan(Eigen::Vector3d(0.5, 0.5, 0.5), Eigen::MatrixXd(0, 3), Eigen::VectorXd(0));
  expect_unchanged();
}

TEST_F(ProbabilityUpdaterBadInput, ThrowsWhenOccupiedThresholdNaNOrAboveOne) {
  EXPECT_THROW((void)map_.get_occupied_voxels(kNaN), std::invalid_argument);
  EXPECT_THROW((void)map_.get_occupied_voxels(1.5), std::invalid_argument);
  EXPECT_THROW((void)map_.query(Eigen::Vector3d(kNaN, 0, 0)), std::invalid_argument);
  expect_unchanged();
}

TEST_F(ProbabilityUpdaterBadInput, ThrowsAndKeepsParamsWhenSetterValueInvalid) {
  IwloParams custom;
  custom.sharpness = 0.7;
  custom.L_max = 8.0;
  custom.adaptive_enabled = false;
  map_.set_params(custom);
  const IwloParams before = map_.get_params();
  expect_params_eq(before, custom);

  EXPECT_THROW(map_.set_iwlo_params(0.1, 0.1, 0.0, -10, 10), std::invalid_argument);   // min_alpha 0
  EXPECT_THROW(map_.set_iwlo_params(0.1, 0.1, 1.5, -10, 10), std::invalid_argument);   // min_alpha > 1
  EXPECT_THROW(map_.set_iwlo_params(0.1, -1.0, 0.3, -10, 10), std::invalid_argument);  // decay < 0
  EXPECT_THROW(map_.set_iwlo_params(kNaN, 0.1, 0.3, -10, 10), std::invalid_argument);  // sharpness NaN
  EXPECT_THROW(map_.set_iwlo_params(0.1, 0.1, 0.3, 10, 10), std::invalid_argument);    // L_min >= L_max
  EXPECT_THROW(map_.set_iwlo_params(0.1, 0.1, 0.3, 5, -5), std::invalid_argument);
  EXPECT_THROW(map_.set_log_odds_params(kNaN, -3.0), std::invalid_argument);
  EXPECT_THROW(map_.set_log_odds_params(3.5, kInf), std::invalid_argument);
  EXPECT_THROW(map_.set_intensity_params(kNaN, 255.0), std::invalid_argument);
  EXPECT_THROW(map_.set_intensity_params(35.0, kInf), std::invalid_argument);
  EXPECT_THROW(map_.set_adaptive_params(true, 0.0, 0.3), std::invalid_argument);
  EXPECT_THROW(map_.set_adaptive_params(true, 1.0, 0.3), std::invalid_argument);
  EXPECT_THROW(map_.set_adaptive_params(true, 0.5, -0.5), std::invalid_argument);
  EXPECT_THROW(map_.set_adaptive_params(true, 0.5, 1.5), std::invalid_argument);
  EXPECT_THROW(map_.set_occupied_threshold(0.0), std::invalid_argument);
  EXPECT_THROW(map_.set_occupied_threshold(1.0), std::invalid_argument);
  EXPECT_THROW(map_.set_occupied_threshold(kNaN), std::invalid_argument);
  IwloParams bad = custom;
  bad.min_alpha = 2.0;
  EXPECT_THROW(map_.set_params(bad), std::invalid_argument);
  expect_params_eq(map_.get_params(), before);
  expect_unchanged();

  // Valid values are taken.
  map_.set_iwlo_params(0.2, 0.3, 0.4, -5, 5);
  map_.set_log_odds_params(2.0, -1.0);
  map_.set_intensity_params(10.0, 100.0);
  map_.set_adaptive_params(true, 0.4, 0.0);
  map_.set_occupied_threshold(0.8);
  const IwloParams after = map_.get_params();
  EXPECT_EQ(after.sharpness, 0.2);
  EXPECT_EQ(after.decay_rate, 0.3);
  EXPECT_EQ(after.min_alpha, 0.4);
  EXPECT_EQ(after.L_min, -5.0);
  EXPECT_EQ(after.L_max, 5.0);
  EXPECT_EQ(after.log_odds_occupied, 2.0);
  EXPECT_EQ(after.log_odds_free, -1.0);
  EXPECT_EQ(after.intensity_threshold, 10.0);
  EXPECT_EQ(after.intensity_max, 100.0);
  EXPECT_TRUE(after.adaptive_enabled);
  EXPECT_EQ(after.adaptive_threshold, 0.4);
  EXPECT_EQ(after.adaptive_max_ratio, 0.0);
  EXPECT_EQ(after.occupied_threshold, 0.8);
}

TEST(ProbabilityUpdater, ThrowsInvalidArgumentWhenResolutionInvalid) {
  EXPECT_THROW(ProbabilityUpdater{0.0}, std::invalid_argument);
  EXPECT_THROW(ProbabilityUpdater{-0.05}, std::invalid_argument);
  EXPECT_THROW(ProbabilityUpdater{kNaN}, std::invalid_argument);
  EXPECT_THROW(ProbabilityUpdater{kInf}, std::invalid_argument);
  try {
    ProbabilityUpdater bad(-0.5);
    ADD_FAILURE() << "accepted a negative resolution";
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find("resolution = -0.5"), std::string::npos) << e.what();
  }
  EXPECT_EQ(ProbabilityUpdater().get_resolution(), 0.05);
  EXPECT_EQ(ProbabilityUpdater(0.2).get_resolution(), 0.2);
}

// ---- lifecycle -------------------------------------------------------------------------------

TEST(ProbabilityUpdater, ForgetsVoxelsAndSkipsAndKeepsParamsWhenCleared) {
  ProbabilityUpdater map(0.1);
  IwloParams custom;
  custom.sharpness = 0.9;
  map.set_params(custom);
  map.batch_update_iwlo(rows({{0.05, 0.05, 0.05}, {kNaN, 0, 0}, {5.0, -5.0, 1.0}}), values({200, 1, 200}),
                        {true, true, true});
  ASSERT_EQ(map.get_num_nodes(), 2u);
  ASSERT_EQ(map.get_num_skipped_points(), 1u);
  map.clear();
  EXPECT_EQ(map.get_num_nodes(), 0u);
  EXPECT_EQ(map.get_num_skipped_points(), 0u);
  EXPECT_TRUE(snapshot(map).empty());
  EXPECT_FALSE(map.query(Eigen::Vector3d(0.05, 0.05, 0.05)).has_value());
  EXPECT_EQ(map.get_occupied_voxels(0.0).rows(), 0);
  EXPECT_EQ(map.get_memory_usage().num_nodes, 0u);
  EXPECT_EQ(map.get_params().sharpness, 0.9);
  // Usable again after clear().
  map.batch_update_iwlo(rows({{0.05, 0.05, 0.05}}), values({200}), {true});
  EXPECT_EQ(map.get_num_nodes(), 1u);
}

TEST(ProbabilityUpdater, ReportsMemoryWhenBlocksAllocated) {
  const double r = 0.1;
  ProbabilityUpdater map(r);
  const MemoryStats empty = map.get_memory_usage();
  EXPECT_EQ(empty.num_nodes, 0u);
  EXPECT_EQ(empty.num_leaf_nodes, 0u);
  EXPECT_GT(empty.memory_mb, 0.0);

  // 64 points in one 8^3 block: keys 0..3 along each axis.
  Eigen::MatrixXd a(64, 3);
  for (int i = 0; i < 64; ++i) a.row(i) << (i % 4 + 0.5) * r, (i / 4 % 4 + 0.5) * r, (i / 16 + 0.5) * r;
  map.batch_update_iwlo(a, Eigen::VectorXd::Constant(64, 200.0), std::vector<bool>(64, true));
  const MemoryStats one = map.get_memory_usage();
  EXPECT_EQ(one.num_nodes, 64u);
  EXPECT_EQ(one.num_leaf_nodes, 64u);
  // One block, its 16 cells of 2 x 2 x 1 voxels (keys 0..3) all full: efficiency = 64 / 64.
  EXPECT_DOUBLE_EQ(one.memory_efficiency, 1.0);
  EXPECT_GT(one.memory_mb, empty.memory_mb);

  // 64 more points, each in its own new block (keys multiples of 8 away).
  Eigen::MatrixXd b(64, 3);
  for (int i = 0; i < 64; ++i) b.row(i) << (8 * (i % 4) + 40.5) * r, (8 * (i / 4 % 4) + 0.5) * r, (8 * (i / 16) + 0.5) * r;
  map.batch_update_iwlo(b, Eigen::VectorXd::Constant(64, 200.0), std::vector<bool>(64, true));
  const MemoryStats many = map.get_memory_usage();
  EXPECT_EQ(many.num_nodes, 128u);
  EXPECT_EQ(many.num_leaf_nodes, map.get_num_nodes());
  // 16 full cells and 64 cells of one known voxel each: efficiency = 128 / (80 * 4).
  EXPECT_DOUBLE_EQ(many.memory_efficiency, 128.0 / (80.0 * 4.0));
  EXPECT_GT(many.memory_efficiency, 0.0);
  EXPECT_LE(many.memory_efficiency, 1.0);
  // At least the 65 block headers (32 bytes) and 80 cells of 4 voxels at 8 bytes are held; the
  // block index grew with the 64 new blocks.
  EXPECT_GE(many.memory_mb, (65.0 * 32 + 80.0 * 4 * 8) / (1024.0 * 1024.0));
  EXPECT_GT(many.memory_mb, one.memory_mb);
}

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

// Maps reuse the memory of destroyed maps while another map lives (see map_memory.h): nothing of
// an old map may show.
TEST(ProbabilityUpdater, StartsEmptyWhenMemoryOfDestroyedMapsIsReused) {
  const ProbabilityUpdater keeper(0.1);  // keeps the process's slab cache alive
  std::mt19937 rng(11u);
  std::uniform_real_distribution<double> pos(-20.0, 20.0);
  Eigen::MatrixXd big(200000, 3);
  for (Eigen::Index i = 0; i < big.rows(); ++i) big.row(i) << pos(rng), pos(rng), pos(rng);
  for (int round = 0; round < 3; ++round) {
    {
      ProbabilityUpdater old(0.1);
      old.batch_update_iwlo(big, Eigen::VectorXd::Constant(big.rows(), 250.0), std::vector<bool>(200000, true));
      ASSERT_GT(old.get_num_nodes(), 190000u);
    }
    ProbabilityUpdater fresh(0.1);
    EXPECT_EQ(fresh.get_num_nodes(), 0u);
    fresh.batch_update_iwlo(big.topRows(100), Eigen::VectorXd::Constant(100, 10.0), std::vector<bool>(100, false));
    const Snapshot s = snapshot(fresh);
    EXPECT_EQ(s.size(), fresh.get_num_nodes());
    std::map<VoxelKey, std::uint32_t> expected;
    for (Eigen::Index i = 0; i < 100; ++i) ++expected[world_to_key(big.row(i).transpose(), 0.1)];
    ASSERT_EQ(s.size(), expected.size());
    for (const auto& [k, v] : s) {
      EXPECT_EQ(v.second, expected.at(k));
      // Free observations only: L = L_free * alpha summed over this voxel's own observations.
      double l = 0.0;
      for (std::uint32_t n = 1; n <= v.second; ++n)
        l = static_cast<float>(iwlo::step(l, n, 10.0, false, 1.0, IwloParams{}));
      EXPECT_EQ(v.first, l);
    }
    EXPECT_EQ(fresh.get_occupied_voxels(0.5).rows(), 0);  // every known voxel is free
  }
}

TEST(ProbabilityUpdater, KeepsAllVoxelsWhenPruned) {
  ProbabilityUpdater map(0.05);
  std::mt19937 rng(5u);
  std::uniform_real_distribution<double> pos(-2.0, 2.0);
  Eigen::MatrixXd pts(3000, 3);
  for (int i = 0; i < 3000; ++i) pts.row(i) << pos(rng), pos(rng), pos(rng);
  map.insert_scan(Eigen::Vector3d(0.01, 0.02, 0.03), pts, Eigen::VectorXd::Constant(3000, 150.0));
  const Snapshot before = snapshot(map);
  const MemoryStats mem_before = map.get_memory_usage();
  ASSERT_GT(before.size(), 3000u);
  // Updates only allocate blocks they write, so no block is empty and nothing is freed.
  EXPECT_EQ(map.prune(), 0u);
  EXPECT_EQ(snapshot(map), before);
  EXPECT_EQ(map.get_num_nodes(), before.size());
  const MemoryStats mem_after = map.get_memory_usage();
  EXPECT_LT(mem_after.memory_mb, mem_before.memory_mb);  // the scan scratch was given back
  EXPECT_EQ(mem_after.num_nodes, mem_before.num_nodes);
  // The map still works after pruning.
  map.batch_update_iwlo(rows({{0.01, 0.02, 0.03}}), values({200}), {true});
  EXPECT_EQ(map.get_num_nodes(), before.size());
}

TEST(ProbabilityUpdater, KeepsMapWhenMoveConstructed) {
  ProbabilityUpdater a(0.1);
  a.batch_update_iwlo(rows({{0.05, 0.05, 0.05}, {-3.0, 2.0, 1.0}}), values({200, 10}), {true, false});
  const Snapshot s = snapshot(a);
  ProbabilityUpdater b(std::move(a));
  EXPECT_EQ(snapshot(b), s);
  EXPECT_EQ(b.get_resolution(), 0.1);
  EXPECT_EQ(b.get_num_nodes(), 2u);
  // The moved-from object refuses to work.
  EXPECT_THROW((void)a.get_num_nodes(), std::logic_error);  // NOLINT(bugprone-use-after-move)
  EXPECT_THROW((void)a.get_resolution(), std::logic_error);
  EXPECT_THROW((void)a.query(Eigen::Vector3d::Zero()), std::logic_error);
  EXPECT_THROW(a.batch_update_iwlo(rows({{0, 0, 0}}), values({1}), {true}), std::logic_error);
  EXPECT_THROW(a.insert_scan(Eigen::Vector3d::Zero(), rows({{1, 0, 0}}), values({1})), std::logic_error);
  EXPECT_THROW((void)a.get_occupied_voxels(), std::logic_error);
  EXPECT_THROW((void)a.get_memory_usage(), std::logic_error);
  EXPECT_THROW(a.for_each_voxel([](const VoxelKey&, const VoxelState&) {}), std::logic_error);
  EXPECT_THROW(a.set_occupied_threshold(0.6), std::logic_error);
  EXPECT_THROW((void)a.get_params(), std::logic_error);
  EXPECT_THROW(a.clear(), std::logic_error);
  EXPECT_THROW(a.prune(), std::logic_error);
  // Assignment revives a moved-from object.
  a = ProbabilityUpdater(0.2);
  EXPECT_EQ(a.get_num_nodes(), 0u);
  EXPECT_EQ(a.get_resolution(), 0.2);
}

TEST(ProbabilityUpdater, KeepsMapWhenMoveAssigned) {
  ProbabilityUpdater a(0.1);
  a.batch_update_iwlo(rows({{0.05, 0.05, 0.05}, {-3.0, 2.0, 1.0}}), values({200, 10}), {true, false});
  const Snapshot s = snapshot(a);
  ProbabilityUpdater b(0.5);
  b.batch_update_iwlo(rows({{7.0, 7.0, 7.0}}), values({200}), {true});
  b = std::move(a);
  EXPECT_EQ(snapshot(b), s);
  EXPECT_EQ(b.get_resolution(), 0.1);
  EXPECT_FALSE(b.query(Eigen::Vector3d(7.0, 7.0, 7.0)).has_value());
  EXPECT_THROW((void)a.get_num_nodes(), std::logic_error);  // NOLINT(bugprone-use-after-move)
  EXPECT_THROW(a.batch_update_iwlo(rows({{0, 0, 0}}), values({1}), {true}), std::logic_error);
}

// ---- factory and optional API ----------------------------------------------------------------

TEST(MakeBackend, CreatesRamBackendWhenNameMatchesIgnoringCase) {
  for (const std::string name : {"RAM", "ram", "Ram"}) {
    SCOPED_TRACE(name);
    const auto backend = make_backend(name, 0.2);
    ASSERT_NE(backend, nullptr);
    EXPECT_EQ(backend->get_backend_type(), "RAM");
    EXPECT_EQ(backend->get_resolution(), 0.2);
    EXPECT_NE(dynamic_cast<ProbabilityUpdater*>(backend.get()), nullptr);
  }
  EXPECT_EQ(make_backend("RAM")->get_resolution(), 0.05);
}

TEST(MakeBackend, ThrowsListingAvailableNamesWhenNameUnknown) {
  try {
    (void)make_backend("nope");
    ADD_FAILURE() << "unknown backend accepted";
  } catch (const std::invalid_argument& e) {
    const std::string msg = e.what();
    EXPECT_NE(msg.find("nope"), std::string::npos) << msg;
    for (const std::string& name : available_backends()) EXPECT_NE(msg.find(name), std::string::npos) << msg;
    EXPECT_NE(msg.find("RAM"), std::string::npos) << msg;
  }
  EXPECT_THROW((void)make_backend("RAM", 0.0), std::invalid_argument);
}

TEST(ProbabilityUpdater, ReportsRamWithoutPersistenceWhenQueried) {
  ProbabilityUpdater map;
  EXPECT_EQ(map.get_backend_type(), "RAM");
  EXPECT_FALSE(map.supports_persistence());
  EXPECT_EQ(map.get_disk_usage(), 0u);
  map.batch_update_iwlo(rows({{0.01, 0.01, 0.01}}), values({200}), {true});
  EXPECT_NO_THROW(map.flush());
  EXPECT_NO_THROW(map.preload_region(Eigen::Vector3d(-1, -1, -1), Eigen::Vector3d(1, 1, 1)));
  EXPECT_EQ(map.get_disk_usage(), 0u);
  EXPECT_EQ(map.get_num_nodes(), 1u);
}

// ---- far coordinates -------------------------------------------------------------------------

TEST(ProbabilityUpdater, StoresAndQueriesWhenHundredKilometresAway) {
  const double r = 0.05;
  ProbabilityUpdater map(r);
  const Eigen::MatrixXd pts = rows({{100000.0123, -100000.0123, 100000.0},
                                    {-100000.0, 100000.0, -99999.951},
                                    {100000.049, 100000.001, -100000.02}});
  map.batch_update_iwlo(pts, values({255, 255, 255}), {true, true, true});
  ASSERT_EQ(map.get_num_nodes(), 3u);
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
  EXPECT_EQ(map.get_num_nodes(), 3u + 21u);
  EXPECT_EQ(state_at(map, -2000000, 2000010, 1000), std::make_pair(-3.0, 1u));
  EXPECT_GT(state_at(map, -2000000, 2000020, 1000).first, 0.0);
}

// ---- threads ----

// Every known voxel of a map, in a canonical order, with its exact stored state.
std::vector<std::tuple<VoxelKey, double, std::uint32_t>> snapshot(const ProbabilityUpdater& m) {
  std::vector<std::tuple<VoxelKey, double, std::uint32_t>> out;
  m.for_each_voxel([&](const VoxelKey& k, const VoxelState& s) { out.emplace_back(k, s.log_odds, s.count); });
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return std::get<0>(a) < std::get<0>(b); });
  return out;
}

TEST(ProbabilityUpdaterThreads, InsertScanIsBitIdenticalForAnyThreadCount) {
  std::vector<SyntheticScan> scans;
  for (int k = 0; k < 3; ++k) {
    SyntheticScanOptions o;
    o.rings = 32;
    o.columns = 512;  // 16,384 rays: enough for every thread count to get work
    o.sensor_xy = Eigen::Vector2d(1.5 * k, 0.7 * k);
    o.seed = static_cast<std::uint32_t>(10 + k);
    scans.push_back(make_synthetic_scan(o));
  }
  scans[1].points(5, 0) = std::numeric_limits<double>::quiet_NaN();  // skipped the same way
  std::vector<std::tuple<VoxelKey, double, std::uint32_t>> reference;
  std::vector<VoxelKey> reference_order;
  for (int threads : {1, 2, 3, 8}) {
    ProbabilityUpdater m(0.15);
    m.set_num_threads(threads);
    EXPECT_EQ(m.get_num_threads(), threads);
    for (const auto& s : scans) m.insert_scan(s.origin, s.points, s.intensities, 18.0);
    const auto state = snapshot(m);
    EXPECT_EQ(m.get_num_skipped_points(), 1u);
    EXPECT_EQ(m.get_num_nodes(), state.size());
    std::vector<VoxelKey> order;  // iteration order must not depend on the thread count either
    m.for_each_voxel([&](const VoxelKey& k, const VoxelState&) { order.push_back(k); });
    if (threads == 1) {
      reference_order = order;
      reference = state;
      ASSERT_GT(reference.size(), 100000u);
      continue;
    }
    ASSERT_EQ(state.size(), reference.size()) << threads << " threads";
    EXPECT_TRUE(state == reference) << threads << " threads give a different map";
    EXPECT_TRUE(order == reference_order) << threads << " threads visit the voxels in another order";
  }
}

TEST(ProbabilityUpdaterThreads, ZeroMeansAllHardwareThreadsAndNegativeThrows) {
  ProbabilityUpdater m(0.1);
  EXPECT_EQ(m.get_num_threads(), 1);
  m.set_num_threads(0);
  EXPECT_GE(m.get_num_threads(), 1);
  EXPECT_THROW(m.set_num_threads(-1), std::invalid_argument);
}

TEST(ProbabilityUpdaterThreads, OutOfRangePointThrowsTheFirstErrorAndKeepsTheMap) {
  const SyntheticScan s = make_synthetic_scan();
  // The scan moved next to the end of the int32 key range (60 m from it at 0.1 m), and two points
  // moved past it (within the longest ray).
  const Eigen::RowVector3d shift(2147483647.0 * 0.1 - 60.0, 0.0, 0.0);
  Eigen::MatrixXd pts = s.points.rowwise() + shift;
  pts(100, 0) += 100.0;    // in the first thread's range
  pts(60000, 0) += 100.0;  // in the last thread's range
  ProbabilityUpdater m(0.1);
  m.set_num_threads(4);
  try {
    m.insert_scan(s.origin + shift.transpose(), pts, s.intensities);
    FAIL() << "no exception";
  } catch (const std::out_of_range& e) {
    EXPECT_NE(std::string(e.what()).find("point 100 "), std::string::npos) << e.what();
  }
  EXPECT_EQ(m.get_num_nodes(), 0u);
}

}  // namespace
}  // namespace iwlomap

namespace iwlomap {
namespace {

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
  if (visited != static_cast<std::size_t>(n) || map.get_num_nodes() != static_cast<std::size_t>(n))
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
