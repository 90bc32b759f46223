// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/trajectory_io.h"

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <sstream>
#include <stdexcept>

namespace iwlomap {

TrajectoryFormat trajectory_format_of(const std::string& path) {
  const std::string ext = ".kitti";
  return path.size() >= ext.size() && path.compare(path.size() - ext.size(), ext.size(), ext) == 0
             ? TrajectoryFormat::kKitti
             : TrajectoryFormat::kTum;
}

void write_trajectory(const std::string& path, const std::vector<Eigen::Isometry3d>& poses,
                      const std::vector<double>& stamps, TrajectoryFormat format) {
  if (!stamps.empty() && stamps.size() != poses.size())
    throw std::invalid_argument("iwlomap: write_trajectory: " + std::to_string(stamps.size()) + " stamps for " +
                                std::to_string(poses.size()) + " poses");
  const std::string tmp = path + ".partial";
  std::FILE* f = std::fopen(tmp.c_str(), "w");
  if (!f) throw std::runtime_error("cannot write " + path + ": " + std::strerror(errno));
  bool ok = true;
  for (std::size_t i = 0; i < poses.size() && ok; ++i) {
    const Eigen::Isometry3d& p = poses[i];
    if (format == TrajectoryFormat::kTum) {
      const Eigen::Quaterniond q(p.linear());
      const double t = stamps.empty() ? static_cast<double>(i) : stamps[i];
      ok = std::fprintf(f, "%.9f %.9f %.9f %.9f %.9f %.9f %.9f %.9f\n", t, p.translation().x(), p.translation().y(),
                        p.translation().z(), q.x(), q.y(), q.z(), q.w()) > 0;
    } else {
      const Eigen::Matrix4d m = p.matrix();
      ok = std::fprintf(f, "%.9e %.9e %.9e %.9e %.9e %.9e %.9e %.9e %.9e %.9e %.9e %.9e\n", m(0, 0), m(0, 1), m(0, 2),
                        m(0, 3), m(1, 0), m(1, 1), m(1, 2), m(1, 3), m(2, 0), m(2, 1), m(2, 2), m(2, 3)) > 0;
    }
  }
  ok = std::fflush(f) == 0 && ok;
  ok = std::fclose(f) == 0 && ok;
  if (!ok || std::rename(tmp.c_str(), path.c_str()) != 0) {
    const std::string why = std::strerror(errno);
    std::remove(tmp.c_str());
    throw std::runtime_error("cannot write " + path + ": " + why);
  }
}

std::vector<Eigen::Isometry3d> read_trajectory(const std::string& path, TrajectoryFormat format,
                                               std::vector<double>* stamps) {
  std::ifstream in(path);
  if (!in) throw std::runtime_error("cannot read " + path + ": " + std::strerror(errno));
  std::vector<Eigen::Isometry3d> poses;
  if (stamps) stamps->clear();
  std::string line;
  for (std::size_t number = 1; std::getline(in, line); ++number) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream s(line);
    double v[12];
    const int want = format == TrajectoryFormat::kTum ? 8 : 12;
    int got = 0;
    while (got < want && s >> v[got]) ++got;
    std::string rest;
    if (got != want || (s >> rest))
      throw std::runtime_error(path + ":" + std::to_string(number) + ": expected " + std::to_string(want) +
                               " numbers");
    Eigen::Isometry3d p = Eigen::Isometry3d::Identity();
    if (format == TrajectoryFormat::kTum) {
      const Eigen::Quaterniond q(v[7], v[4], v[5], v[6]);
      if (!(q.norm() > 0.5)) throw std::runtime_error(path + ":" + std::to_string(number) + ": not a unit quaternion");
      p.linear() = q.normalized().toRotationMatrix();
      p.translation() = Eigen::Vector3d(v[1], v[2], v[3]);
      if (stamps) stamps->push_back(v[0]);
    } else {
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 4; ++c) p.matrix()(r, c) = v[4 * r + c];
    }
    poses.push_back(p);
  }
  return poses;
}

}  // namespace iwlomap
