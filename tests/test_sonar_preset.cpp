// SPDX-License-Identifier: BSD-3-Clause
// The SNR weight of sonar echoes (SonarSnrWeight) by hand, in the projector's weights, and the
// sonar preset (sonar_preset.h): its settings are valid, a weak echo alone does not make a voxel
// occupied while the same surface seen from a second pose does, bad values are rejected.

#include "iwlomap/probability_updater.h"
#include "iwlomap/sonar_cfar.h"
#include "iwlomap/sonar_image_projector.h"
#include "iwlomap/sonar_preset.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap {
namespace {

TEST(SonarSnrWeight, ByHand) {
  const SonarSnrWeight w;  // centre 0 dB, width 5.570 dB
  EXPECT_DOUBLE_EQ(sonar_snr_weight(0.0, w), 0.5);
  EXPECT_NEAR(sonar_snr_weight(kRayleighPowerSpreadDb, w), 1.0 / (1.0 + std::exp(-1.0)), 1e-12);  // 0.731
  EXPECT_NEAR(sonar_snr_weight(2.0 * kRayleighPowerSpreadDb, w), 0.880797, 1e-6);
  EXPECT_NEAR(sonar_snr_weight(-kRayleighPowerSpreadDb, w), 0.268941, 1e-6);
  SonarSnrWeight shifted;
  shifted.centre_db = 6.0;
  shifted.width_db = 3.0;
  EXPECT_DOUBLE_EQ(sonar_snr_weight(6.0, shifted), 0.5);
  EXPECT_NEAR(sonar_snr_weight(9.0, shifted), 0.731059, 1e-6);
  EXPECT_NEAR(sonar_snr_weight(std::numeric_limits<double>::infinity(), w), 1.0, 0.0);
  // The spread of the power of Rayleigh noise in dB: (pi / sqrt(6)) * 10 / ln 10.
  EXPECT_NEAR(kRayleighPowerSpreadDb, 3.14159265358979 / std::sqrt(6.0) * 10.0 / std::log(10.0), 1e-5);
}

// One beam, no vertical aperture (one sample per range), a quiet floor of intensity 10, and an
// echo of intensity `echo` at bin 200 after `floor` over bins 150..199 (below the echo threshold). The occupied observation's
// weight, with the SNR weight on.
double echo_weight(double echo, double floor) {
  const int bins = 300;
  SonarImageF image = SonarImageF::Constant(bins, 1, 10.0F);
  for (int r = 150; r < 200; ++r) image(r, 0) = static_cast<float>(floor);
  image(200, 0) = static_cast<float>(echo);
  SonarGeometry g;
  g.bearings = {0.0};
  g.range_resolution = 0.02;
  g.max_range = bins * 0.02;
  SonarProjectorParams p;
  p.intensity_threshold = 35.0;
  p.detector = SonarDetector::kOrderedStatisticCfar;
  p.snr_weight.enabled = true;
  const SonarObservations obs =
      SonarImageProjector(0.1, p).project(make_sonar_image_view(image), g, Eigen::Isometry3d::Identity());
  double weight = -1.0;
  for (std::size_t i = 0; i < obs.size(); ++i)
    if (obs.is_occupied[i]) {
      EXPECT_LT(weight, 0.0) << "one occupied voxel expected";
      EXPECT_NEAR(obs.points(static_cast<Eigen::Index>(i), 0), 4.05, 1e-9);  // bin 200: 4.01 m
      weight = obs.weights[static_cast<Eigen::Index>(i)];
    }
  return weight;
}

TEST(SonarSnrWeight, ProjectorWeighsEchoesByTheirExcessOverTheCfarThreshold) {
  const SonarCfar cfar(SonarDetector::kOrderedStatisticCfar, SonarCfarParams{});
  const double alpha = cfar.factor(16);  // the near-side window holds 18 - 2 = 16 training cells
  // Quiet water: noise power 10^2, threshold alpha * 100.
  const auto expected = [&](double echo, double noise) {
    return sonar_snr_weight(10.0 * std::log10(echo * echo / (alpha * noise * noise)), SonarSnrWeight{});
  };
  const double weak = echo_weight(45.0, 10.0), strong = echo_weight(400.0, 10.0);
  EXPECT_NEAR(weak, expected(45.0, 10.0), 1e-12);
  EXPECT_NEAR(strong, expected(400.0, 10.0), 1e-12);
  EXPECT_GT(strong, weak);
  EXPECT_GT(strong, 0.95);
  EXPECT_LT(weak, 0.75);
  // The same echo after a bright stretch (a floor raised to 25, still below the echo threshold of
  // 35): it stands out less, so it weighs less.
  const double quiet = echo_weight(200.0, 10.0), bright = echo_weight(200.0, 25.0);
  EXPECT_NEAR(bright, expected(200.0, 25.0), 1e-12);
  EXPECT_LT(bright, quiet - 0.1);
}

TEST(SonarSnrWeight, BadParametersAreRejectedWithTheirValue) {
  const auto rejects = [](const SonarProjectorParams& p, const std::string& text) {
    try {
      const SonarImageProjector projector(0.1, p);
      ADD_FAILURE() << "accepted; expected an error naming " << text;
    } catch (const std::invalid_argument& e) {
      EXPECT_NE(std::string(e.what()).find(text), std::string::npos) << e.what();
    }
  };
  SonarProjectorParams p;
  p.snr_weight.enabled = true;  // with the fixed-threshold detector
  rejects(p, "snr_weight.enabled");
  p.detector = SonarDetector::kCellAveragingCfar;
  p.snr_weight.width_db = 0.0;
  rejects(p, "width_db = 0");
  p.snr_weight.width_db = 3.0;
  p.snr_weight.centre_db = std::numeric_limits<double>::quiet_NaN();
  rejects(p, "centre_db");
  p.snr_weight.enabled = false;  // off: not checked
  EXPECT_NO_THROW(SonarImageProjector(0.1, p));
}

TEST(SonarPreset, SettingsAreValidAndKeepTheReferenceDefaults) {
  const SonarPreset preset = sonar_preset();
  EXPECT_NO_THROW(preset.map.validate());
  EXPECT_NO_THROW(preset.projector.validate());
  EXPECT_EQ(preset.projector.detector, SonarDetector::kOrderedStatisticCfar);
  EXPECT_TRUE(preset.projector.snr_weight.enabled);
  EXPECT_EQ(preset.map.intensity_threshold, 35.0);
  EXPECT_EQ(preset.projector.intensity_threshold, 35.0);
  EXPECT_EQ(sonar_preset(50.0).projector.intensity_threshold, 50.0);
  EXPECT_EQ(sonar_preset(50.0).map.intensity_threshold, 50.0);
  // The reference defaults do not change with the preset.
  EXPECT_EQ(SonarProjectorParams{}.detector, SonarDetector::kThreshold);
  EXPECT_FALSE(SonarProjectorParams{}.snr_weight.enabled);
  EXPECT_EQ(IwloParams{}.log_odds_occupied, 3.5);
  EXPECT_EQ(IwloParams{}.sharpness, 0.1);
  EXPECT_THROW(static_cast<void>(sonar_preset(std::numeric_limits<double>::quiet_NaN())), std::invalid_argument);
}

// A wall 4 m ahead seen by a 32-beam sonar with a 10-degree aperture, over a quiet floor of 8.
// Returns the occupied voxels after the pings at the given sideways offsets (metres).
Eigen::MatrixXd wall_map(std::uint8_t echo, const std::vector<double>& offsets) {
  const int bins = 300, beams = 32;
  SonarImage8 image = SonarImage8::Constant(bins, beams, 8);
  for (int b = 0; b < beams; ++b) image(200, b) = echo;  // 4.01 m
  SonarGeometry g;
  for (int b = 0; b < beams; ++b) g.bearings.push_back(-0.2 + 0.4 * b / (beams - 1));
  g.range_resolution = 0.02;
  g.max_range = bins * 0.02;
  g.vertical_aperture = 10.0 * 3.14159265358979 / 180.0;
  const SonarPreset preset = sonar_preset();
  const SonarImageProjector projector(0.1, preset.projector);
  ProbabilityUpdater map(0.1);
  map.set_params(preset.map);
  for (const double y : offsets) {
    Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
    pose.translation().y() = y;
    static_cast<void>(projector.integrate(map, make_sonar_image_view(image), g, pose));
  }
  return map.get_occupied_voxels(preset.map.occupied_threshold);
}

// A weak echo (intensity 40: just above the echo threshold of 35, a few dB above the CFAR
// threshold) does not make a voxel occupied on its own; the same wall seen again from 0.3 m to
// the side does, at the wall's range only. A strong echo (250) is occupied at once.
TEST(SonarPreset, AWeakEchoAloneIsNotOccupiedTwoViewsAre) {
  EXPECT_EQ(wall_map(40, {0.0}).rows(), 0);
  for (const auto& occupied : {wall_map(40, {0.0, 0.3}), wall_map(250, {0.0})}) {
    ASSERT_GT(occupied.rows(), 0);
    for (Eigen::Index i = 0; i < occupied.rows(); ++i) {
      const double range = occupied.row(i).head<3>().norm();
      EXPECT_GT(range, 3.7) << "row " << i;
      EXPECT_LT(range, 4.4) << "row " << i;
    }
  }
}

}  // namespace
}  // namespace iwlomap
