// SPDX-License-Identifier: BSD-3-Clause
#pragma once

// A small reader of binary PCD files for the benchmark programs that do not link PCL.

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <cmath>
#include <cstddef>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap::bench {

// A binary PCD file with float32 fields x, y, z, intensity; VIEWPOINT gives the sensor origin.
struct PcdCloud {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  Eigen::Quaterniond orientation = Eigen::Quaterniond::Identity();  // VIEWPOINT's qw qx qy qz
  Eigen::MatrixXd points;
  Eigen::VectorXd intensities;
  std::size_t non_finite = 0;  // points dropped because a coordinate or the intensity was not finite
};

inline PcdCloud read_pcd(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  if (!f) throw std::runtime_error("cannot open " + path);
  std::vector<std::string> fields;
  std::vector<int> sizes, counts;
  std::vector<char> types;
  long long points = -1, width = -1, height = 1;
  std::vector<double> viewpoint;
  std::string data;
  std::string line;
  while (data.empty() && std::getline(f, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty() || line[0] == '#') continue;
    std::istringstream ls(line);
    std::string key;
    ls >> key;
    if (key == "FIELDS") {
      for (std::string t; ls >> t;) fields.push_back(t);
    } else if (key == "SIZE") {
      for (int t; ls >> t;) sizes.push_back(t);
    } else if (key == "TYPE") {
      for (std::string t; ls >> t;) types.push_back(t.empty() ? '?' : t[0]);
    } else if (key == "COUNT") {
      for (int t; ls >> t;) counts.push_back(t);
    } else if (key == "WIDTH") {
      ls >> width;
    } else if (key == "HEIGHT") {
      ls >> height;
    } else if (key == "POINTS") {
      ls >> points;
    } else if (key == "VIEWPOINT") {
      for (double t; ls >> t;) viewpoint.push_back(t);
    } else if (key == "DATA") {
      ls >> data;
    }
  }
  if (data.empty()) throw std::runtime_error(path + ": no DATA line in the PCD header");
  if (data != "binary") throw std::runtime_error(path + ": DATA " + data + " is not supported (binary only)");
  if (counts.empty()) counts.assign(fields.size(), 1);
  if (fields.empty() || sizes.size() != fields.size() || types.size() != fields.size() ||
      counts.size() != fields.size())
    throw std::runtime_error(path + ": FIELDS, SIZE, TYPE and COUNT disagree in length");
  if (points < 0) points = width * height;
  if (points < 0) throw std::runtime_error(path + ": neither POINTS nor WIDTH/HEIGHT given");

  std::size_t stride = 0;
  int offset[4] = {-1, -1, -1, -1};
  const char* wanted[4] = {"x", "y", "z", "intensity"};
  for (std::size_t i = 0; i < fields.size(); ++i) {
    for (int k = 0; k < 4; ++k) {
      if (fields[i] == wanted[k]) {
        if (types[i] != 'F' || sizes[i] != 4 || counts[i] != 1)
          throw std::runtime_error(path + ": field " + fields[i] + " is not a single float32");
        offset[k] = static_cast<int>(stride);
      }
    }
    stride += static_cast<std::size_t>(sizes[i]) * static_cast<std::size_t>(counts[i]);
  }
  for (int k = 0; k < 4; ++k)
    if (offset[k] < 0) throw std::runtime_error(path + ": no field '" + wanted[k] + "'");

  std::vector<unsigned char> raw(static_cast<std::size_t>(points) * stride);
  f.read(reinterpret_cast<char*>(raw.data()), static_cast<std::streamsize>(raw.size()));
  if (static_cast<std::size_t>(f.gcount()) != raw.size())
    throw std::runtime_error(path + ": truncated binary data (" + std::to_string(f.gcount()) + " of " +
                             std::to_string(raw.size()) + " bytes)");

  PcdCloud c;
  if (viewpoint.size() >= 3) c.origin = Eigen::Vector3d(viewpoint[0], viewpoint[1], viewpoint[2]);
  if (viewpoint.size() >= 7)
    c.orientation = Eigen::Quaterniond(viewpoint[3], viewpoint[4], viewpoint[5], viewpoint[6]).normalized();
  c.points.resize(points, 3);
  c.intensities.resize(points);
  Eigen::Index n = 0;
  for (long long i = 0; i < points; ++i) {
    float v[4];
    for (int k = 0; k < 4; ++k)
      std::memcpy(&v[k], raw.data() + static_cast<std::size_t>(i) * stride + static_cast<std::size_t>(offset[k]),
                  sizeof(float));
    if (!(std::isfinite(v[0]) && std::isfinite(v[1]) && std::isfinite(v[2]) && std::isfinite(v[3]))) {
      ++c.non_finite;
      continue;
    }
    c.points.row(n) << v[0], v[1], v[2];
    c.intensities(n) = v[3];
    ++n;
  }
  c.points.conservativeResize(n, 3);
  c.intensities.conservativeResize(n);
  return c;
}

}  // namespace iwlomap::bench
