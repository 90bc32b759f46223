// SPDX-License-Identifier: BSD-3-Clause
// OccupancyFilter as an index filter: OutputMode::kInputPoints, and the pcl::FilterIndices
// interface (filter(pcl::Indices&), setNegative, setKeepOrganized, setUserFilterValue,
// getRemovedIndices) used through a reference to the PCL base class, for a precompiled point type
// and for one PCL does not know.

#define PCL_NO_PRECOMPILE
#include <iwlomap/filters/occupancy_filter.h>
#include <iwlomap/sensor_preset.h>

#include <gtest/gtest.h>
#include <pcl/filters/filter_indices.h>
#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/register_point_struct.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <utility>
#include <vector>

// A point type that no PCL library was compiled for: a lidar return with its ring.
struct RingPoint {
  PCL_ADD_POINT4D;
  float intensity;
  std::uint16_t ring;
  PCL_MAKE_ALIGNED_OPERATOR_NEW
};
POINT_CLOUD_REGISTER_POINT_STRUCT(RingPoint, (float, x, x)(float, y, y)(float, z, z)(float, intensity, intensity)(
                                                 std::uint16_t, ring, ring))

namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZI>;
using Filter = iwlomap::OccupancyFilter<pcl::PointXYZI>;

// An organised frame seen from the origin: a wall at x = 4 m (20 x 10 points), and, when
// \p with_box, a box face at x = 2 m in front of its middle (the wall points behind it hidden).
// Returns the frame and the indices of the box's points.
template <class PointT = pcl::PointXYZI>
std::pair<typename pcl::PointCloud<PointT>::Ptr, std::vector<int>> wall_frame(bool with_box, float box_x = 2.0f) {
  auto c = pcl::make_shared<pcl::PointCloud<PointT>>();
  c->width = 20;
  c->height = 10;
  c->is_dense = true;
  c->resize(200);
  std::vector<int> box;
  for (int row = 0; row < 10; ++row)
    for (int col = 0; col < 20; ++col) {
      const float y = -1.0f + 0.1f * static_cast<float>(col) + 0.05f;
      const float z = -0.5f + 0.1f * static_cast<float>(row) + 0.05f;
      const bool hidden = with_box && std::abs(y) < 0.35f && std::abs(z) < 0.25f;
      PointT& p = (*c)[static_cast<std::size_t>(row * 20 + col)];
      const float along = box_x / 4.0f;  // on the ray towards the hidden wall point
      p.x = hidden ? box_x : 4.0f;
      p.y = hidden ? y * along : y;
      p.z = hidden ? z * along : z;
      p.intensity = 100.0f;
      if (hidden) box.push_back(row * 20 + col);
    }
  c->sensor_origin_ = Eigen::Vector4f::Zero();
  return {c, box};
}

// Input-points mode: a box that appears in space the map saw free for ten frames is transient
// on first sight: its points are removed, the static wall's kept, every field untouched.
TEST(OccupancyFilter, InputPointsModeRemovesAnObjectInSpaceSeenFree) {
  Filter f(/*extract_removed_indices=*/true);
  f.setResolution(0.1);
  f.setSensorPreset(iwlomap::SensorPreset::kLidar);
  f.setOutputMode(iwlomap::OutputMode::kInputPoints);
  EXPECT_EQ(f.getOutputMode(), iwlomap::OutputMode::kInputPoints);
  Cloud out;
  for (int k = 0; k < 10; ++k) {
    f.setInputCloud(wall_frame<>(false).first);
    f.filter(out);
  }
  EXPECT_EQ(out.size(), 200u) << "the static wall is kept whole";
  EXPECT_TRUE(f.getRemovedIndices()->empty());

  const auto [frame, box] = wall_frame<>(true);
  ASSERT_EQ(box.size(), 35u);
  f.setInputCloud(frame);
  f.filter(out);
  EXPECT_EQ(out.size(), 200u - box.size());
  EXPECT_EQ(*f.getRemovedIndices(), box);
  for (const auto& p : out) {
    EXPECT_EQ(p.x, 4.0f) << "only wall points are kept";
    EXPECT_EQ(p.intensity, 100.0f) << "fields untouched";
  }
  EXPECT_EQ(out.height, 1u);

  // Negative: the removed points instead.
  f.setNegative(true);
  f.setInputCloud(frame);
  f.filter(out);
  EXPECT_EQ(out.size(), box.size());
  for (const auto& p : out) EXPECT_EQ(p.x, 2.0f);

  // Organised: the input's layout, the removed points NaN.
  f.setNegative(false);
  f.setKeepOrganized(true);
  f.setInputCloud(frame);
  f.filter(out);
  ASSERT_EQ(out.width, 20u);
  ASSERT_EQ(out.height, 10u);
  EXPECT_FALSE(out.is_dense);
  for (int i = 0; i < 200; ++i) {
    const bool removed = std::find(box.begin(), box.end(), i) != box.end();
    EXPECT_EQ(std::isnan(out[static_cast<std::size_t>(i)].x), removed) << i;
    if (!removed) {
      EXPECT_EQ(out[static_cast<std::size_t>(i)].x, (*frame)[static_cast<std::size_t>(i)].x);
    }
  }
}

// A box that appears, then moves, in space the map saw free: at each place its points are removed
// on first sight and for the next frames, and kept once its voxels are occupied; its old place
// clears. The numbers of frames are the lidar preset's (README, "The PCL filter").
TEST(OccupancyFilter, InputPointsModeFollowsABoxMovedBetweenFrames) {
  Filter f(/*extract_removed_indices=*/true);
  f.setResolution(0.1);
  f.setSensorPreset(iwlomap::SensorPreset::kLidar);
  f.setOutputMode(iwlomap::OutputMode::kInputPoints);
  Cloud out;
  const auto removed_of = [&](float box_x) {
    const auto [frame, box] = wall_frame<>(true, box_x);
    f.setInputCloud(frame);
    f.filter(out);
    std::size_t removed_box = 0;
    for (const int i : *f.getRemovedIndices())
      removed_box += std::find(box.begin(), box.end(), i) != box.end() ? 1 : 0;
    EXPECT_EQ(f.getRemovedIndices()->size(), removed_box) << "only box points are ever removed";
    return removed_box;
  };
  // Ten frames of the wall alone: the space in front of it is seen free.
  for (int k = 0; k < 10; ++k) {
    f.setInputCloud(wall_frame<>(false).first);
    f.filter(out);
  }
  // A box 2 m out, staying 10 frames.
  std::vector<std::size_t> at_first;
  for (int k = 0; k < 10; ++k) at_first.push_back(removed_of(2.0f));
  // Moved 1 m back, into space the first ten frames saw free (and the box then hid).
  std::vector<std::size_t> removed;
  for (int k = 0; k < 12; ++k) removed.push_back(removed_of(3.0f));
  // Both places: removed whole for the first 3 frames; from the 4th most points are kept (the
  // box's edge voxels, which rays to the wall also cross, take 2 frames more); whole from the 6th.
  for (const std::vector<std::size_t>* run : {&at_first, &removed}) {
    const std::vector<std::size_t>& r = *run;
    for (std::size_t k = 0; k < 3; ++k) EXPECT_EQ(r[k], 35u) << "frame " << k + 1;
    for (std::size_t k = 3; k < 5; ++k) EXPECT_LE(r[k], 7u) << "frame " << k + 1;
    for (std::size_t k = 5; k < r.size(); ++k) EXPECT_EQ(r[k], 0u) << "frame " << k + 1;
  }
  // Its old place: in the map (map mode), no occupied voxel at x = 2 m once the rays to the box's
  // new place have crossed it 7 times.
  f.setOutputMode(iwlomap::OutputMode::kMap);
  f.setInputCloud(wall_frame<>(true, 3.0f).first);
  f.filter(out);
  for (const auto& p : out) EXPECT_GT(p.x, 2.5f) << "the box's old place is clear";
}

// The wall frames (ten without the box, then one with it) through filter(pcl::Indices&) on a
// reference to the PCL base class: the selected indices are the wall's, the removed ones the
// box's, and they are exactly the points kInputPoints outputs (checked on a twin filter).
template <class PointT>
void expect_index_filter_selects_the_wall() {
  iwlomap::OccupancyFilter<PointT> f(/*extract_removed_indices=*/true);
  iwlomap::OccupancyFilter<PointT> twin;
  for (auto* g : {&f, &twin}) {
    g->setResolution(0.1);
    g->setSensorPreset(iwlomap::SensorPreset::kLidar);
  }
  twin.setOutputMode(iwlomap::OutputMode::kInputPoints);
  pcl::FilterIndices<PointT>& base = f;
  pcl::Indices selected;
  pcl::PointCloud<PointT> twin_out;
  for (int k = 0; k < 10; ++k) {
    const auto frame = wall_frame<PointT>(false).first;
    base.setInputCloud(frame);
    base.filter(selected);
    twin.setInputCloud(frame);
    twin.filter(twin_out);
  }
  EXPECT_EQ(selected.size(), 200u);
  EXPECT_TRUE(base.getRemovedIndices()->empty());

  const auto [frame, box] = wall_frame<PointT>(true);
  base.setInputCloud(frame);
  base.filter(selected);
  twin.setInputCloud(frame);
  twin.filter(twin_out);
  std::vector<int> wall;
  for (int i = 0; i < 200; ++i)
    if (std::find(box.begin(), box.end(), i) == box.end()) wall.push_back(i);
  EXPECT_EQ(std::vector<int>(selected.begin(), selected.end()), wall);
  EXPECT_EQ(std::vector<int>(base.getRemovedIndices()->begin(), base.getRemovedIndices()->end()), box);
  ASSERT_EQ(twin_out.size(), selected.size());
  for (std::size_t i = 0; i < selected.size(); ++i)
    EXPECT_EQ(twin_out[i].y, (*frame)[static_cast<std::size_t>(selected[i])].y) << i;

  // Negative through the base class: the box's indices, the wall's removed. The map keeps
  // integrating, so the box is seen a second time (still removed whole; see the test above).
  base.setNegative(true);
  EXPECT_TRUE(base.getNegative());
  base.setInputCloud(frame);
  base.filter(selected);
  EXPECT_EQ(std::vector<int>(selected.begin(), selected.end()), box);
  EXPECT_EQ(base.getRemovedIndices()->size(), wall.size());
}

TEST(OccupancyFilterIndices, SelectsThroughTheFilterIndicesBase) { expect_index_filter_selects_the_wall<pcl::PointXYZI>(); }

TEST(OccupancyFilterIndices, WorksForAPointTypePclDidNotPrecompile) {
  expect_index_filter_selects_the_wall<RingPoint>();
  // Input-points mode keeps the type's own field.
  iwlomap::OccupancyFilter<RingPoint> f;
  f.setResolution(0.1);
  f.setSensorPreset(iwlomap::SensorPreset::kLidar);
  f.setOutputMode(iwlomap::OutputMode::kInputPoints);
  auto frame = wall_frame<RingPoint>(false).first;
  for (std::size_t i = 0; i < frame->size(); ++i) (*frame)[i].ring = static_cast<std::uint16_t>(i / 20);
  pcl::PointCloud<RingPoint> out;
  for (int k = 0; k < 3; ++k) {
    f.setInputCloud(frame);
    f.filter(out);
  }
  ASSERT_EQ(out.size(), 200u);
  for (std::size_t i = 0; i < out.size(); ++i) EXPECT_EQ(out[i].ring, i / 20) << i;
}

// setKeepOrganized with a user filter value: the removed points' coordinates take that value, and
// a finite value keeps the cloud dense; setIndices restricts the selection, and points outside the
// indices are removed from the organised output too.
TEST(OccupancyFilterIndices, KeepOrganizedUsesTheUserFilterValueAndHonoursIndices) {
  Filter f;
  f.setResolution(0.1);
  f.setSensorPreset(iwlomap::SensorPreset::kLidar);
  f.setOutputMode(iwlomap::OutputMode::kInputPoints);
  Cloud out;
  for (int k = 0; k < 10; ++k) {
    f.setInputCloud(wall_frame<>(false).first);
    f.filter(out);
  }
  const auto [frame, box] = wall_frame<>(true);
  f.setKeepOrganized(true);
  f.setUserFilterValue(-9.0f);
  auto first_rows = pcl::make_shared<pcl::Indices>();
  for (int i = 0; i < 100; ++i) first_rows->push_back(i);
  f.setInputCloud(frame);
  f.setIndices(first_rows);
  f.filter(out);
  ASSERT_EQ(out.size(), 200u);
  EXPECT_EQ(out.width, 20u);
  EXPECT_TRUE(out.is_dense) << "a finite filter value keeps the cloud dense";
  for (int i = 0; i < 200; ++i) {
    const bool kept = i < 100 && std::find(box.begin(), box.end(), i) == box.end();
    const auto& p = out[static_cast<std::size_t>(i)];
    if (kept)
      EXPECT_EQ(p.x, 4.0f) << i;
    else
      EXPECT_TRUE(p.x == -9.0f && p.y == -9.0f && p.z == -9.0f) << i;
  }
}

}  // namespace
