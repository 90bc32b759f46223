// SPDX-License-Identifier: BSD-3-Clause
// `iwlomap info`: what a cloud file holds.

#include "args.h"
#include "cloud_io.h"
#include "commands.h"

#include <cmath>
#include <iostream>
#include <limits>

namespace iwlomap::tool {

namespace {
const char* kHelp = R"(usage: iwlomap info FILE...

Describes each FILE: for a .pcd or .ply cloud, the number of points (and of non-finite ones),
the organisation, the bounding box in metres, the intensity range and the sensor origin.
)";
}  // namespace

int run_info(const std::vector<std::string>& argv) {
  const Args args(argv, {}, {"-h", "--help"});
  if (args.flag("-h") || args.flag("--help")) {
    std::cout << kHelp;
    return 0;
  }
  if (args.positional().empty()) throw UsageError("no file given");
  for (const std::string& path : args.positional()) {
    const LoadedCloud in = load_cloud(path, std::numeric_limits<float>::quiet_NaN());
    const auto& c = *in.cloud;
    Eigen::Vector3f lo = Eigen::Vector3f::Constant(std::numeric_limits<float>::max()), hi = -lo;
    float imin = std::numeric_limits<float>::max(), imax = -imin;
    std::size_t finite = 0;
    for (const auto& p : c) {
      const Eigen::Vector3f v(p.x, p.y, p.z);
      if (!v.allFinite()) continue;
      ++finite;
      lo = lo.cwiseMin(v);
      hi = hi.cwiseMax(v);
      if (std::isfinite(p.intensity)) {
        imin = std::min(imin, p.intensity);
        imax = std::max(imax, p.intensity);
      }
    }
    std::cout << path << ": cloud, " << c.size() << " points (" << c.size() - finite << " non-finite), "
              << (c.height > 1 ? "organised " + std::to_string(c.width) + " x " + std::to_string(c.height)
                               : std::string("unorganised"))
              << "\n";
    if (finite > 0)
      std::cout << "  bounds (m): x [" << lo.x() << ", " << hi.x() << "] y [" << lo.y() << ", " << hi.y() << "] z ["
                << lo.z() << ", " << hi.z() << "]\n";
    if (!in.has_intensity)
      std::cout << "  intensity: none (the map tool uses --intensity-max for every point)\n";
    else if (imin <= imax)
      std::cout << "  intensity: [" << imin << ", " << imax << "]\n";
    const auto& o = c.sensor_origin_;
    const auto& q = c.sensor_orientation_;
    std::cout << "  sensor origin (m): (" << o.x() << ", " << o.y() << ", " << o.z() << "), orientation (w x y z): ("
              << q.w() << ", " << q.x() << ", " << q.y() << ", " << q.z() << ")\n";
  }
  return 0;
}

}  // namespace iwlomap::tool
