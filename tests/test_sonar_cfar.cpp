// SPDX-License-Identifier: BSD-3-Clause
// CFAR detection (sonar_cfar.h): the false-alarm rate on Rayleigh noise within binomial bounds for
// both variants, at several noise levels and across a step in the noise floor; detection of
// targets; the factors by hand; the projector's first return with a CFAR detector under a noise
// floor that a fixed threshold cannot handle; bad parameters.

#include "iwlomap/sonar_cfar.h"
#include "iwlomap/sonar_image_projector.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <random>
#include <stdexcept>
#include <string>

namespace iwlomap {
namespace {

// Rayleigh amplitude of scale sigma: its power is exponential with mean 2 sigma^2.
double rayleigh(std::mt19937& rng, double sigma) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  return sigma * std::sqrt(-2.0 * std::log(1.0 - u(rng)));
}

struct Counts {
  std::size_t cells = 0, detections = 0;
};

// Noise-only beams; the noise scale jumps from sigma to 10 sigma at bin step (a gain change), and
// the cells whose window straddles the step are left out of the count.
Counts false_alarms(SonarDetector detector, SonarCfarWindow window, double pfa, double sigma, std::uint32_t seed,
                    int step = -1) {
  SonarCfarParams p;
  p.window = window;
  p.false_alarm_rate = pfa;
  p.min_noise_intensity = 0.0;  // continuous noise here
  const SonarCfar cfar(detector, p);
  std::mt19937 rng(seed);
  Counts c;
  const int bins = 400;
  for (int beam = 0; beam < 250; ++beam) {
    Eigen::VectorXd v(bins);
    for (int i = 0; i < bins; ++i) v[i] = rayleigh(rng, step >= 0 && i >= step ? 10.0 * sigma : sigma);
    const std::vector<bool> d = cfar.detect(v);
    for (int i = 0; i < bins; ++i) {
      if (step >= 0 && std::abs(i - step) <= p.training_cells) continue;
      ++c.cells;
      c.detections += d[static_cast<std::size_t>(i)] ? 1 : 0;
    }
  }
  return c;
}

// Detections within 5 standard deviations of the binomial expectation.
void expect_rate(const Counts& c, double pfa, const std::string& what) {
  const double expected = pfa * static_cast<double>(c.cells);
  const double sd = std::sqrt(expected * (1.0 - pfa));
  EXPECT_NEAR(static_cast<double>(c.detections), expected, 5.0 * sd)
      << what << ": " << c.detections << " false alarms in " << c.cells << " cells";
}

TEST(SonarCfar, FalseAlarmRateHoldsAtAnyNoiseLevel) {
  for (const SonarDetector d : {SonarDetector::kCellAveragingCfar, SonarDetector::kOrderedStatisticCfar})
    for (const SonarCfarWindow w : {SonarCfarWindow::kNearSide, SonarCfarWindow::kBothSides})
      for (const double pfa : {1e-2, 1e-3})
        for (std::uint32_t seed = 1; seed <= 5; ++seed) {
          const double sigma = seed * 7.0;  // the rate must not depend on the level
          expect_rate(false_alarms(d, w, pfa, sigma, seed), pfa,
                      "detector " + std::to_string(static_cast<int>(d)) + ", window " +
                          std::to_string(static_cast<int>(w)) + ", pfa " + std::to_string(pfa) + ", seed " +
                          std::to_string(seed));
        }
}

TEST(SonarCfar, FalseAlarmRateHoldsOnBothSidesOfAGainStep) {
  for (const SonarDetector d : {SonarDetector::kCellAveragingCfar, SonarDetector::kOrderedStatisticCfar})
    for (const SonarCfarWindow w : {SonarCfarWindow::kNearSide, SonarCfarWindow::kBothSides})
      expect_rate(false_alarms(d, w, 1e-2, 5.0, 11, 200), 1e-2,
                  "gain step, detector " + std::to_string(static_cast<int>(d)));
  // A fixed threshold set for the quiet half (its 1e-2 point) fires on nearly every loud bin.
  std::mt19937 rng(11);
  const double threshold = 5.0 * std::sqrt(-2.0 * std::log(1e-2));
  std::size_t loud = 0;
  for (int i = 0; i < 10000; ++i) loud += rayleigh(rng, 50.0) > threshold ? 1 : 0;
  EXPECT_GT(loud, 9000u);
}

TEST(SonarCfar, DetectsTargetsTwentyDecibelsAboveTheFloor) {
  for (const SonarDetector d : {SonarDetector::kCellAveragingCfar, SonarDetector::kOrderedStatisticCfar}) {
    SonarCfarParams p;
    p.window = SonarCfarWindow::kBothSides;
    p.min_noise_intensity = 0.0;
    const SonarCfar cfar(d, p);
    std::mt19937 rng(21);
    std::size_t targets = 0, found = 0;
    for (int beam = 0; beam < 300; ++beam) {
      Eigen::VectorXd v(300);
      for (int i = 0; i < v.size(); ++i) v[i] = rayleigh(rng, 4.0);
      // Two targets 40 bins apart, amplitude 10x the noise's RMS (20 dB in power).
      for (const int t : {100, 140}) v[t] += 10.0 * 4.0 * std::sqrt(2.0);
      const std::vector<bool> det = cfar.detect(v);
      for (const int t : {100, 140}) {
        ++targets;
        found += det[static_cast<std::size_t>(t)] ? 1 : 0;
      }
    }
    EXPECT_GE(static_cast<double>(found), 0.97 * targets) << "detector " << static_cast<int>(d);
  }
}

TEST(SonarCfar, FactorsByHand) {
  SonarCfarParams p;
  p.guard_cells = 1;
  p.training_cells = 3;  // 2 training cells per side, 4 in all
  p.window = SonarCfarWindow::kBothSides;
  p.false_alarm_rate = 0.01;
  const SonarCfar ca(SonarDetector::kCellAveragingCfar, p);
  EXPECT_NEAR(ca.factor(4), 4.0 * (std::pow(0.01, -0.25) - 1.0), 1e-12);  // 8.649
  EXPECT_NEAR(ca.factor(1), 99.0, 1e-9);
  // OS, rank 0.75 of 4 cells: k = 3, P = 4 * 3 * 2 / ((4 + a)(3 + a)(2 + a)).
  const SonarCfar os(SonarDetector::kOrderedStatisticCfar, p);
  const double a = os.factor(4);
  EXPECT_NEAR(24.0 / ((4 + a) * (3 + a) * (2 + a)), 0.01, 1e-9);
  // A beam of ones with a 10 at bin 5: CA threshold there = 8.649 * mean(1, 1, 1, 1) in power,
  // so 100 > 8.649 detects; bin 3 sees the 10 among its training cells: mean power 25.75.
  Eigen::VectorXd v = Eigen::VectorXd::Ones(11);
  v[5] = 10.0;
  const std::vector<bool> d = ca.detect(v);
  for (int i = 0; i < 11; ++i) EXPECT_EQ(d[static_cast<std::size_t>(i)], i == 5) << i;
  std::vector<double> power(11, 1.0), scratch;
  power[5] = 100.0;
  EXPECT_NEAR(ca.threshold(power, 3, scratch), ca.factor(4) * (1.0 + 1.0 + 1.0 + 100.0) / 4.0, 1e-9);
  EXPECT_NEAR(ca.threshold(power, 0, scratch), ca.factor(2) * 1.0, 1e-12);  // one side only
}

// An extended echo (a seabed that keeps echoing beyond its leading edge): with the near-side
// window the first detection is the edge; a window on both sides counts the echo beyond the edge
// as noise and finds the edge far less often.
TEST(SonarCfar, NearSideWindowFindsTheLeadingEdgeOfAnExtendedEcho) {
  std::mt19937 rng(8);
  int near_found = 0, both_found = 0;
  SonarCfarParams p;
  p.false_alarm_rate = 1e-3;
  const SonarCfar near(SonarDetector::kOrderedStatisticCfar, p);
  p.window = SonarCfarWindow::kBothSides;
  const SonarCfar both(SonarDetector::kOrderedStatisticCfar, p);
  for (int beam = 0; beam < 200; ++beam) {
    Eigen::VectorXd v(300);
    for (int i = 0; i < v.size(); ++i) v[i] = rayleigh(rng, 6.0) + (i >= 150 ? 60.0 * rayleigh(rng, 1.0) : 0.0);
    const auto first = [&](const SonarCfar& c) { return c.first_detection(300, 0, 299, [&](int i) { return v[i]; }); };
    near_found += std::abs(first(near) - 150) <= 2 ? 1 : 0;
    both_found += std::abs(first(both) - 150) <= 2 ? 1 : 0;
  }
  std::printf("leading edge within 2 bins: near side %d, both sides %d of 200\n", near_found, both_found);
  EXPECT_GE(near_found, 160);
  EXPECT_LT(both_found, near_found);
}

// A noise floor far above the fixed threshold (Rayleigh scale 40 against 35) and a wall at bin 300:
// the fixed threshold takes noise near the sonar as every beam's return, CFAR finds the wall.
TEST(SonarCfar, ProjectorFindsTheWallUnderAHighNoiseFloor) {
  const int bins = 400, beams = 32;
  std::mt19937 rng(5);
  SonarImageF image(bins, beams);
  for (int b = 0; b < beams; ++b)
    for (int r = 0; r < bins; ++r) image(r, b) = static_cast<float>(rayleigh(rng, 40.0) + (r == 300 ? 900.0 : 0.0));
  SonarGeometry g;
  for (int b = 0; b < beams; ++b) g.bearings.push_back(-0.3 + 0.6 * b / (beams - 1));
  g.range_resolution = 0.02;
  g.max_range = bins * 0.02;
  const auto returns = [&](SonarDetector d) {
    SonarProjectorParams p;
    p.detector = d;
    p.cfar.false_alarm_rate = 1e-4;
    p.occupied_band = 0.0;
    const SonarObservations obs = SonarImageProjector(0.1, p).project(make_sonar_image_view(image), g,
                                                                       Eigen::Isometry3d::Identity());
    // Occupied observations lie at the echo's range: count those near the wall (6 m).
    std::size_t at_wall = 0, occupied = 0;
    for (std::size_t i = 0; i < obs.size(); ++i)
      if (obs.is_occupied[i]) {
        ++occupied;
        at_wall += std::abs(obs.points.row(static_cast<Eigen::Index>(i)).norm() - 6.01) < 0.15 ? 1 : 0;
      }
    return std::make_pair(at_wall, occupied);
  };
  const auto fixed = returns(SonarDetector::kThreshold);
  EXPECT_GT(fixed.second, 0u);
  EXPECT_EQ(fixed.first, 0u);  // every beam's fixed-threshold return is noise near the sonar
  for (const SonarDetector d : {SonarDetector::kCellAveragingCfar, SonarDetector::kOrderedStatisticCfar}) {
    const auto c = returns(d);
    EXPECT_GT(c.second, 0u);
    EXPECT_GE(c.first, c.second * 8 / 10) << "detector " << static_cast<int>(d);
  }
}

TEST(SonarCfar, BadParametersAreRejectedWithTheirValue) {
  const auto rejects = [](SonarCfarParams p, const std::string& text) {
    try {
      const SonarCfar c(SonarDetector::kCellAveragingCfar, p);
      ADD_FAILURE() << "accepted; expected an error naming " << text;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    }
  };
  SonarCfarParams p;
  p.guard_cells = 4;
  p.training_cells = 4;
  rejects(p, "training_cells = 4");
  p = SonarCfarParams{};
  p.guard_cells = -1;
  rejects(p, "guard_cells = -1");
  for (const double bad : {0.0, 1.0, -0.5, std::numeric_limits<double>::quiet_NaN()}) {
    p = SonarCfarParams{};
    p.false_alarm_rate = bad;
    rejects(p, "false_alarm_rate");
  }
  p = SonarCfarParams{};
  p.false_alarm_rate = 1.5;
  rejects(p, "false_alarm_rate = 1.5");
  p = SonarCfarParams{};
  p.os_rank = 0.0;
  rejects(p, "os_rank = 0");
  EXPECT_THROW(SonarCfar(SonarDetector::kThreshold, SonarCfarParams{}), std::invalid_argument);
  SonarProjectorParams pp;
  pp.detector = SonarDetector::kOrderedStatisticCfar;
  pp.cfar.training_cells = 1;
  EXPECT_THROW(SonarImageProjector(0.1, pp), std::invalid_argument);
  pp.detector = SonarDetector::kThreshold;  // the CFAR settings are not used, nor checked
  EXPECT_NO_THROW(SonarImageProjector(0.1, pp));
  const SonarCfar ok(SonarDetector::kCellAveragingCfar, SonarCfarParams{});
  Eigen::VectorXd bad(3);
  bad << 1.0, std::numeric_limits<double>::quiet_NaN(), 2.0;
  EXPECT_THROW(static_cast<void>(ok.detect(bad)), std::invalid_argument);
}

}  // namespace
}  // namespace iwlomap
