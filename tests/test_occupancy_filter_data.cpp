// SPDX-License-Identifier: BSD-3-Clause
// OccupancyFilter on the recorded data (skipped when it is absent): the Ouster lidar frames give
// a ground plane, the tool's map through the lidar preset and the same map for any thread count;
// the Oculus sonar pings without rays occupy their strong echoes.

#include <Eigen/Geometry>
#include <iwlomap/filters/occupancy_filter.h>
#include <iwlomap/filters/pointcloud2.h>

#include "occupancy_filter_test_support.h"

#include <gtest/gtest.h>
#include <unistd.h>
#include <pcl/conversions.h>
#include <pcl/io/pcd_io.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <map>
#include <stdexcept>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

namespace {

using iwlomap::filter_test::Cloud;
using iwlomap::filter_test::Filter;
using iwlomap::filter_test::keys_of;
using iwlomap::filter_test::KeySet;

// ---- recorded data ----

std::filesystem::path data_dir() { return IWLOMAP_SHARED_DATA_DIR; }

Cloud::Ptr load_or_skip(const std::filesystem::path& path) {
  Cloud::Ptr c(new Cloud);
  if (!std::filesystem::exists(path)) return nullptr;
  if (pcl::io::loadPCDFile(path.string(), *c) < 0) throw std::runtime_error("cannot read " + path.string());
  return c;
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
  const std::size_t known = map->get_num_known_voxels();
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
