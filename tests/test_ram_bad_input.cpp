// SPDX-License-Identifier: BSD-3-Clause
// The RAM backend's error contract of IMapperBackend: bad batches, scans, thresholds, parameters
// and resolutions throw and leave the map and its parameters as they were; valid rows that only
// the detailed check can vouch for are applied.

#include "iwlomap/probability_updater.h"
#include "iwlomap/voxel_key.h"

#include "ram_test_support.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <map>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap {
namespace {

using ram_test::kInf;
using ram_test::kNaN;
using ram_test::rows;
using ram_test::Snapshot;
using ram_test::snapshot;
using ram_test::values;

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
    EXPECT_EQ(map_.get_num_known_voxels(), 2u);
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
  EXPECT_EQ(map.get_num_known_voxels(), 2u);
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

}  // namespace
}  // namespace iwlomap
