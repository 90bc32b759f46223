// SPDX-License-Identifier: BSD-3-Clause
#include "cloud_io.h"

#include "args.h"
#include "cloud_check.h"

#include <iwlomap/filters/pointcloud2.h>

#include <Eigen/Geometry>
#include <pcl/PCLPointCloud2.h>
#include <pcl/io/pcd_io.h>
#include <pcl/io/ply_io.h>
#include <pcl/register_point_struct.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <stdexcept>

namespace iwlomap::tool {
/// An occupied voxel with its probability and mean colour, as `iwlomap map` writes it.
struct EIGEN_ALIGN16 ColoredVoxel {
  PCL_ADD_POINT4D;
  PCL_ADD_RGB;
  float intensity;
  PCL_MAKE_ALIGNED_OPERATOR_NEW
};
}  // namespace iwlomap::tool

POINT_CLOUD_REGISTER_POINT_STRUCT(iwlomap::tool::ColoredVoxel,
                                  (float, x, x)(float, y, y)(float, z, z)(float, intensity, intensity)(float, rgb, rgb))

namespace iwlomap::tool {

namespace {

constexpr const char* kMapComment = "iwlomap map";

// The comment line of \p info (the resolution in the fewest digits that read back exactly).
std::string map_comment(const MapCloudInfo& info) {
  return std::string(kMapComment) + " resolution " + shortest(info.resolution) + " positions " +
         (info.mean_positions ? "means" : "centres");
}

// The MapCloudInfo of the first comment that starts with kMapComment; one that does but does not
// parse is refused, naming \p path.
std::optional<MapCloudInfo> parse_map_comment(const std::vector<std::string>& comments, const std::string& path) {
  for (const std::string& c : comments) {
    if (c.rfind(kMapComment, 0) != 0) continue;
    std::istringstream in(c.substr(std::string(kMapComment).size()));
    std::string key1, value, key2, positions, rest;
    in >> key1 >> value >> key2 >> positions;
    MapCloudInfo info;
    std::size_t used = 0;
    try {
      info.resolution = std::stod(value, &used);
    } catch (const std::exception&) {
      used = 0;
    }
    if (key1 != "resolution" || used != value.size() || !(info.resolution > 0.0 && std::isfinite(info.resolution)) ||
        key2 != "positions" || (positions != "centres" && positions != "means") || (in >> rest))
      throw std::runtime_error("'" + path + "': malformed map comment '" + c +
                               "' (expected 'iwlomap map resolution METRES positions centres|means')");
    info.mean_positions = positions == "means";
    return info;
  }
  return std::nullopt;
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

// A PCD header that PCL's parser reads otherwise than check_cloud_file() did.
struct HeaderMismatch : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// Reads \p path with PCL's reader for \p ext; for a PCD, first checks that PCL parses the header
// as check_cloud_file() did (HeaderMismatch otherwise). Returns PCL's code (< 0: failure).
int read_with_pcl(const std::string& path, const std::string& ext, const CloudHeader& header, pcl::PCLPointCloud2& blob,
                  Eigen::Vector4f& origin, Eigen::Quaternionf& orientation, int& version) {
  if (ext != ".pcd") return pcl::PLYReader().read(path, blob, origin, orientation, version);
  int data_type = 0;
  unsigned int data_idx = 0;
  const int rc = pcl::PCDReader().readHeader(path, blob, origin, orientation, version, data_type, data_idx);
  if (rc < 0) return rc;
  if (blob.fields.size() != header.fields || blob.point_step != header.point_size ||
      static_cast<std::uint64_t>(blob.width) * blob.height != header.points)
    throw HeaderMismatch("'" + path + "': the header reads differently in PCL's parser (" +
                             std::to_string(blob.fields.size()) + " fields of " + std::to_string(blob.point_step) +
                             " bytes, expected " + std::to_string(header.fields) + " of " +
                             std::to_string(header.point_size) + "): a header line inside the data?");
  // PCL 1.13's PCDReader::read fails on an empty cloud: its header is all there is.
  return header.points > 0 ? pcl::PCDReader().read(path, blob, origin, orientation, version) : rc;
}

}  // namespace

LoadedCloud load_cloud(const std::string& path, float missing_intensity) {
  if (!std::ifstream(path).good()) throw std::runtime_error("cannot open '" + path + "'");
  // PCL's readers trust the header; only a header consistent with itself and the file reaches them.
  const CloudHeader header = check_cloud_file(path);
  const std::string ext = extension(path);
  pcl::PCLPointCloud2 blob;
  Eigen::Vector4f origin = Eigen::Vector4f::Zero();
  Eigen::Quaternionf orientation = Eigen::Quaternionf::Identity();
  int version = 0;
  int rc = 0;
  // check_cloud_file() refuses the data PCL's parser would read as header lines (found by
  // fuzzing); should PCL still parse another header or throw, the error names the file.
  try {
    rc = read_with_pcl(path, ext, header, blob, origin, orientation, version);
  } catch (const HeaderMismatch&) {
    throw;
  } catch (const std::bad_alloc&) {
    throw std::runtime_error("'" + path + "': PCL's reader ran out of memory on this file");
  } catch (const std::exception& e) {
    throw std::runtime_error("'" + path + "': PCL's reader failed (" + e.what() + "): a header line inside the data?");
  }
  if (rc < 0) throw std::runtime_error("'" + path + "': not a readable " + ext + " file");
  if (static_cast<std::uint64_t>(blob.width) * blob.height != header.points)
    throw std::runtime_error("'" + path + "': " + std::to_string(static_cast<std::uint64_t>(blob.width) * blob.height) +
                             " points read, the header promises " + std::to_string(header.points) + " (truncated?)");
  if (!origin.allFinite() || !orientation.coeffs().allFinite())
    throw std::runtime_error("'" + path + "': the sensor origin or orientation is not finite");
  LoadedCloud out;
  out.cloud.reset(new pcl::PointCloud<pcl::PointXYZI>);
  out.has_intensity = has_intensity(blob);
  blob_to_xyzi(blob, missing_intensity, path, *out.cloud, out.colors);
  out.cloud->sensor_origin_ = origin;
  out.cloud->sensor_orientation_ = orientation;
  out.map_info = parse_map_comment(header.comments, path);
  return out;
}

namespace {

// Adds \p comment to the header of the .pcd or .ply file \p file: after a PCD's first line (its
// format comment), or after a PLY's format line. The file is rewritten whole; the clouds written
// this way are the tool's map outputs, which take a small part of a run.
void add_header_comment(const std::string& file, const std::string& ext, const std::string& comment,
                        const std::string& shown_as) {
  std::string bytes;
  {
    std::ifstream in(file, std::ios::binary);
    bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    if (!in.good() && !in.eof()) throw std::runtime_error("cannot read back '" + shown_as + "'");
  }
  const std::size_t format = ext == ".pcd" ? 0 : bytes.find("\nformat ");
  const std::size_t eol = format == std::string::npos ? format : bytes.find('\n', format + (ext == ".pcd" ? 0 : 1));
  if (eol == std::string::npos) throw std::logic_error("add_header_comment: no line to follow in '" + shown_as + "'");
  bytes.insert(eol + 1, (ext == ".pcd" ? "# " : "comment ") + comment + "\n");
  std::ofstream out(file, std::ios::binary | std::ios::trunc);
  out.write(bytes.data(), static_cast<std::streamsize>(bytes.size()));
  out.close();
  if (!out) throw std::runtime_error("cannot write '" + shown_as + "'");
}

// Writes \p cloud as binary .pcd or .ply; \p min_point_bytes per point is the least a complete
// file holds (PCL's PLY writer does not check its stream: a short file, a full disk, is caught by
// its size).
template <typename PointT>
void save_any(const std::string& file, const pcl::PointCloud<PointT>& cloud, std::size_t min_point_bytes,
              const std::string& shown_as, const std::optional<MapCloudInfo>& info) {
  const std::string ext = extension(file);
  if (ext != ".pcd" && ext != ".ply")
    throw std::runtime_error("'" + shown_as + "': unsupported output format (use .pcd or .ply)");
  if (cloud.empty()) {
    // PCL's writers refuse a cloud without points; an empty map is still a valid result.
    write_empty(file, ext, shown_as);
    if (info) add_header_comment(file, ext, map_comment(*info), shown_as);
    return;
  }
  const int rc = ext == ".pcd" ? pcl::io::savePCDFileBinary(file, cloud) : pcl::io::savePLYFileBinary(file, cloud);
  std::error_code ec;
  const auto size = std::filesystem::file_size(file, ec);
  if (rc < 0 || ec || size < cloud.size() * min_point_bytes)
    throw std::runtime_error("cannot write '" + shown_as + "'" + (ec ? ": " + ec.message() : std::string()));
  if (info) add_header_comment(file, ext, map_comment(*info), shown_as);
}

}  // namespace

void save_cloud(const std::string& file, const pcl::PointCloud<pcl::PointXYZI>& cloud, const std::string& shown_as,
                const std::optional<MapCloudInfo>& info) {
  save_any(file, cloud, 3 * sizeof(float), shown_as, info);
}

void save_cloud(const std::string& file, const pcl::PointCloud<pcl::PointXYZI>& cloud, const ColorMatrix& colors,
                const std::string& shown_as, const std::optional<MapCloudInfo>& info) {
  if (colors.rows() != static_cast<Eigen::Index>(cloud.size()))
    throw std::logic_error("save_cloud: " + std::to_string(colors.rows()) + " colours for " +
                           std::to_string(cloud.size()) + " points");
  pcl::PointCloud<ColoredVoxel> out;
  out.resize(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    ColoredVoxel& q = out[i];
    q.x = cloud[i].x;
    q.y = cloud[i].y;
    q.z = cloud[i].z;
    q.intensity = cloud[i].intensity;
    const auto row = static_cast<Eigen::Index>(i);
    q.r = colors(row, 0);
    q.g = colors(row, 1);
    q.b = colors(row, 2);
    q.a = 255;
  }
  out.width = cloud.width;
  out.height = cloud.height;
  out.is_dense = cloud.is_dense;
  out.sensor_origin_ = cloud.sensor_origin_;
  out.sensor_orientation_ = cloud.sensor_orientation_;
  save_any(file, out, 3 * sizeof(float) + 3, shown_as, info);
}

Eigen::Isometry3d viewpoint_pose(const pcl::PointCloud<pcl::PointXYZI>& cloud) {
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = cloud.sensor_orientation_.cast<double>().normalized().toRotationMatrix();
  pose.translation() = cloud.sensor_origin_.head<3>().cast<double>();
  return pose;
}

}  // namespace iwlomap::tool
