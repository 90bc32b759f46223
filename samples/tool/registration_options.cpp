// SPDX-License-Identifier: BSD-3-Clause
#include "registration_options.h"

#include <cmath>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace iwlomap::tool {

namespace {
constexpr double kDeg = 3.14159265358979323846 / 180.0;
}

std::set<std::string> registration_value_options() { return {"--window", "--min-score", "--max-distance"}; }
std::set<std::string> registration_flag_options() { return {"--no-coarse", "--no-fine"}; }

const char* registration_options_help() {
  return R"(registration:
  --window XY,Z,YAW         the coarse search window each way: metres in x and y, metres in z,
                            degrees of yaw (default 1,0.5,10)
  --min-score S             the coarse pose must score at least S in [0, 1] (default 0.3)
  --max-distance M          ICP pairs a scan point with map points within M metres (default 0.5)
  --no-coarse               ICP only, from the initial pose
  --no-fine                 branch and bound only (to within a voxel and a yaw step)
)";
}

registration::ScanMatcherOptions registration_options_from(const Args& args) {
  registration::ScanMatcherOptions o;
  if (const auto w = args.value("--window")) {
    const auto v = parse_list("--window", *w, 3);
    o.window.linear_xy = v[0];
    o.window.linear_z = v[1];
    o.window.angular_yaw = v[2] * kDeg;
  }
  if (const auto s = args.number("--min-score")) o.min_coarse_score = *s;
  if (const auto d = args.number("--max-distance")) o.icp.max_correspondence_distance = *d;
  o.coarse = !args.flag("--no-coarse");
  o.fine = !args.flag("--no-fine");
  try {
    o.validate();
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    throw UsageError(what.rfind("iwlomap: ", 0) == 0 ? what.substr(9) : what);
  }
  return o;
}

Eigen::Isometry3d pose_from_text(const std::string& option, const std::string& text) {
  std::stringstream ss(text);
  std::vector<double> v;
  for (std::string item; ss >> item;) v.push_back(parse_list(option, item, 1)[0]);
  if (v.size() != 6)
    throw UsageError(option + " needs \"X Y Z ROLL PITCH YAW\" (metres, degrees), got '" + text + "'");
  Eigen::Isometry3d pose = Eigen::Isometry3d::Identity();
  pose.linear() = (Eigen::AngleAxisd(v[5] * kDeg, Eigen::Vector3d::UnitZ()) *
                   Eigen::AngleAxisd(v[4] * kDeg, Eigen::Vector3d::UnitY()) *
                   Eigen::AngleAxisd(v[3] * kDeg, Eigen::Vector3d::UnitX()))
                      .toRotationMatrix();
  pose.translation() = Eigen::Vector3d(v[0], v[1], v[2]);
  return pose;
}

}  // namespace iwlomap::tool
