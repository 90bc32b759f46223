// SPDX-License-Identifier: BSD-3-Clause
// OccupancyFilter: the PCL filter contract, indices, accumulation over frames, ray casting and
// its range limit, use inside a PCL pipeline, the setters, and the backends it maps into.

#include <Eigen/Geometry>
#include <iwlomap/filters/occupancy_filter.h>
#include <iwlomap/probability_updater.h>

#include "occupancy_filter_test_support.h"
#include "reference_api_double.h"

#include <gtest/gtest.h>
#include <pcl/filters/passthrough.h>
#include <pcl/filters/voxel_grid.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <stdexcept>
#include <tuple>
#include <vector>

namespace {

using iwlomap::filter_test::Cloud;
using iwlomap::filter_test::Filter;
using iwlomap::filter_test::make_wall_scan;
using iwlomap::filter_test::keys_of;

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
  const std::size_t known = f.getMap()->get_num_known_voxels();
  Cloud::Ptr empty(new Cloud);
  f.setInputCloud(empty);
  Cloud second;
  f.filter(second);
  EXPECT_EQ(keys_of(second, 0.1), keys_of(first, 0.1));
  EXPECT_EQ(f.getMap()->get_num_known_voxels(), known);
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
  EXPECT_EQ(with_indices.getMap()->get_num_known_voxels(), reference.getMap()->get_num_known_voxels());
  Filter all;
  all.setResolution(0.1);
  all.setInputCloud(in);
  Cloud c;
  all.filter(c);
  EXPECT_LT(with_indices.getMap()->get_num_known_voxels(), all.getMap()->get_num_known_voxels() + 1);
}

// Successive frames build one map: the same as feeding the scans to a backend directly, with
// either ray model.
TEST(OccupancyFilter, SuccessiveFramesBuildOneMapWithEitherRayModel) {
  auto first = make_wall_scan(200.0f, 200, 1);
  auto second = make_wall_scan(200.0f, 200, 2);
  for (auto& p : *second) p.x = -2.0f;  // a second wall behind the sensor
  std::size_t known[2] = {0, 0};
  for (const iwlomap::RayModel model : {iwlomap::RayModel::kExact, iwlomap::RayModel::kFast}) {
    Filter f;
    EXPECT_EQ(f.getRayModel(), iwlomap::RayModel::kExact);
    f.setResolution(0.1);
    f.setRayModel(model);
    EXPECT_EQ(f.getRayModel(), model);
    f.setInputCloud(first);
    Cloud out1, out2;
    f.filter(out1);
    f.setInputCloud(second);
    f.filter(out2);
    EXPECT_GT(out2.size(), out1.size());
    EXPECT_EQ(f.getMap()->get_ray_model(), model);
    iwlomap::ProbabilityUpdater direct(0.1);
    direct.set_ray_model(model);
    for (const auto& c : {first, second}) {
      Eigen::MatrixXd pts(static_cast<Eigen::Index>(c->size()), 3);
      Eigen::VectorXd inten(static_cast<Eigen::Index>(c->size()));
      for (std::size_t i = 0; i < c->size(); ++i) {
        pts.row(static_cast<Eigen::Index>(i)) << (*c)[i].x, (*c)[i].y, (*c)[i].z;
        inten[static_cast<Eigen::Index>(i)] = (*c)[i].intensity;
      }
      direct.insert_scan(c->sensor_origin_.head<3>().cast<double>(), pts, inten);
    }
    EXPECT_EQ(direct.get_num_known_voxels(), f.getMap()->get_num_known_voxels());
    EXPECT_EQ(direct.get_occupied_voxels(0.7).rows(), static_cast<Eigen::Index>(out2.size()));
    known[model == iwlomap::RayModel::kFast ? 1 : 0] = direct.get_num_known_voxels();
  }
  EXPECT_LT(known[1], known[0]);  // the line marks fewer voxels free than the exact walk
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
  EXPECT_EQ(f.getMap()->get_num_known_voxels(), 20u);  // no rays: only the points' own voxels
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
  EXPECT_GT(f.getMap()->get_num_known_voxels(), 0u);
  EXPECT_FALSE(f.getMap()->query(Eigen::Vector3d(1.5, 0.05, 0.05)).has_value());
}

}  // namespace
