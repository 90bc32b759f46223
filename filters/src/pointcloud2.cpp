// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/filters/pointcloud2.h"

#include <cstdint>
#include <cstring>
#include <stdexcept>

namespace iwlomap {

namespace {

// Bytes of one value of a PCLPointField datatype; 0 for an unknown type.
std::size_t value_bytes(std::uint8_t datatype) {
  switch (datatype) {
    case pcl::PCLPointField::INT8:
    case pcl::PCLPointField::UINT8: return 1;
    case pcl::PCLPointField::INT16:
    case pcl::PCLPointField::UINT16: return 2;
    case pcl::PCLPointField::INT32:
    case pcl::PCLPointField::UINT32:
    case pcl::PCLPointField::FLOAT32: return 4;
    case pcl::PCLPointField::FLOAT64:
    case pcl::PCLPointField::INT64:
    case pcl::PCLPointField::UINT64: return 8;
    default: return 0;
  }
}

// The value of a field of type \p datatype (value_bytes() > 0) at \p p.
double read_value(const std::uint8_t* p, std::uint8_t datatype) {
  const auto get = [p](auto v) {
    std::memcpy(&v, p, sizeof v);
    return static_cast<double>(v);
  };
  switch (datatype) {
    case pcl::PCLPointField::INT8: return get(std::int8_t{});
    case pcl::PCLPointField::UINT8: return get(std::uint8_t{});
    case pcl::PCLPointField::INT16: return get(std::int16_t{});
    case pcl::PCLPointField::UINT16: return get(std::uint16_t{});
    case pcl::PCLPointField::INT32: return get(std::int32_t{});
    case pcl::PCLPointField::UINT32: return get(std::uint32_t{});
    case pcl::PCLPointField::FLOAT32: return get(float{});
    case pcl::PCLPointField::FLOAT64: return get(double{});
    case pcl::PCLPointField::INT64: return get(std::int64_t{});
    default: return get(std::uint64_t{});
  }
}

}  // namespace

bool has_field(const pcl::PCLPointCloud2& blob, const std::string& name) {
  for (const auto& f : blob.fields)
    if (f.name == name) return true;
  return false;
}

namespace {

// The field \p name of \p blob, checked to have a known type and to lie within the point; null
// when there is none.
const pcl::PCLPointField* checked_field(const pcl::PCLPointCloud2& blob, const char* name) {
  for (const auto& f : blob.fields) {
    if (f.name != name) continue;
    const std::size_t bytes = value_bytes(f.datatype);
    if (bytes == 0)
      throw std::invalid_argument(std::string("iwlomap: field '") + name + "' has unknown datatype " +
                                  std::to_string(f.datatype));
    if (static_cast<std::uint64_t>(f.offset) + bytes > blob.point_step)
      throw std::invalid_argument(std::string("iwlomap: field '") + name + "' (offset " + std::to_string(f.offset) +
                                  ", " + std::to_string(bytes) + " bytes) lies outside the point of " +
                                  std::to_string(blob.point_step) + " bytes");
    return &f;
  }
  return nullptr;
}

// width x height, checked against the data's length.
std::uint64_t point_count(const pcl::PCLPointCloud2& blob) {
  const std::uint64_t n = static_cast<std::uint64_t>(blob.width) * blob.height;
  if (n != 0 && (blob.point_step == 0 || n > blob.data.size() / blob.point_step))
    throw std::invalid_argument("iwlomap: the cloud's data holds " + std::to_string(blob.data.size()) +
                                " bytes, less than " + std::to_string(n) + " points of " +
                                std::to_string(blob.point_step) + " bytes");
  return n;
}

// The intensity field: `intensity`, else the names other programs give it (CloudCompare writes a
// scalar field as `scalar_<name>`).
const pcl::PCLPointField* intensity_field(const pcl::PCLPointCloud2& blob) {
  for (const char* name : kIntensityFieldNames)
    if (const pcl::PCLPointField* f = checked_field(blob, name)) return f;
  return nullptr;
}

}  // namespace

bool has_intensity(const pcl::PCLPointCloud2& blob) {
  for (const char* name : kIntensityFieldNames)
    if (has_field(blob, name)) return true;
  return false;
}

void pointcloud2_to_xyzi(const pcl::PCLPointCloud2& blob, pcl::PointCloud<pcl::PointXYZI>& out,
                         float missing_intensity) {
  const pcl::PCLPointField* fx = checked_field(blob, "x");
  const pcl::PCLPointField* fy = checked_field(blob, "y");
  const pcl::PCLPointField* fz = checked_field(blob, "z");
  const pcl::PCLPointField* fi = intensity_field(blob);
  if (fx == nullptr || fy == nullptr || fz == nullptr)
    throw std::invalid_argument("iwlomap: the cloud has no x, y and z fields");
  const std::uint64_t n = point_count(blob);
  out.resize(static_cast<std::size_t>(n));
  out.width = blob.width;
  out.height = blob.height;
  out.is_dense = false;
  for (std::uint64_t i = 0; i < n; ++i) {
    const std::uint8_t* p = blob.data.data() + i * blob.point_step;
    pcl::PointXYZI& q = out[static_cast<std::size_t>(i)];
    q.x = static_cast<float>(read_value(p + fx->offset, fx->datatype));
    q.y = static_cast<float>(read_value(p + fy->offset, fy->datatype));
    q.z = static_cast<float>(read_value(p + fz->offset, fz->datatype));
    q.intensity = fi != nullptr ? static_cast<float>(read_value(p + fi->offset, fi->datatype)) : missing_intensity;
  }
}

std::optional<ColorMatrix> pointcloud2_colors(const pcl::PCLPointCloud2& blob) {
  const pcl::PCLPointField* f = checked_field(blob, "rgb");
  if (f == nullptr) f = checked_field(blob, "rgba");
  if (f == nullptr) return std::nullopt;
  if (value_bytes(f->datatype) != 4)
    throw std::invalid_argument("iwlomap: field '" + f->name + "' has " + std::to_string(value_bytes(f->datatype)) +
                                " bytes, expected PCL's packed 4-byte colour");
  const std::uint64_t n = point_count(blob);
  ColorMatrix colors(static_cast<Eigen::Index>(n), 3);
  for (std::uint64_t i = 0; i < n; ++i) {
    std::uint32_t packed = 0;  // 0xAARRGGBB, whether stored as float32 or as an integer
    std::memcpy(&packed, blob.data.data() + i * blob.point_step + f->offset, sizeof packed);
    const auto row = static_cast<Eigen::Index>(i);
    colors(row, 0) = static_cast<std::uint8_t>(packed >> 16);
    colors(row, 1) = static_cast<std::uint8_t>(packed >> 8);
    colors(row, 2) = static_cast<std::uint8_t>(packed);
  }
  return colors;
}

}  // namespace iwlomap
