// SPDX-License-Identifier: BSD-3-Clause
// OccupancyFilter: the PCL filter contract, accumulation over frames, use inside a PCL pipeline,
// and integration on the recorded lidar and sonar data.

#include <Eigen/Geometry>
#include <iwlomap/filters/occupancy_filter.h>
#include <iwlomap/filters/pointcloud2.h>
#include <iwlomap/probability_updater.h>

#include "reference_api_double.h"

#include <gtest/gtest.h>
#include <unistd.h>
#include <pcl/console/print.h>
#include <pcl/conversions.h>
#include <pcl/filters/passthrough.h>
#include <pcl/filters/voxel_grid.h>
#include <pcl/io/pcd_io.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <limits>
#include <map>
#include <random>
#include <set>
#include <tuple>
#include <utility>
#include <vector>

namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZI>;
using Filter = iwlomap::OccupancyFilter<pcl::PointXYZI>;

// A small scene seen from (0.05, 0.05, 0.05): a wall at x = 2 m, hit by a fan of rays.
Cloud::Ptr make_wall_scan(float intensity = 200.0f, int n = 200, std::uint32_t seed = 7) {
  Cloud::Ptr c(new Cloud);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-0.5f, 0.5f);
  for (int i = 0; i < n; ++i) {
    pcl::PointXYZI p;
    p.x = 2.0f;
    p.y = u(rng);
    p.z = u(rng);
    p.intensity = intensity;
    c->push_back(p);
  }
  c->sensor_origin_ = Eigen::Vector4f(0.05f, 0.05f, 0.05f, 0.0f);
  c->sensor_orientation_ = Eigen::Quaternionf(Eigen::AngleAxisf(0.3f, Eigen::Vector3f::UnitZ()));
  c->header.frame_id = "map";
  c->header.stamp = 123456;
  c->header.seq = 42;
  return c;
}

using KeySet = std::set<std::tuple<long, long, long>>;
KeySet keys_of(const Cloud& c, double resolution) {
  KeySet s;
  for (const auto& p : c)
    s.emplace(std::lround(std::floor(p.x / resolution)), std::lround(std::floor(p.y / resolution)),
              std::lround(std::floor(p.z / resolution)));
  return s;
}

TEST(OccupancyFilter, OutputFollowsThePointCloudContract) {
  auto in = make_wall_scan();
  Filter f;
  f.setResolution(0.1);
  f.setInputCloud(in);
  Cloud out;
  f.filter(out);
  ASSERT_GT(out.size(), 0u);
  EXPECT_EQ(out.width, out.size());
  EXPECT_EQ(out.height, 1u);
  EXPECT_TRUE(out.is_dense);
  EXPECT_EQ(out.header.frame_id, "map");
  EXPECT_EQ(out.header.stamp, 123456u);
  EXPECT_EQ(out.header.seq, 42u);
  EXPECT_TRUE(out.sensor_origin_.isApprox(in->sensor_origin_));
  EXPECT_TRUE(out.sensor_orientation_.coeffs().isApprox(in->sensor_orientation_.coeffs()));
  // Output = the map's occupied voxels above the threshold, centres, intensity = probability.
  const Eigen::MatrixXd occ = f.getMap()->get_occupied_voxels(f.getOccupiedThreshold());
  ASSERT_EQ(static_cast<Eigen::Index>(out.size()), occ.rows());
  for (const auto& p : out) {
    EXPECT_GT(p.intensity, 0.7f);
    EXPECT_LE(p.intensity, 1.0f);
    EXPECT_NEAR(p.x, 2.05f, 1e-5);  // voxel centre of the wall's voxel column at 0.1 m
  }
}

TEST(OccupancyFilter, RaysFromTheSensorOriginMarkFreeSpace) {
  Filter f;
  f.setResolution(0.1);
  f.setInputCloud(make_wall_scan());
  Cloud out;
  f.filter(out);
  const auto map = f.getMap();
  const auto between = map->query(Eigen::Vector3d(1.0, 0.05, 0.05));
  ASSERT_TRUE(between.has_value());
  EXPECT_LT(between->probability, 0.5);
  EXPECT_FALSE(map->query(Eigen::Vector3d(-1.0, 0.05, 0.05)).has_value());  // behind the sensor
}

TEST(OccupancyFilter, InPlaceFilteringGivesTheSameResult) {
  auto in = make_wall_scan();
  Filter a, b;
  a.setResolution(0.1);
  b.setResolution(0.1);
  a.setInputCloud(in);
  Cloud expected;
  a.filter(expected);
  auto cloud = make_wall_scan();
  b.setInputCloud(cloud);
  b.filter(*cloud);
  ASSERT_EQ(cloud->size(), expected.size());
  EXPECT_EQ(keys_of(*cloud, 0.1), keys_of(expected, 0.1));
  EXPECT_EQ(cloud->header.frame_id, "map");
  EXPECT_EQ(cloud->height, 1u);
}

TEST(OccupancyFilter, EmptyInputReturnsTheCurrentMap) {
  Filter f;
  f.setResolution(0.1);
  f.setInputCloud(make_wall_scan());
  Cloud first;
  f.filter(first);
  const std::size_t known = f.getMap()->get_num_nodes();
  Cloud::Ptr empty(new Cloud);
  f.setInputCloud(empty);
  Cloud second;
  f.filter(second);
  EXPECT_EQ(keys_of(second, 0.1), keys_of(first, 0.1));
  EXPECT_EQ(f.getMap()->get_num_nodes(), known);
}

TEST(OccupancyFilter, NoInputLeavesTheOutputUntouched) {
  Filter f;
  Cloud out;
  out.push_back(pcl::PointXYZI(1.0f));
  f.filter(out);  // PCL reports "no input" and returns
  EXPECT_EQ(out.size(), 1u);
}

TEST(OccupancyFilter, NonFinitePointsAreSkippedAndCounted) {
  auto in = make_wall_scan();
  pcl::PointXYZI bad;
  bad.x = std::numeric_limits<float>::quiet_NaN();
  bad.y = bad.z = 0.0f;
  bad.intensity = 100.0f;
  in->push_back(bad);
  pcl::PointXYZI inf_point = bad;
  inf_point.x = 1.0f;
  inf_point.z = std::numeric_limits<float>::infinity();
  in->push_back(inf_point);
  in->is_dense = false;
  Filter f;
  f.setResolution(0.1);
  f.setInputCloud(in);
  Cloud out;
  f.filter(out);
  EXPECT_EQ(f.getMap()->get_num_skipped_points(), 2u);
  EXPECT_TRUE(out.is_dense);
  for (const auto& p : out) EXPECT_TRUE(std::isfinite(p.x) && std::isfinite(p.y) && std::isfinite(p.z));
}

TEST(OccupancyFilter, IndicesSelectThePointsIntegrated) {
  auto in = make_wall_scan();
  pcl::IndicesPtr indices(new pcl::Indices);
  Cloud::Ptr subset(new Cloud);
  subset->sensor_origin_ = in->sensor_origin_;
  for (int i = 0; i < static_cast<int>(in->size()); i += 3) {
    indices->push_back(i);
    subset->push_back((*in)[static_cast<std::size_t>(i)]);
  }
  Filter with_indices, reference;
  with_indices.setResolution(0.1);
  reference.setResolution(0.1);
  with_indices.setInputCloud(in);
  with_indices.setIndices(indices);
  reference.setInputCloud(subset);
  Cloud a, b;
  with_indices.filter(a);
  reference.filter(b);
  EXPECT_EQ(keys_of(a, 0.1), keys_of(b, 0.1));
  EXPECT_EQ(with_indices.getMap()->get_num_nodes(), reference.getMap()->get_num_nodes());
  Filter all;
  all.setResolution(0.1);
  all.setInputCloud(in);
  Cloud c;
  all.filter(c);
  EXPECT_LT(with_indices.getMap()->get_num_nodes(), all.getMap()->get_num_nodes() + 1);
}

TEST(OccupancyFilter, SuccessiveFramesBuildOneMap) {
  auto first = make_wall_scan(200.0f, 200, 1);
  auto second = make_wall_scan(200.0f, 200, 2);
  for (auto& p : *second) p.x = -2.0f;  // a second wall behind the sensor
  Filter f;
  f.setResolution(0.1);
  f.setInputCloud(first);
  Cloud out1, out2;
  f.filter(out1);
  f.setInputCloud(second);
  f.filter(out2);
  EXPECT_GT(out2.size(), out1.size());
  // The same as feeding both scans to a backend directly.
  iwlomap::ProbabilityUpdater direct(0.1);
  for (const auto& c : {first, second}) {
    Eigen::MatrixXd pts(static_cast<Eigen::Index>(c->size()), 3);
    Eigen::VectorXd inten(static_cast<Eigen::Index>(c->size()));
    for (std::size_t i = 0; i < c->size(); ++i) {
      pts.row(static_cast<Eigen::Index>(i)) << (*c)[i].x, (*c)[i].y, (*c)[i].z;
      inten[static_cast<Eigen::Index>(i)] = (*c)[i].intensity;
    }
    direct.insert_scan(c->sensor_origin_.head<3>().cast<double>(), pts, inten);
  }
  EXPECT_EQ(direct.get_num_nodes(), f.getMap()->get_num_nodes());
  EXPECT_EQ(direct.get_occupied_voxels(0.7).rows(), static_cast<Eigen::Index>(out2.size()));
}

TEST(OccupancyFilter, WithoutRayCastingIntensityDecidesOccupancy) {
  Cloud::Ptr in(new Cloud);
  for (int i = 0; i < 10; ++i) {
    pcl::PointXYZI strong;
    strong.x = 1.0f + 0.2f * static_cast<float>(i);
    strong.y = 0.0f;
    strong.z = 0.0f;
    strong.intensity = 250.0f;
    in->push_back(strong);
    pcl::PointXYZI weak = strong;
    weak.y = 1.0f;
    weak.intensity = 20.0f;  // at or below the threshold 35: free evidence
    in->push_back(weak);
  }
  Filter f;
  f.setResolution(0.1);
  f.setRayCasting(false);
  EXPECT_FALSE(f.getRayCasting());
  f.setOccupiedThreshold(0.5);
  f.setInputCloud(in);
  Cloud out;
  f.filter(out);
  EXPECT_EQ(out.size(), 10u);
  for (const auto& p : out) EXPECT_NEAR(p.y, 0.05f, 1e-5);
  EXPECT_EQ(f.getMap()->get_num_nodes(), 20u);  // no rays: only the points' own voxels
}

TEST(OccupancyFilter, PointXYZCountsEveryPointAsAFullHit) {
  pcl::PointCloud<pcl::PointXYZ>::Ptr in(new pcl::PointCloud<pcl::PointXYZ>);
  in->push_back(pcl::PointXYZ(1.0f, 0.0f, 0.0f));
  in->push_back(pcl::PointXYZ(0.0f, 1.0f, 0.0f));
  iwlomap::OccupancyFilter<pcl::PointXYZ> f;
  f.setResolution(0.1);
  f.setInputCloud(in);
  pcl::PointCloud<pcl::PointXYZ> out;
  f.filter(out);
  EXPECT_EQ(out.size(), 2u);
  const auto state = f.getMap()->query(Eigen::Vector3d(1.0, 0.0, 0.0));
  ASSERT_TRUE(state.has_value());
  // First observation at I = I_max: L = L_occ * w(u = 1) = 3.5 / (1 + exp(-0.05)).
  EXPECT_NEAR(state->log_odds, 3.5 / (1.0 + std::exp(-0.05)), 1e-6);
}

TEST(OccupancyFilter, PointXYZINormalIsInstantiated) {
  pcl::PointCloud<pcl::PointXYZINormal>::Ptr in(new pcl::PointCloud<pcl::PointXYZINormal>);
  pcl::PointXYZINormal p;
  p.x = 1.0f;
  p.y = p.z = 0.0f;
  p.intensity = 255.0f;
  in->push_back(p);
  iwlomap::OccupancyFilter<pcl::PointXYZINormal> f;
  f.setResolution(0.1);
  f.setInputCloud(in);
  pcl::PointCloud<pcl::PointXYZINormal> out;
  f.filter(out);
  ASSERT_EQ(out.size(), 1u);
  // One full-weight hit: p = 1 / (1 + exp(-L)) with L = 3.5 / (1 + exp(-0.05)) = 1.7937.
  EXPECT_NEAR(out[0].intensity, 1.0 / (1.0 + std::exp(-3.5 / (1.0 + std::exp(-0.05)))), 1e-6);
}

TEST(OccupancyFilter, WorksInsideAPclPipeline) {
  auto in = make_wall_scan(200.0f, 2000);
  pcl::PointXYZI far_point;
  far_point.x = 50.0f;
  far_point.y = far_point.z = 0.0f;
  far_point.intensity = 200.0f;
  in->push_back(far_point);
  Cloud::Ptr cropped(new Cloud);
  pcl::PassThrough<pcl::PointXYZI> pass;
  pass.setInputCloud(in);
  pass.setFilterFieldName("x");
  pass.setFilterLimits(-10.0f, 10.0f);
  pass.filter(*cropped);
  ASSERT_EQ(cropped->size(), 2000u);
  EXPECT_TRUE(cropped->sensor_origin_.isApprox(in->sensor_origin_));

  Cloud::Ptr occupied(new Cloud);
  Filter occ;
  occ.setResolution(0.05);
  occ.setInputCloud(cropped);
  occ.filter(*occupied);
  ASSERT_GT(occupied->size(), 100u);

  Cloud down;
  pcl::VoxelGrid<pcl::PointXYZI> grid;
  grid.setInputCloud(occupied);
  grid.setLeafSize(0.2f, 0.2f, 0.2f);
  grid.filter(down);
  EXPECT_GT(down.size(), 10u);
  EXPECT_LT(down.size(), occupied->size());
  for (const auto& p : down) EXPECT_NEAR(p.x, 2.0f, 0.1f);
}

TEST(OccupancyFilter, SettersValidateAndGettersMatch) {
  Filter f;
  EXPECT_DOUBLE_EQ(f.getResolution(), 0.05);
  EXPECT_DOUBLE_EQ(f.getOccupiedThreshold(), 0.7);
  EXPECT_DOUBLE_EQ(f.getMaxRange(), -1.0);
  EXPECT_TRUE(f.getRayCasting());
  EXPECT_THROW(f.setResolution(0.0), std::invalid_argument);
  EXPECT_THROW(f.setResolution(std::nan("")), std::invalid_argument);
  EXPECT_THROW(f.setOccupiedThreshold(1.0), std::invalid_argument);
  EXPECT_THROW(f.setMaxRange(std::nan("")), std::invalid_argument);
  EXPECT_THROW(f.setBackend(nullptr), std::invalid_argument);
  iwlomap::IwloParams bad;
  bad.min_alpha = 0.0;
  EXPECT_THROW(f.setIwloParams(bad), std::invalid_argument);
  EXPECT_DOUBLE_EQ(f.getIwloParams().min_alpha, 0.3);
  f.setResolution(0.2);
  f.setMaxRange(30.0);
  EXPECT_DOUBLE_EQ(f.getResolution(), 0.2);
  EXPECT_DOUBLE_EQ(f.getMaxRange(), 30.0);
  EXPECT_DOUBLE_EQ(f.getMap()->get_resolution(), 0.2);
  EXPECT_THROW(f.setResolution(0.1), std::logic_error);
}

TEST(OccupancyFilter, UsesAGivenBackendAndAppliesParameters) {
  auto backend = std::make_shared<iwlomap::ProbabilityUpdater>(0.25);
  Filter f;
  f.setBackend(backend);
  EXPECT_DOUBLE_EQ(f.getResolution(), 0.25);
  iwlomap::IwloParams p;
  p.intensity_threshold = 0.0;
  f.setIwloParams(p);
  auto in = make_wall_scan(10.0f);  // weak returns: hits only with threshold 0
  f.setInputCloud(in);
  Cloud out;
  f.filter(out);
  EXPECT_EQ(f.getMap().get(), backend.get());
  EXPECT_DOUBLE_EQ(backend->get_params().intensity_threshold, 0.0);
  EXPECT_GT(out.size(), 0u);
}

// A backend of the reference API alone (only the required methods) works in the filter through
// IMapperBackend's defaults, and gives the RAM backend's output.
TEST(OccupancyFilter, WorksWithABackendOfTheReferenceApiAlone) {
  Filter with_double, with_ram;
  with_double.setBackend(std::make_shared<iwlomap::test_support::ReferenceApiDouble>(0.1));
  with_ram.setResolution(0.1);
  Cloud a, b;
  for (std::uint32_t seed : {7u, 8u}) {
    auto in = make_wall_scan(150.0f, 300, seed);
    with_double.setInputCloud(in);
    with_double.filter(a);
    with_ram.setInputCloud(in);
    with_ram.filter(b);
  }
  ASSERT_GT(b.size(), 10u);
  ASSERT_EQ(a.size(), b.size());
  const auto sorted = [](const Cloud& c) {
    std::vector<std::tuple<float, float, float, float>> v;
    for (const auto& p : c) v.emplace_back(p.x, p.y, p.z, p.intensity);
    std::sort(v.begin(), v.end());
    return v;
  };
  EXPECT_EQ(sorted(a), sorted(b));
}

TEST(OccupancyFilter, MaxRangeClipsRaysAndDropsTheirHits) {
  Filter f;
  f.setResolution(0.1);
  f.setMaxRange(1.0);
  f.setInputCloud(make_wall_scan());
  Cloud out;
  f.filter(out);
  EXPECT_EQ(out.size(), 0u);
  EXPECT_GT(f.getMap()->get_num_nodes(), 0u);
  EXPECT_FALSE(f.getMap()->query(Eigen::Vector3d(1.5, 0.05, 0.05)).has_value());
}

// ---- recorded data ----

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

std::filesystem::path data_dir() { return IWLOMAP_SHARED_DATA_DIR; }

Cloud::Ptr load_or_skip(const std::filesystem::path& path) {
  Cloud::Ptr c(new Cloud);
  if (!std::filesystem::exists(path)) return nullptr;
  if (pcl::io::loadPCDFile(path.string(), *c) < 0) throw std::runtime_error("cannot read " + path.string());
  return c;
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

TEST(OccupancyFilterData, OusterFramesGiveAGroundPlaneBelowTheSensor) {
  const auto dir = data_dir() / "ouster_os1_128_3frames";
  if (!std::filesystem::exists(dir)) GTEST_SKIP() << "recorded data not found at " << dir << "; test skipped";
  Filter f;
  f.setResolution(0.2);
  f.setMaxRange(60.0);
  iwlomap::IwloParams lidar;
  lidar.intensity_threshold = 0.0;  // every return with a positive intensity is a hit
  f.setIwloParams(lidar);
  Cloud out;
  Eigen::Vector3f first_origin = Eigen::Vector3f::Zero();
  for (int k = 0; k < 3; ++k) {
    auto frame = load_or_skip(dir / ("frame_00" + std::to_string(k) + "_world.pcd"));
    ASSERT_TRUE(frame) << "frame " << k << " missing";
    if (k == 0) first_origin = frame->sensor_origin_.head<3>();
    f.setInputCloud(frame);
    f.filter(out);
  }
  const auto map = f.getMap();
  const std::size_t known = map->get_num_nodes();
  const std::size_t occupied = out.size();
  std::cout << "[ ouster ] 3 frames at 0.2 m: " << known << " known voxels, " << occupied << " occupied, "
            << known - occupied << " not occupied\n";
  RecordProperty("known_voxels", std::to_string(known));
  RecordProperty("occupied_voxels", std::to_string(occupied));
  EXPECT_GT(occupied, 20000u);
  EXPECT_GT(known, 20 * occupied);  // rays clear far more space than surfaces occupy

  // The most populated 0.2 m height slab of occupied voxels is the road, 1.3-2.5 m below the sensor.
  std::map<long, std::size_t> slabs;
  for (const auto& p : out) ++slabs[std::lround(std::floor(p.z / 0.2))];
  const auto ground = std::max_element(slabs.begin(), slabs.end(),
                                       [](const auto& a, const auto& b) { return a.second < b.second; });
  const double ground_z = (static_cast<double>(ground->first) + 0.5) * 0.2;
  std::cout << "[ ouster ] ground slab at z = " << ground_z << " m with " << ground->second << " voxels\n";
  EXPECT_GT(ground_z, first_origin.z() - 2.5);
  EXPECT_LT(ground_z, first_origin.z() - 1.3);
  EXPECT_GT(ground->second, occupied / 20);
  // Just above the road, under the sensor, the space is free.
  const auto above_road = map->query(first_origin.cast<double>() + Eigen::Vector3d(3.0, 0.0, -0.5));
  ASSERT_TRUE(above_road.has_value());
  EXPECT_LT(above_road->probability, 0.5);
}

// The lidar preset through the filter gives the map `iwlomap map --sensor lidar` gives: the same
// occupied voxels with the same probabilities, on the three Ouster frames at 0.2 m.
#ifdef IWLOMAP_TOOL_BINARY
TEST(OccupancyFilterData, OusterFramesThroughTheLidarPresetMatchTheTool) {
  const auto dir = data_dir() / "ouster_os1_128_3frames";
  if (!std::filesystem::exists(dir)) GTEST_SKIP() << "recorded data not found at " << dir << "; test skipped";
  std::vector<std::string> files;
  for (int k = 0; k < 3; ++k) files.push_back((dir / ("frame_00" + std::to_string(k) + "_world.pcd")).string());
  const std::string tool_out =
      (std::filesystem::temp_directory_path() / ("iwlomap_filter_vs_tool_" + std::to_string(::getpid()) + ".pcd")).string();
  std::string command = std::string("'") + IWLOMAP_TOOL_BINARY + "' map --sensor lidar --resolution 0.2 -q -o '" + tool_out + "'";
  for (const std::string& f : files) command += " '" + f + "'";
  ASSERT_EQ(std::system(command.c_str()), 0) << command;
  Cloud from_tool;
  ASSERT_EQ(pcl::io::loadPCDFile(tool_out, from_tool), 0);
  std::filesystem::remove(tool_out);

  Filter f;
  f.setResolution(0.2);
  f.setSensorPreset(iwlomap::SensorPreset::kLidar);
  Cloud from_filter;
  for (const std::string& file : files) {
    pcl::PCLPointCloud2 blob;
    Eigen::Vector4f origin;
    Eigen::Quaternionf orientation;
    ASSERT_EQ(pcl::io::loadPCDFile(file, blob, origin, orientation), 0);
    auto frame = pcl::make_shared<Cloud>();
    iwlomap::pointcloud2_to_xyzi(blob, *frame);
    frame->sensor_origin_ = origin;
    f.setInputCloud(frame);
    f.filter(from_filter);
  }
  const auto rows = [](const Cloud& c) {
    std::vector<std::array<float, 4>> r;
    for (const auto& p : c) r.push_back({p.x, p.y, p.z, p.intensity});
    std::sort(r.begin(), r.end());
    return r;
  };
  std::cout << "[ ouster ] lidar preset, 3 frames at 0.2 m: " << from_filter.size() << " occupied voxels (filter), "
            << from_tool.size() << " (tool)\n";
  ASSERT_GT(from_filter.size(), 40000u);
  EXPECT_EQ(rows(from_filter), rows(from_tool));
}
#endif

TEST(OccupancyFilterData, OusterFramesGiveBitIdenticalMapsForAnyThreadCount) {
  const auto dir = data_dir() / "ouster_os1_128_3frames";
  if (!std::filesystem::exists(dir)) GTEST_SKIP() << "recorded data not found at " << dir << "; test skipped";
  std::vector<Cloud::Ptr> frames;
  for (int k = 0; k < 3; ++k) frames.push_back(load_or_skip(dir / ("frame_00" + std::to_string(k) + "_world.pcd")));
  using State = std::vector<std::tuple<iwlomap::VoxelKey, double, std::uint32_t>>;
  State reference;
  for (int threads : {1, 2, 3, 8}) {
    Filter f;
    f.setResolution(0.25);
    f.setMaxRange(40.0);
    f.setNumThreads(threads);
    EXPECT_EQ(f.getNumThreads(), threads);
    Cloud out;
    for (const auto& frame : frames) {
      ASSERT_TRUE(frame);
      f.setInputCloud(frame);
      f.filter(out);
    }
    EXPECT_EQ(f.getMap()->get_num_threads(), threads);
    State state;
    f.getMap()->for_each_voxel([&](const iwlomap::VoxelKey& k, const iwlomap::VoxelState& v) {
      state.emplace_back(k, v.log_odds, v.count);
    });
    if (threads == 1) {
      reference = std::move(state);
      ASSERT_GT(reference.size(), 100000u);
      continue;
    }
    ASSERT_EQ(state.size(), reference.size()) << threads << " threads";
    EXPECT_TRUE(state == reference) << threads << " threads give a different map";
  }
  Filter f;
  EXPECT_THROW(f.setNumThreads(-2), std::invalid_argument);
}

TEST(OccupancyFilterData, OculusPingsWithoutRaysOccupyStrongEchoes) {
  const auto path = data_dir() / "oculus_sonar_3pings" / "ping_000_fan.pcd";
  auto ping = load_or_skip(path);
  if (!ping) GTEST_SKIP() << "recorded data not found at " << path << "; test skipped";
  ASSERT_EQ(ping->width, 256u);
  ASSERT_EQ(ping->height, 703u);
  const double res = 0.01;
  Filter f;
  f.setResolution(res);
  f.setRayCasting(false);
  f.setOccupiedThreshold(0.5);
  f.setInputCloud(ping);
  Cloud out;
  f.filter(out);
  // Per voxel: the strongest echo that fell in it.
  std::map<std::tuple<long, long, long>, float> strongest;
  for (const auto& p : *ping) {
    auto& s = strongest[{std::lround(std::floor(p.x / res)), std::lround(std::floor(p.y / res)),
                         std::lround(std::floor(p.z / res))}];
    s = std::max(s, p.intensity);
  }
  std::size_t strong_voxels = 0, strong_occupied = 0;
  const KeySet occ = keys_of(out, res);
  for (const auto& [key, intensity] : strongest) {
    if (intensity < 150.0f) continue;
    ++strong_voxels;
    strong_occupied += occ.count(key);
  }
  for (const auto& key : occ) {
    ASSERT_GT(strongest.at(key), 35.0f) << "an occupied voxel holds no echo above the threshold";
  }
  std::cout << "[ oculus ] ping 0 at 1 cm: " << occ.size() << " occupied voxels; " << strong_occupied << " of "
            << strong_voxels << " voxels with an echo >= 150 are occupied\n";
  ASSERT_GT(strong_voxels, 100u);
  EXPECT_GT(static_cast<double>(strong_occupied), 0.95 * static_cast<double>(strong_voxels));
}

}  // namespace
