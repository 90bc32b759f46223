// SPDX-License-Identifier: BSD-3-Clause
// pcl::PCLPointCloud2 input (filters/pointcloud2.h): every numeric field type, packed colours,
// the intensity field under the names other programs give it, clear errors for inconsistent
// blobs, and a converted cloud filtered as the typed one.
#include <iwlomap/filters/occupancy_filter.h>
#include <iwlomap/filters/pointcloud2.h>

#include <gtest/gtest.h>
#include <pcl/console/print.h>
#include <pcl/conversions.h>

#include <cstdint>
#include <cstring>
#include <random>
#include <string>

namespace {

using Cloud = pcl::PointCloud<pcl::PointXYZI>;
using Filter = iwlomap::OccupancyFilter<pcl::PointXYZI>;

}  // namespace

namespace {

// A 2 x 2 organised blob with double x, y, z, a 16-bit intensity and 3 bytes of padding between.
pcl::PCLPointCloud2 double_blob() {
  pcl::PCLPointCloud2 blob;
  const auto field = [](const char* name, std::uint32_t offset, std::uint8_t type) {
    pcl::PCLPointField f;
    f.name = name;
    f.offset = offset;
    f.datatype = type;
    f.count = 1;
    return f;
  };
  blob.fields = {field("x", 0, pcl::PCLPointField::FLOAT64), field("y", 8, pcl::PCLPointField::FLOAT64),
                 field("z", 16, pcl::PCLPointField::FLOAT64), field("intensity", 27, pcl::PCLPointField::UINT16)};
  blob.point_step = 29;
  blob.width = 2;
  blob.height = 2;
  blob.row_step = blob.point_step * blob.width;
  blob.data.assign(static_cast<std::size_t>(blob.point_step) * 4, 0);
  for (std::size_t i = 0; i < 4; ++i) {
    const double xyz[3] = {1.25 + static_cast<double>(i), -2.5 * static_cast<double>(i), 0.125};
    const std::uint16_t intensity = static_cast<std::uint16_t>(300 + 1000 * i);
    std::memcpy(&blob.data[i * blob.point_step], xyz, sizeof xyz);
    std::memcpy(&blob.data[i * blob.point_step + 27], &intensity, sizeof intensity);
  }
  return blob;
}

TEST(PointCloud2, ConvertsEveryNumericTypeAndKeepsTheOrganisation) {
  Cloud out;
  iwlomap::pointcloud2_to_xyzi(double_blob(), out);
  ASSERT_EQ(out.size(), 4u);
  EXPECT_EQ(out.width, 2u);
  EXPECT_EQ(out.height, 2u);
  for (std::size_t i = 0; i < 4; ++i) {
    EXPECT_EQ(out[i].x, static_cast<float>(1.25 + static_cast<double>(i)));
    EXPECT_EQ(out[i].y, static_cast<float>(-2.5 * static_cast<double>(i)));
    EXPECT_EQ(out[i].z, 0.125f);
    EXPECT_EQ(out[i].intensity, static_cast<float>(300 + 1000 * i));
  }
  // PCL's own conversion leaves fields of another type at zero: the reason for this helper.
  Cloud pcl_way;
  pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);
  pcl::fromPCLPointCloud2(double_blob(), pcl_way);
  EXPECT_EQ(pcl_way[1].x, 0.0f);
  // Without an intensity field, every point gets the given intensity.
  pcl::PCLPointCloud2 no_intensity = double_blob();
  no_intensity.fields.pop_back();
  iwlomap::pointcloud2_to_xyzi(no_intensity, out, 42.0f);
  EXPECT_EQ(out[3].intensity, 42.0f);
  EXPECT_TRUE(iwlomap::has_field(double_blob(), "intensity"));
  EXPECT_FALSE(iwlomap::has_field(no_intensity, "intensity"));
}

// PCL's packed colours, from a typed cloud's conversion (float32 rgb, uint32 rgba) and by hand.
TEST(PointCloud2, ReadsPackedColoursOfEitherFieldType) {
  pcl::PointCloud<pcl::PointXYZRGB> rgb;
  pcl::PointCloud<pcl::PointXYZRGBA> rgba;
  for (int i = 0; i < 3; ++i) {
    pcl::PointXYZRGB p(static_cast<std::uint8_t>(10 * i), 20, static_cast<std::uint8_t>(250 - i));
    rgb.push_back(p);
    pcl::PointXYZRGBA q;
    q.r = 1;
    q.g = static_cast<std::uint8_t>(i);
    q.b = 3;
    q.a = 4;
    rgba.push_back(q);
  }
  pcl::PCLPointCloud2 a, b;
  pcl::toPCLPointCloud2(rgb, a);
  pcl::toPCLPointCloud2(rgba, b);
  const auto ca = iwlomap::pointcloud2_colors(a);
  const auto cb = iwlomap::pointcloud2_colors(b);
  ASSERT_TRUE(ca && cb);
  ASSERT_EQ(ca->rows(), 3);
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(std::make_tuple(int{(*ca)(i, 0)}, int{(*ca)(i, 1)}, int{(*ca)(i, 2)}), std::make_tuple(10 * i, 20, 250 - i));
    EXPECT_EQ(std::make_tuple(int{(*cb)(i, 0)}, int{(*cb)(i, 1)}, int{(*cb)(i, 2)}), std::make_tuple(1, i, 3));
  }
  EXPECT_FALSE(iwlomap::pointcloud2_colors(double_blob()).has_value());
  pcl::PCLPointCloud2 wide = a;
  for (auto& f : wide.fields)
    if (f.name == "rgb") f.datatype = pcl::PCLPointField::FLOAT64;
  EXPECT_THROW((void)iwlomap::pointcloud2_colors(wide), std::invalid_argument);
  pcl::PCLPointCloud2 short_data = a;
  short_data.data.resize(short_data.point_step);
  EXPECT_THROW((void)iwlomap::pointcloud2_colors(short_data), std::invalid_argument);
}

TEST(PointCloud2, ThrowsNamingTheProblemWhenTheBlobIsInconsistent) {
  const auto message = [](const pcl::PCLPointCloud2& blob) {
    Cloud out;
    try {
      iwlomap::pointcloud2_to_xyzi(blob, out);
    } catch (const std::invalid_argument& e) {
      return std::string(e.what());
    }
    return std::string("no exception");
  };
  pcl::PCLPointCloud2 no_z = double_blob();
  no_z.fields.erase(no_z.fields.begin() + 2);
  EXPECT_NE(message(no_z).find("no x, y and z"), std::string::npos);
  pcl::PCLPointCloud2 outside = double_blob();
  outside.fields[3].offset = 28;  // 2 bytes from 28 pass the 29-byte point
  EXPECT_NE(message(outside).find("'intensity'"), std::string::npos) << message(outside);
  pcl::PCLPointCloud2 unknown = double_blob();
  unknown.fields[0].datatype = 42;
  EXPECT_NE(message(unknown).find("unknown datatype 42"), std::string::npos) << message(unknown);
  pcl::PCLPointCloud2 short_data = double_blob();
  short_data.data.resize(short_data.data.size() - 1);
  EXPECT_NE(message(short_data).find("less than 4 points"), std::string::npos) << message(short_data);
}

// A cloud sent as PCLPointCloud2 (as ROS messages arrive) maps as the typed cloud does.
TEST(PointCloud2, FiltersAsTheTypedCloudDoes) {
  Cloud::Ptr typed(new Cloud);
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-3.0f, 3.0f);
  for (int i = 0; i < 500; ++i) {
    pcl::PointXYZI p;
    p.x = u(rng);
    p.y = u(rng);
    p.z = u(rng) * 0.2f;
    p.intensity = static_cast<float>(i % 250);
    typed->push_back(p);
  }
  pcl::PCLPointCloud2 blob;
  pcl::toPCLPointCloud2(*typed, blob);
  Cloud::Ptr converted(new Cloud);
  iwlomap::pointcloud2_to_xyzi(blob, *converted);
  converted->sensor_origin_ = typed->sensor_origin_;
  const auto lidar_map_of = [](const Cloud::Ptr& in) {
    Filter f;
    f.setResolution(0.1);
    f.setSensorPreset(iwlomap::SensorPreset::kLidar);
    f.setInputCloud(in);
    Cloud out;
    f.filter(out);
    return out;
  };
  const Cloud a = lidar_map_of(typed), b = lidar_map_of(converted);
  ASSERT_GT(a.size(), 100u);
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].x, b[i].x);
    EXPECT_EQ(a[i].intensity, b[i].intensity);
  }
}

// Clouds exported by other programs name the intensity otherwise: CloudCompare's PLY writes
// `scalar_intensity` (or `scalar_Intensity`); `intensity` wins when several are present.
TEST(PointCloud2, ReadsTheIntensityUnderOtherProgramsNames) {
  for (const char* name : {"Intensity", "scalar_intensity", "scalar_Intensity"}) {
    pcl::PCLPointCloud2 blob = double_blob();
    blob.fields.back().name = name;
    EXPECT_TRUE(iwlomap::has_intensity(blob)) << name;
    Cloud out;
    iwlomap::pointcloud2_to_xyzi(blob, out, 42.0f);
    EXPECT_EQ(out[2].intensity, 2300.0f) << name;
  }
  pcl::PCLPointCloud2 other = double_blob();
  other.fields.back().name = "scalar_range";
  EXPECT_FALSE(iwlomap::has_intensity(other));
  Cloud out;
  iwlomap::pointcloud2_to_xyzi(other, out, 42.0f);
  EXPECT_EQ(out[2].intensity, 42.0f);
  // Both `intensity` and `scalar_intensity`: `intensity` is read.
  pcl::PCLPointCloud2 both = double_blob();
  pcl::PCLPointField extra = both.fields.back();
  extra.name = "scalar_intensity";
  extra.offset = 24;  // one of the padding bytes, 0
  extra.datatype = pcl::PCLPointField::UINT8;
  both.fields.push_back(extra);
  iwlomap::pointcloud2_to_xyzi(both, out);
  EXPECT_EQ(out[2].intensity, 2300.0f);
}

}  // namespace
