// SPDX-License-Identifier: BSD-3-Clause
// OccupancyFilter and what its points carry: all-zero intensities and the lidar preset, every
// precompiled point type, the mean colour of each voxel, and voxels at their mean hit position.

#include <Eigen/Geometry>
#include <iwlomap/filters/occupancy_filter.h>

#include "occupancy_filter_test_support.h"

#include <gtest/gtest.h>
#include <pcl/console/print.h>

#include <cstdint>
#include <functional>
#include <stdexcept>
#include <string>
#include <tuple>

namespace {

using iwlomap::filter_test::Cloud;
using iwlomap::filter_test::Filter;
using iwlomap::filter_test::make_wall_scan;

// A cloud whose intensities are all 0 (a converted PointXYZ cloud, OctoMap's example scan): the
// default (sonar) parameters make every return free space and say so once; the lidar preset maps it.
TEST(OccupancyFilter, AllZeroIntensitiesWarnOnceAndMapWithTheLidarPreset) {
  const auto frame1 = make_wall_scan(0.0f, 200, 3);
  const auto frame2 = make_wall_scan(0.0f, 200, 4);
  Filter sonar;
  sonar.setResolution(0.1);
  Cloud out;
  const auto verbosity = pcl::console::getVerbosityLevel();
  pcl::console::setVerbosityLevel(pcl::console::L_WARN);
  testing::internal::CaptureStderr();
  for (const auto& f : {frame1, frame2}) {
    sonar.setInputCloud(f);
    sonar.filter(out);
  }
  const std::string sonar_log = testing::internal::GetCapturedStderr();
  EXPECT_EQ(out.size(), 0u) << "sonar semantics: no echo above the threshold, no surface";
  EXPECT_NE(sonar_log.find("setSensorPreset(iwlomap::SensorPreset::kLidar)"), std::string::npos) << sonar_log;
  EXPECT_EQ(sonar_log.find("kLidar"), sonar_log.rfind("kLidar")) << "one warning per filter: " << sonar_log;

  Filter lidar;
  lidar.setResolution(0.1);
  lidar.setSensorPreset(iwlomap::SensorPreset::kLidar);
  testing::internal::CaptureStderr();
  for (const auto& f : {frame1, frame2}) {
    lidar.setInputCloud(f);
    lidar.filter(out);
  }
  const std::string lidar_log = testing::internal::GetCapturedStderr();
  pcl::console::setVerbosityLevel(verbosity);
  EXPECT_TRUE(lidar_log.empty()) << lidar_log;
  EXPECT_GT(out.size(), 50u) << "every return is a hit under the lidar preset";
  for (const auto& p : out) EXPECT_NEAR(p.x, 2.0f, 0.1f);  // the wall's voxels
  EXPECT_EQ(lidar.getIwloParams().intensity_threshold,
            iwlomap::sensor_preset_params(iwlomap::SensorPreset::kLidar).intensity_threshold);
}

// Every precompiled point type maps, and input-points mode keeps each type's own fields.
template <class PointT>
void expect_point_type_maps(const std::function<void(PointT&, int)>& fill, const std::function<bool(const PointT&, int)>& same) {
  auto c = pcl::make_shared<pcl::PointCloud<PointT>>();
  for (int i = 0; i < 100; ++i) {
    PointT p;
    p.x = 2.0f;
    p.y = -0.5f + 0.01f * static_cast<float>(i);
    p.z = 0.05f;
    fill(p, i);
    c->push_back(p);
  }
  iwlomap::OccupancyFilter<PointT> f;
  f.setResolution(0.1);
  f.setInputCloud(c);
  pcl::PointCloud<PointT> voxels;
  f.filter(voxels);
  EXPECT_GE(voxels.size(), 10u);
  f.setOutputMode(iwlomap::OutputMode::kInputPoints);
  pcl::PointCloud<PointT> kept;
  f.filter(kept);
  ASSERT_EQ(kept.size(), c->size());
  for (std::size_t i = 0; i < kept.size(); ++i) EXPECT_TRUE(same(kept[i], static_cast<int>(i))) << i;
}

TEST(OccupancyFilter, EveryPrecompiledPointTypeMaps) {
  expect_point_type_maps<pcl::PointXYZRGB>(
      [](pcl::PointXYZRGB& p, int i) { p.r = static_cast<std::uint8_t>(i); p.g = 7; p.b = 9; },
      [](const pcl::PointXYZRGB& p, int i) { return p.r == i && p.g == 7 && p.b == 9; });
  expect_point_type_maps<pcl::PointXYZRGBA>(
      [](pcl::PointXYZRGBA& p, int i) { p.r = static_cast<std::uint8_t>(i); p.a = 200; },
      [](const pcl::PointXYZRGBA& p, int i) { return p.r == i && p.a == 200; });
  expect_point_type_maps<pcl::PointXYZL>([](pcl::PointXYZL& p, int i) { p.label = static_cast<std::uint32_t>(1000 + i); },
                                         [](const pcl::PointXYZL& p, int i) { return p.label == 1000u + static_cast<std::uint32_t>(i); });
  expect_point_type_maps<pcl::PointXYZ>([](pcl::PointXYZ&, int) {}, [](const pcl::PointXYZ& p, int) { return p.x == 2.0f; });
  expect_point_type_maps<pcl::PointXYZI>([](pcl::PointXYZI& p, int) { p.intensity = 150.0f; },
                                         [](const pcl::PointXYZI& p, int) { return p.intensity == 150.0f; });
  expect_point_type_maps<pcl::PointXYZINormal>([](pcl::PointXYZINormal& p, int) { p.intensity = 150.0f; p.normal_x = 1.0f; },
                                               [](const pcl::PointXYZINormal& p, int) { return p.normal_x == 1.0f; });
}

// Colour means: two voxels of a wall at 0.1 m, hit by points of known colours; the output
// carries the rounded mean of each voxel's hits, by hand: voxel y in [0, 0.1): r (10 + 20 + 31) / 3
// = 20.33 -> 20, g 100, b (0 + 1 + 1) / 3 = 0.67 -> 1; voxel y in [0.1, 0.2): (200 + 201) / 2 =
// 200.5 -> 201, g 50, b 255.
template <class PointT>
void expect_colour_means() {
  auto c = pcl::make_shared<pcl::PointCloud<PointT>>();
  const auto add = [&](float y, std::uint8_t r, std::uint8_t g, std::uint8_t b) {
    PointT p;
    p.x = 2.05f;
    p.y = y;
    p.z = 0.05f;
    p.r = r;
    p.g = g;
    p.b = b;
    c->push_back(p);
  };
  add(0.02f, 10, 100, 0);
  add(0.05f, 20, 100, 1);
  add(0.08f, 31, 100, 1);
  add(0.12f, 200, 50, 255);
  add(0.18f, 201, 50, 255);
  c->sensor_origin_ = Eigen::Vector4f(0.05f, 0.05f, 0.05f, 0.0f);
  iwlomap::OccupancyFilter<PointT> f;
  EXPECT_TRUE(f.getColorMeans());
  f.setResolution(0.1);
  f.setInputCloud(c);
  pcl::PointCloud<PointT> out;
  f.filter(out);
  ASSERT_EQ(out.size(), 2u);
  for (const auto& p : out) {
    if (p.y < 0.1f)
      EXPECT_EQ(std::make_tuple(int{p.r}, int{p.g}, int{p.b}), std::make_tuple(20, 100, 1));
    else
      EXPECT_EQ(std::make_tuple(int{p.r}, int{p.g}, int{p.b}), std::make_tuple(201, 50, 255));
  }
  ASSERT_NE(f.getVoxelColors(), nullptr);
  EXPECT_EQ(f.getVoxelColors()->hits(Eigen::Vector3d(2.05, 0.05, 0.05)), 3u);
  // A second frame adds to the running mean: (10 + 20 + 31 + 255) / 4 = 79 in r.
  auto more = pcl::make_shared<pcl::PointCloud<PointT>>();
  more->push_back(c->front());
  (*more)[0].r = 255;
  more->sensor_origin_ = c->sensor_origin_;
  f.setInputCloud(more);
  f.setOutputMeanPositions(true);  // the mean position lies in the same voxel: same colour
  f.filter(out);
  for (const auto& p : out)
    if (p.y < 0.1f) {
      EXPECT_EQ(int{p.r}, 79);
    }
  // Off: the colours are forgotten and the output is black.
  f.setColorMeans(false);
  EXPECT_EQ(f.getVoxelColors(), nullptr);
  f.filter(out);
  ASSERT_EQ(out.size(), 2u);
  for (const auto& p : out) EXPECT_EQ(std::make_tuple(int{p.r}, int{p.g}, int{p.b}), std::make_tuple(0, 0, 0));
}

TEST(OccupancyFilter, ColourTypesOutputTheMeanColourOfEachVoxel) {
  expect_colour_means<pcl::PointXYZRGB>();
  expect_colour_means<pcl::PointXYZRGBA>();
  Filter grey;
  EXPECT_FALSE(grey.getColorMeans());
  EXPECT_THROW(grey.setColorMeans(true), std::invalid_argument);
  grey.setColorMeans(false);
}

// A colour hit is counted where the map counts a hit: below the intensity threshold (a type with
// intensity has none here, so the preset's threshold decides) and beyond the range, no colour.
TEST(OccupancyFilter, ColourMeansFollowTheMapsHits) {
  auto c = pcl::make_shared<pcl::PointCloud<pcl::PointXYZRGB>>();
  for (int i = 0; i < 50; ++i) {
    pcl::PointXYZRGB p;
    p.x = 2.05f + 0.1f * static_cast<float>(i % 5);  // one point per voxel
    p.y = 0.01f + 0.02f * static_cast<float>(i);
    p.z = 0.05f;
    p.r = static_cast<std::uint8_t>(5 * i);
    c->push_back(p);
  }
  c->sensor_origin_ = Eigen::Vector4f(0.0f, 0.0f, 0.05f, 0.0f);
  iwlomap::OccupancyFilter<pcl::PointXYZRGB> f;
  f.setResolution(0.1);
  f.setMaxRange(2.25);
  f.setInputCloud(c);
  pcl::PointCloud<pcl::PointXYZRGB> out;
  f.filter(out);
  const auto colors = f.getVoxelColors();
  ASSERT_NE(colors, nullptr);
  std::size_t coloured = 0;
  for (const auto& p : *c) {
    const Eigen::Vector3d q(p.x, p.y, p.z);
    const bool within = (q - Eigen::Vector3d(0, 0, 0.05)).norm() <= 2.25;
    EXPECT_EQ(colors->mean(q).has_value(), within) << q.transpose();
    coloured += within ? 1 : 0;
  }
  EXPECT_GT(coloured, 10u);
  EXPECT_GT(out.size(), 5u);
}

// The wall at x = 2 m sits on a voxel boundary at 0.15 m (x key 13 covers [1.95, 2.1)): centres
// are 0.025 m off, mean hit positions are on the wall.
TEST(OccupancyFilter, MeanPositionsPutVoxelsAtTheirMeanHit) {
  auto in = make_wall_scan(200.0f, 2000);
  Filter f;
  f.setResolution(0.15);
  f.setInputCloud(in);
  EXPECT_FALSE(f.getOutputMeanPositions());
  Cloud centres, means;
  f.filter(centres);
  EXPECT_FALSE(f.getMap()->get_hit_accumulation());
  f.getMap()->clear();
  f.setOutputMeanPositions(true);
  f.filter(means);
  EXPECT_TRUE(f.getMap()->get_hit_accumulation());
  ASSERT_EQ(means.size(), centres.size());
  ASSERT_GT(means.size(), 10u);
  for (std::size_t i = 0; i < means.size(); ++i) {
    EXPECT_NEAR(centres[i].x, 2.025f, 1e-5f);
    EXPECT_NEAR(means[i].x, 2.0f, 1e-5f);
    EXPECT_EQ(means[i].intensity, centres[i].intensity);
  }
}

}  // namespace
