// SPDX-License-Identifier: BSD-3-Clause
#include "cloud_io.h"

#include "args.h"

#include <pcl/PCLPointCloud2.h>
#include <pcl/conversions.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>

#include <algorithm>
#include <fstream>
#include <stdexcept>

namespace iwlomap::tool {

namespace {
bool has_field(const pcl::PCLPointCloud2& c, const std::string& name) {
  return std::any_of(c.fields.begin(), c.fields.end(), [&](const pcl::PCLPointField& f) { return f.name == name; });
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
    rc = pcl::PCDReader().read(path, blob, origin, orientation, version);
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

void save_cloud(const std::string& path, const pcl::PointCloud<pcl::PointXYZI>& cloud) {
  const std::string ext = extension(path);
  int rc = -1;
  if (ext == ".pcd") {
    rc = cloud.empty() ? pcl::PCDWriter().writeASCII(path, cloud) : pcl::io::savePCDFileBinary(path, cloud);
  } else if (ext == ".ply") {
    rc = pcl::io::savePLYFileBinary(path, cloud);
  } else {
    throw std::runtime_error("'" + path + "': unsupported output format (use .pcd or .ply)");
  }
  if (rc < 0) throw std::runtime_error("cannot write '" + path + "'");
}

}  // namespace iwlomap::tool
