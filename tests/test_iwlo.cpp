// SPDX-License-Identifier: BSD-3-Clause
// The IWLO update math against values worked out by hand from the formulas of iwlomap/iwlo.h
// (README, "The IWLO update"). Every expected number below is derived in the comment next to it,
// never by calling the library's own functions.

#include "iwlomap/iwlo.h"
#include "model/probability_above.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <functional>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap {
namespace {

constexpr double kTol = 1e-12;
constexpr double kNaN = std::numeric_limits<double>::quiet_NaN();
constexpr double kInf = std::numeric_limits<double>::infinity();

// ---- intensity weight ------------------------------------------------------------------------

TEST(IwloIntensityWeight, ZeroWhenIntensityAtOrBelowThreshold) {
  const IwloParams p;  // I_th = 35
  EXPECT_EQ(iwlo::intensity_weight(35.0, p), 0.0);
  EXPECT_EQ(iwlo::intensity_weight(34.999, p), 0.0);
  EXPECT_EQ(iwlo::intensity_weight(0.0, p), 0.0);
  EXPECT_EQ(iwlo::intensity_weight(-5.0, p), 0.0);
  // Just above the threshold: u ~ 0, w = 1 / (1 + exp(0.1 * 0.5)) ~ 0.4875 > 0.
  EXPECT_GT(iwlo::intensity_weight(35.001, p), 0.48);
}

TEST(IwloIsOccupiedObservation, FreeWhenIntensityAtOrBelowThresholdOrFlagUnset) {
  const IwloParams p;  // I_th = 35
  EXPECT_FALSE(iwlo::is_occupied_observation(true, 35.0, p));
  EXPECT_FALSE(iwlo::is_occupied_observation(true, 10.0, p));
  EXPECT_FALSE(iwlo::is_occupied_observation(false, 200.0, p));
  EXPECT_TRUE(iwlo::is_occupied_observation(true, 35.5, p));
}

TEST(IwloStep, FreeObservationWhenFlagSetButIntensityAtThreshold) {
  const IwloParams p;
  // L = 0 -> P = 0.5; free branch: P > 1 - P_th = 0.5 is false -> s = 1; n = 1 -> alpha = 1.
  // dL = L_free * alpha * s = -3.0 (the occupied flag is ignored because I = I_th gives w = 0).
  EXPECT_NEAR(iwlo::delta(0.0, 1, 35.0, true, 1.0, p), -3.0, kTol);
  EXPECT_NEAR(iwlo::step(0.0, 1, 35.0, true, 1.0, p), -3.0, kTol);
  EXPECT_NEAR(iwlo::step(0.0, 1, 12.0, true, 1.0, p), -3.0, kTol);
}

TEST(IwloIntensityWeight, FullWeightWhenIntensitySpanBelowGuard) {
  IwloParams p;
  p.sharpness = 2.0;
  p.intensity_threshold = 100.0;
  // u = 1 by the guard: w = 1 / (1 + exp(-2 * (1 - 0.5))) = 1 / (1 + e^-1) = 0.7310585786300049.
  p.intensity_max = 100.0;  // span 0
  EXPECT_NEAR(iwlo::intensity_weight(150.0, p), 0.7310585786300049, kTol);
  p.intensity_max = 100.0 + 1e-10;  // span 1e-10 <= 1e-9
  EXPECT_NEAR(iwlo::intensity_weight(150.0, p), 0.7310585786300049, kTol);
  // Negative span: without the guard u = clamp(50 / -50, 0, 1) = 0 would give
  // 1 / (1 + e^1) = 0.2689; the guard makes it u = 1.
  p.intensity_max = 50.0;
  EXPECT_NEAR(iwlo::intensity_weight(150.0, p), 0.7310585786300049, kTol);
  // The guard never turns an intensity at or below I_th into a positive weight.
  EXPECT_EQ(iwlo::intensity_weight(100.0, p), 0.0);
  EXPECT_EQ(iwlo::intensity_weight(80.0, p), 0.0);
}

TEST(IwloIntensityWeight, ClampedWhenIntensityAboveMax) {
  IwloParams p;  // sharpness 0.1, I_th 35, I_max 255
  // u = clamp((I - 35) / 220, 0, 1) = 1 for I >= 255: w = 1 / (1 + exp(-0.05)) = 0.5124973964842103.
  EXPECT_NEAR(iwlo::intensity_weight(255.0, p), 0.5124973964842103, kTol);
  EXPECT_NEAR(iwlo::intensity_weight(300.0, p), 0.5124973964842103, kTol);
  EXPECT_NEAR(iwlo::intensity_weight(1e6, p), 0.5124973964842103, kTol);
  p.sharpness = 2.0;
  // w = 1 / (1 + exp(-2 * 0.5)) = 0.7310585786300049.
  EXPECT_NEAR(iwlo::intensity_weight(1000.0, p), 0.7310585786300049, kTol);
}

TEST(IwloIntensityWeight, SigmoidOfNormalisedIntensityWhenInRange) {
  IwloParams p;
  // I = 145: u = (145 - 35) / 220 = 0.5 -> w = 1 / (1 + exp(0)) = 0.5 exactly.
  EXPECT_NEAR(iwlo::intensity_weight(145.0, p), 0.5, kTol);
  p.sharpness = 2.0;
  // I = 90: u = 55 / 220 = 0.25 -> w = 1 / (1 + exp(-2 * -0.25)) = 1 / (1 + e^0.5) = 0.3775406687981454.
  EXPECT_NEAR(iwlo::intensity_weight(90.0, p), 0.3775406687981454, kTol);
}

// ---- adaptive scale --------------------------------------------------------------------------

TEST(IwloAdaptiveScale, ReducesOccupiedWhenProbabilityBelowThreshold) {
  IwloParams p;  // P_th 0.5, r_max 0.3
  // s = (0.25 / 0.5) * 0.3 = 0.15.
  EXPECT_NEAR(iwlo::adaptive_scale(0.25, true, p), 0.15, kTol);
  // P = 0.5 is not < P_th -> 1.
  EXPECT_NEAR(iwlo::adaptive_scale(0.5, true, p), 1.0, kTol);
  EXPECT_NEAR(iwlo::adaptive_scale(0.9, true, p), 1.0, kTol);
  // Through delta(): L = -1 -> P = 1 / (1 + e) = 0.2689414213699951,
  // s = 0.2689414213699951 / 0.5 * 0.3 = 0.16136485282199706; I = 145 -> w = 0.5; n = 1 -> alpha = 1.
  // dL = 3.5 * 0.5 * 1 * 0.16136485282199706 = 0.28238849243849484.
  EXPECT_NEAR(iwlo::delta(-1.0, 1, 145.0, true, 1.0, p), 0.28238849243849484, kTol);
  p.adaptive_threshold = 0.2;
  // s = (0.1 / 0.2) * 0.3 = 0.15; P = 0.3 >= 0.2 -> 1.
  EXPECT_NEAR(iwlo::adaptive_scale(0.1, true, p), 0.15, kTol);
  EXPECT_NEAR(iwlo::adaptive_scale(0.3, true, p), 1.0, kTol);
}

TEST(IwloAdaptiveScale, ReducesFreeWhenProbabilityAboveOneMinusThreshold) {
  IwloParams p;  // P_th 0.5, r_max 0.3
  // P = 0.9 > 0.5: f = (0.9 - 0.5) / 0.5 = 0.8, s = 0.3 + 0.7 * (1 - 0.8) = 0.44.
  EXPECT_NEAR(iwlo::adaptive_scale(0.9, false, p), 0.44, kTol);
  // P = 0.5 is not > 0.5 -> 1; P = 0.1 -> 1.
  EXPECT_NEAR(iwlo::adaptive_scale(0.5, false, p), 1.0, kTol);
  EXPECT_NEAR(iwlo::adaptive_scale(0.1, false, p), 1.0, kTol);
  // Through delta(): L = 2 -> P = 1 / (1 + e^-2) = 0.8807970779778823,
  // f = (0.8807970779778823 - 0.5) / 0.5 = 0.7615941559557646,
  // s = 0.3 + 0.7 * 0.2384058440442354 = 0.4668840908309647, dL = -3 * 1 * s = -1.400652272492894.
  EXPECT_NEAR(iwlo::delta(2.0, 1, 0.0, false, 1.0, p), -1.400652272492894, kTol);
  p.adaptive_threshold = 0.2;
  // 1 - P_th = 0.8; P = 0.9: f = 0.1 / 0.2 = 0.5, s = 0.3 + 0.7 * 0.5 = 0.65. P = 0.75 -> 1.
  EXPECT_NEAR(iwlo::adaptive_scale(0.9, false, p), 0.65, kTol);
  EXPECT_NEAR(iwlo::adaptive_scale(0.75, false, p), 1.0, kTol);
}

TEST(IwloAdaptiveScale, OneWhenAdaptiveDisabled) {
  IwloParams p;
  p.adaptive_enabled = false;
  EXPECT_EQ(iwlo::adaptive_scale(0.01, true, p), 1.0);
  EXPECT_EQ(iwlo::adaptive_scale(0.99, false, p), 1.0);
  // Same inputs as the adaptive cases above, now unscaled:
  // L = -1, I = 145 (w = 0.5), occupied: dL = 3.5 * 0.5 * 1 * 1 = 1.75.
  EXPECT_NEAR(iwlo::delta(-1.0, 1, 145.0, true, 1.0, p), 1.75, kTol);
  // L = 2, free: dL = -3 * 1 * 1 = -3.
  EXPECT_NEAR(iwlo::delta(2.0, 1, 0.0, false, 1.0, p), -3.0, kTol);
}

// ---- learning rate ---------------------------------------------------------------------------

TEST(IwloLearningRate, OneWhenFirstObservation) {
  IwloParams p;
  EXPECT_EQ(iwlo::learning_rate(1, p), 1.0);
  p.decay_rate = 5.0;
  EXPECT_EQ(iwlo::learning_rate(1, p), 1.0);
  // n = 2 with decay 5: 1 / (1 + 5) = 0.1667 < min_alpha 0.3 -> 0.3.
  EXPECT_NEAR(iwlo::learning_rate(2, p), 0.3, kTol);
  p.decay_rate = 0.1;
  // n = 2: 1 / (1 + 0.1) = 0.9090909090909091.
  EXPECT_NEAR(iwlo::learning_rate(2, p), 0.9090909090909091, kTol);
}

TEST(IwloLearningRate, FloorWhenDecayedBelowMinAlpha) {
  IwloParams p;  // decay 0.1, min_alpha 0.3
  // n = 24: 1 / (1 + 2.3) = 0.303030303030303 > 0.3 (not yet at the floor).
  EXPECT_NEAR(iwlo::learning_rate(24, p), 0.303030303030303, kTol);
  // n = 25: 1 / (1 + 2.4) = 0.294 < 0.3 -> 0.3.
  EXPECT_NEAR(iwlo::learning_rate(25, p), 0.3, kTol);
  EXPECT_NEAR(iwlo::learning_rate(1000, p), 0.3, kTol);
  // L = 0, free, n = 100: dL = -3 * 0.3 * 1 = -0.9.
  EXPECT_NEAR(iwlo::delta(0.0, 100, 0.0, false, 1.0, p), -0.9, kTol);
  p.min_alpha = 1.0;
  EXPECT_NEAR(iwlo::learning_rate(5, p), 1.0, kTol);
}

// ---- clamps and weights ----------------------------------------------------------------------

TEST(IwloStep, ClampedAtLmaxWhenIncrementOvershoots) {
  IwloParams p;
  // L = 9 -> P > 0.5 -> occupied s = 1; I = 255 -> w = 0.5124973964842103; n = 1 -> alpha = 1.
  // 9 + 3.5 * 0.5124973964842103 = 10.7937... -> clamped to L_max = 10.
  EXPECT_EQ(iwlo::step(9.0, 1, 255.0, true, 1.0, p), 10.0);
  p.L_max = 2.0;
  // 1.5 + 1.79 = 3.29 -> 2.
  EXPECT_EQ(iwlo::step(1.5, 1, 255.0, true, 1.0, p), 2.0);
  // Below the clamp nothing is cut: L = 0 (P = 0.5 -> s = 1), I = 145 (w = 0.5): 0 + 3.5 * 0.5 = 1.75 < 2.
  EXPECT_NEAR(iwlo::step(0.0, 1, 145.0, true, 1.0, p), 1.75, kTol);
}

TEST(IwloStep, ClampedAtLminWhenDecrementOvershoots) {
  IwloParams p;
  // L = -9 -> P = 1.2339e-4, not > 0.5 -> s = 1; free dL = -3 -> -12 -> clamped to L_min = -10.
  EXPECT_EQ(iwlo::step(-9.0, 1, 0.0, false, 1.0, p), -10.0);
  p.L_min = -1.0;
  // 0 - 3 = -3 -> -1.
  EXPECT_EQ(iwlo::step(0.0, 1, 0.0, false, 1.0, p), -1.0);
}

TEST(IwloStep, IncrementScaledWhenPerPointWeightGiven) {
  const IwloParams p;
  // W = 0: no change at all, occupied or free.
  EXPECT_EQ(iwlo::delta(1.25, 1, 200.0, true, 0.0, p), 0.0);
  EXPECT_EQ(iwlo::step(1.25, 1, 200.0, true, 0.0, p), 1.25);
  EXPECT_EQ(iwlo::step(-0.5, 3, 0.0, false, 0.0, p), -0.5);
  // L = 0, free, n = 1: dL = -3 * W.
  EXPECT_NEAR(iwlo::delta(0.0, 1, 0.0, false, 0.5, p), -1.5, kTol);
  EXPECT_NEAR(iwlo::delta(0.0, 1, 0.0, false, 2.0, p), -6.0, kTol);
  // L = 0, occupied, I = 145 (w = 0.5), P = 0.5 not < 0.5 -> s = 1: dL = 3.5 * 0.5 * W.
  EXPECT_NEAR(iwlo::delta(0.0, 1, 145.0, true, 0.5, p), 0.875, kTol);
  EXPECT_NEAR(iwlo::delta(0.0, 1, 145.0, true, 2.0, p), 3.5, kTol);
}

TEST(IwloStep, CombinesAllFactorsWhenOccupiedAfterSeveralObservations) {
  const IwloParams p;
  // L = -1, n = 3, I = 90, W = 0.5:
  //   u = 55 / 220 = 0.25, w = 1 / (1 + exp(-0.1 * -0.25)) = 1 / (1 + e^0.025) = 0.49375032550048964
  //   alpha = max(0.3, 1 / (1 + 0.1 * 2)) = 0.8333333333333334
  //   P = 0.2689414213699951 < 0.5 -> s = 0.16136485282199706
  //   dL = 3.5 * w * alpha * s * 0.5 = 0.1161911750492495 -> L = -0.8838088249507505.
  EXPECT_NEAR(iwlo::delta(-1.0, 3, 90.0, true, 0.5, p), 0.1161911750492495, kTol);
  EXPECT_NEAR(iwlo::step(-1.0, 3, 90.0, true, 0.5, p), -0.8838088249507505, kTol);
}

// ---- stored state ----------------------------------------------------------------------------

TEST(IwloApplyObservation, StoresFixedPointAndCountsWhenObserved) {
  const IwloParams p;
  float L = 0.0f;
  std::uint16_t n = 0;
  iwlo::apply_observation(L, n, 0.0, false, 1.0, p);
  // First free observation: -3, a multiple of the step 2^-19.
  EXPECT_EQ(L, -3.0f);
  EXPECT_EQ(n, 1);
  iwlo::apply_observation(L, n, 0.0, false, 1.0, p);
  // n = 2: alpha = 1 / 1.1; P(-3) = 0.0474 not > 0.5 -> s = 1; -3 - 3 / 1.1 = -5.727272727272727,
  // stored to the nearest 2^-19: -3002740 / 524288 = -5.72727203369140625.
  EXPECT_EQ(L, static_cast<float>(-3002740.0 / 524288.0));
  EXPECT_EQ(n, 2);
  // W = 0 counts the observation but leaves L alone.
  iwlo::apply_observation(L, n, 200.0, true, 0.0, p);
  EXPECT_EQ(L, static_cast<float>(-3002740.0 / 524288.0));
  EXPECT_EQ(n, 3);
}

TEST(IwloApplyObservation, CountSaturatesWhenAtMaxCount) {
  static_assert(iwlo::kMaxCount == 65535u, "the widest count is 16 bits");
  EXPECT_EQ(iwlo::increment_count(0), 1u);
  EXPECT_EQ(iwlo::increment_count(65534), 65535u);
  EXPECT_EQ(iwlo::increment_count(65535), 65535u);
  EXPECT_EQ(iwlo::increment_count(70000), 65535u);

  // The defaults' voxels count to 255 (8 bits: the learning rate is at its floor from n = 25).
  const IwloParams p;
  float L = 0.0f;
  std::uint16_t n = 254;
  iwlo::apply_observation(L, n, 0.0, false, 1.0, p);
  EXPECT_EQ(n, 255);
  // alpha at n = 255 is the floor 0.3; P = 0.5 -> s = 1: L = -3 * 0.3 = -0.9 (to the nearest 2^-19).
  EXPECT_EQ(L, iwlo::voxel_format(p).quantize(-0.9));
  iwlo::apply_observation(L, n, 0.0, false, 1.0, p);
  EXPECT_EQ(n, 255);  // never wraps to 0
  // Still updated: P(-0.9) = 0.289, s = 1: -0.9 - 0.9 = -1.8.
  EXPECT_NEAR(L, -1.8, 1e-6);

  // A learning rate that decays for longer keeps a wider count: decay 1e-5 reaches the floor
  // after 233,334 observations, beyond any count, so 16 bits.
  IwloParams slow;
  slow.decay_rate = 1e-5;
  ASSERT_EQ(iwlo::voxel_format(slow).max_count(), 65535u);
  n = 65534;
  L = 0.0f;
  iwlo::apply_observation(L, n, 0.0, false, 1.0, slow);
  EXPECT_EQ(n, 65535);
  iwlo::apply_observation(L, n, 0.0, false, 1.0, slow);
  EXPECT_EQ(n, 65535);
}

// ---- the 4-byte voxel format ----------------------------------------------------------------

TEST(VoxelFormat, DefaultsStore24BitLogOddsAnd8BitCounts) {
  const iwlo::VoxelFormat f = iwlo::voxel_format(IwloParams{});
  EXPECT_EQ(f, iwlo::VoxelFormat{});
  EXPECT_EQ(f.count_bits(), 8);
  EXPECT_EQ(f.max_count(), 255u);
  EXPECT_EQ(f.fraction_bits(), 19);  // 2^23 - 1 steps of 2^-19 reach 15.99999, past +-15
  EXPECT_EQ(f.step(), 0x1p-19);
  EXPECT_EQ(f.q_min(), -10 * 524288);  // L_min and L_max are whole steps
  EXPECT_EQ(f.q_max(), 10 * 524288);
  EXPECT_EQ(f.q_limit(), (1 << 23) - 1);
}

TEST(VoxelFormat, WidensTheCountWhenTheLearningRateDecaysLonger) {
  const auto bits = [](double decay_rate, double min_alpha) {
    IwloParams p;
    p.decay_rate = decay_rate;
    p.min_alpha = min_alpha;
    return iwlo::voxel_format(p).count_bits();
  };
  // The floor is reached at the first n >= 1 + (1/min_alpha - 1)/decay_rate.
  EXPECT_EQ(bits(0.1, 0.3), 8);     // n = 25
  EXPECT_EQ(bits(0.0092, 0.3), 8);  // n = 255: a count saturated at 255 has the floor's rate
  EXPECT_EQ(bits(0.0091, 0.3), 9);  // n = 258
  EXPECT_EQ(bits(0.005, 0.3), 9);   // n = 468
  EXPECT_EQ(bits(0.001, 0.3), 12);  // n = 2,335
  EXPECT_EQ(bits(1e-5, 0.3), 16);   // n = 233,335: beyond any count, 16 bits saturate
  EXPECT_EQ(bits(0.0, 0.3), 8);     // the rate never decays: the count does not matter
  EXPECT_EQ(bits(0.001, 1.0), 8);
  // The log-odds keep the other bits: 12 count bits leave 20, steps of 2^-15 over +-16.
  IwloParams p;
  p.decay_rate = 0.001;
  EXPECT_EQ(iwlo::voxel_format(p).fraction_bits(), 15);
  // A clamp beyond +-15 takes coarser steps; one within it keeps the defaults' layout.
  p = IwloParams{};
  p.L_max = 100.0;
  EXPECT_EQ(iwlo::voxel_format(p).fraction_bits(), 16);  // +-128
  p = IwloParams{};
  p.L_min = -2.0;
  p.L_max = 3.5;
  EXPECT_TRUE(iwlo::voxel_format(p).same_layout(iwlo::VoxelFormat{}));
  EXPECT_EQ(iwlo::voxel_format(p).q_max(), 7 * 262144);
}

TEST(VoxelFormat, RoundsToTheNearestStepWithinTheClampRange) {
  const iwlo::VoxelFormat f;
  const double step = f.step();
  std::mt19937 rng(3u);
  std::uniform_real_distribution<double> any(-10.0, 10.0);
  for (int i = 0; i < 100000; ++i) {
    const double L = any(rng);
    const std::uint32_t n = 1 + static_cast<std::uint32_t>(rng() % 255);
    const std::uint32_t w = f.encode(L, n);
    ASSERT_NE(w, 0u);  // a known voxel's word is never "unknown"
    EXPECT_EQ(f.count(w), n);
    EXPECT_LE(std::abs(static_cast<double>(f.log_odds(w)) - L), step / 2);
    EXPECT_EQ(static_cast<double>(f.log_odds(w)), f.log_odds_exact(w));  // every stored value is a float
    EXPECT_EQ(f.encode(f.log_odds(w), n), w);                           // and stores as itself
  }
  EXPECT_EQ(f.log_odds(f.encode(0.0, 1)), 0.0f);
  EXPECT_EQ(f.log_odds(f.encode(1.5 * step, 1)), static_cast<float>(2 * step));  // ties to the even step
  EXPECT_EQ(f.log_odds(f.encode(2.5 * step, 1)), static_cast<float>(2 * step));
  EXPECT_EQ(f.log_odds(f.encode(-2.5 * step, 1)), static_cast<float>(-2 * step));
  EXPECT_EQ(f.log_odds(f.encode(1e9, 1)), 10.0f);  // bounded to [L_min, L_max]
  EXPECT_EQ(f.log_odds(f.encode(-1e9, 1)), -10.0f);
  EXPECT_EQ(f.log_odds(f.encode(std::numeric_limits<double>::quiet_NaN(), 1)), -10.0f);
  // A clamp that is not a whole step is rounded inwards.
  IwloParams p;
  p.L_max = 3.0 + 0.3 * step;
  const iwlo::VoxelFormat g = iwlo::voxel_format(p);
  EXPECT_EQ(g.log_odds(g.encode(p.L_max, 1)), 3.0f);
  // Kept values (a conversion) are bounded only by the bits: +-(2^23 - 1) steps.
  EXPECT_EQ(f.log_odds(f.encode_kept(12.0, 1)), 12.0f);
  EXPECT_EQ(f.log_odds(f.encode_kept(40.0, 1)), static_cast<float>(f.q_limit() * step));
  EXPECT_EQ(f.count(f.encode_kept(-1.0, 1000)), 255u);
}

// The stored chain (fixed point after each observation) follows the double chain: 500 random
// sequences of 1,000 observations each (own mix of hits and misses, hit intensities 36..255, miss
// intensities 0..255), the defaults. Measured on this set: worst 7.8e-6 (float storage: 2.1e-6).
TEST(VoxelFormat, StoredChainStaysWithin1e4OfTheDoubleChain) {
  const IwloParams p;
  std::mt19937 rng(7u);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  double worst = 0.0;
  for (int s = 0; s < 500; ++s) {
    const double hit_share = u(rng);
    double exact = 0.0;
    float stored = 0.0f;
    std::uint16_t n = 0;
    for (std::uint32_t i = 1; i <= 1000; ++i) {
      const bool hit = u(rng) < hit_share;
      const double I = hit ? 36.0 + std::floor(u(rng) * 220.0) : std::floor(u(rng) * 256.0);
      exact = iwlo::step(exact, i, I, hit, 1.0, p);
      iwlo::apply_observation(stored, n, I, hit, 1.0, p);
      worst = std::max(worst, std::abs(iwlo::probability(stored) - iwlo::probability(exact)));
    }
  }
  EXPECT_LT(worst, 1e-4);
  EXPECT_GT(worst, 0.0);  // the chains do part: the comparison is not vacuous
}

TEST(IwloProbability, LogOddsRoundTripWhenKnownValues) {
  EXPECT_EQ(iwlo::probability(0.0), 0.5);
  // 1 / (1 + exp(-ln 3)) = 1 / (1 + 1/3) = 0.75.
  EXPECT_NEAR(iwlo::probability(1.0986122886681098), 0.75, kTol);
  EXPECT_NEAR(iwlo::log_odds(0.75), 1.0986122886681098, kTol);
  // ln(0.7 / 0.3) = ln(7/3) = 0.8472978603872037.
  EXPECT_NEAR(iwlo::log_odds(0.7), 0.8472978603872037, kTol);
  EXPECT_NEAR(iwlo::log_odds(0.5), 0.0, kTol);
}

// ---- parameters ------------------------------------------------------------------------------

TEST(IwloParams, DefaultsMatchTheDocumentedValues) {
  const IwloParams p;
  EXPECT_EQ(p.sharpness, 0.1);
  EXPECT_EQ(p.decay_rate, 0.1);
  EXPECT_EQ(p.min_alpha, 0.3);
  EXPECT_EQ(p.L_min, -10.0);
  EXPECT_EQ(p.L_max, 10.0);
  EXPECT_EQ(p.log_odds_occupied, 3.5);
  EXPECT_EQ(p.log_odds_free, -3.0);
  EXPECT_EQ(p.intensity_threshold, 35.0);
  EXPECT_EQ(p.intensity_max, 255.0);
  EXPECT_TRUE(p.adaptive_enabled);
  EXPECT_EQ(p.adaptive_threshold, 0.5);
  EXPECT_EQ(p.adaptive_max_ratio, 0.3);
  EXPECT_EQ(p.occupied_threshold, 0.7);
  EXPECT_NO_THROW(p.validate());
}

struct InvalidCase {
  const char* label;
  std::function<void(IwloParams&)> mutate;
  std::string expected;  // "name = value" as it must appear in the message
};

TEST(IwloParams, ValidateThrowsNamingParameterAndValueWhenInvalid) {
  const std::vector<InvalidCase> cases = {
      {"sharpness NaN", [](IwloParams& p) { p.sharpness = kNaN; }, "sharpness = nan"},
      {"sharpness inf", [](IwloParams& p) { p.sharpness = kInf; }, "sharpness = inf"},
      {"decay_rate negative", [](IwloParams& p) { p.decay_rate = -0.5; }, "decay_rate = -0.5"},
      {"decay_rate inf", [](IwloParams& p) { p.decay_rate = kInf; }, "decay_rate = inf"},
      {"min_alpha zero", [](IwloParams& p) { p.min_alpha = 0.0; }, "min_alpha = 0"},
      {"min_alpha negative", [](IwloParams& p) { p.min_alpha = -0.25; }, "min_alpha = -0.25"},
      {"min_alpha above one", [](IwloParams& p) { p.min_alpha = 1.5; }, "min_alpha = 1.5"},
      {"min_alpha NaN", [](IwloParams& p) { p.min_alpha = kNaN; }, "min_alpha = nan"},
      {"L_min equal L_max", [](IwloParams& p) { p.L_min = 5.0; p.L_max = 5.0; }, "L_min = 5"},
      {"L_min above L_max", [](IwloParams& p) { p.L_min = 3.0; p.L_max = -2.0; }, "L_min = 3"},
      {"L_min NaN", [](IwloParams& p) { p.L_min = kNaN; }, "L_min = nan"},
      {"L_max inf", [](IwloParams& p) { p.L_max = kInf; }, "L_max = inf"},
      {"log_odds_occupied NaN", [](IwloParams& p) { p.log_odds_occupied = kNaN; }, "log_odds_occupied = nan"},
      {"log_odds_free -inf", [](IwloParams& p) { p.log_odds_free = -kInf; }, "log_odds_free = -inf"},
      {"intensity_threshold NaN", [](IwloParams& p) { p.intensity_threshold = kNaN; }, "intensity_threshold = nan"},
      {"intensity_max inf", [](IwloParams& p) { p.intensity_max = kInf; }, "intensity_max = inf"},
      {"adaptive_threshold zero", [](IwloParams& p) { p.adaptive_threshold = 0.0; }, "adaptive_threshold = 0"},
      {"adaptive_threshold one", [](IwloParams& p) { p.adaptive_threshold = 1.0; }, "adaptive_threshold = 1"},
      {"adaptive_threshold NaN", [](IwloParams& p) { p.adaptive_threshold = kNaN; }, "adaptive_threshold = nan"},
      {"adaptive_max_ratio negative", [](IwloParams& p) { p.adaptive_max_ratio = -0.5; }, "adaptive_max_ratio = -0.5"},
      {"adaptive_max_ratio above one", [](IwloParams& p) { p.adaptive_max_ratio = 1.25; }, "adaptive_max_ratio = 1.25"},
      {"occupied_threshold zero", [](IwloParams& p) { p.occupied_threshold = 0.0; }, "occupied_threshold = 0"},
      {"occupied_threshold one", [](IwloParams& p) { p.occupied_threshold = 1.0; }, "occupied_threshold = 1"},
      {"occupied_threshold NaN", [](IwloParams& p) { p.occupied_threshold = kNaN; }, "occupied_threshold = nan"},
  };
  for (const InvalidCase& c : cases) {
    SCOPED_TRACE(c.label);
    IwloParams p;
    c.mutate(p);
    try {
      p.validate();
      ADD_FAILURE() << "validate() accepted " << c.label;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(c.expected), std::string::npos)
          << "message '" << e.what() << "' does not contain '" << c.expected << "'";
    } catch (...) {
      ADD_FAILURE() << "validate() threw something other than std::invalid_argument for " << c.label;
    }
  }
}

TEST(IwloParams, ValidateAcceptsWhenValuesOnInclusiveBoundaries) {
  IwloParams p;
  p.min_alpha = 1.0;          // (0, 1] includes 1
  p.adaptive_max_ratio = 0.0;  // [0, 1]
  p.decay_rate = 0.0;
  EXPECT_NO_THROW(p.validate());
  p.adaptive_max_ratio = 1.0;
  EXPECT_NO_THROW(p.validate());
  // I_max <= I_th is allowed (the weight guard handles it).
  p.intensity_threshold = 100.0;
  p.intensity_max = 100.0;
  EXPECT_NO_THROW(p.validate());
  p.intensity_max = 10.0;
  EXPECT_NO_THROW(p.validate());
  p.intensity_threshold = 0.0;  // every positive return a hit
  p.intensity_max = 255.0;
  EXPECT_NO_THROW(p.validate());
}

// ProbabilityAbove decides probability(l) > t mostly from l alone; it must agree with the
// probability itself for every l, including the floats next to the boundary and thresholds so
// close to 0 or 1 that many log-odds round to the same probability.
TEST(IwloProbabilityAbove, AgreesWithTheProbabilityAtAndAroundEveryThreshold) {
  std::mt19937 rng(5);
  std::size_t above = 0, checked = 0;
  for (const double t : {0.5, 0.7, 0.12, 0.97, 1e-12, 1.0 - 1e-12, 1e-300, 0.999999999999999, 1.0, 0.0}) {
    const detail::ProbabilityAbove test(t);
    const double b = (t > 0.0 && t < 1.0) ? iwlo::log_odds(t) : 0.0;
    std::vector<float> ls;
    float f = static_cast<float>(b);
    float g = f;
    for (int i = 0; i < 2000; ++i) {  // the floats on both sides of the boundary
      ls.push_back(f);
      ls.push_back(g);
      f = std::nextafter(f, -std::numeric_limits<float>::infinity());
      g = std::nextafter(g, std::numeric_limits<float>::infinity());
    }
    std::uniform_real_distribution<double> spread(-40.0, 40.0);
    for (int i = 0; i < 20000; ++i) ls.push_back(static_cast<float>(b + spread(rng)));
    for (const float l : ls) {
      const bool expected = iwlo::probability(l) > t;
      ASSERT_EQ(test(l), expected) << "threshold " << t << ", log-odds " << l;
      above += expected ? 1 : 0;
      ++checked;
    }
  }
  EXPECT_GT(above, checked / 4);  // both answers occur
  EXPECT_LT(above, 3 * checked / 4);
}

}  // namespace
}  // namespace iwlomap
