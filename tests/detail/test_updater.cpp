// SPDX-License-Identifier: BSD-3-Clause
// The backends' precomputed IWLO step (integrate/updater.h) against hand values and against the
// reference iwlo::step() of the public header, bit for bit.

#include "integrate/updater.h"
#include "integrate/voxel_update.h"
#include "iwlomap/iwlo.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdint>
#include <stdexcept>
#include <vector>

namespace iwlomap {
namespace {

constexpr double kTol = 1e-12;

TEST(Updater, MatchesHandValuesWhenDefaultParams) {
  const detail::Updater u;
  // Same as the adaptive occupied case above: -1 + 0.28238849243849484 = -0.7176115075615052.
  EXPECT_NEAR(u.step(-1.0, 1, 145.0, true, 1.0), -0.7176115075615052, kTol);
  // First free observation from 0: -3; clamped at L_min from -9.
  EXPECT_NEAR(u.step(0.0, 1, 0.0, false, 1.0), -3.0, kTol);
  EXPECT_EQ(u.step(-9.0, 1, 0.0, false, 1.0), -10.0);
  // Alpha floor at n = 100: -3 * 0.3 = -0.9.
  EXPECT_NEAR(u.step(0.0, 100, 0.0, false, 1.0), -0.9, kTol);
  // Non-integer intensity 90.5 (not in the integer table): u = 55.5 / 220 = 0.2522727272727273,
  // u - 0.5 = -0.24772727272727274, w = 1 / (1 + exp(0.024772727272727274));
  // L = 0 (P = 0.5, s = 1): 3.5 * w = 1.7283249721004328.
  EXPECT_NEAR(u.step(0.0, 1, 90.5, true, 1.0), 1.7283249721004328, kTol);
}

TEST(Updater, ThrowsWhenParamsInvalid) {
  IwloParams p;
  p.min_alpha = 0.0;
  EXPECT_THROW(detail::Updater{p}, std::invalid_argument);
}

// The Updater promises bit-identical results to step(); sweep the inputs where its shortcuts
// (tables, skipped probability near the adaptive thresholds) could diverge.
TEST(Updater, BitIdenticalToStepWhenSweepingInputs) {
  std::vector<IwloParams> param_sets(8);
  param_sets[1].adaptive_enabled = false;
  param_sets[2].adaptive_threshold = 0.2;
  param_sets[2].adaptive_max_ratio = 0.6;
  param_sets[3].adaptive_threshold = 0.8;
  param_sets[3].adaptive_max_ratio = 0.0;
  param_sets[4].decay_rate = 1e-4;  // floor reached only after ~23,000 observations
  param_sets[5].decay_rate = 0.0;
  param_sets[5].min_alpha = 0.5;
  param_sets[6].intensity_threshold = 100.0;  // I_max < I_th: the guard
  param_sets[6].intensity_max = 50.0;
  param_sets[6].sharpness = 2.0;
  param_sets[7].intensity_threshold = 0.0;  // every positive return a hit
  param_sets[7].min_alpha = 1.0;
  const double counts[] = {1, 2, 3, 24, 25, 100, 4095, 4096, 4097, 5000, 30000, 65535};
  const double intensities[] = {-1.0, 0.0, 1.0, 34.0, 35.0, 35.5, 36.0, 90.5, 100.0, 145.25, 200.0, 254.9999,
                                255.0, 256.0, 300.0};
  const double weights[] = {0.0, 0.5, 1.0, 2.0};
  std::size_t compared = 0;
  std::size_t mismatches = 0;
  for (const IwloParams& p : param_sets) {
    const detail::Updater u(p);
    std::vector<double> log_odds = {-10.0, -3.0, -1e-7, 0.0, 1e-7, 0.3, 2.0, 9.99};
    for (double th : {p.adaptive_threshold, 1.0 - p.adaptive_threshold}) {
      const double l = std::log(th / (1.0 - th));
      for (double eps : {0.0, 1e-12, 1e-9, 1e-6, 2e-6, 1e-3}) {
        log_odds.push_back(l + eps);
        log_odds.push_back(l - eps);
      }
    }
    for (double L : log_odds)
      for (double n : counts)
        for (double I : intensities)
          for (bool flag : {false, true})
            for (double W : weights) {
              const auto c = static_cast<std::uint32_t>(n);
              const double want = iwlo::step(L, c, I, flag, W, p);
              const double got = u.step(L, c, I, flag, W);
              ++compared;
              if (want != got && ++mismatches <= 10)
                ADD_FAILURE() << "L = " << L << " n = " << c << " I = " << I << " flag = " << flag << " W = " << W
                              << ": step() " << want << ", Updater " << got;
            }
  }
  EXPECT_EQ(mismatches, 0u) << "of " << compared;
  EXPECT_GT(compared, 100000u);
}

TEST(UpdateVoxelState, SameStoredStateAsApplyObservation) {
  const IwloParams p;
  const detail::Updater u(p);
  float La = 0.0f;
  std::uint16_t na = 0;
  std::uint32_t word = 0;
  const double seq[][3] = {{200, 1, 1}, {20, 1, 1}, {0, 0, 0.5}, {255, 1, 2}, {145.5, 1, 1}, {35, 1, 1}};
  for (const auto& o : seq) {
    iwlo::apply_observation(La, na, o[0], o[1] != 0.0, o[2], p);
    detail::update_voxel_state(word, o[0], o[1] != 0.0, o[2], u);
    EXPECT_EQ(La, u.format().log_odds(word));
    EXPECT_EQ(na, u.format().count(word));
  }
  EXPECT_EQ(na, 6);
}

}  // namespace
}  // namespace iwlomap
