// SPDX-License-Identifier: BSD-3-Clause
#include "cloud_io.h"

#include "args.h"

#include <Eigen/Geometry>
#include <pcl/PCLPointCloud2.h>
#include <pcl/conversions.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <stdexcept>

namespace iwlomap::tool {

namespace {
bool has_field(const pcl::PCLPointCloud2& c, const std::string& name) {
  return std::any_of(c.fields.begin(), c.fields.end(), [&](const pcl::PCLPointField& f) { return f.name == name; });
}
void write_empty(const std::string& path, const std::string& ext, const std::string& shown_as) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) throw std::runtime_error("cannot write '" + shown_as + "'");
  if (ext == ".pcd")
    out << "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS x y z intensity\nSIZE 4 4 4 4\n"
           "TYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 0\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 0\nDATA ascii\n";
  else if (ext == ".ply")
    out << "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\n"
           "property float intensity\nend_header\n";
  out.close();
  if (!out) throw std::runtime_error("cannot write '" + shown_as + "'");
}

}  // namespace

LoadedCloud load_cloud(const std::string& path, float missing_intensity) {
  if (!std::ifstream(path).good()) throw std::runtime_error("cannot open '" + path + "'");
  const std::string ext = extension(path);
  pcl::PCLPointCloud2 blob;
  Eigen::Vector4f origin = Eigen::Vector4f::Zero();
  Eigen::Quaternionf orientation = Eigen::Quaternionf::Identity();
  int rc = -1;
  int version = 0;
  if (ext == ".pcd") {
    // PCL 1.13's PCDReader::read crashes on a file without a valid header, so check it first.
    pcl::PCDReader reader;
    int data_type = 0;
    unsigned int data_idx = 0;
    pcl::PCLPointCloud2 header;
    if (reader.readHeader(path, header, origin, orientation, version, data_type, data_idx) < 0 ||
        header.fields.empty())
      throw std::runtime_error("'" + path + "': not a PCD file (no valid header)");
    rc = header.width * header.height == 0 ? (blob = header, 0) : reader.read(path, blob, origin, orientation, version);
  } else if (ext == ".ply") {
    rc = pcl::PLYReader().read(path, blob, origin, orientation, version);
  } else {
    throw std::runtime_error("'" + path + "': unsupported cloud format (use .pcd or .ply)");
  }
  if (rc < 0) throw std::runtime_error("'" + path + "': not a readable " + ext + " file");
  if (!has_field(blob, "x") || !has_field(blob, "y") || !has_field(blob, "z"))
    throw std::runtime_error("'" + path + "': the cloud has no x, y, z fields");
  LoadedCloud out;
  out.cloud.reset(new pcl::PointCloud<pcl::PointXYZI>);
  out.has_intensity = has_field(blob, "intensity");
  pcl::fromPCLPointCloud2(blob, *out.cloud);
  if (!out.has_intensity)
    for (auto& p : *out.cloud) p.intensity = missing_intensity;
  out.cloud->sensor_origin_ = origin;
  out.cloud->sensor_orientation_ = orientation;
  return out;
}

void save_cloud(const std::string& file, const pcl::PointCloud<pcl::PointXYZI>& cloud, const std::string& shown_as) {
  const std::string ext = extension(file);
  if (ext != ".pcd" && ext != ".ply")
    throw std::runtime_error("'" + shown_as + "': unsupported output format (use .pcd or .ply)");
  if (cloud.empty()) {
    // PCL's writers refuse a cloud without points; an empty map is still a valid result.
    write_empty(file, ext, shown_as);
    return;
  }
  const int rc = ext == ".pcd" ? pcl::io::savePCDFileBinary(file, cloud) : pcl::io::savePLYFileBinary(file, cloud);
  // PCL's PLY writer does not check its stream: a short file (full disk) is caught by its size.
  std::error_code ec;
  const auto size = std::filesystem::file_size(file, ec);
  if (rc < 0 || ec || size < cloud.size() * 3 * sizeof(float))
    throw std::runtime_error("cannot write '" + shown_as + "'" + (ec ? ": " + ec.message() : std::string()));
}

}  // namespace iwlomap::tool
