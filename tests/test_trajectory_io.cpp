// SPDX-License-Identifier: BSD-3-Clause
// Trajectory files: TUM and KITTI written and read back, the format by extension, errors.

#include "iwlomap/trajectory_io.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <stdexcept>
#include <vector>

namespace iwlomap {
namespace {

Eigen::Isometry3d pose(double x, double y, double yaw) {
  Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
  p.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  p.translation() = Eigen::Vector3d(x, y, 0.0);
  return p;
}

TEST(TrajectoryIo, TumAndKittiFilesRoundTrip) {
  const std::vector<Eigen::Isometry3d> p = {pose(1, 2, 0.3), pose(-4, 5.5, -1.2)};
  const auto dir = std::filesystem::temp_directory_path();
  for (const char* name : {"iwlomap_test_poses.tum", "iwlomap_test_poses.kitti"}) {
    const std::string path = (dir / name).string();
    const TrajectoryFormat f = trajectory_format_of(path);
    write_trajectory(path, p, {}, f);
    const std::vector<Eigen::Isometry3d> back = read_trajectory(path, f);
    ASSERT_EQ(back.size(), 2u);
    for (std::size_t i = 0; i < 2; ++i) EXPECT_TRUE(back[i].isApprox(p[i], 1e-8)) << name;
    std::filesystem::remove(path);
  }
  EXPECT_EQ(trajectory_format_of("a.kitti"), TrajectoryFormat::kKitti);
  EXPECT_EQ(trajectory_format_of("a.txt"), TrajectoryFormat::kTum);
  EXPECT_THROW(write_trajectory("/nonexistent-dir/x.tum", p, {}, TrajectoryFormat::kTum), std::runtime_error);
  EXPECT_THROW(write_trajectory((dir / "x.tum").string(), p, {1.0}, TrajectoryFormat::kTum), std::invalid_argument);
}

TEST(TrajectoryIo, AMalformedLineNamesTheFileAndLine) {
  const std::string path = (std::filesystem::temp_directory_path() / "iwlomap_test_bad.tum").string();
  {
    std::ofstream f(path);
    f << "0 1 2 3 0 0 0 1\n1 2 3\n";
  }
  try {
    (void)read_trajectory(path, TrajectoryFormat::kTum);
    ADD_FAILURE() << "no exception";
  } catch (const std::runtime_error& e) {
    EXPECT_NE(std::string(e.what()).find(path + ":2"), std::string::npos) << e.what();
  }
  std::filesystem::remove(path);
}

}  // namespace
}  // namespace iwlomap
