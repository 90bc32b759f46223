// SPDX-License-Identifier: BSD-3-Clause
// The sonar front end: SonarImageProjector on hand-made images (expected voxels worked out from
// the geometry, independently of the projector's sampling), and the Oculus reader against the
// three real pings and their fan clouds in ../shared/data.

#include "iwlomap/oculus_reader.h"
#include "iwlomap/probability_updater.h"
#include "iwlomap/sonar_image_projector.h"
#include "iwlomap/sonar_preset.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <limits>
#include <set>
#include <sstream>
#include <string>
#include <vector>

namespace iwlomap {
namespace {

constexpr double kPi = 3.14159265358979323846;

using KeySet = std::set<VoxelKey>;

// A one-beam image of `bins` bins of `range_res` metres, silent except for the given echoes.
struct Ping {
  SonarImage8 image;
  SonarGeometry geometry;
};

Ping one_beam(int bins, double range_res, double aperture, std::vector<std::pair<int, std::uint8_t>> echoes = {},
              double bearing = 0.0) {
  Ping p;
  p.image = SonarImage8::Constant(bins, 1, 5);  // a quiet noise floor below the threshold
  for (const auto& [bin, value] : echoes) p.image(bin, 0) = value;
  p.geometry.bearings = {bearing};
  p.geometry.range_resolution = range_res;
  p.geometry.min_range = 0.0;
  p.geometry.max_range = bins * range_res;
  p.geometry.vertical_aperture = aperture;
  return p;
}

KeySet keys_where(const SonarObservations& obs, double resolution, bool occupied) {
  KeySet out;
  for (std::size_t i = 0; i < obs.size(); ++i)
    if (obs.is_occupied[i] == occupied)
      out.insert(world_to_key(obs.points.row(static_cast<Eigen::Index>(i)).transpose(), resolution));
  return out;
}

// The voxels a continuous arc of radius r over elevations [-a/2, a/2] at bearing b passes through,
// found by sampling it 20,000 times (far finer than any voxel).
KeySet arc_voxels(const Eigen::Isometry3d& pose, double r, double bearing, double aperture, double resolution) {
  KeySet out;
  const int n = 20000;
  for (int i = 0; i <= n; ++i) {
    const double e = -0.5 * aperture + aperture * i / n;
    const Eigen::Vector3d d(std::cos(e) * std::cos(bearing), std::cos(e) * std::sin(bearing), std::sin(e));
    out.insert(world_to_key(pose * (r * d), resolution));
  }
  return out;
}

TEST(SonarImageCopy, CopiesThroughTheViewsStridesIntoRowMajorPixels) {
  // A column-major Eigen image (bin_stride 1) and a 16-bit one: the copy's row-major view reads
  // the same pixels, and outlives the source.
  SonarImage16 image(5, 3);
  for (int r = 0; r < 5; ++r)
    for (int b = 0; b < 3; ++b) image(r, b) = static_cast<std::uint16_t>(1000 * r + b);
  const SonarImageCopy copy = [&] {
    const SonarImage16 temporary = image;
    return SonarImageCopy(make_sonar_image_view(temporary));
  }();
  const SonarImageView v = copy.view();
  EXPECT_EQ(v.type, SonarPixelType::kUint16);
  EXPECT_EQ(v.range_bins, 5);
  EXPECT_EQ(v.beams, 3);
  EXPECT_EQ(v.bin_stride, 3);
  EXPECT_EQ(copy.size_bytes(), 5u * 3u * 2u);
  for (int r = 0; r < 5; ++r)
    for (int b = 0; b < 3; ++b) EXPECT_EQ(v.at(r, b), 1000.0 * r + b);
  EXPECT_THROW(SonarImageCopy(SonarImageView{}), std::invalid_argument);
}

TEST(SonarImageProjector, SingleEchoGivesOccupiedArcAndFreeVoxelsBeforeIt) {
  const double res = 0.05, aperture = 0.3;
  Ping p = one_beam(100, 0.01, aperture, {{59, 200}});  // echo at r = 0.595 m
  SonarProjectorParams params;
  params.elevation_sample_spacing = 0.05;  // fine enough that no voxel of the arc is missed
  const SonarImageProjector projector(res, params);
  const Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  const SonarObservations obs = projector.project(make_sonar_image_view(p.image), p.geometry, pose);

  EXPECT_EQ(obs.beams_with_return, 1u);
  EXPECT_EQ(obs.beams_without_return, 0u);
  const KeySet occupied = keys_where(obs, res, true);
  EXPECT_EQ(occupied, arc_voxels(pose, 0.595, 0.0, aperture, res));

  // Free voxels: exactly the voxels the fan crosses before the echo, minus the arc's voxels.
  const KeySet free = keys_where(obs, res, false);
  ASSERT_FALSE(free.empty());
  const double half_diagonal = 0.5 * std::sqrt(3.0) * res;
  for (std::size_t i = 0; i < obs.size(); ++i) {
    const Eigen::Vector3d c = obs.points.row(static_cast<Eigen::Index>(i)).transpose();
    if (obs.is_occupied[i]) {
      EXPECT_NEAR(c.norm(), 0.595, half_diagonal);
      EXPECT_EQ(obs.intensities[i], 200.0);
    } else {
      EXPECT_LT(c.norm(), 0.595 + half_diagonal) << "a free voxel beyond the echo";
      EXPECT_LE(obs.intensities[i], 35.0);
    }
    EXPECT_GT(obs.weights[i], 0.0);
    EXPECT_LE(obs.weights[i], 1.0);
  }
  // The beam's axis before the echo is free, voxel by voxel.
  for (double r = 0.0; r < 0.595 - res; r += 0.5 * res) {
    const VoxelKey k = world_to_key(Eigen::Vector3d(r, 0.0, 0.0), res);
    EXPECT_TRUE(free.count(k) == 1 || occupied.count(k) == 1) << "r = " << r;
    if (r < 0.595 - 2 * res) { EXPECT_EQ(free.count(k), 1u) << "r = " << r; }
  }
  // Every free voxel is one the fan crosses before the arc.
  KeySet fan;
  for (double r = 0.0; r < 0.595; r += 0.002) {
    const KeySet a = arc_voxels(pose, r, 0.0, aperture, res);
    fan.insert(a.begin(), a.end());
  }
  for (const VoxelKey& k : free) EXPECT_EQ(fan.count(k), 1u) << k.x << " " << k.y << " " << k.z;
  // One observation per voxel.
  EXPECT_EQ(occupied.size() + free.size(), obs.size());
}

TEST(SonarImageProjector, OccupiedBandCoversTheRangesAfterTheEcho) {
  const double res = 0.05;
  Ping p = one_beam(100, 0.01, 0.0, {{40, 90}, {45, 180}});  // echo at 0.405 m, peaking at 0.455 m
  SonarProjectorParams params;
  params.occupied_band = 0.1;
  const SonarObservations obs =
      SonarImageProjector(res, params).project(make_sonar_image_view(p.image), p.geometry, Eigen::Isometry3d::Identity());
  // Zero aperture: the band is the axis from 0.405 to 0.505 m, voxels x = 8, 9, 10.
  KeySet expected;
  for (int x = 8; x <= 10; ++x) expected.insert(VoxelKey{x, 0, 0});
  EXPECT_EQ(keys_where(obs, res, true), expected);
  for (std::size_t i = 0; i < obs.size(); ++i)
    if (obs.is_occupied[i]) { EXPECT_EQ(obs.intensities[i], 180.0) << "the band carries the echo's peak"; }
  // Nothing beyond the band: that is acoustic shadow.
  for (std::size_t i = 0; i < obs.size(); ++i) EXPECT_LT(obs.points(static_cast<Eigen::Index>(i), 0), 0.55);
}

TEST(SonarImageProjector, NoEchoGivesNothingOrFreeToMaxRangeAsConfigured) {
  const double res = 0.05;
  Ping p = one_beam(100, 0.01, 0.2);
  p.geometry.max_range = 0.8;
  SonarProjectorParams params;
  params.no_return = SonarNoReturn::kNothing;
  const auto view = make_sonar_image_view(p.image);
  const SonarObservations none =
      SonarImageProjector(res, params).project(view, p.geometry, Eigen::Isometry3d::Identity());
  EXPECT_EQ(none.size(), 0u);
  EXPECT_EQ(none.beams_without_return, 1u);

  params.no_return = SonarNoReturn::kFreeToMaxRange;
  const SonarObservations free =
      SonarImageProjector(res, params).project(view, p.geometry, Eigen::Isometry3d::Identity());
  ASSERT_GT(free.size(), 0u);
  double farthest = 0.0;
  for (std::size_t i = 0; i < free.size(); ++i) {
    EXPECT_FALSE(free.is_occupied[i]);
    farthest = std::max(farthest, free.points.row(static_cast<Eigen::Index>(i)).norm());
  }
  const double half_diagonal = 0.5 * std::sqrt(3.0) * res;
  EXPECT_LE(farthest, 0.8 + half_diagonal);
  EXPECT_GE(farthest, 0.8 - half_diagonal);
  // The voxel at max range on the axis is free.
  const KeySet free_keys = keys_where(free, res, false);
  EXPECT_EQ(free_keys.count(world_to_key(Eigen::Vector3d(0.79, 0.0, 0.0), res)), 1u);
}

TEST(SonarImageProjector, EchoInsideMinRangeIsIgnored) {
  const double res = 0.05;
  Ping p = one_beam(100, 0.01, 0.0, {{5, 250}, {60, 120}});
  p.geometry.min_range = 0.2;
  const SonarObservations obs =
      SonarImageProjector(res).project(make_sonar_image_view(p.image), p.geometry, Eigen::Isometry3d::Identity());
  EXPECT_EQ(keys_where(obs, res, true), (KeySet{VoxelKey{12, 0, 0}}));  // r = 0.605
  for (std::size_t i = 0; i < obs.size(); ++i)
    EXPECT_GE(obs.points(static_cast<Eigen::Index>(i), 0), 0.2 - res) << "evidence inside min_range";
}

TEST(SonarImageProjector, PoseMovesAndTurnsTheObservations) {
  const double res = 0.1;
  Ping p = one_beam(100, 0.01, 0.0, {{49, 200}});  // r = 0.495 m straight ahead
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.translate(Eigen::Vector3d(1.02, 2.03, -2.96));
  pose.rotate(Eigen::AngleAxisd(kPi / 2, Eigen::Vector3d::UnitZ()));  // sonar +X along map +Y
  const SonarObservations obs = SonarImageProjector(res).project(make_sonar_image_view(p.image), p.geometry, pose);
  // The echo is at (1.02, 2.03 + 0.495, -2.96): key (10, 25, -30).
  EXPECT_EQ(keys_where(obs, res, true), (KeySet{VoxelKey{10, 25, -30}}));
  for (std::size_t i = 0; i < obs.size(); ++i) {
    const Eigen::Vector3d c = obs.points.row(static_cast<Eigen::Index>(i)).transpose();
    EXPECT_NEAR(c.x(), 1.05, 1e-12);
    EXPECT_NEAR(c.z(), -2.95, 1e-12);
    EXPECT_GE(c.y(), 2.0);
  }

  // A general pose with aperture: the occupied voxels are those of the arc moved by the pose.
  Ping q = one_beam(120, 0.01, 0.25, {{80, 150}}, 0.3);
  Eigen::Isometry3d g = Eigen::Isometry3d::Identity();
  g.translate(Eigen::Vector3d(-3.3, 0.7, 12.1));
  g.rotate(Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, -2, 0.5).normalized()));
  SonarProjectorParams fine;
  fine.elevation_sample_spacing = 0.05;
  const SonarObservations moved = SonarImageProjector(0.05, fine).project(make_sonar_image_view(q.image), q.geometry, g);
  EXPECT_EQ(keys_where(moved, 0.05, true), arc_voxels(g, 0.805, 0.3, 0.25, 0.05));
}

TEST(SonarImageProjector, PositiveBearingIsToTheRightAndPositiveElevationDown) {
  const double res = 0.05;
  Ping p = one_beam(100, 0.01, 0.0, {{79, 200}}, 0.5);
  const SonarObservations obs =
      SonarImageProjector(res).project(make_sonar_image_view(p.image), p.geometry, Eigen::Isometry3d::Identity());
  const KeySet occ = keys_where(obs, res, true);
  ASSERT_EQ(occ.size(), 1u);
  EXPECT_EQ(*occ.begin(), world_to_key(Eigen::Vector3d(0.795 * std::cos(0.5), 0.795 * std::sin(0.5), 0.0), res));
  EXPECT_GT(occ.begin()->y, 0);
  // Pitching the sonar down by 30 degrees (a rotation about its +Y) moves the echo to +Z (down).
  Eigen::Isometry3d pitched = Eigen::Isometry3d::Identity();
  pitched.rotate(Eigen::AngleAxisd(-kPi / 6, Eigen::Vector3d::UnitY()));
  Ping ahead = one_beam(100, 0.01, 0.0, {{79, 200}});
  const SonarObservations down =
      SonarImageProjector(res).project(make_sonar_image_view(ahead.image), ahead.geometry, pitched);
  const KeySet d = keys_where(down, res, true);
  ASSERT_EQ(d.size(), 1u);
  EXPECT_EQ(*d.begin(), world_to_key(Eigen::Vector3d(0.795 * std::cos(kPi / 6), 0.0, 0.795 * std::sin(kPi / 6)), res));
}

TEST(SonarImageProjector, OccupiedWinsOverFreeInOneVoxel) {
  const double res = 0.05;
  // Two nearly parallel beams: the first echoes at 0.305 m, the second hears nothing until 0.805 m,
  // so its free samples cross the first beam's echo voxel.
  SonarImage8 image = SonarImage8::Constant(100, 2, 0);
  image(30, 0) = 200;
  image(80, 1) = 200;
  SonarGeometry g;
  g.bearings = {0.0, 0.001};
  g.range_resolution = 0.01;
  g.max_range = 1.0;
  const SonarObservations obs =
      SonarImageProjector(res).project(make_sonar_image_view(image), g, Eigen::Isometry3d::Identity());
  const KeySet occ = keys_where(obs, res, true);
  EXPECT_EQ(occ.count(VoxelKey{6, 0, 0}), 1u);
  EXPECT_EQ(occ.count(VoxelKey{16, 0, 0}), 1u);
  EXPECT_EQ(keys_where(obs, res, false).count(VoxelKey{6, 0, 0}), 0u);
  EXPECT_EQ(occ.size() + keys_where(obs, res, false).size(), obs.size());
}

TEST(SonarImageProjector, WeightCountsSamplesPerVoxelCappedAtOne) {
  // Zero aperture, stride 0.25 voxels: a voxel the axis crosses gets 4 samples = 4 / 4 expected.
  // (A resolution of 1/16 m keeps every sample range exact in binary.)
  double res = 0.0625;
  Ping p = one_beam(100, 0.01, 0.0, {{90, 200}});
  SonarProjectorParams params;
  params.free_sample_stride = 0.25;
  const SonarObservations obs =
      SonarImageProjector(res, params).project(make_sonar_image_view(p.image), p.geometry, Eigen::Isometry3d::Identity());
  for (std::size_t i = 0; i < obs.size(); ++i) {
    if (obs.is_occupied[i]) continue;
    EXPECT_DOUBLE_EQ(obs.weights[i], 1.0) << "x = " << obs.points(static_cast<Eigen::Index>(i), 0);
  }
  // A fan of 64 beams over 60 degrees and 0.2 rad aperture: near the sonar many beams share a
  // voxel (capped at 1); at the far edge, voxels the fan only grazes get less than 1.
  res = 0.05;
  SonarImage8 image = SonarImage8::Constant(200, 64, 0);
  SonarGeometry g;
  for (int b = 0; b < 64; ++b) g.bearings.push_back((-30.0 + 60.0 * b / 63.0) * kPi / 180.0);
  g.range_resolution = 0.01;
  g.max_range = 2.0;
  g.vertical_aperture = 0.2;
  const SonarObservations fan =
      SonarImageProjector(res).project(make_sonar_image_view(image), g, Eigen::Isometry3d::Identity());
  double near_weight = 0.0, min_weight = 1.0;
  for (std::size_t i = 0; i < fan.size(); ++i) {
    EXPECT_FALSE(fan.is_occupied[i]);
    EXPECT_GT(fan.weights[i], 0.0);
    EXPECT_LE(fan.weights[i], 1.0);
    min_weight = std::min(min_weight, fan.weights[i]);
    if (fan.points.row(static_cast<Eigen::Index>(i)).norm() < 0.05) near_weight = fan.weights[i];
  }
  EXPECT_EQ(near_weight, 1.0);
  EXPECT_LE(min_weight, 0.5);  // one sample of the two expected
}

TEST(SonarImageProjector, PixelTypesAndLayoutsGiveTheSameObservations) {
  const double res = 0.05;
  SonarImage8 image8(150, 3);
  for (int r = 0; r < 150; ++r)
    for (int b = 0; b < 3; ++b) image8(r, b) = static_cast<std::uint8_t>((r * 7 + b * 13) % 40);
  image8(70, 0) = 120;
  image8(90, 1) = 60;
  SonarGeometry g;
  g.bearings = {-0.2, 0.0, 0.25};
  g.range_resolution = 0.01;
  g.max_range = 1.5;
  g.vertical_aperture = 0.2;
  const SonarImageProjector projector(res);
  const Eigen::Isometry3d pose(Eigen::Translation3d(0.3, -0.1, 0.2));
  const SonarObservations a = projector.project(make_sonar_image_view(image8), g, pose);
  const SonarImage16 image16 = image8.cast<std::uint16_t>();
  const SonarImageF imagef = image8.cast<float>();
  const Eigen::Matrix<std::uint8_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> row_major = image8;
  for (const SonarImageView& v :
       {make_sonar_image_view(image16), make_sonar_image_view(imagef), make_sonar_image_view(row_major),
        make_sonar_image_view(row_major.data(), 150, 3)}) {
    const SonarObservations b = projector.project(v, g, pose);
    EXPECT_EQ(a.points, b.points);
    EXPECT_EQ(a.intensities, b.intensities);
    EXPECT_EQ(a.is_occupied, b.is_occupied);
    EXPECT_EQ(a.weights, b.weights);
  }
}

TEST(SonarImageProjector, IntegrateUpdatesTheMapAndChecksItsResolution) {
  Ping p = one_beam(100, 0.01, 0.0, {{49, 200}});
  const SonarImageProjector projector(0.05);
  ProbabilityUpdater map(0.05);
  const SonarObservations obs =
      projector.integrate(map, make_sonar_image_view(p.image), p.geometry, Eigen::Isometry3d::Identity());
  EXPECT_EQ(map.get_num_known_voxels(), obs.size());
  const auto hit = map.query(Eigen::Vector3d(0.495, 0.0, 0.0));
  ASSERT_TRUE(hit.has_value());
  EXPECT_GT(hit->probability, 0.5);
  const auto water = map.query(Eigen::Vector3d(0.2, 0.0, 0.0));
  ASSERT_TRUE(water.has_value());
  EXPECT_LT(water->probability, 0.5);
  ProbabilityUpdater coarse(0.1);
  EXPECT_THROW((void)projector.integrate(coarse, make_sonar_image_view(p.image), p.geometry,
                                         Eigen::Isometry3d::Identity()),
               std::invalid_argument);
}

// Expects std::invalid_argument whose message contains \p name.
template <typename F>
void expect_invalid(F&& f, const std::string& name) {
  try {
    f();
    ADD_FAILURE() << "no exception for " << name;
  } catch (const std::invalid_argument& e) {
    EXPECT_NE(std::string(e.what()).find(name), std::string::npos) << e.what();
  }
}

TEST(SonarImageProjector, InvalidInputThrowsNamingTheValue) {
  expect_invalid([] { SonarImageProjector(0.0); }, "resolution");
  expect_invalid(
      [] {
        SonarProjectorParams q;
        q.free_sample_stride = 0.0;
        SonarImageProjector(0.1, q);
      },
      "free_sample_stride");
  expect_invalid(
      [] {
        SonarProjectorParams q;
        q.elevation_sample_spacing = -1.0;
        SonarImageProjector(0.1, q);
      },
      "elevation_sample_spacing");
  expect_invalid(
      [] {
        SonarProjectorParams q;
        q.occupied_band = std::numeric_limits<double>::quiet_NaN();
        SonarImageProjector(0.1, q);
      },
      "occupied_band");
  const SonarImageProjector projector(0.05);
  const Ping good = one_beam(50, 0.01, 0.1, {{20, 100}});
  const auto project_with = [&](const SonarGeometry& g) {
    (void)projector.project(make_sonar_image_view(good.image), g, Eigen::Isometry3d::Identity());
  };
  SonarGeometry g = good.geometry;
  g.bearings = {0.0, 0.1};
  expect_invalid([&] { project_with(g); }, "bearings.size()");
  g = good.geometry;
  g.range_resolution = 0.0;
  expect_invalid([&] { project_with(g); }, "range_resolution");
  g = good.geometry;
  g.min_range = 0.3;
  g.max_range = 0.3;
  expect_invalid([&] { project_with(g); }, "max_range");
  // Beyond what a sonar measures (a crafted file would take memory without bound).
  g = good.geometry;
  g.range_resolution = 10.0;
  expect_invalid([&] { project_with(g); }, "range_resolution");
  g = good.geometry;
  g.max_range = 5000.0;
  expect_invalid([&] { project_with(g); }, "max_range");
  g = good.geometry;
  g.min_range = -0.1;
  expect_invalid([&] { project_with(g); }, "min_range");
  g = good.geometry;
  g.vertical_aperture = -0.1;
  expect_invalid([&] { project_with(g); }, "vertical_aperture");
  g = good.geometry;
  g.bearings = {std::numeric_limits<double>::infinity()};
  expect_invalid([&] { project_with(g); }, "bearings[0]");
  SonarImageF bad = good.image.cast<float>();
  bad(7, 0) = std::numeric_limits<float>::quiet_NaN();
  expect_invalid([&] { (void)projector.project(make_sonar_image_view(bad), good.geometry, Eigen::Isometry3d::Identity()); },
                 "pixel (bin 7, beam 0)");
  Eigen::Isometry3d nan_pose = Eigen::Isometry3d::Identity();
  nan_pose.translation().x() = std::numeric_limits<double>::quiet_NaN();
  expect_invalid([&] { (void)projector.project(make_sonar_image_view(good.image), good.geometry, nan_pose); }, "pose");
  SonarImageView empty = make_sonar_image_view(good.image);
  empty.range_bins = 0;
  expect_invalid([&] { (void)projector.project(empty, good.geometry, Eigen::Isometry3d::Identity()); }, "range_bins");
}

// ---- Oculus reader ------------------------------------------------------------------------------

const std::string kOculusDir = std::string(IWLOMAP_SHARED_DATA_DIR) + "/oculus_sonar_3pings";

std::vector<std::uint8_t> read_bytes(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

bool have_oculus_data() { return std::ifstream(kOculusDir + "/three_pings_8bit.raw").good(); }

#define SKIP_WITHOUT_OCULUS_DATA()                                                                              \
  if (!have_oculus_data())                                                                                      \
  GTEST_SKIP() << "recorded data not found: " << kOculusDir                                                     \
               << "/three_pings_8bit.raw (set IWLOMAP_SHARED_DATA_DIR to the shared data folder)"

// An organised binary PCD with fields x y z intensity (all F 4), read without PCL.
struct FanCloud {
  int width = 0, height = 0;
  std::vector<float> xyzi;  // 4 floats per point
};

FanCloud read_fan_pcd(const std::string& path) {
  const std::vector<std::uint8_t> bytes = read_bytes(path);
  FanCloud cloud;
  std::size_t at = 0;
  while (at < bytes.size()) {
    const auto eol = std::find(bytes.begin() + static_cast<std::ptrdiff_t>(at), bytes.end(), '\n');
    const std::string line(bytes.begin() + static_cast<std::ptrdiff_t>(at), eol);
    at = static_cast<std::size_t>(eol - bytes.begin()) + 1;
    std::istringstream s(line);
    std::string key;
    s >> key;
    if (key == "FIELDS") { EXPECT_EQ(line, "FIELDS x y z intensity") << path; }
    if (key == "TYPE") { EXPECT_EQ(line, "TYPE F F F F") << path; }
    if (key == "WIDTH") s >> cloud.width;
    if (key == "HEIGHT") s >> cloud.height;
    if (key == "DATA") {
      EXPECT_EQ(line, "DATA binary") << path;
      break;
    }
  }
  const std::size_t n = static_cast<std::size_t>(cloud.width) * static_cast<std::size_t>(cloud.height);
  EXPECT_EQ(bytes.size() - at, n * 16) << path;
  cloud.xyzi.resize(4 * n);
  std::memcpy(cloud.xyzi.data(), bytes.data() + at, std::min(bytes.size() - at, n * 16));
  return cloud;
}

TEST(OculusReader, ReadsTheThreeRealPingsWithTheirSettings) {
  SKIP_WITHOUT_OCULUS_DATA();
  const std::vector<OculusPing> pings = read_oculus_pings(kOculusDir + "/three_pings_8bit.raw");
  ASSERT_EQ(pings.size(), 3u);
  for (std::size_t i = 0; i < pings.size(); ++i) {
    const OculusPing& p = pings[i];
    SCOPED_TRACE(i);
    EXPECT_EQ(p.file_offset, i * 182016);
    EXPECT_EQ(p.ping_id, 415323u + i);
    EXPECT_EQ(p.beams, 256);
    EXPECT_EQ(p.range_bins, 703);
    EXPECT_DOUBLE_EQ(p.range, 2.0);
    EXPECT_DOUBLE_EQ(p.gain_percent, 50.0);
    EXPECT_NEAR(p.speed_of_sound, 1490.7, 0.05);
    EXPECT_NEAR(p.frequency, 2.099e6, 1e3);
    EXPECT_NEAR(p.range_resolution, 0.002842, 1e-6);
    EXPECT_EQ(p.image.size(), 256u * 703u);
    EXPECT_TRUE(p.row_gains.empty());
    EXPECT_EQ(p.bearing_table.front(), -3000);
    EXPECT_EQ(p.bearing_table.back(), 3000);
  }
  // The bearing table agrees with bearings_deg.txt (two decimals).
  std::ifstream txt(kOculusDir + "/bearings_deg.txt");
  std::vector<double> degrees{std::istream_iterator<double>(txt), std::istream_iterator<double>()};
  ASSERT_EQ(degrees.size(), 256u);
  for (std::size_t b = 0; b < degrees.size(); ++b)
    EXPECT_NEAR(pings[0].bearings[b] * 180.0 / kPi, degrees[b], 0.005) << "beam " << b;
}

TEST(OculusReader, EveryPixelMatchesTheFanClouds) {
  SKIP_WITHOUT_OCULUS_DATA();
  const std::vector<OculusPing> pings = read_oculus_pings(kOculusDir + "/three_pings_8bit.raw");
  ASSERT_EQ(pings.size(), 3u);
  for (std::size_t i = 0; i < 3; ++i) {
    const OculusPing& p = pings[i];
    const FanCloud fan = read_fan_pcd(kOculusDir + "/ping_00" + std::to_string(i) + "_fan.pcd");
    ASSERT_EQ(fan.width, p.beams);
    ASSERT_EQ(fan.height, p.range_bins);
    const SonarImageView view = p.image_view();
    std::size_t bad_position = 0, bad_intensity = 0;
    for (int bin = 0; bin < p.range_bins; ++bin) {
      for (int beam = 0; beam < p.beams; ++beam) {
        const float* q = &fan.xyzi[4 * (static_cast<std::size_t>(bin) * 256 + static_cast<std::size_t>(beam))];
        const double r = (bin + 0.5) * p.range_resolution;
        const double b = p.bearings[static_cast<std::size_t>(beam)];
        if (std::abs(q[0] - r * std::cos(b)) > 1e-4 || std::abs(q[1] - r * std::sin(b)) > 1e-4 || std::abs(q[2]) > 1e-4)
          ++bad_position;
        if (q[3] != static_cast<float>(p.intensity(bin, beam)) || view.at(bin, beam) != q[3]) ++bad_intensity;
      }
    }
    EXPECT_EQ(bad_position, 0u) << "ping " << i;
    EXPECT_EQ(bad_intensity, 0u) << "ping " << i;
  }
}

// Expects OculusFormatError at \p offset whose message names the source and contains \p words.
void expect_format_error(const std::vector<std::uint8_t>& bytes, std::size_t offset, const std::string& words) {
  try {
    (void)parse_oculus_pings(bytes.data(), bytes.size(), "test.raw");
    ADD_FAILURE() << "no error for '" << words << "'";
  } catch (const OculusFormatError& e) {
    EXPECT_EQ(e.offset(), offset) << e.what();
    EXPECT_EQ(e.source(), "test.raw");
    const std::string what = e.what();
    EXPECT_NE(what.find("test.raw"), std::string::npos) << what;
    EXPECT_NE(what.find("offset " + std::to_string(offset)), std::string::npos) << what;
    EXPECT_NE(what.find(words), std::string::npos) << what;
  }
}

void put_u32(std::vector<std::uint8_t>& b, std::size_t at, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) b[at + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(v >> (8 * i));
}

// The three real pings at one pose, 1 cm voxels, 20-degree aperture, the first bins skipped
// (transducer ringing). The images are dark (median intensity 7-20) up to 0.70 m, with a faint
// echo ring at 0.50-0.53 m in a fifth of the beams, and bright (median 44-166) from 0.70 m to
// 1.2 m. The reference projection takes the first pixel above 35, mostly speckle in the dark
// stretch; the sonar preset's CFAR detection and SNR weight put far more of the map where the
// images turn bright.
double share_where_bright(const SonarPreset* preset) {
  const std::vector<OculusPing> pings = read_oculus_pings(kOculusDir + "/three_pings_8bit.raw");
  ProbabilityUpdater map(0.01);
  if (preset != nullptr) map.set_params(preset->map);
  const SonarImageProjector projector(0.01, preset != nullptr ? preset->projector : SonarProjectorParams{});
  for (const OculusPing& ping : pings)
    static_cast<void>(projector.integrate(map, ping.image_view(), ping.geometry(20.0 * 3.14159265358979 / 180.0, 0.05),
                                          Eigen::Isometry3d::Identity()));
  const Eigen::MatrixXd occupied = map.get_occupied_voxels(map.get_params().occupied_threshold);
  EXPECT_GT(occupied.rows(), 500);
  std::size_t bright = 0;
  for (Eigen::Index i = 0; i < occupied.rows(); ++i) {
    const double r = occupied.row(i).head<3>().norm();
    bright += r >= 0.70 && r <= 1.2 ? 1 : 0;
  }
  return static_cast<double>(bright) / static_cast<double>(std::max<Eigen::Index>(1, occupied.rows()));
}

TEST(OculusReader, SonarPresetMapsTheRealPingsWhereTheImagesTurnBright) {
  SKIP_WITHOUT_OCULUS_DATA();
  const SonarPreset preset = sonar_preset();
  const double reference = share_where_bright(nullptr), with_preset = share_where_bright(&preset);
  EXPECT_LT(reference, 0.1);     // measured 0.052
  EXPECT_GT(with_preset, 0.35);  // measured 0.405
}

void put_f64(std::vector<std::uint8_t>& b, std::size_t at, double v) {
  std::uint64_t bits = 0;
  std::memcpy(&bits, &v, sizeof bits);
  for (int i = 0; i < 8; ++i) b[at + static_cast<std::size_t>(i)] = static_cast<std::uint8_t>(bits >> (8 * i));
}

TEST(OculusReader, MalformedOrTruncatedFilesNameTheFileAndOffset) {
  SKIP_WITHOUT_OCULUS_DATA();
  const std::vector<std::uint8_t> good = read_bytes(kOculusDir + "/three_pings_8bit.raw");
  ASSERT_EQ(good.size(), 3u * 182016u);

  std::vector<std::uint8_t> cut(good.begin(), good.begin() + 182016 + 1000);
  expect_format_error(cut, 182016, "truncated");
  cut.assign(good.begin(), good.begin() + 182016 + 7);
  expect_format_error(cut, 182016, "truncated message header");

  std::vector<std::uint8_t> bad = good;
  bad[2 * 182016] = 'X';
  expect_format_error(bad, 2 * 182016, "magic");

  bad = good;
  put_u32(bad, 182016 + 114, 12345);  // image size
  expect_format_error(bad, 182016 + 114, "image size 12345");

  bad = good;
  put_u32(bad, 110, 300);  // image offset inside the bearing table
  expect_format_error(bad, 110, "image offset 300");

  bad = good;
  put_f64(bad, 98, 10.0);  // 10 m range bins: no sonar has them
  expect_format_error(bad, 98, "range resolution 10 m");

  bad = good;
  put_f64(bad, 98, 1e-5);  // bins too fine for a sonar (1e-154 made min_range / bin overflow an int)
  expect_format_error(bad, 98, "range resolution 1.0000000000000001e-05 m is not in [0.0001, 1] m");

  bad = good;
  put_f64(bad, 21, 5000.0);  // a 5 km range
  expect_format_error(bad, 21, "range 5000 m");

  bad = good;
  bad[97] = 1;  // 16-bit data
  expect_format_error(bad, 97, "data size 1");

  bad = good;
  bad[8] = 2;  // SimplePingResult2
  expect_format_error(bad, 8, "version 2");

  expect_format_error({}, 0, "no SimplePingResult");

  try {
    (void)read_oculus_pings("/nonexistent/pings.raw");
    ADD_FAILURE() << "no error for a missing file";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent/pings.raw"), std::string::npos) << e.what();
  }
}

TEST(OculusReader, SkipsOtherMessagesAndReadsRowGains) {
  SKIP_WITHOUT_OCULUS_DATA();
  const std::vector<std::uint8_t> good = read_bytes(kOculusDir + "/three_pings_8bit.raw");
  const std::vector<OculusPing> reference = parse_oculus_pings(good.data(), good.size(), "good");
  // A message with another id (a 20-byte status-like message) before the first ping is skipped.
  std::vector<std::uint8_t> bytes = {0x53, 0x4f, 0, 0, 0, 0, 0x80, 0, 0, 0, 4, 0, 0, 0, 0, 0, 1, 2, 3, 4};
  // The first ping rewritten with flag 0x04: every row starts with a uint32 gain (row index * 3).
  const std::size_t bins = 703, beams = 256, image_offset = 2048;
  std::vector<std::uint8_t> ping(good.begin(), good.begin() + image_offset);
  ping[20] |= 0x04;
  for (std::size_t row = 0; row < bins; ++row) {
    for (int i = 0; i < 4; ++i) ping.push_back(static_cast<std::uint8_t>((row * 3) >> (8 * i)));
    ping.insert(ping.end(), good.begin() + static_cast<std::ptrdiff_t>(image_offset + row * beams),
                good.begin() + static_cast<std::ptrdiff_t>(image_offset + (row + 1) * beams));
  }
  put_u32(ping, 10, static_cast<std::uint32_t>(ping.size() - 16));  // payload size
  put_u32(ping, 114, static_cast<std::uint32_t>(bins * (beams + 4)));  // image size
  put_u32(ping, 118, static_cast<std::uint32_t>(ping.size()));       // message size
  bytes.insert(bytes.end(), ping.begin(), ping.end());
  const std::vector<OculusPing> pings = parse_oculus_pings(bytes.data(), bytes.size(), "gains");
  ASSERT_EQ(pings.size(), 1u);
  EXPECT_EQ(pings[0].file_offset, 20u);
  EXPECT_EQ(pings[0].image, reference[0].image);
  ASSERT_EQ(pings[0].row_gains.size(), bins);
  EXPECT_EQ(pings[0].row_gains[100], 300u);
}

TEST(OculusReader, RealPingProjectsIntoTheMap) {
  SKIP_WITHOUT_OCULUS_DATA();
  const std::vector<OculusPing> pings = read_oculus_pings(kOculusDir + "/three_pings_8bit.raw");
  const SonarImageProjector projector(0.02);
  ProbabilityUpdater map(0.02);
  for (const OculusPing& p : pings) {
    const SonarObservations obs =
        projector.integrate(map, p.image_view(), p.geometry(20.0 * kPi / 180.0, 0.1), Eigen::Isometry3d::Identity());
    EXPECT_EQ(obs.beams_with_return + obs.beams_without_return, 256u);
    EXPECT_GT(obs.beams_with_return, 0u);
  }
  EXPECT_GT(map.get_occupied_voxels(0.5).rows(), 0);
  // Everything lies inside the 2 m fan, +-30 degrees, +-10 degrees of elevation.
  map.for_each_voxel([&](const VoxelKey& k, const VoxelState&) {
    const Eigen::Vector3d c = key_to_center(k, 0.02);
    EXPECT_LT(c.norm(), 2.0 + 0.02);
    EXPECT_GT(c.x(), 0.0);
  });
}

}  // namespace
}  // namespace iwlomap
